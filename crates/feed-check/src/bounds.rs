//! The settings the checker explores: each a set of budgets small enough to exhaust, chosen
//! to reach one kind of trouble (full queues and outbox, wrap-around, resets, channel faults,
//! time) in few steps.

use handwheel_core::SequencePace;

use crate::host::RuleConfig;
use crate::model::Bounds;

/// The shipped rule with the epoch field lowered.
const fn rule(epoch_bits: u8) -> RuleConfig {
    RuleConfig {
        epoch_bits,
        ..RuleConfig::shipped(100)
    }
}

/// The narrowed device pace: 12 numbers at once (a break of 8 and its record fit, as in the
/// shipped 64), one per 10 ms.
const NARROW_PACE: SequencePace = SequencePace {
    burst: 12,
    us_per_number: 10_000,
};

/// The rule narrowed with the sequence: 7 bits (a wrap is 128 numbers), the pace above, 10 ms
/// in transit, an order window of 150 ms and copies up to 800 ms old: the same relation as
/// the shipped values (`RuleConfig::holds`: max_ahead(150 ms) = 28, an 800 ms old copy at
/// most 92 behind, 28 + 92 < 128), reached in about a hundred records instead of 65 536.
const fn narrow(epoch_bits: u8) -> RuleConfig {
    RuleConfig {
        sequence_bits: 7,
        epoch_bits,
        burst: NARROW_PACE.burst as u64,
        us_per_number: NARROW_PACE.us_per_number as u64,
        in_transit_us: 10_000,
        order_window_us: 150_000,
        copy_age_us: 800_000,
        ..RuleConfig::shipped(50)
    }
}

const BASE: Bounds = Bounds {
    name: "",
    rule: rule(3),
    transmit_capacity: 3,
    turns: 0,
    switches: 0,
    feed_writes: 0,
    nmt: 0,
    power_cycles: 0,
    ticks: 0,
    tick_ms: 50,
    event_timer_ms: 100,
    inhibit_100us: 0,
    channel_faults: 0,
    copy_depth: 0,
    copy_age_ms: 0,
    pace: SequencePace::SHIPPED,
    configures: 0,
    host_stalls: 0,
    master_beats: 0,
    consumer_ms: 250,
    late_ms: 500,
    warmups: &[],
};

/// The narrowed sequence and pace, their 50 ms event timer and tick, and copies of any
/// record of the narrowed contract's age (800 ms).
const NARROW: Bounds = Bounds {
    rule: narrow(3),
    pace: NARROW_PACE,
    event_timer_ms: 50,
    tick_ms: 50,
    // The pace allows at most 800 / 10 + 12 = 92 records in 800 ms: every one can be copied.
    copy_depth: 92,
    copy_age_ms: 800,
    ..BASE
};

/// What `cargo xtask test` explores.
pub const ALL: &[Bounds] = &[
    // Stops, starts and selection changes while the transmit path is full: the epoch field
    // lowered to 2 bits, so that 4 unseen epochs bring it round.
    Bounds {
        name: "nmt and outbox",
        rule: rule(2),
        transmit_capacity: 1,
        turns: 2,
        switches: 2,
        feed_writes: 1,
        nmt: 2,
        ..BASE
    },
    // Resets and power cycles with the sequence and its pace narrowed, from where it is about
    // to wrap.
    Bounds {
        name: "resets and wrap",
        transmit_capacity: 1,
        turns: 1,
        feed_writes: 1,
        nmt: 2,
        power_cycles: 1,
        configures: 1,
        warmups: &[121, 123, 125, 127],
        copy_depth: 0,
        ..NARROW
    },
    // Lost and doubled frames and copies of any record of the contract's age, with the
    // sequence narrowed and started near its wrap.
    Bounds {
        name: "copies of any age",
        transmit_capacity: 2,
        turns: 1,
        switches: 1,
        ticks: 1,
        channel_faults: 2,
        warmups: &[80, 124],
        ..NARROW
    },
    // A power cycle whose boot-up may be lost, copies of records from before it, and the
    // host configuring again when its rule asks.
    Bounds {
        name: "power cycles and copies",
        transmit_capacity: 2,
        turns: 1,
        feed_writes: 1,
        power_cycles: 1,
        channel_faults: 2,
        configures: 1,
        warmups: &[60],
        ..NARROW
    },
    // Time: holds longer than the stall limit, event-timer records, staleness, a host that
    // stalls and reads a backlog.
    Bounds {
        name: "time and stalls",
        turns: 2,
        switches: 1,
        ticks: 4,
        tick_ms: 100,
        host_stalls: 1,
        ..BASE
    },
    // The master's heartbeat lost and back (consumer time 250 ms), re-enabling after it.
    Bounds {
        name: "master loss",
        turns: 1,
        feed_writes: 1,
        ticks: 5,
        tick_ms: 100,
        master_beats: 1,
        ..BASE
    },
    // The shipped widths, inhibit time and transmit path (16 queued + 3 mailboxes).
    Bounds {
        name: "shipped sizes",
        transmit_capacity: 19,
        inhibit_100us: 20,
        turns: 2,
        switches: 2,
        feed_writes: 1,
        nmt: 2,
        ..BASE
    },
];
