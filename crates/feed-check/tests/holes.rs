//! A checker that cannot find a hole proves nothing: with a host rule weakened where the
//! contract depends on it, the same settings must lead to a breach. (The device's own holes
//! are in `mutants.rs`; what old copies and power cycles broke on the code before feed record
//! v2, in `bounds::COPIES_AND_POWER_CYCLES`, which the checker's run passes.)

mod common;

use common::{breach, setting};
use feed_check::model::{Action, Warm};

#[test]
fn without_the_pace_bound_a_copy_is_credited() {
    // A host that took any number ahead as new (as if the device's pace allowed anything)
    // credits a copy of an earlier record.
    let mut b = setting("copies of any age");
    b.rule.burst = 10_000;
    b.switches = 0;
    b.ticks = 0;
    b.warmups = &[&[Warm::Turns(124)]];
    let (found, _) = breach(b).expect("a copy is read as a new record");
    assert!(
        found.contains("again") || found.contains("backwards") || found.contains("more than"),
        "{found}"
    );
}

#[test]
fn copies_older_than_the_contract_alias_at_the_wrap() {
    // The checker reaches the wrap: with copies twice the contract's age (narrowed: 800 ms,
    // 128 numbers) some copy lies far enough behind to read as a few ahead.
    let mut b = setting("copies of any age");
    b.copy_age_ms = 1_600;
    b.copy_depth = 160;
    b.switches = 0;
    b.ticks = 0;
    b.channel_faults = 1;
    b.warmups = &[&[Warm::Turns(124)]];
    assert!(breach(b).is_some(), "an old copy is credited");
}

#[test]
fn without_the_backlog_rule_a_stalled_host_credits_late() {
    let mut b = setting("time and stalls");
    b.rule.backlog_limit_ms = u64::MAX;
    // A stall longer than the lateness bound (500 ms) needs more ticks than the setting's.
    b.ticks = 6;
    let (found, _) = breach(b).expect("the backlog of a stalled host is credited");
    assert!(found.contains("ms after it was turned"), "{found}");
}

#[test]
fn without_dating_a_gateways_hold_is_credited_late() {
    // A path between the bus and the host holds the device's records longer than the bound
    // and releases them at once: the host's receive path never backed up, so only the dating
    // by the sequence probe keeps the motion they carry from being credited late.
    let mut b = setting("gateway hold");
    b.rule.dating = false;
    let (found, path) = breach(b).expect("a held record is credited late");
    eprintln!("{found}\n  after {path:?}");
    assert!(found.contains("ms after it was turned"), "{found}");
    assert!(path.contains(&Action::Hold), "{path:?}");
}

/// "tokens reused" passes only if it reaches both answers of the uptime's proof: the host's
/// one token written again at once after a reset of the node (the same power life), and not
/// written after a power cycle until the copy age has passed.
#[test]
fn the_tokens_reused_setting_reaches_a_proven_reuse_and_a_refused_one() {
    use feed_check::model::{FeedModel, Nmt};
    use stateright::Model;
    let model = FeedModel::new(setting("tokens reused"));
    let start = model.init_states().remove(0);
    assert_eq!(start.host_session(), Some(1));
    let run = |actions: &[Action]| {
        actions.iter().fold(start.clone(), |w, &a| {
            model
                .next_state(&w, a)
                .unwrap_or_else(|| panic!("{a:?} not taken"))
        })
    };
    let reset = [Action::Nmt(Nmt::ResetNode), Action::Pass, Action::Configure];
    assert_eq!(run(&reset).host_session(), Some(1), "reused at once");
    let cycled = [
        Action::PowerCycle,
        Action::Pass,
        Action::Tick,
        Action::Configure,
    ];
    assert_eq!(run(&cycled).host_session(), None, "not after a power cycle");
}
