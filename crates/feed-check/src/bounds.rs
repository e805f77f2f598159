//! The settings the checker explores: each a set of budgets small enough to exhaust, chosen
//! to reach one kind of trouble (full queues and outbox, wrap-around, resets, channel faults,
//! time) in few steps.

use handwheel_core::SequencePace;

use crate::host::RuleConfig;
use crate::model::{Bounds, Warm};

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
    mailboxes: 0,
    turns: 0,
    backward: false,
    inner_turns: 0,
    inner_locks: 0,
    switches: 0,
    multipliers: 0,
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
    settles: 0,
    holds: 0,
    token_writes: 0,
    foreign_writes: 0,
    foreign: &[],
    warmups: &[],
    mutant: None,
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

/// Another master writes the host's own token after a power cycle whose boot-up the host
/// missed (in [`COPIES_AND_POWER_CYCLES`]).
const TOKEN_WRITTEN_AGAIN: Bounds = Bounds {
    name: "token written again after an unseen power cycle",
    rule: RuleConfig {
        dating: true,
        ..narrow(3)
    },
    transmit_capacity: 2,
    turns: 1,
    feed_writes: 1,
    nmt: 1,
    power_cycles: 1,
    channel_faults: 1,
    token_writes: 1,
    warmups: &[&[Warm::Turns(125)]],
    copy_depth: 0,
    ..NARROW
};

/// `bounds` at the shipped widths, pace, event timer, copy age and token count, its dating as
/// it has it: the component's rule exactly as `core.py` runs it, for the vectors' random
/// walks through the narrowed settings (power cycles, copies, resets, reconfigurations).
pub const fn at_shipped_widths(bounds: &Bounds) -> Bounds {
    Bounds {
        rule: RuleConfig {
            dating: bounds.rule.dating,
            ..RuleConfig::shipped(100)
        },
        pace: SequencePace::SHIPPED,
        event_timer_ms: 100,
        copy_age_ms: 60_000,
        ..*bounds
    }
}

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
        // At x100 (the switch's position survives resets).
        warmups: &[
            &[Warm::Multiplier, Warm::Multiplier, Warm::Turns(121)],
            &[Warm::Multiplier, Warm::Multiplier, Warm::Turns(123)],
            &[Warm::Multiplier, Warm::Multiplier, Warm::Turns(125)],
            &[Warm::Multiplier, Warm::Multiplier, Warm::Turns(127)],
        ],
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
        warmups: &[&[Warm::Turns(80)], &[Warm::Turns(124)]],
        ..NARROW
    },
    // The one record of an epoch lost between two others: with a record waiting, the axis
    // switched, a detent turned, the axis switched again, so that the middle epoch's only
    // record (its final state) is the one the channel loses. Its motion must not be taken
    // as the next epoch's, whose record follows the lost one without a gap in the epochs
    // the host can tell.
    Bounds {
        name: "an epoch lost between two",
        transmit_capacity: 1,
        turns: 1,
        switches: 2,
        channel_faults: 1,
        warmups: &[&[Warm::Turns(80), Warm::Held(1)]],
        copy_depth: 0,
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
        warmups: &[&[Warm::Turns(60)]],
        ..NARROW
    },
    // Time: holds longer than the stall limit, event-timer records, staleness, a host that
    // stalls and reads a backlog.
    Bounds {
        name: "time and stalls",
        turns: 1,
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
        ticks: 4,
        tick_ms: 100,
        master_beats: 1,
        ..BASE
    },
    // The shipped widths, inhibit time and transmit path (16 queued + 3 mailboxes, which
    // the bus empties by identifier).
    Bounds {
        name: "shipped sizes",
        transmit_capacity: 19,
        mailboxes: 3,
        inhibit_100us: 20,
        turns: 2,
        switches: 2,
        feed_writes: 1,
        nmt: 2,
        ..BASE
    },
    // NMT commands and time: what the outbox held at a stop would go out after the next
    // start, late (a tick longer than the bound).
    Bounds {
        name: "nmt and time",
        transmit_capacity: 1,
        turns: 3,
        switches: 1,
        nmt: 2,
        ticks: 1,
        tick_ms: 600,
        ..BASE
    },
    // A detent lands inside a round: at any of the CAN side's accesses to the wheel while
    // the device answers a frame, builds a record or sends one.
    Bounds {
        name: "edges in a round",
        transmit_capacity: 2,
        mailboxes: 1,
        turns: 2,
        inner_turns: 1,
        inner_locks: 16,
        switches: 1,
        feed_writes: 1,
        nmt: 1,
        ..BASE
    },
    // A bus that takes a frame now and then (one per 95 ms tick) while six records wait: the
    // path never runs empty, so the stall watch trips 100 ms after it last was (before its
    // fix it counted from the last frame that got out, and the last records came late).
    Bounds {
        name: "trickling bus",
        transmit_capacity: 8,
        ticks: 7,
        tick_ms: 95,
        warmups: &[&[Warm::Held(6)]],
        ..BASE
    },
    // A path between the bus and the host (a gateway) holds the device's frames, and the
    // answers to the host's probes, for longer than the bound (six 100 ms ticks) while the
    // wheel turns, then releases them at once: the host's receive path never backs up, so
    // only the dating (the sequence probe, one per 100 ms) keeps the motion they carry from
    // being credited late. A frame lost on its way leaves a gap that the date must not skip.
    Bounds {
        name: "gateway hold",
        rule: RuleConfig {
            dating: true,
            ..rule(3)
        },
        turns: 3,
        ticks: 6,
        tick_ms: 100,
        channel_faults: 1,
        holds: 1,
        event_timer_ms: 0,
        ..BASE
    },
    // Another master writes an object the host's session stands for (a heartbeat consumer
    // entry, TPDO1's event timer, the encoder's direction or counts per detent) while the
    // host holds it: the session must end, or the host credits motion under the other
    // master's settings. The host configures again after it.
    Bounds {
        name: "foreign writes",
        turns: 2,
        backward: true,
        foreign_writes: 1,
        configures: 1,
        ..BASE
    },
    // The host's tokens used up: one token only, so that every configuration after its
    // session ended (a reset of the node: the same power life; a power cycle: a new one, its
    // boot-up seen or lost) must write it again within the contract's age, proven by the
    // device's uptime (0x2035) or not at all; copies of any record, the old life's included,
    // with the narrowed sequence near its wrap, so that the new life's first numbers follow
    // the old life's last ones. A tick of half a second lets the new life grow old enough
    // for a session within the copy age.
    Bounds {
        name: "tokens reused",
        rule: RuleConfig {
            dating: true,
            tokens: 1,
            ..narrow(3)
        },
        transmit_capacity: 2,
        turns: 1,
        feed_writes: 1,
        nmt: 1,
        power_cycles: 1,
        channel_faults: 1,
        configures: 2,
        ticks: 1,
        tick_ms: 500,
        warmups: &[&[Warm::Turns(124)], &[Warm::Turns(125)]],
        ..NARROW
    },
    // The pace narrowed to 10 numbers at once (a break of 8 and its record fit), one per 50 ms: thirteen detents in quick
    // succession outrun it, which must end the session.
    Bounds {
        name: "pace outrun",
        rule: RuleConfig {
            burst: 10,
            us_per_number: 50_000,
            ..rule(3)
        },
        pace: SequencePace {
            burst: 10,
            us_per_number: 50_000,
        },
        transmit_capacity: 2,
        turns: 13,
        ..BASE
    },
];

/// What found old copies and power cycles breaching the contract on the code before feed
/// record v2 (there with the sequence lowered to 5 bits and copies of any age: an old copy
/// moving the axis backwards, a Y record seven epochs old moving Y while X was selected, a
/// dead wheel after a quick power cycle, the first record after an unseen power cycle linked
/// to the last one before it), with the narrowed v2 sequence, its pace and copies of the
/// contract's age: no breach now. `cargo xtask feed-check` runs them after [`ALL`], optimised
/// on two threads (as a test they took over a minute).
pub const COPIES_AND_POWER_CYCLES: &[Bounds] = &[
    // Before v2: a copy of a record as old as the sequence's wrap read as one a few ahead.
    // The wheel turned at x100 and back, copies of any record of the contract's age.
    Bounds {
        name: "copies at the wrap",
        turns: 1,
        backward: true,
        multipliers: 1,
        channel_faults: 1,
        warmups: &[&[Warm::Multiplier, Warm::Multiplier, Warm::Turns(124)]],
        ..NARROW
    },
    // Before v2: a Y record seven epochs old, copied while X is selected, read as "the
    // previous epoch's final record". The Y records are about as old as the contract allows
    // copies to be when the exploration starts.
    Bounds {
        name: "copies across epochs",
        turns: 1,
        switches: 1,
        channel_faults: 1,
        warmups: &[&[
            Warm::Switch,
            Warm::Turns(3),
            Warm::Switch,
            Warm::Switch,
            Warm::Switch,
            Warm::Switch,
            Warm::Switch,
            Warm::Switch,
            Warm::Switch,
            Warm::Turns(56),
        ]],
        ..NARROW
    },
    // Before v2: a quick power cycle, its boot-up seen: the records after it started at 0
    // again, which read as behind the last one before it, and nothing was credited though
    // no record was missing.
    Bounds {
        name: "power cycle seen",
        turns: 1,
        feed_writes: 1,
        nmt: 1,
        power_cycles: 1,
        configures: 1,
        settles: 1,
        warmups: &[&[Warm::Turns(4)], &[Warm::Turns(100)]],
        copy_depth: 0,
        ..NARROW
    },
    // Copies and power cycles together, near the wrap: NMT from any node, a power cycle
    // (its boot-up lost or not), a lost or doubled frame or a copy, time settling, turns both
    // ways. One FIFO: with bxCAN's mailboxes the boot-up of a power cycle can be overtaken
    // (`UNFILED`, "boot-up overtaken").
    Bounds {
        name: "nmt, power cycle, copies",
        transmit_capacity: 2,
        mailboxes: 0,
        turns: 1,
        backward: true,
        feed_writes: 1,
        nmt: 1,
        power_cycles: 1,
        channel_faults: 1,
        configures: 1,
        settles: 1,
        warmups: &[&[Warm::Turns(118)]],
        ..NARROW
    },
    // NMT and time with copies: stops and starts around the wrap, held epochs, event-timer
    // records, a copy of any of them.
    Bounds {
        name: "nmt, time and copies",
        transmit_capacity: 1,
        turns: 1,
        switches: 1,
        nmt: 2,
        ticks: 1,
        tick_ms: 300,
        channel_faults: 1,
        warmups: &[&[Warm::Turns(122)]],
        ..NARROW
    },
    // Before v2: a power cycle whose boot-up the host never sees (the channel loses it), an
    // NMT start from another node and an enable while the transmit path is full: the first
    // record of the new power-up linked to the last one before it.
    Bounds {
        name: "power cycle unseen",
        transmit_capacity: 1,
        feed_writes: 1,
        nmt: 1,
        power_cycles: 1,
        channel_faults: 1,
        configures: 1,
        warmups: &[&[Warm::Turns(100)], &[Warm::Turns(124)]],
        ..NARROW
    },
    // Before the session key and delay: another master writes the host's own token after a
    // power cycle whose boot-up the host missed, starts the node and enables the feed, and a
    // record of the new power life linked to the host's reference from the old one. The
    // host's dating on, as the component runs.
    TOKEN_WRITTEN_AGAIN,
    // The same, the device grown past the delay before a session opens (a tick of 0.5 s):
    // another master's token in the new life, with the host's dates from the old one
    // expired, still never makes the host's probes date the new life (the key).
    Bounds {
        name: "token written again, the device grown up",
        ticks: 1,
        tick_ms: 500,
        ..TOKEN_WRITTEN_AGAIN
    },
];

/// Breaches found on the way that no issue names yet (not in [`ALL`]; each breaches today).
pub const UNFILED: &[Bounds] = &[
    // A reset node right after a stop or another reset whose boot-up the host saw: the host
    // configures before the second boot-up reaches it (the bus held for it while bxCAN's mailboxes let
    // the answers, 0x590, and the records, 0x190, overtake it, 0x710). When it arrives the
    // host ends the session it just opened: what was turned meanwhile is never credited,
    // though no record was missing. Nothing wrong is credited.
    Bounds {
        name: "boot-up overtaken",
        transmit_capacity: 2,
        mailboxes: 1,
        turns: 1,
        feed_writes: 1,
        // Two resets of the node: after a power cycle no session opens for 0.5 s, by when
        // the boot-up has come.
        nmt: 2,
        configures: 1,
        settles: 1,
        ..NARROW
    },
];
