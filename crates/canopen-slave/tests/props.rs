//! Property tests over random traffic: no panics, ignored frames change nothing, rejected
//! writes leave the dictionary untouched.
mod common;
use canopen_slave::Instant;
use common::*;
use proptest::prelude::*;

/// Frames the device must ignore whatever its state.
fn must_ignore(id: u16, dlc: usize) -> bool {
    let known =
        id == 0 || id == 0x080 || id == SDO_RX || id == RPDO1 || (0x701..=0x77F).contains(&id);
    !known || (id == 0 && dlc != 2) || (id == SDO_RX && dlc != 8)
}

fn any_frame() -> impl Strategy<Value = (u16, Vec<u8>)> {
    let interesting = prop_oneof![
        Just(0u16),
        Just(0x080),
        Just(SDO_RX),
        Just(RPDO1),
        Just(0x707),
        Just(HB),
        0u16..=0x7FF,
    ];
    (interesting, proptest::collection::vec(any::<u8>(), 0..=8))
}

fn sdo_request() -> impl Strategy<Value = [u8; 8]> {
    let index = prop_oneof![
        Just(0x1000u16),
        Just(0x1003),
        Just(0x1005),
        Just(0x1010),
        Just(0x1011),
        Just(0x1014),
        Just(0x1016),
        Just(0x1017),
        Just(0x1400),
        Just(0x1600),
        Just(0x1800),
        Just(0x1801),
        Just(0x1A00),
        Just(0x1A01),
        Just(0x2000),
        Just(0x2100),
        Just(0x2200),
        any::<u16>(),
    ];
    (any::<u8>(), index, 0u8..10, any::<[u8; 4]>())
        .prop_map(|(cmd, index, sub, data)| req(cmd, index, sub, data))
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]

    #[test]
    fn random_traffic_never_panics_and_ignored_frames_change_nothing(
        start_operational in any::<bool>(),
        steps in proptest::collection::vec((0u64..300_000, any_frame()), 1..60),
    ) {
        let mut b = if start_operational { Bench::operational() } else { Bench::new() };
        let mut t = 0u64;
        for (dt, (id, data)) in steps {
            t += dt;
            let now = Instant::from_micros(t);
            let f = frame(id, &data);
            if must_ignore(id, data.len()) {
                let dev = b.dev.clone();
                let app = b.app.clone();
                b.rx_at(now, f);
                prop_assert_eq!(&b.dev, &dev);
                prop_assert_eq!(&b.app, &app);
                prop_assert!(b.tx.frames.is_empty());
            } else {
                b.rx_at(now, f);
            }
            b.poll_at(now);
            // poll leaves no overdue work behind.
            if let Some(deadline) = b.dev.next_deadline() {
                prop_assert!(deadline > now, "{:?} <= {:?}", deadline, now);
            }
            for out in b.take() {
                prop_assert!(out.dlc() <= 8);
                if out.id() == SDO_TX || out.id() == EMCY {
                    prop_assert_eq!(out.dlc(), 8);
                }
            }
        }
    }

    #[test]
    fn refused_sdo_requests_leave_the_dictionary_unchanged(
        requests in proptest::collection::vec(sdo_request(), 1..40),
    ) {
        let mut b = Bench::new();
        for r in requests {
            let before = b.snapshot();
            let app = b.app.clone();
            let reply = b.sdo(r);
            if let Some(reply) = reply {
                prop_assert!(matches!(reply[0], 0x80 | 0x60 | 0x41 | 0x43 | 0x47 | 0x4B | 0x4F | 0x00..=0x1F | 0x20 | 0x30));
                if reply[0] == 0x80 {
                    prop_assert_eq!(b.snapshot(), before);
                    prop_assert_eq!(&b.app, &app);
                }
            }
        }
    }
}
