//! Breaches the checker finds on today's code that no issue names yet (`bounds::UNFILED`):
//! each setting must still breach, with its own symptom, until a fix turns its test around
//! and moves the setting into `bounds::ALL`.

mod common;

use common::{breach, setting};

fn found(name: &str) -> String {
    let (found, path) = breach(setting(name)).unwrap_or_else(|| panic!("{name:?}: no breach"));
    eprintln!("{name:?}: {found}\n  after {path:?}");
    found
}

/// A boot-up that reaches the host after the configuration that followed it ends the new
/// session: motion is lost (never wrong).
#[test]
fn a_boot_up_overtaken_by_a_configuration_loses_owed_motion() {
    let found = found("boot-up overtaken");
    assert!(found.contains("no record was missing"), "{found}");
}
