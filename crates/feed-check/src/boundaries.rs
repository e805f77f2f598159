//! Test vectors at the host rule's boundaries: short record streams with a limit of the rule
//! met exactly and missed by one (a number, a millisecond), what [`crate::host`] credits for
//! each, in the vectors' format. The model's random walks rarely land on a limit; these tie
//! `core.py` to the checked rule where an off-by-one or a rounding of time would part them.

use std::fmt::Write as _;

use handwheel_core::{Axis, FeedRecord, FeedState, FeedStatus, Multiplier};

use crate::host::{HostRule, RuleConfig};
use crate::model::NODE;

const TPDO1: u16 = 0x180 + NODE as u16;
/// The event timer the streams assume (the component's default): records older than three
/// periods are stale.
const EVENT_TIMER_MS: u64 = 100;
/// The first record's sequence number and time.
const FIRST_SEQUENCE: u16 = 100;
const FIRST_MS: u64 = 10;

/// One event of a stream.
#[derive(Clone, Copy, Debug)]
enum Event {
    /// A configuration at a time that found 0x2002 at this value.
    Configure(u8, u64),
    /// The host found its receive path empty.
    Drained(u64),
    /// A feed record of X at x1, feed enabled: position, sequence, epoch, session, time.
    Record(i32, u16, u8, u8, u64),
}

/// The record's bytes as the device encodes them (one layout: `handwheel_core`'s).
fn record_bytes(position: i32, sequence: u16, epoch: u8, session: u8) -> [u8; 8] {
    let state = FeedState {
        position,
        axis: Some(Axis::X),
        multiplier: Multiplier::X1,
        status: FeedStatus::ENABLED,
        epoch,
        session,
    };
    FeedRecord { state, sequence }.to_bytes()
}

/// The session the first configuration writes (the lowest free token).
const SESSION: u8 = 1;

/// A stream: the configuration, then records each with the receive path drained at its
/// time, unless `drained` says otherwise.
fn stream(records: &[(i32, u16, u8, u64)]) -> Vec<Event> {
    let mut events = vec![Event::Configure(0, 0)];
    for &(position, sequence, epoch, at) in records {
        events.push(Event::Drained(at));
        events.push(Event::Record(position, sequence, epoch, SESSION, at));
    }
    events
}

/// The boundary streams, named, in pairs where the second misses the limit by one.
fn cases() -> Vec<(String, Vec<Event>)> {
    let rule = RuleConfig::shipped(EVENT_TIMER_MS);
    let s0 = FIRST_SEQUENCE;
    let t0 = FIRST_MS;
    let mut cases = Vec::new();
    // The most numbers a record may lie ahead: at the limit it becomes the reference (a
    // baseline, too far to link), and the record after it credits its 3 counts; one further
    // it is bad, and the next is as far from the old reference.
    for dt in [0, 1, 50, 999, 3_999] {
        let limit = rule.max_ahead(dt * 1000) as u16;
        for (over, label) in [(0, "at"), (1, "past")] {
            let far = s0.wrapping_add(limit + over);
            cases.push((
                format!("boundary: {label} max_ahead {dt} ms after the reference"),
                stream(&[
                    (0, s0, 1, t0),
                    (7, far, 1, t0 + dt),
                    (10, far.wrapping_add(1), 1, t0 + dt + 1),
                ]),
            ));
        }
    }
    // The order window: the last record of the session may follow the reference by 4 s.
    for (dt, label) in [(4_000, "at"), (4_001, "past")] {
        let window = rule.order_window_us / 1000;
        assert_eq!(window, 4_000);
        cases.push((
            format!("boundary: {label} the order window"),
            stream(&[
                (0, s0, 1, t0),
                (5, s0 + 1, 1, t0 + dt),
                (9, s0 + 2, 1, t0 + dt + 1),
            ]),
        ));
    }
    // Stale after three event-timer periods: a record exactly that late still links.
    for (dt, label) in [(300, "at"), (301, "past")] {
        cases.push((
            format!("boundary: {label} the stale limit"),
            stream(&[(0, s0, 1, t0), (4, s0 + 1, 1, t0 + dt)]),
        ));
    }
    // The same epoch hides at most 6 missing numbers.
    for (gap, label) in [(6, "at"), (7, "past")] {
        cases.push((
            format!("boundary: {label} the same epoch's gap"),
            stream(&[(0, s0, 1, t0), (2, s0 + 1 + gap, 1, t0 + 5)]),
        ));
    }
    // The next epoch links only to the previous epoch's final record.
    for (gap, label) in [(0, "at"), (1, "past")] {
        cases.push((
            format!("boundary: {label} the next epoch's gap"),
            stream(&[(0, s0, 1, t0), (2, s0 + 1 + gap, 2, t0 + 5)]),
        ));
    }
    // The sequence wraps: 65535 then 0 is one ahead.
    cases.push((
        "boundary: the sequence's wrap".into(),
        stream(&[(0, u16::MAX, 1, t0), (3, 0, 1, t0 + 5)]),
    ));
    // A backlog: a record handled 100 ms after the path was last found empty is credited,
    // 101 ms after it only a baseline.
    for (late, label) in [(100, "at"), (101, "past")] {
        let mut events = stream(&[(0, s0, 1, t0)]);
        events.push(Event::Drained(t0 + 5));
        events.push(Event::Record(6, s0 + 1, 1, SESSION, t0 + 5 + late));
        cases.push((format!("boundary: {label} the backlog limit"), events));
    }
    cases
}

/// What the rule credits X and Y for `events`.
fn counts(events: &[Event]) -> [i32; 2] {
    let mut host: HostRule<()> = HostRule::new(RuleConfig::shipped(EVENT_TIMER_MS));
    for &event in events {
        match event {
            Event::Configure(found, at) => {
                assert!(host.configure_due(at), "a configuration the host asks for");
                let token = host.next_token(at, found, None);
                host.configured(found, token, at);
            }
            Event::Drained(at) => host.drained(at),
            Event::Record(position, sequence, epoch, session, at) => {
                host.record(record_bytes(position, sequence, epoch, session), (), at);
            }
        }
    }
    host.counts
}

/// The boundary streams as vector lines (see [`crate::vectors::write`]).
pub fn write(out: &mut String) {
    for (name, events) in cases() {
        let [x, y] = counts(&events);
        let _ = write!(out, "{{\"name\": \"{name}\", \"events\": [");
        for (i, event) in events.iter().enumerate() {
            let sep = if i == 0 { "" } else { ", " };
            let seconds = |ms: u64| ms as f64 / 1000.0;
            let _ = match *event {
                Event::Configure(found, at) => {
                    write!(out, "{sep}[\"configure\", {found}, {}]", seconds(at))
                }
                Event::Drained(at) => write!(out, "{sep}[\"drained\", {}]", seconds(at)),
                Event::Record(position, sequence, epoch, session, at) => {
                    let data = record_bytes(position, sequence, epoch, session);
                    write!(out, "{sep}[\"frame\", {TPDO1}, {data:?}, {}]", seconds(at))
                }
            };
        }
        let _ = writeln!(out, "], \"counts\": {{\"x\": {x}, \"y\": {y}}}}}");
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn credited(name: &str) -> i32 {
        let (_, events) = cases()
            .into_iter()
            .find(|(n, _)| n == name)
            .expect("a case of that name");
        counts(&events)[0]
    }

    #[test]
    fn each_pair_parts_at_its_limit() {
        // Every pair must differ, or the vector would not tell which side of the limit a
        // rule puts the record.
        for dt in [0, 1, 50, 999, 3_999] {
            let at = credited(&format!(
                "boundary: at max_ahead {dt} ms after the reference"
            ));
            let past = credited(&format!(
                "boundary: past max_ahead {dt} ms after the reference"
            ));
            assert_eq!((at, past), (3, 0), "{dt} ms");
        }
        assert_eq!(credited("boundary: at the order window"), 4);
        assert_eq!(credited("boundary: past the order window"), 0);
        assert_eq!(credited("boundary: at the stale limit"), 4);
        assert_eq!(credited("boundary: past the stale limit"), 0);
        assert_eq!(credited("boundary: at the same epoch's gap"), 2);
        assert_eq!(credited("boundary: past the same epoch's gap"), 0);
        assert_eq!(credited("boundary: at the next epoch's gap"), 2);
        assert_eq!(credited("boundary: past the next epoch's gap"), 0);
        assert_eq!(credited("boundary: the sequence's wrap"), 3);
        assert_eq!(credited("boundary: at the backlog limit"), 6);
        assert_eq!(credited("boundary: past the backlog limit"), 0);
    }
}
