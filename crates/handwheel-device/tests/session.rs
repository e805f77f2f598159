//! The master's session (0x2002): what opens it, what ends it, and the pace of the record
//! sequence that bounds it (README "Feed record").

mod common;

use common::*;
use handwheel_core::{Axis, FeedStatus, Multiplier, SEQUENCE_BURST};
use handwheel_device::od::SESSION_DELAY_MS;

/// Operational, X at x1, the session `token` opened, the feed enabled.
fn in_session(token: u8) -> Bench {
    let mut b = Bench::new();
    b.select(Some(Axis::X), Multiplier::X1);
    b.open_session(token);
    b.nmt(0x01);
    b.sdo_write(0x2000, 0, &[1]).unwrap();
    b.advance_ms(5);
    b.take();
    b
}

fn last_record(b: &mut Bench) -> handwheel_core::FeedRecord {
    feed_record(b.take_id(TPDO1).last().expect("a feed record"))
}

#[test]
fn every_record_carries_the_session_a_master_opened() {
    let mut b = in_session(5);
    assert_eq!(b.read_u32(0x2002, 0), 5);
    b.turn(3);
    b.advance_ms(5);
    let records = b.take_id(TPDO1);
    assert!(!records.is_empty());
    for r in records.iter().map(feed_record) {
        assert_eq!(r.state.session, 5);
        assert!(r.state.status.contains(FeedStatus::ENABLED));
    }
    assert_eq!(b.read_u32(0x2030, 0) >> 5, 5, "0x2030 bits 5-7");
}

#[test]
fn a_new_session_is_a_new_epoch_with_the_feed_off() {
    let mut b = in_session(2);
    let epoch = b.read_u32(0x2010, 3);
    b.open_session(2);
    assert_eq!(
        b.read_u32(0x2000, 0),
        1,
        "the same session again changes nothing"
    );
    b.open_session(3);
    assert_eq!(
        b.read_u32(0x2000, 0),
        0,
        "a new session starts with the feed off"
    );
    assert_eq!(b.read_u32(0x2010, 3), epoch + 1);
    b.advance_ms(5);
    let r = last_record(&mut b);
    assert_eq!(r.state.session, 3);
    assert!(!r.state.status.contains(FeedStatus::ENABLED));
    assert!(
        !r.state.status.contains(FeedStatus::MASTER_LOST),
        "not a loss"
    );
    assert_eq!(b.sdo_write(0x2002, 0, &[8]), Err(0x0609_0031), "1..7 only");
}

#[test]
fn configuration_writes_end_the_session_and_the_feed() {
    let cases: [(u16, u8, &[u8]); 5] = [
        (0x1016, 1, &0x0001_01F4u32.to_le_bytes()),
        (0x1017, 0, &500u16.to_le_bytes()),
        (0x1800, 5, &200u16.to_le_bytes()),
        (0x2020, 3, &[2]),
        (0x2001, 0, &[0]),
    ];
    for (index, sub, value) in cases {
        let mut b = in_session(4);
        assert_eq!(b.sdo_write(index, sub, value), Ok(()), "{index:#06x}:{sub}");
        assert_eq!(b.read_u32(0x2002, 0), 0, "{index:#06x}:{sub} ends it");
        assert_eq!(
            b.read_u32(0x2000, 0),
            0,
            "{index:#06x}:{sub} stops the feed"
        );
        b.advance_ms(5);
        assert_eq!(last_record(&mut b).state.session, 0);
    }
}

#[test]
fn enabling_and_clearing_errors_keep_the_session_and_refused_writes_change_nothing() {
    let mut b = in_session(6);
    b.sdo_write(0x2000, 0, &[0]).unwrap();
    b.sdo_write(0x2000, 0, &[1]).unwrap();
    b.sdo_write(0x1003, 0, &[0]).unwrap();
    assert_eq!(b.sdo_write(0x2020, 3, &[3]), Err(0x0609_0030));
    assert_eq!(b.sdo_write(0x1010, 1, b"save"), Err(0x0800_0022), "feed on");
    assert_eq!(b.read_u32(0x2002, 0), 6);
    b.sdo_write(0x2000, 0, &[0]).unwrap();
    b.sdo_write(0x1010, 1, b"save").unwrap();
    assert_eq!(
        b.read_u32(0x2002, 0),
        6,
        "storing changes nothing the session rests on"
    );
}

#[test]
fn the_sequence_probe_keeps_the_session_and_dates_the_next_record() {
    let mut b = in_session(3);
    let next = b.read_u32(0x2031, 0);
    // Bits 13-15 of a write are not the nonce's; bits 16-31 (0: no key) are the key's.
    b.sdo_write(0x2033, 0, &0x0000_BEEFu32.to_le_bytes())
        .unwrap();
    assert_eq!(b.read_u32(0x2002, 0), 3, "a probe keeps the session");
    assert_eq!(b.read_u32(0x2000, 0), 1, "and the feed");
    assert_eq!(
        b.read_u32(0x2033, 0),
        next << 16 | 3 << 13 | (0xBEEF & 0x1FFF),
        "the next record's number, the session and the nonce's low 13 bits"
    );
    b.turn(1);
    b.advance_ms(5);
    let r = last_record(&mut b);
    assert_eq!(
        u32::from(r.sequence),
        next,
        "the record made after the probe"
    );
    assert_eq!(
        b.read_u32(0x2033, 0),
        (next + 1) << 16 | 3 << 13 | (0xBEEF & 0x1FFF)
    );
    assert_eq!(
        b.sdo_write(0x2033, 0, &[1, 2]),
        Err(0x0607_0013),
        "four bytes: two are too few"
    );
}

#[test]
fn resets_end_the_session_and_stop_and_start_keep_it() {
    for command in [0x81, 0x82] {
        let mut b = in_session(7);
        b.nmt(command);
        assert_eq!(b.read_u32(0x2002, 0), 0, "NMT {command:#04x}");
    }
    let mut b = in_session(7);
    b.nmt(0x02);
    b.nmt(0x80);
    b.nmt(0x01);
    assert_eq!(
        b.read_u32(0x2002, 0),
        7,
        "0x1016 and the rest are still as configured"
    );
    assert_eq!(b.read_u32(0x2000, 0), 0, "but the stop stopped the feed");
}

#[test]
fn numbers_faster_than_the_pace_end_the_session() {
    // A stop and a start take 8 numbers (one break) and the record the start sends one more:
    // a master that sends them faster than one number per millisecond (beyond the burst)
    // ends the session.
    let mut b = in_session(1);
    let breaks = usize::from(SEQUENCE_BURST) / 8 + 1;
    for _ in 0..breaks {
        b.nmt(0x80);
        b.nmt(0x01);
    }
    assert_eq!(b.read_u32(0x2002, 0), 0);
    // At the pace a master can keep going for ever.
    let mut b = in_session(1);
    for _ in 0..50 {
        b.nmt(0x80);
        b.nmt(0x01);
        b.advance_ms(16);
    }
    assert_eq!(b.read_u32(0x2002, 0), 1);
}

#[test]
fn a_fast_wheel_at_the_default_inhibit_time_keeps_the_session() {
    let mut b = in_session(3);
    for _ in 0..2000 {
        b.turn(1);
        b.advance_ms(1);
    }
    assert_eq!(b.read_u32(0x2002, 0), 3);
    assert_eq!(b.read_u32(0x6004, 0), 2000);
}

#[test]
fn a_session_opens_only_half_a_second_after_the_start() {
    let mut b = Bench::new();
    b.nmt(0x01);
    b.advance_ms(SESSION_DELAY_MS - 1);
    assert_eq!(
        b.sdo_write(0x2002, 0, &[1]),
        Err(0x0800_0022),
        "a young device opens no session"
    );
    assert_eq!(b.read_u32(0x2002, 0), 0);
    assert_eq!(b.sdo_write(0x2002, 0, &[0]), Ok(()), "0 is always taken");
    b.advance_ms(1);
    assert_eq!(b.sdo_write(0x2002, 0, &[1]), Ok(()));
    assert_eq!(b.read_u32(0x2002, 0), 1);
    b.nmt(0x81);
    assert_eq!(
        b.sdo_write(0x2002, 0, &[2]),
        Ok(()),
        "a reset node is no new power life: no delay after it"
    );
}

#[test]
fn the_session_key_belongs_to_the_session_and_guards_the_probe() {
    let mut b = Bench::new();
    assert_eq!(
        b.sdo_write(0x2034, 0, &0x1234u16.to_le_bytes()),
        Err(0x0800_0022),
        "no session, no key"
    );
    assert_eq!(b.sdo_upload(0x2034, 0), Err(0x0601_0001), "write-only");
    let mut b = in_session(3);
    b.sdo_write(0x2034, 0, &0x1234u16.to_le_bytes()).unwrap();
    assert_eq!(b.read_u32(0x2002, 0), 3, "the key keeps the session");
    assert_eq!(b.read_u32(0x2000, 0), 1, "and the feed");
    let probe = |key: u32, nonce: u32| (key << 16 | nonce).to_le_bytes();
    b.sdo_write(0x2033, 0, &probe(0x1234, 7)).unwrap();
    assert_eq!(b.read_u32(0x2033, 0) & 0xFFFF, 3 << 13 | 7);
    assert_eq!(
        b.sdo_write(0x2033, 0, &probe(0x1235, 8)),
        Err(0x0800_0022),
        "another key"
    );
    assert_eq!(
        b.read_u32(0x2033, 0) & 0x1FFF,
        7,
        "a refused probe changes nothing"
    );
    b.sdo_write(0x2033, 0, &probe(0, 9)).unwrap();
    assert_eq!(
        b.read_u32(0x2033, 0) & 0x1FFF,
        9,
        "anyone may probe without a key"
    );
    // The same token written again is the same session, with its key.
    b.sdo_write(0x2002, 0, &[3]).unwrap();
    b.sdo_write(0x2033, 0, &probe(0x1234, 10)).unwrap();
    // Ended and opened again (by anyone, with the same token): the key is gone.
    b.sdo_write(0x2002, 0, &[0]).unwrap();
    b.sdo_write(0x2002, 0, &[3]).unwrap();
    assert_eq!(
        b.sdo_write(0x2033, 0, &probe(0x1234, 11)),
        Err(0x0800_0022),
        "the token is the host's, the session is not"
    );
    for end in [0x81u8, 0x82] {
        let mut b = in_session(3);
        b.sdo_write(0x2034, 0, &0x1234u16.to_le_bytes()).unwrap();
        b.nmt(end);
        b.nmt(0x01);
        b.open_session(3);
        assert_eq!(
            b.sdo_write(0x2033, 0, &probe(0x1234, 1)),
            Err(0x0800_0022),
            "NMT {end:#04x} ended the key with the session"
        );
    }
}

#[test]
fn the_uptime_counts_from_the_start_through_every_reset_of_the_node() {
    let mut b = Bench::new();
    assert_eq!(b.read_u32(0x2035, 0), 0);
    b.advance_ms(1234);
    assert_eq!(b.read_u32(0x2035, 0), 1234);
    b.nmt(0x81);
    b.advance_ms(10);
    assert_eq!(
        b.read_u32(0x2035, 0),
        1244,
        "a reset node is no new power life"
    );
    b.nmt(0x82);
    b.advance_ms(1);
    assert_eq!(b.read_u32(0x2035, 0), 1245, "nor a reset of communication");
    assert_eq!(
        b.sdo_write(0x2035, 0, &[0, 0, 0, 0]),
        Err(0x0601_0002),
        "read-only"
    );
}
