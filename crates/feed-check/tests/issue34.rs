//! What issue 34 found, on the code of feed record v2: the settings of `bounds::ISSUE34`
//! (the stimulus that reached findings 1, 2, 4 and 6 on the code before it, with the narrowed
//! v2 sequence, its pace and copies of the contract's age) find no breach.
//!
//! On the code before feed record v2 each of them breached with the finding's own symptom
//! (with a 5-bit sequence and copies of any age): an old copy moving the axis backwards, an
//! old Y copy moving Y while X was selected, a dead wheel after a quick power cycle, and the
//! first record after an unseen power cycle linked to the last one before it. That the
//! checker still reaches such holes is `holes.rs`'s part: copies older than the contract
//! alias at the wrap, and a host without the pace bound credits a copy.

mod common;

use common::{breach, setting};

fn holds(name: &str) {
    if let Some((found, path)) = breach(setting(name)) {
        panic!("{name:?}: {found}\n  after {path:?}");
    }
}

/// Finding 1: a copy of a record as old as the wrap moved the axis backwards.
#[test]
fn finding_1_no_copy_of_the_contract_age_moves_the_axis() {
    holds("copies at the wrap");
}

/// Finding 2: a Y record as old as the wrap of sequence and epoch moved Y while X was
/// selected, with the wrong sign.
#[test]
fn finding_2_no_old_y_copy_moves_y() {
    holds("copies across epochs");
}

/// Finding 4: after a quick power cycle whose boot-up was seen, what was turned was not
/// credited though no record was missing.
#[test]
fn finding_4_after_a_power_cycle_the_wheel_feeds() {
    holds("power cycle seen");
}

/// Finding 6: a power cycle whose boot-up was lost linked the new power-up's first record
/// to the last one before it.
#[test]
fn finding_6_an_unseen_power_cycle_credits_nothing_wrong() {
    holds("power cycle unseen");
}

/// The rest of what issue 34 added, at once.
#[test]
fn issue_34_at_once() {
    holds("issue 34 at once");
}

/// NMT commands and time with copies, near the wrap.
#[test]
fn nmt_time_and_copies() {
    holds("nmt, time and copies");
}
