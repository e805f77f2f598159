//! A setting that grows past its caps fails the run instead of holding it: the caps trip.

mod common;

use common::setting;
use feed_check::run::{explore, Caps};

#[test]
fn a_tiny_state_cap_trips() {
    let caps = Caps {
        states: 1_000,
        seconds: 600.0,
    };
    let run = explore(setting("gateway hold"), caps, 1, false);
    assert!(run.breach.is_none());
    let over = run.over.expect("the state cap trips");
    assert!(over.contains("1000 states"), "{over}");
    assert!(run.states < 100_000, "stopped near the cap: {}", run.states);
}

#[test]
fn a_tiny_time_cap_trips() {
    let caps = Caps {
        states: usize::MAX,
        seconds: 0.2,
    };
    let run = explore(setting("gateway hold"), caps, 1, false);
    let over = run.over.expect("the time cap trips");
    assert!(over.contains("0.2 s"), "{over}");
    assert!(
        run.seconds < 30.0,
        "stopped near the cap: {} s",
        run.seconds
    );
}
