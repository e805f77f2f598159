//! The settings the checker explores: each a set of budgets small enough to exhaust, chosen
//! to reach one kind of trouble (full queues and outbox, wrap-around, resets, channel faults,
//! time) in few steps.

use crate::host::RuleConfig;
use crate::model::Bounds;

const fn rule(sequence_bits: u8, epoch_bits: u8) -> RuleConfig {
    RuleConfig {
        sequence_bits,
        epoch_bits,
        ..RuleConfig::shipped(100)
    }
}

const BASE: Bounds = Bounds {
    name: "",
    rule: rule(8, 3),
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
    replay_depth: 0,
    host_stalls: 0,
    master_beats: 0,
    consumer_ms: 250,
    late_ms: 500,
    warmups: &[],
};

/// What `cargo xtask test` explores.
pub const ALL: &[Bounds] = &[
    // Stops, starts and selection changes while the transmit path is full: the epoch field
    // lowered to 2 bits, so that 4 unseen epochs bring it round.
    Bounds {
        name: "nmt and outbox",
        rule: rule(8, 2),
        transmit_capacity: 1,
        turns: 2,
        switches: 2,
        feed_writes: 1,
        nmt: 2,
        ..BASE
    },
    // Resets and power cycles with the sequence lowered to 5 bits (the smallest width in
    // which a break of 8 still reads as a gap), from where it is about to wrap.
    Bounds {
        name: "resets and wrap",
        rule: rule(5, 3),
        transmit_capacity: 1,
        turns: 1,
        feed_writes: 1,
        nmt: 2,
        power_cycles: 1,
        warmups: &[25, 26, 27, 28, 29, 30, 31],
        ..BASE
    },
    // Lost, doubled and replayed frames.
    Bounds {
        name: "channel faults",
        transmit_capacity: 2,
        turns: 2,
        switches: 1,
        feed_writes: 1,
        nmt: 1,
        channel_faults: 2,
        replay_depth: 3,
        ..BASE
    },
    // Time: holds longer than the stall limit, event-timer records, staleness, a host that
    // stalls and reads a backlog.
    Bounds {
        name: "time and stalls",
        turns: 2,
        switches: 1,
        ticks: 6,
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
