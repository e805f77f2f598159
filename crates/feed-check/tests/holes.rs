//! A checker that cannot find a hole proves nothing: with a host rule weakened where the
//! contract depends on it, the same settings must lead to a breach. (The device's own holes,
//! findings 1 and 2 of the third hostile run, were found on the code before their fix; the
//! closing note of that work lists the paths.)

use feed_check::bounds;
use feed_check::model::{Bounds, FeedModel};
use stateright::{Checker, HasDiscoveries, Model};

fn breach(bounds: Bounds) -> Option<String> {
    let model = FeedModel { bounds };
    let name = model.properties()[0].name;
    let checker = model
        .checker()
        .finish_when(HasDiscoveries::AnyFailures)
        .spawn_bfs()
        .join();
    checker
        .discovery(name)
        .and_then(|path| path.last_state().violation.clone())
}

fn setting(name: &str) -> Bounds {
    *bounds::ALL
        .iter()
        .find(|b| b.name == name)
        .expect("a setting of that name")
}

#[test]
fn without_the_ordering_rule_a_replay_is_credited_again() {
    let mut b = setting("channel faults");
    b.rule.order_expiry_ms = 0;
    let found = breach(b).expect("a replayed record becomes a reference");
    assert!(
        found.contains("again") || found.contains("backwards"),
        "{found}"
    );
}

#[test]
fn without_the_backlog_rule_a_stalled_host_credits_late() {
    let mut b = setting("time and stalls");
    b.rule.backlog_limit_ms = u64::MAX;
    let found = breach(b).expect("the backlog of a stalled host is credited");
    assert!(found.contains("ms after it was turned"), "{found}");
}
