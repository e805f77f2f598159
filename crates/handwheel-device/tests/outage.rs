//! Feed records across a blocked bus: motion reaches the axis it was turned on, exactly, or
//! (when a selection's records had to be dropped) no axis; never another axis.

mod common;

use common::*;
use handwheel_core::{Axis, FeedRecord, FeedStatus, Multiplier, HELD_EPOCHS};
use proptest::prelude::*;

/// The firmware's transmit queue (16 frames) plus bxCAN's three mailboxes.
const QUEUE: usize = 19;

/// What a host following the README's rule credits to each axis (index = axis byte 1..5):
/// the wrapping difference of two consecutive records goes to the newer record's axis when
/// both belong to the same epoch (at most 6 records missing in between) or to consecutive
/// epochs with none missing; anything else is a new baseline.
fn host_counts(records: &[Seen]) -> [i64; 6] {
    let mut counts = [0i64; 6];
    let mut prev: Option<FeedRecord> = None;
    for r in records.iter().filter(|s| s.id == TPDO1).map(feed_record) {
        if let Some(p) = prev {
            let gap = r.sequence.wrapping_sub(p.sequence).wrapping_sub(1);
            let epochs = r.state.epoch.wrapping_sub(p.state.epoch) & 7;
            let continuous = (epochs == 0 && gap <= 6) || (epochs == 1 && gap == 0);
            if continuous && r.state.status.contains(FeedStatus::ENABLED) {
                let delta = r.state.position.wrapping_sub(p.state.position);
                counts[usize::from(Axis::option_value(r.state.axis))] += i64::from(delta);
            }
        }
        prev = Some(r);
    }
    counts
}

/// Turns `detents` one at a time, 3 ms apart (longer than the 2 ms inhibit time, so that
/// every detent is a record of its own while the bus takes them).
fn turn_slowly(b: &mut Bench, detents: i32) {
    for _ in 0..detents.unsigned_abs() {
        b.turn(detents.signum());
        b.advance_ms(3);
    }
}

/// A record at position 0 for the host to start from (the event timer sends one).
fn baseline(axis: Axis) -> Bench {
    let mut b = Bench::operational_enabled(axis, Multiplier::X1);
    b.advance_ms(100);
    b
}

#[test]
fn a_turn_on_y_during_an_outage_reaches_y_not_x() {
    let mut b = baseline(Axis::X);
    b.block_bus(QUEUE);
    // About 90 ms of turning: more records than the queue holds.
    turn_slowly(&mut b, 30);
    b.select(Some(Axis::Y), Multiplier::X1);
    turn_slowly(&mut b, 7);
    b.select(Some(Axis::X), Multiplier::X1);
    turn_slowly(&mut b, 2);
    b.unblock_bus();
    b.advance_ms(50);
    let seen = b.take();
    let counts = host_counts(&seen);
    assert_eq!(
        (counts[1], counts[2]),
        (32, 7),
        "X and Y each get their own turn"
    );
    // The closing records: X's final 30, then Y's final 37, in that order, and the
    // sequence shows no gap (nothing was dropped).
    let records: Vec<_> = seen
        .iter()
        .filter(|s| s.id == TPDO1)
        .map(|s| (record(s), record_epoch(s)))
        .collect();
    let y_at = records
        .iter()
        .position(|(r, _)| r.1 == 2)
        .expect("a record names Y");
    assert_eq!(records[y_at - 1].0 .0, 30, "X's final position before Y");
    assert_eq!(records[y_at].0 .0, 37, "Y's final position");
    assert_eq!(
        records[y_at].1,
        (records[y_at - 1].1 + 1) & 7,
        "the next epoch"
    );
    for pair in records.windows(2) {
        assert_eq!(pair[1].0 .4, pair[0].0 .4.wrapping_add(1), "no gap");
    }
}

#[test]
fn more_changes_than_the_outbox_holds_drop_the_oldest_to_no_axis() {
    let mut b = baseline(Axis::X);
    b.block_bus(QUEUE);
    turn_slowly(&mut b, 25);
    // Flip between Y and Z, one detent each, more often than the outbox holds epochs.
    let flips = HELD_EPOCHS + 4;
    for i in 0..flips {
        let axis = if i % 2 == 0 { Axis::Y } else { Axis::Z };
        b.select(Some(axis), Multiplier::X1);
        turn_slowly(&mut b, 1);
    }
    b.select(Some(Axis::X), Multiplier::X1);
    turn_slowly(&mut b, 2);
    b.unblock_bus();
    b.advance_ms(100);
    let seen = b.take();
    let counts = host_counts(&seen);
    let truth = [0, 27, flips as i64 / 2, flips as i64 / 2, 0, 0];
    for axis in 1..=5 {
        assert!(
            counts[axis] <= truth[axis],
            "axis {axis}: host {} > truth {}",
            counts[axis],
            truth[axis]
        );
    }
    assert!(
        counts[2] + counts[3] < truth[2] + truth[3],
        "some epochs dropped"
    );
    // The queue's 19 records carry X to 19; X's final 25 went with the oldest held epochs;
    // after the gap the host starts afresh, and X's last epoch adds its 2.
    assert_eq!(
        counts[1],
        QUEUE as i64 + 2,
        "X: what the queue took, and X after"
    );
    let records: Vec<_> = seen.iter().filter(|s| s.id == TPDO1).map(record).collect();
    assert!(
        records.windows(2).any(|p| p[1].4.wrapping_sub(p[0].4) > 1),
        "the drop shows as a sequence gap"
    );
}

#[test]
fn leaving_operational_with_unsent_motion_breaks_continuity() {
    let mut b = baseline(Axis::X);
    b.block_bus(QUEUE);
    turn_slowly(&mut b, 25);
    b.unblock_bus();
    // The last detents may still wait for the inhibit time when the master stops the node.
    b.turn(3);
    b.nmt(0x80);
    b.select(Some(Axis::Y), Multiplier::X1);
    b.nmt(0x01);
    b.sdo_write(0x2000, 0, &[1]).unwrap();
    turn_slowly(&mut b, 4);
    b.advance_ms(20);
    let counts = host_counts(&b.take());
    assert_eq!(counts[2], 4, "Y gets its own turn");
    assert!(
        counts[1] <= 28,
        "X never more than it was turned: {}",
        counts[1]
    );
}

#[derive(Clone, Debug)]
enum Act {
    Turn(u8),
    Select(u8, u8),
    Block,
    Unblock,
    Toggle,
    Wait(u8),
}

fn act() -> impl Strategy<Value = Act> {
    prop_oneof![
        4 => (1u8..6).prop_map(Act::Turn),
        2 => (0u8..6, 0u8..3).prop_map(|(a, m)| Act::Select(a, m)),
        1 => Just(Act::Block),
        1 => Just(Act::Unblock),
        1 => Just(Act::Toggle),
        1 => (1u8..30).prop_map(Act::Wait),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(200))]

    /// Whatever the operator does while the bus comes and goes, each axis gets at most what
    /// was turned on it (all turning is forward), and exactly that when the stream shows no
    /// gap.
    #[test]
    fn motion_never_reaches_another_axis(acts in prop::collection::vec(act(), 1..60)) {
        let mut b = baseline(Axis::X);
        let mut truth = [0i64; 6];
        let (mut axis, mut factor, mut enabled) = (1usize, 1i64, true);
        for a in acts {
            match a {
                Act::Turn(n) => {
                    if enabled {
                        truth[axis] += i64::from(n) * factor;
                    }
                    turn_slowly(&mut b, i32::from(n));
                }
                Act::Select(ax, m) => {
                    let (mult, f) = [(Multiplier::X1, 1), (Multiplier::X10, 10), (Multiplier::X100, 100)][usize::from(m)];
                    axis = usize::from(ax);
                    factor = f;
                    b.select(Axis::from_object_value(ax), mult);
                }
                Act::Block => {
                    if b.blocked.is_none() {
                        b.block_bus(QUEUE);
                    }
                }
                Act::Unblock => b.unblock_bus(),
                Act::Toggle => {
                    // An SDO needs the bus: only while it is free.
                    if b.blocked.is_none() {
                        enabled = !enabled;
                        b.sdo_write(0x2000, 0, &[u8::from(enabled)]).unwrap();
                    }
                }
                Act::Wait(ms) => b.advance_ms(u64::from(ms)),
            }
        }
        b.unblock_bus();
        b.advance_ms(200);
        let seen = b.take();
        let counts = host_counts(&seen);
        let records: Vec<_> = seen.iter().filter(|s| s.id == TPDO1).map(record).collect();
        let gapless = records.windows(2).all(|p| p[1].4 == p[0].4.wrapping_add(1));
        for ax in 1..=5 {
            prop_assert!(counts[ax] <= truth[ax], "axis {}: host {} truth {}", ax, counts[ax], truth[ax]);
            if gapless {
                prop_assert_eq!(counts[ax], truth[ax], "axis {}", ax);
            }
        }
    }
}
