//! Property tests: random operators, masters and buses against the device's safety rules.

mod common;

use common::*;
use handwheel_core::{AbLevels, Axis, Multiplier};
use proptest::prelude::*;

#[derive(Clone, Debug)]
enum Event {
    /// Raw A/B levels as the EXTI task reads them (chatter and jumps included).
    Edge(u8),
    /// Whole detents.
    Turn(i8),
    Select(Option<usize>, usize),
    Nmt(u8),
    /// SDO download to an application object with an arbitrary value.
    Write(u16, u8, u32, u8),
    /// The master's heartbeat (node 1) with a state byte.
    MasterHeartbeat(u8),
    /// Any frame at all.
    Frame(u16, Vec<u8>),
    Wait(u16),
}

fn events() -> impl Strategy<Value = Vec<Event>> {
    // (index, sub, size): mostly the right size, so that writes get past the length check.
    let app_objects = prop_oneof![
        4 => Just((0x2000u16, 0u8, 1u8)),
        1 => Just((0x2001, 0, 1)),
        1 => Just((0x2020, 3, 1)),
        1 => Just((0x2020, 4, 1)),
        1 => Just((0x2040, 3, 2)),
        1 => Just((0x1016, 1, 4)),
        1 => Just((0x1017, 0, 2)),
        1 => Just((0x1800, 3, 2)),
    ];
    // Mostly small values, so that the interesting ones (0, 1, 2, 4) come up often.
    let value = prop_oneof![3 => 0..5u32, 1 => any::<u32>()];
    let size = prop_oneof![4 => Just(None), 1 => (1..=4u8).prop_map(Some)];
    let e = prop_oneof![
        4 => (0..4u8).prop_map(Event::Edge),
        4 => (-3..=3i8).prop_map(Event::Turn),
        1 => (prop::option::of(0..5usize), 0..3usize).prop_map(|(a, m)| Event::Select(a, m)),
        2 => prop_oneof![3 => Just(0x01u8), 1 => Just(0x02), 1 => Just(0x80), 1 => Just(0x81), 1 => Just(0x82)]
            .prop_map(Event::Nmt),
        3 => (app_objects, value, size)
            .prop_map(|((i, s, n), v, other)| Event::Write(i, s, v, other.unwrap_or(n))),
        1 => prop_oneof![Just(0x05u8), Just(0x7F), Just(0x04)].prop_map(Event::MasterHeartbeat),
        1 => (0..0x800u16, prop::collection::vec(any::<u8>(), 0..=8))
            .prop_map(|(id, d)| Event::Frame(id, d)),
        3 => (1..300u16).prop_map(Event::Wait),
    ];
    prop::collection::vec(e, 0..120)
}

const MULTIPLIERS: [Multiplier; 3] = [Multiplier::X1, Multiplier::X10, Multiplier::X100];

fn apply(b: &mut Bench, e: &Event) {
    match e {
        Event::Edge(bits) => {
            let l = AbLevels::from_bits(*bits);
            b.levels = l;
            b.edge(l);
        }
        Event::Turn(n) => b.turn(i32::from(*n)),
        Event::Select(a, m) => b.select(a.map(|i| Axis::ALL[i]), MULTIPLIERS[*m]),
        Event::Nmt(c) => b.nmt(*c),
        Event::Write(i, s, v, n) => {
            // Raw request: in Stopped no reply comes, and the outcome is not the point here.
            let v = v.to_le_bytes();
            let cmd = 0x23 | ((4 - n) << 2);
            b.receive(
                SDO_RX,
                &[cmd, *i as u8, (*i >> 8) as u8, *s, v[0], v[1], v[2], v[3]],
            );
        }
        Event::MasterHeartbeat(state) => b.receive(0x701, &[*state]),
        // Our own SDO server id carries requests that expect a reply; random data there is
        // the SDO property tests' business in canopen-slave.
        Event::Frame(id, _) if *id == SDO_RX => {}
        Event::Frame(id, d) => b.receive(*id, d),
        Event::Wait(ms) => b.advance_ms(u64::from(*ms)),
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    /// Whatever the operator, the master and the bus do: feed is never enabled outside
    /// Operational, the position never moves while feed is disabled, no PDO leaves outside
    /// Operational, a master-loss EMCY comes with the feed stopped, every feed record is
    /// well-formed, and every unit step names the axis selected.
    #[test]
    fn safety_rules_hold(evs in events()) {
        let mut b = Bench::new();
        b.take();
        for e in &evs {
            let operational = b.device.nmt_state() == canopen_slave::NmtState::Operational;
            let enabled = b.wheel.feed().enabled();
            let position = b.wheel.feed().position();
            apply(&mut b, e);
            let now_operational = b.device.nmt_state() == canopen_slave::NmtState::Operational;
            prop_assert!(
                !b.wheel.feed().enabled() || now_operational,
                "enabled outside Operational after {:?}", e
            );
            // Reset node restarts the application: position 0 after a boot-up, which a host
            // takes as a new baseline. Anything else must not move a disabled feed.
            let reset = matches!(e, Event::Nmt(0x81));
            if !enabled && !b.wheel.feed().enabled() && !reset {
                prop_assert_eq!(b.wheel.feed().position(), position, "moved while disabled: {:?}", e);
            }
            for f in b.take() {
                if f.id == EMCY && f.data[..2] == [0x30, 0x81] {
                    prop_assert!(!b.wheel.feed().enabled(), "master lost but feed enabled");
                }
                if f.id == TPDO1 || f.id == TPDO2 {
                    prop_assert!(operational || now_operational, "PDO outside Operational: {:?}", e);
                }
                // The mapping is never written here: TPDO1 is the feed record.
                if f.id == TPDO1 {
                    let r = record(&f);
                    prop_assert!(r.1 <= 5 && [1, 10, 100].contains(&r.2) && r.3 < 0x20);
                }
                if f.id == TPDO2 {
                    let (step, _) = handwheel_core::UnitStepEncoder::decode(f.data[0])
                        .expect("valid axis field");
                    prop_assert_eq!(b.wheel.feed().selection().axis, Some(step.axis), "step for another axis: {:?}", e);
                }
            }
        }
    }
}
