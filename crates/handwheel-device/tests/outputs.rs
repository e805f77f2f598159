//! The digital outputs: 0x6A00 (the CNC's outputs), 0x6A06/0x6A07 (their error reaction,
//! CiA 401's layout) and "jog live" (0x2036, the device's own output).

mod common;

use common::*;
use handwheel_core::{Axis, Intake, Multiplier, Mutex, Wheel};
use handwheel_device::{DigitalOutputs, TransmitState, TRANSMIT_STALL_MS};
use proptest::prelude::*;

/// The master whose heartbeat the device watches in these tests.
const MASTER: u8 = 1;

fn outputs(b: &mut Bench) -> DigitalOutputs {
    b.device.digital_outputs(&mut b.wheel)
}

/// Watches the master's heartbeat (0x1016:1, 100 ms) and hears it once.
fn watch_master(b: &mut Bench) {
    let entry = u32::from(MASTER) << 16 | 100;
    b.sdo_write(0x1016, 1, &entry.to_le_bytes()).unwrap();
    beat(b);
}

fn beat(b: &mut Bench) {
    b.receive(0x700 + u16::from(MASTER), &[0x05]);
}

#[test]
fn the_objects_have_cia_401s_layout_and_defaults() {
    let mut b = Bench::new();
    for index in [0x6A00, 0x6A06, 0x6A07] {
        assert_eq!(b.read_u32(index, 0), 1, "{index:#06x}:0");
    }
    assert_eq!(b.read_u32(0x6A00, 1), 0);
    assert_eq!(b.read_u32(0x6A06, 1), 0xFF);
    assert_eq!(b.read_u32(0x6A07, 1), 0);
    assert_eq!(b.read_u32(0x2036, 0), 0);
    assert_eq!(
        b.sdo_write(0x2036, 0, &[1]),
        Err(0x0601_0002),
        "jog live is read-only"
    );
    assert_eq!(
        b.sdo_write(0x6A00, 1, &[1, 0]),
        Err(0x0607_0012),
        "one byte"
    );
    b.sdo_write(0x6A00, 1, &[0xA5]).unwrap();
    assert_eq!(b.read_u32(0x6A00, 1), 0xA5);
    assert_eq!(outputs(&mut b).written, 0xA5);
    assert!(!outputs(&mut b).jog_live, "0x6A00 never lights jog live");
    // The whole range of a byte: every output pattern.
    b.sdo_write(0x6A06, 1, &[0x00]).unwrap();
    b.sdo_write(0x6A07, 1, &[0xFF]).unwrap();
    assert_eq!((b.read_u32(0x6A06, 1), b.read_u32(0x6A07, 1)), (0, 0xFF));
}

#[test]
fn driving_the_outputs_keeps_the_feed_session() {
    let mut b = Bench::new();
    b.select(Some(Axis::X), Multiplier::X1);
    b.open_session(3);
    b.nmt(0x01);
    b.sdo_write(0x2000, 0, &[1]).unwrap();
    for (index, value) in [(0x6A00, 0x81), (0x6A06, 0x0F), (0x6A07, 0x05)] {
        b.sdo_write(index, 1, &[value]).unwrap();
        assert_eq!(b.read_u32(0x2002, 0), 3, "{index:#06x} keeps the session");
        assert_eq!(b.read_u32(0x2000, 0), 1, "{index:#06x} keeps the feed");
    }
}

#[test]
fn master_loss_applies_the_error_value_in_the_round_that_finds_it() {
    let mut b = Bench::new();
    b.sdo_write(0x6A06, 1, &[0x0F]).unwrap();
    b.sdo_write(0x6A07, 1, &[0x0A]).unwrap();
    b.nmt(0x01);
    b.sdo_write(0x6A00, 1, &[0b1010_0101]).unwrap();
    watch_master(&mut b);
    b.take();
    let heard_us = b.now_us;
    // Round by round until the device reports the loss (its EMCY): the outputs changed in
    // that very round, and not before.
    while b.take_id(EMCY).is_empty() {
        assert_eq!(outputs(&mut b).written, 0b1010_0101, "before the loss");
        assert!(
            b.now_us <= heard_us + 101_000,
            "found within the consumer time"
        );
        b.now_us += 100;
        b.poll();
    }
    assert_eq!(
        outputs(&mut b).written,
        0b1010_1010,
        "bits 0-3 from 0x6A07, 4-7 kept"
    );
    // Back: nothing changes until the master writes the outputs again.
    beat(&mut b);
    b.advance_ms(20);
    assert_eq!(
        b.read_u32(0x6A00, 1),
        0b1010_1010,
        "recovery keeps the error value"
    );
    b.sdo_write(0x6A00, 1, &[0x33]).unwrap();
    assert_eq!(outputs(&mut b).written, 0x33);
}

#[test]
fn nmt_stop_applies_the_error_value_and_the_resets_do_what_they_say() {
    let mut b = Bench::new();
    b.nmt(0x01);
    b.sdo_write(0x6A00, 1, &[0x7E]).unwrap();
    // Default error mode 0xFF, value 0: every output off.
    b.nmt(0x02);
    assert_eq!(outputs(&mut b).written, 0);
    b.nmt(0x01);
    assert_eq!(b.read_u32(0x6A00, 1), 0, "a start keeps the error value");
    // Pre-operational is no error.
    b.sdo_write(0x6A00, 1, &[0x7E]).unwrap();
    b.nmt(0x80);
    assert_eq!(b.read_u32(0x6A00, 1), 0x7E);
    // Reset communication keeps application state; reset node is power-on: all off.
    b.nmt(0x82);
    assert_eq!(b.read_u32(0x6A00, 1), 0x7E);
    b.nmt(0x81);
    assert_eq!(b.read_u32(0x6A00, 1), 0);
}

#[test]
fn the_error_reaction_is_stored_by_0x1010() {
    let mut b = Bench::new();
    b.sdo_write(0x6A06, 1, &[0x03]).unwrap();
    b.sdo_write(0x6A07, 1, &[0x01]).unwrap();
    b.sdo_write(0x1010, 1, b"save").unwrap();
    b.sdo_write(0x6A06, 1, &[0xFF]).unwrap();
    b.nmt(0x81);
    assert_eq!((b.read_u32(0x6A06, 1), b.read_u32(0x6A07, 1)), (0x03, 0x01));
    b.nmt(0x01);
    b.sdo_write(0x6A00, 1, &[0xF0]).unwrap();
    b.nmt(0x02);
    assert_eq!(outputs(&mut b).written, 0xF1);
}

/// Whether a detent turned now moves the feed position: turned on a copy of the device and
/// wheel, taken in as the next round's start does.
fn a_detent_moves_the_feed(b: &Bench) -> bool {
    let mut wheel = b.wheel.clone();
    let before = wheel.lock(|w| w.feed.position());
    let mut levels = b.levels;
    for _ in 0..4 {
        levels = levels.next_forward();
        let _ = wheel.edge().on_edge(levels);
    }
    wheel.take_motion(Intake::RoundStart);
    wheel.lock(|w| w.feed.position()) != before
}

fn assert_jog_live_is_motion(b: &mut Bench, what: &str) -> bool {
    let live = outputs(b).jog_live;
    assert_eq!(live, a_detent_moves_the_feed(b), "{what}");
    live
}

/// The frames wait for the bus for the stall time (`blocked`, the transmit path then counts
/// as blocked), or the path runs empty.
fn watch_transmit(b: &mut Bench, blocked: bool) {
    let state = TransmitState {
        waiting: blocked,
        ran_empty: !blocked,
    };
    let mut tx = Recorder::default();
    let mut at = |b: &mut Bench| {
        let now = canopen_slave::Instant::from_micros(b.now_us);
        b.device.watch_transmit(now, state, &mut b.wheel, &mut tx);
    };
    at(b);
    if blocked {
        b.now_us += TRANSMIT_STALL_MS * 1000;
        at(b);
    }
}

/// One state input of the device, as the list the test walks.
#[derive(Clone, Copy, Debug)]
enum Step {
    Nmt(u8),
    Enable(bool),
    Axis(Option<Axis>),
    Multiplier(Multiplier),
    Session(u8),
    Format(u8),
    MasterSilent,
    MasterBeats,
    BlockTransmit,
    TransmitDrains,
    Time(u64),
    Turn(i32),
}

fn apply(b: &mut Bench, step: Step) {
    let selection = b.wheel.lock(|w| w.feed.selection());
    match step {
        // NMT commands from a master; SDO writes the device may refuse in its state.
        Step::Nmt(command) => b.nmt(command),
        Step::Enable(on) => {
            if b.device.nmt_state() != canopen_slave::NmtState::Stopped {
                let _ = b.sdo_write(0x2000, 0, &[u8::from(on)]);
            }
        }
        Step::Axis(axis) => b.select(axis, selection.multiplier),
        Step::Multiplier(multiplier) => b.select(selection.axis, multiplier),
        Step::Session(token) => {
            if b.device.nmt_state() != canopen_slave::NmtState::Stopped {
                let _ = b.sdo_write(0x2002, 0, &[token]);
            }
        }
        Step::Format(format) => {
            if b.device.nmt_state() != canopen_slave::NmtState::Stopped {
                let _ = b.sdo_write(0x2001, 0, &[format]);
            }
        }
        Step::MasterSilent => b.advance_ms(150),
        Step::MasterBeats => beat(b),
        Step::BlockTransmit => watch_transmit(b, true),
        Step::TransmitDrains => watch_transmit(b, false),
        Step::Time(ms) => b.advance_ms(ms),
        Step::Turn(detents) => b.turn(detents),
    }
}

/// A device that watches its master (so that the master can be lost), older than the session
/// delay, with the master beating.
fn watched_bench() -> Bench {
    let mut b = Bench::new();
    watch_master(&mut b);
    b.now_us = 600_000;
    beat(&mut b);
    b
}

#[test]
fn jog_live_in_each_state_the_device_can_be_in() {
    use Step::*;
    let live = [Nmt(0x01), Axis(Some(handwheel_core::Axis::Y)), Enable(true)];
    let cases: &[(&str, &[Step], bool)] = &[
        ("live: Operational, axis, enabled", &[], true),
        ("in a session", &[Session(2), Enable(true)], true),
        (
            "x100",
            &[Multiplier(handwheel_core::Multiplier::X100)],
            true,
        ),
        ("the paper's format", &[Format(1), Enable(true)], true),
        ("disabled", &[Enable(false)], false),
        ("no axis", &[Axis(None)], false),
        (
            "axis back: the feed stays enabled",
            &[Axis(None), Axis(Some(handwheel_core::Axis::X))],
            true,
        ),
        ("Pre-operational", &[Nmt(0x80)], false),
        ("Stopped", &[Nmt(0x02)], false),
        (
            "Operational again: not enabled",
            &[Nmt(0x02), Nmt(0x01)],
            false,
        ),
        ("master lost", &[MasterSilent], false),
        (
            "master back: not enabled",
            &[MasterSilent, MasterBeats],
            false,
        ),
        ("transmit blocked", &[BlockTransmit], false),
        (
            "session ended by a write",
            &[Session(2), Enable(true), Format(0)],
            false,
        ),
        (
            "transmit drained: not enabled",
            &[BlockTransmit, TransmitDrains],
            false,
        ),
        (
            "enabled again",
            &[BlockTransmit, TransmitDrains, MasterBeats, Enable(true)],
            true,
        ),
        (
            "master back, enabled again",
            &[MasterSilent, MasterBeats, Enable(true)],
            true,
        ),
        (
            "new session",
            &[Session(2), Enable(true), Session(3)],
            false,
        ),
        ("reset communication", &[Nmt(0x82)], false),
        ("reset node", &[Nmt(0x81)], false),
    ];
    for &(what, steps, expected) in cases {
        let mut b = watched_bench();
        for &step in live.iter().chain(steps) {
            apply(&mut b, step);
        }
        assert_eq!(assert_jog_live_is_motion(&mut b, what), expected, "{what}");
        if b.device.nmt_state() != canopen_slave::NmtState::Stopped {
            assert_eq!(b.read_u32(0x2036, 0), u32::from(expected), "0x2036: {what}");
        }
    }
}

fn step() -> impl Strategy<Value = Step> {
    let axis = prop_oneof![Just(None), Just(Some(Axis::X)), Just(Some(Axis::V))];
    let multiplier = prop_oneof![Just(Multiplier::X1), Just(Multiplier::X100)];
    prop_oneof![
        prop_oneof![Just(0x01), Just(0x02), Just(0x80), Just(0x81), Just(0x82)].prop_map(Step::Nmt),
        any::<bool>().prop_map(Step::Enable),
        axis.prop_map(Step::Axis),
        multiplier.prop_map(Step::Multiplier),
        (0u8..=3).prop_map(Step::Session),
        (0u8..=1).prop_map(Step::Format),
        Just(Step::MasterSilent),
        Just(Step::MasterBeats),
        Just(Step::BlockTransmit),
        Just(Step::TransmitDrains),
        (1u64..=30).prop_map(Step::Time),
        (-2i32..=2).prop_map(Step::Turn),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(128))]

    /// After any sequence of the state inputs (NMT, enable, axis, multiplier, session,
    /// format, the master's heartbeat, a blocked transmit path, time, turns), jog live is
    /// exactly "a detent turned now moves the feed position", and 0x2036 reads it.
    #[test]
    fn jog_live_is_whether_a_detent_moves_the_feed(steps in proptest::collection::vec(step(), 1..24)) {
        let mut b = watched_bench();
        for (i, &s) in steps.iter().enumerate() {
            apply(&mut b, s);
            let what = format!("after {:?}", &steps[..=i]);
            let live = assert_jog_live_is_motion(&mut b, &what);
            if b.device.nmt_state() != canopen_slave::NmtState::Stopped {
                prop_assert_eq!(b.read_u32(0x2036, 0), u32::from(live), "{}", what);
            }
        }
    }
}
