//! COB-IDs a master can move: SYNC (0x1005), EMCY (0x1014), TPDOs (0x1800+n:1). No two
//! objects of this node may share one, none may sit on a reserved identifier, and the
//! acceptance filter follows SYNC.
mod common;
use canopen_slave::RxFilter;
use common::*;

const INVALID: u32 = 0x8000_0000;
/// TPDO COB-IDs read with bit 30 set: RTR is not served.
const NO_RTR: u32 = 0x4000_0000;
const INCOMPATIBLE: u32 = 0x0604_0043;
const INVALID_VALUE: u32 = 0x0609_0030;

#[test]
fn a_tpdo_may_not_take_our_emcy_or_sync_identifier() {
    let mut b = Bench::new();
    // TPDO2 onto this node's EMCY (0x085): the feed would be read as emergencies.
    b.download_u32(0x1801, 1, INVALID | 0x285).unwrap();
    assert_eq!(
        b.download_u32(0x1801, 1, u32::from(EMCY)),
        Err(INCOMPATIBLE)
    );
    // Parked there while invalid it claims nothing, but it cannot become valid.
    b.download_u32(0x1801, 1, INVALID | u32::from(EMCY))
        .unwrap();
    assert_eq!(
        b.download_u32(0x1801, 1, u32::from(EMCY)),
        Err(INCOMPATIBLE)
    );
    assert_eq!(b.upload_u32(0x1801, 1), NO_RTR | INVALID | u32::from(EMCY));
    // Onto SYNC, or onto the other TPDO.
    assert_eq!(b.download_u32(0x1801, 1, 0x080), Err(INCOMPATIBLE));
    assert_eq!(
        b.download_u32(0x1801, 1, u32::from(TPDO1)),
        Err(INCOMPATIBLE)
    );
    // A free identifier is fine.
    b.download_u32(0x1801, 1, 0x1F0).unwrap();
    assert_eq!(b.upload_u32(0x1801, 1), NO_RTR | 0x1F0);
}

#[test]
fn emcy_may_not_take_a_tpdo_identifier() {
    let mut b = Bench::new();
    b.download_u32(0x1800, 1, INVALID | u32::from(TPDO1))
        .unwrap();
    b.download_u32(0x1800, 1, 0x095).unwrap();
    b.download_u32(0x1014, 0, INVALID | u32::from(EMCY))
        .unwrap();
    assert_eq!(b.download_u32(0x1014, 0, 0x095), Err(INCOMPATIBLE));
    assert_eq!(
        b.download_u32(0x1014, 0, 0x080),
        Err(INCOMPATIBLE),
        "SYNC's"
    );
    assert_eq!(b.upload_u32(0x1014, 0), INVALID | u32::from(EMCY));
    b.download_u32(0x1014, 0, 0x0A5).unwrap();
    // Once the TPDO gives the identifier up, EMCY may have it.
    b.download_u32(0x1800, 1, INVALID | 0x095).unwrap();
    b.download_u32(0x1014, 0, INVALID | 0x0A5).unwrap();
    b.download_u32(0x1014, 0, 0x095).unwrap();
    assert_eq!(b.upload_u32(0x1014, 0), 0x095);
}

#[test]
fn sync_refuses_reserved_and_used_identifiers() {
    let mut b = Bench::new();
    let cases = [
        (0x000, INVALID_VALUE), // NMT
        (0x07F, INVALID_VALUE),
        (0x585, INVALID_VALUE), // SDO
        (0x605, INVALID_VALUE),
        (0x701, INVALID_VALUE), // heartbeat
        (0x7E5, INVALID_VALUE), // LSS
        (u32::from(EMCY), INCOMPATIBLE),
        (u32::from(TPDO1), INCOMPATIBLE),
        (u32::from(TPDO2), INCOMPATIBLE),
    ];
    for (value, code) in cases {
        assert_eq!(b.download_u32(0x1005, 0, value), Err(code), "{value:#x}");
        assert_eq!(b.upload_u32(0x1005, 0), 0x080);
    }
    b.download_u32(0x1005, 0, 0x081).unwrap();
    assert_eq!(b.upload_u32(0x1005, 0), 0x081);
}

#[test]
fn moved_sync_is_received_on_its_new_identifier_only() {
    let mut b = Bench::operational();
    let node = canopen_slave::NodeId::new(NODE).unwrap();
    assert_eq!(
        b.dev.rx_filter(),
        RxFilter::new(node).with_rpdo(Some(RPDO1))
    );
    // TPDO1 on every SYNC.
    b.download(0x1800, 2, &[1]).unwrap();
    b.download_u32(0x1005, 0, 0x081).unwrap();
    let filter = b.dev.rx_filter();
    assert_eq!(filter.sync(), 0x081);
    assert!(filter.accepts(0x081) && !filter.accepts(0x080));
    b.take();
    b.rx_at(ms(10), frame(0x080, &[]));
    assert_eq!(b.take(), vec![], "the old identifier is no SYNC any more");
    b.rx_at(ms(20), frame(0x081, &[]));
    let sent = b.take();
    assert_eq!(sent.len(), 1);
    assert_eq!(sent[0].id(), TPDO1);
    // Reset communication brings the default back, and the filter with it.
    b.nmt(0x82, NODE);
    assert_eq!(
        b.dev.rx_filter(),
        RxFilter::new(node).with_rpdo(Some(RPDO1))
    );
}

#[test]
fn tpdo_cob_ids_say_no_rtr_whatever_is_written() {
    // The engine serves no remote frames, so bit 30 ("no RTR allowed", CiA 301) reads 1 on
    // every TPDO, from the defaults and after a master writes it clear.
    let mut b = Bench::new();
    for index in [0x1800u16, 0x1801] {
        let cob = b.upload_u32(index, 1);
        assert_eq!(cob & NO_RTR, NO_RTR, "{index:#06x} default");
        b.download_u32(index, 1, cob & !NO_RTR).unwrap();
        assert_eq!(b.upload_u32(index, 1), cob);
        b.download_u32(index, 1, INVALID | (cob & 0x7FF)).unwrap();
        assert_eq!(b.upload_u32(index, 1), NO_RTR | INVALID | (cob & 0x7FF));
    }
}
