//! Test vectors for the component's own rule: record streams the model reaches, with what
//! [`crate::host`] credits for them, replayed through `core.py` by `host/tests`.
//!
//! The exhaustive search keeps no paths, so the vectors come from seeded random walks through
//! the same model (every kind of action, the shipped widths only, since `core.py` has no
//! other): each walk's host input and the per-axis counts the Rust rule ends with. A
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
/// `{"name": .., "events": [["frame", id, [bytes..], t_s] | ["drained", t_s], ..],
/// "counts": {"x": .., "y": ..}}`.
pub fn write(bounds: &Bounds, walks: usize, steps: usize, seed: u64, out: &mut String) {
    let model = FeedModel { bounds: *bounds };
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
        let counts = w.host_counts();
        let _ = write!(out, "{{\"name\": \"{}\", \"events\": [", bounds.name);
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
                HostEvent::Configure(found, at_ms) => {
                    let _ = write!(
                        out,
                        "{sep}[\"configure\", {found}, {}]",
                        *at_ms as f64 / 1000.0
                    );
                }
            }
        }
        let _ = writeln!(
            out,
            "], \"counts\": {{\"x\": {}, \"y\": {}}}}}",
            counts[0], counts[1]
        );
    }
}
