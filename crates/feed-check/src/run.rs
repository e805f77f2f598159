//! One setting explored with caps on its states and its time, so that a setting grown by a
//! change fails the run instead of holding CI for hours.

use std::collections::BTreeSet;
use std::time::{Duration, Instant};

use stateright::{Checker, HasDiscoveries, Model};

use crate::model::{Action, Bounds, FeedModel};

/// The most one setting may take.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Caps {
    /// Unique states.
    pub states: usize,
    /// Seconds of exploration.
    pub seconds: f64,
}

impl Caps {
    /// What `cargo xtask feed-check` allows each setting: about twice the largest today's
    /// run reaches (2.1 million states, 9 s on two cores).
    pub const RUN: Self = Self {
        states: 5_000_000,
        seconds: 60.0,
    };
}

/// What exploring one setting found.
#[derive(Clone, Debug)]
pub struct Explored {
    /// Unique states.
    pub states: usize,
    /// The deepest path.
    pub depth: usize,
    /// Seconds it took.
    pub seconds: f64,
    /// The first breach (on a shortest path): its message, the warm-up it started from,
    /// the path.
    pub breach: Option<(String, usize, Vec<Action>)>,
    /// The cap it reached, if any: the exploration stopped there, unfinished.
    pub over: Option<String>,
}

/// Explores `bounds` breadth first on `threads` threads within `caps` (on past breaches with
/// `through`).
pub fn explore(bounds: Bounds, caps: Caps, threads: usize, through: bool) -> Explored {
    let t = Instant::now();
    // The time cap as a boundary: stateright's own timeout is only looked at when a thread
    // runs out of work, which one thread never does.
    let model = FeedModel {
        bounds,
        deadline: Some(t + Duration::from_secs_f64(caps.seconds)),
    };
    let name = model.properties()[0].name;
    let mut checker = model
        .checker()
        .threads(threads)
        .target_state_count(caps.states);
    if through {
        checker = checker.finish_when(HasDiscoveries::AnyOf(BTreeSet::new()));
    }
    let checker = checker.spawn_bfs().join();
    let seconds = t.elapsed().as_secs_f64();
    let states = checker.unique_state_count();
    let breach = checker.discovery(name).map(|path| {
        let last = path.last_state();
        let found = last.violation.clone().unwrap_or_default();
        (found, last.warmup(), path.into_actions())
    });
    let over = if states >= caps.states {
        Some(format!("reached the cap of {} states", caps.states))
    } else if seconds >= caps.seconds {
        Some(format!("reached the cap of {} s", caps.seconds))
    } else {
        None
    };
    Explored {
        states,
        depth: checker.max_depth(),
        seconds,
        breach,
        over,
    }
}
