//! The checker kills the device bugs that nothing caught before it, and a change made without
//! taking the wheel's motion in first (at the round's named intake points): one plausible bug
//! each, in the real device code, selected at run time (`handwheel_device::mutant`). A
//! checker that stops seeing any of them fails here. The same settings pass on the real code
//! (`cargo xtask test` runs them all).

mod common;

use common::{breach, setting};
use handwheel_device::mutant::Mutant;

fn killed(name: &str, mutant: Mutant) -> String {
    let mut b = setting(name);
    b.mutant = Some(mutant);
    let (found, path) = breach(b).unwrap_or_else(|| panic!("{mutant:?} survives {name:?}"));
    eprintln!("{mutant:?} in {name:?}: {found}\n  after {path:?}");
    found
}

#[test]
fn an_nmt_stop_that_keeps_held_epochs_credits_late() {
    let found = killed("nmt and time", Mutant::NmtStopKeepsHeld);
    assert!(found.contains("ms after it was turned"), "{found}");
}

#[test]
fn a_reset_that_keeps_pending_frames_sends_them_after_it() {
    let found = killed("resets and wrap", Mutant::ResetKeepsPending);
    assert!(
        found.contains("made before a reset went out after it"),
        "{found}"
    );
}

#[test]
fn a_record_read_at_send_time_credits_the_wrong_axis() {
    let found = killed("edges in a round", Mutant::TpdoReadAtSend);
    assert!(found.contains("a detent turned on X"), "{found}");
}

#[test]
fn an_enable_written_without_taking_the_motion_in_first_misplaces_a_detent() {
    let found = killed("edges in a round", Mutant::EnableWithoutIntake);
    assert!(found.contains("was taken in after a change"), "{found}");
}

#[test]
fn a_stall_watch_restarted_by_every_frame_keeps_the_feed_on_a_trickling_bus() {
    // The model's own stall watch (the device's promise) trips where the mutant's does not.
    let found = killed("trickling bus", Mutant::StallCompletions);
    assert!(found.contains("after its frames waited 100 ms"), "{found}");
}
