//! Test vectors for the component's own rule: record streams the model reaches, with what
//! [`crate::host`] credits for them, replayed through `core.py` by `host/tests`.
//!
//! The exhaustive search keeps no paths, so the vectors come from seeded random walks through
//! the same model (every kind of action, the shipped widths only, since `core.py` has no
//! other: the narrowed settings run at them, `bounds::at_shipped_widths`): each walk's host input and the per-axis counts the Rust rule ends with. A
//! difference between the two rules on any of them fails the host tests.

use std::fmt::Write as _;

use stateright::Model;

use crate::model::{Action, Bounds, FeedModel, HostEvent};

/// A small deterministic generator (xorshift64*): the vectors are the same on every run.
struct Walk(u64);

impl Walk {
    fn next(&mut self, below: usize) -> usize {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        (self.0.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 33) as usize % below.max(1)
    }
}

/// `walks` random walks of up to `steps` actions through `bounds`, as JSON lines:
/// `{"name": .., "events": [["frame", id, [bytes..], t_s] | ["drained", t_s] |
/// ["configure", found, t_s(, uptime_ms | null(, "refused"))] | ["probe", nonce, floor | null,
/// t_s] | ["probed", value, t_s],
/// ..], "dating": bool, "counts": {"x": .., "y": ..}}` (`dating`: replay with the core's
/// dating on).
pub fn write(bounds: &Bounds, walks: usize, steps: usize, seed: u64, out: &mut String) {
    let model = FeedModel::new(*bounds);
    let mut rng = Walk(seed | 1);
    let starts = model.init_states();
    for _ in 0..walks {
        let mut w = starts[rng.next(starts.len())].clone();
        // Replay the start with a log: the host's input from power-on.
        w = model.recorded(&w);
        for _ in 0..steps {
            let mut actions = Vec::new();
            model.actions(&w, &mut actions);
            if actions.is_empty() {
                break;
            }
            // Half the steps turn the wheel or let the bus take a frame, so that most walks
            // credit motion before a fault or a stop ends it.
            let common: Vec<_> = actions
                .iter()
                .copied()
                .filter(|a| matches!(a, Action::Turn | Action::Pass))
                .collect();
            let action = if !common.is_empty() && rng.next(2) == 0 {
                common[rng.next(common.len())]
            } else {
                actions[rng.next(actions.len())]
            };
            if let Some(next) = model.next_state(&w, action) {
                w = next;
            }
        }
        line(bounds, bounds.name, &w, out);
    }
}

/// Paths through "gateway hold" that the dating's mutants (`tests/mutants.rs`) breach on,
/// the shortest the checker finds for each: a random walk seldom holds long enough. On the
/// rule as it is they credit nothing late; `core.py` must credit the same.
pub const DATING_PATHS: &[(&str, &[Action])] = &[
    // Records held 500 ms: DATE_LIMIT ten times too generous credits them.
    (
        "gateway hold: records held past the date limit",
        &[
            Action::Turn,
            Action::Turn,
            Action::Hold,
            Action::Pass,
            Action::Pass,
            Action::Tick,
            Action::Tick,
            Action::Tick,
            Action::Tick,
            Action::Tick,
            Action::Release,
            Action::Turn,
            Action::Pass,
        ],
    ),
    // A probe's answer held with the records: its send time, not its arrival, dates them.
    (
        "gateway hold: a probe's answer held",
        &[
            Action::Turn,
            Action::Hold,
            Action::Pass,
            Action::Tick,
            Action::Turn,
            Action::Pass,
            Action::Tick,
            Action::Tick,
            Action::Tick,
            Action::Tick,
            Action::Tick,
            Action::Release,
            Action::Turn,
            Action::Pass,
        ],
    ),
    // A record lost in the hold: the date is of the reference's successor, not the record.
    (
        "gateway hold: a record lost in the hold",
        &[
            Action::Turn,
            Action::Turn,
            Action::Hold,
            Action::Pass,
            Action::Lose,
            Action::Tick,
            Action::Tick,
            Action::Tick,
            Action::Tick,
            Action::Tick,
            Action::Release,
            Action::Turn,
            Action::Pass,
        ],
    ),
];

/// The [`DATING_PATHS`] through `bounds` (from its first initial state), as JSON lines like
/// [`write()`]'s. Each action must be one the model offers there.
pub fn write_paths(bounds: &Bounds, paths: &[(&str, &[Action])], out: &mut String) {
    let model = FeedModel::new(*bounds);
    let start = &model.init_states()[0];
    for (name, path) in paths {
        let mut w = model.recorded(start);
        for &action in *path {
            let mut actions = Vec::new();
            model.actions(&w, &mut actions);
            assert!(actions.contains(&action), "{name}: {action:?} not offered");
            w = model
                .next_state(&w, action)
                .unwrap_or_else(|| panic!("{name}: {action:?} does not happen"));
        }
        assert!(w.violation.is_none(), "{name}: {:?}", w.violation);
        line(bounds, name, &w, out);
    }
}

/// One vector: the host's input `w` recorded, and the counts the Rust rule ends with.
fn line(bounds: &Bounds, name: &str, w: &crate::model::World, out: &mut String) {
    let counts = w.host_counts();
    let _ = write!(out, "{{\"name\": \"{name}\", \"events\": [");
    for (i, event) in w.log.iter().flatten().enumerate() {
        let sep = if i == 0 { "" } else { ", " };
        match event {
            HostEvent::Frame { id, data, at_ms } => {
                let _ = write!(
                    out,
                    "{sep}[\"frame\", {id}, {data:?}, {}]",
                    *at_ms as f64 / 1000.0
                );
            }
            HostEvent::Drained(at_ms) => {
                let _ = write!(out, "{sep}[\"drained\", {}]", *at_ms as f64 / 1000.0);
            }
            HostEvent::Configure(found, at_ms, uptime, refused) => {
                let uptime = match (uptime, refused) {
                    (_, true) => format!(
                        ", {}, \"refused\"",
                        uptime.map_or("null".into(), |ms| ms.to_string())
                    ),
                    (Some(ms), false) => format!(", {ms}"),
                    (None, false) => String::new(),
                };
                let _ = write!(
                    out,
                    "{sep}[\"configure\", {found}, {}{uptime}]",
                    *at_ms as f64 / 1000.0
                );
            }
            HostEvent::Probe {
                nonce,
                floor,
                at_ms,
            } => {
                let floor = floor.map_or("null".to_string(), |f| f.to_string());
                let _ = write!(
                    out,
                    "{sep}[\"probe\", {nonce}, {floor}, {}]",
                    *at_ms as f64 / 1000.0
                );
            }
            HostEvent::Probed { value, at_ms } => {
                let _ = write!(
                    out,
                    "{sep}[\"probed\", {value}, {}]",
                    *at_ms as f64 / 1000.0
                );
            }
            HostEvent::ProbeRefused { at_ms } => {
                let _ = write!(out, "{sep}[\"probe_refused\", {}]", *at_ms as f64 / 1000.0);
            }
            HostEvent::Unanswered { at_ms } => {
                let _ = write!(out, "{sep}[\"probed\", null, {}]", *at_ms as f64 / 1000.0);
            }
        }
    }
    let _ = writeln!(
        out,
        "], \"dating\": {}, \"counts\": {{\"x\": {}, \"y\": {}}}}}",
        bounds.rule.dating, counts[0], counts[1]
    );
}
