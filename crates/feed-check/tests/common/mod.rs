//! What the checker's own tests share: a setting by name, and the first breach it finds.

use feed_check::bounds;
use feed_check::model::{Action, Bounds, FeedModel};
use stateright::{Checker, HasDiscoveries, Model};

/// The first breach BFS finds in `bounds` (so on the shortest path), and that path.
#[allow(dead_code, reason = "each test file uses what it needs")]
pub fn breach(bounds: Bounds) -> Option<(String, Vec<Action>)> {
    let model = FeedModel::new(bounds);
    let name = model.properties()[0].name;
    let checker = model
        .checker()
        .finish_when(HasDiscoveries::AnyFailures)
        .spawn_bfs()
        .join();
    checker.discovery(name).map(|path| {
        let found = path.last_state().violation.clone().unwrap_or_default();
        (found, path.into_actions())
    })
}

/// The setting of that name in `bounds::ALL`, `bounds::COPIES_AND_POWER_CYCLES` or
/// `bounds::UNFILED`.
#[allow(dead_code, reason = "each test file uses what it needs")]
pub fn setting(name: &str) -> Bounds {
    *bounds::ALL
        .iter()
        .chain(bounds::COPIES_AND_POWER_CYCLES)
        .chain(bounds::UNFILED)
        .find(|b| b.name == name)
        .expect("a setting of that name")
}
