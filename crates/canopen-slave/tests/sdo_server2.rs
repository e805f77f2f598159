//! The second SDO server (0x1201): its parameters and their checks, transfers on it, both
//! servers at once, resets, NMT Stopped and the acceptance filter.
mod common;
use canopen_slave::{NodeId, RxFilter};
use common::*;

const INVALID: u32 = 0x8000_0000;
const INCOMPATIBLE: u32 = 0x0604_0043;
const INVALID_VALUE: u32 = 0x0609_0030;
const TOO_HIGH: u32 = 0x0609_0031;
const NO_SUB: u32 = 0x0609_0011;
const NO_OBJECT: u32 = 0x0602_0000;
const UNKNOWN_COMMAND: u32 = 0x0504_0001;
const TIMEOUT: u32 = 0x0504_0000;
const DEFAULT: (u16, u16) = (SDO_RX, SDO_TX);
const SECOND: (u16, u16) = (SDO2_RX, SDO2_TX);

fn node() -> NodeId {
    NodeId::new(NODE).unwrap()
}

/// 0x1201:1..3 as a fresh device has them: both COB-IDs not valid, no client.
fn params(b: &mut Bench) -> [u32; 3] {
    [1, 2, 3].map(|sub| b.upload_u32(0x1201, sub))
}

/// Configures the second server over the default one.
fn configure(b: &mut Bench) {
    b.sdo_ids = DEFAULT;
    b.download_u32(0x1201, 1, u32::from(SDO2_RX)).unwrap();
    b.download_u32(0x1201, 2, u32::from(SDO2_TX)).unwrap();
    b.download(0x1201, 3, &[1]).unwrap();
}

#[test]
fn defaults_and_a_channel_that_is_not_valid_answers_nothing() {
    let mut b = Bench::new();
    assert_eq!(b.upload(0x1201, 0).unwrap(), [3]);
    assert_eq!(params(&mut b), [INVALID, INVALID, 0]);
    assert_eq!(b.upload(0x1201, 4), Err(NO_SUB));
    assert_eq!(
        b.upload(0x1202, 1),
        Err(NO_OBJECT),
        "one additional server only"
    );
    assert_eq!(
        b.download(0x1201, 0, &[3]),
        Err(0x0601_0002),
        "sub 0 is const"
    );
    let request = req(0x40, 0x1000, 0, [0; 4]);
    b.rx(frame(SDO2_RX, &request));
    assert_eq!(b.take(), vec![], "0x1201 not valid");
    // Only one direction valid is not a server either.
    b.download_u32(0x1201, 1, u32::from(SDO2_RX)).unwrap();
    b.rx(frame(SDO2_RX, &request));
    assert_eq!(b.take(), vec![], "0x1201:2 still not valid");
    assert_eq!(
        b.dev.rx_filter(),
        RxFilter::new(node()).with_rpdo(Some(RPDO1))
    );
}

#[test]
fn a_configured_channel_serves_expedited_and_segmented_transfers() {
    let mut b = Bench::new();
    configure(&mut b);
    assert_eq!(params(&mut b), [u32::from(SDO2_RX), u32::from(SDO2_TX), 1]);
    b.sdo_ids = SECOND;
    // Expedited upload, exact frame, answered on 0x1201:2 only.
    assert_eq!(
        b.sdo(req(0x40, 0x1000, 0, [0; 4])),
        Some([0x43, 0x00, 0x10, 0x00, 0x96, 0x01, 0x02, 0x00])
    );
    // Segmented upload, exact first frames.
    assert_eq!(
        b.sdo(req(0x40, 0x1008, 0, [0; 4])),
        Some([0x41, 0x08, 0x10, 0x00, 18, 0, 0, 0])
    );
    assert_eq!(
        b.sdo([0x60, 0, 0, 0, 0, 0, 0, 0]),
        Some([0x00, b'T', b'e', b's', b't', b' ', b'h', b'a'])
    );
    b.sdo(abort(0x1008, 0, 0x0800_0000));
    assert_eq!(b.upload(0x1008, 0).unwrap(), b"Test handwheel MPG");
    // Expedited download.
    b.download(0x2100, 1, &[1]).unwrap();
    assert_eq!(b.app.vars[1], 1);
    b.download_u32(0x2100, 7, 999).unwrap();
    assert_eq!(b.upload_u32(0x2100, 7), 999);
    // Segmented download, then its upload.
    b.download_segmented(0x2200, 0, b"second channel").unwrap();
    assert_eq!(b.app.text, b"second channel");
    assert_eq!(b.upload(0x2200, 0).unwrap(), b"second channel");
    // Aborts as on the default server.
    assert_eq!(b.download(0x1000, 0, &[0]), Err(0x0601_0002));
    assert_eq!(b.upload(0x1004, 0), Err(NO_OBJECT));
    assert_eq!(
        b.sdo(req(0xA0, 0x1000, 0, [0; 4])),
        Some(abort(0x1000, 0, UNKNOWN_COMMAND)),
        "no block transfer"
    );
    // The server reads its own parameters.
    assert_eq!(b.upload_u32(0x1201, 1), u32::from(SDO2_RX));
    // Requests of another length are ignored.
    b.rx(frame(SDO2_RX, &[0x40, 0x00, 0x10, 0x00]));
    assert_eq!(b.take(), vec![]);
}

#[test]
fn interleaved_transfers_on_both_channels_both_complete() {
    let mut b = Bench::new();
    configure(&mut b);
    b.app.vars[7] = 500;
    // A segmented download on the default server, three segments...
    b.sdo_ids = DEFAULT;
    assert_eq!(
        b.sdo(req(0x21, 0x2200, 0, [20, 0, 0, 0])),
        Some(req(0x60, 0x2200, 0, [0; 4]))
    );
    let segments: [[u8; 8]; 3] = [
        [0x00, b'i', b'n', b't', b'e', b'r', b'l', b'e'],
        [0x10, b'a', b'v', b'e', b'd', b' ', b'o', b'n'],
        // 6 bytes: n = 1, c = 1, t = 0.
        [0x03, b' ', b'b', b'o', b't', b'h', b'!', 0],
    ];
    let replies = [0x20, 0x30, 0x20];
    for (segment, reply) in segments.iter().zip(replies) {
        // ...with expedited reads and a write on the second between them.
        b.sdo_ids = SECOND;
        assert_eq!(b.upload_u32(0x1017, 0), 1000);
        assert_eq!(b.upload_u32(0x2100, 7), 500);
        b.download(0x2100, 5, &[reply]).unwrap();
        b.sdo_ids = DEFAULT;
        assert_eq!(b.sdo(*segment), Some([reply, 0, 0, 0, 0, 0, 0, 0]));
    }
    assert_eq!(b.app.text, b"interleaved on both!");
    assert_eq!(b.app.vars[5], 0x20);
    // The other way round: a segmented upload on the second server, a segmented download
    // and expedited transfers on the default one in between.
    b.sdo_ids = SECOND;
    assert_eq!(
        b.sdo(req(0x40, 0x1008, 0, [0; 4])),
        Some([0x41, 0x08, 0x10, 0x00, 18, 0, 0, 0])
    );
    b.sdo_ids = DEFAULT;
    b.download_segmented(0x2200, 0, b"default one").unwrap();
    b.sdo_ids = SECOND;
    assert_eq!(
        b.sdo([0x60, 0, 0, 0, 0, 0, 0, 0]),
        Some([0x00, b'T', b'e', b's', b't', b' ', b'h', b'a'])
    );
    b.sdo_ids = DEFAULT;
    assert_eq!(b.upload(0x1008, 0).unwrap(), b"Test handwheel MPG");
    b.sdo_ids = SECOND;
    assert_eq!(
        b.sdo([0x70, 0, 0, 0, 0, 0, 0, 0]),
        Some([0x10, b'n', b'd', b'w', b'h', b'e', b'e', b'l'])
    );
    assert_eq!(
        b.sdo([0x60, 0, 0, 0, 0, 0, 0, 0]),
        Some([0x07, b' ', b'M', b'P', b'G', 0, 0, 0])
    );
    assert_eq!(b.app.text, b"default one");
}

#[test]
fn each_channel_has_its_own_timeout() {
    let mut b = Bench::new();
    configure(&mut b);
    b.now = ms(100);
    b.sdo_ids = SECOND;
    b.sdo(req(0x40, 0x1008, 0, [0; 4])).unwrap();
    b.now = ms(600);
    b.sdo_ids = DEFAULT;
    b.sdo(req(0x21, 0x2200, 0, [10, 0, 0, 0])).unwrap();
    b.poll_at(ms(1000));
    b.take(); // the heartbeat
    assert_eq!(b.dev.next_deadline(), Some(ms(1100)));
    b.poll_at(ms(1100));
    assert_eq!(
        b.take(),
        vec![frame(SDO2_TX, &abort(0x1008, 0, TIMEOUT))],
        "the second server's transfer only"
    );
    // The default server's transfer goes on.
    b.now = ms(1500);
    assert_eq!(
        b.sdo([0x00, 1, 2, 3, 4, 5, 6, 7]),
        Some([0x20, 0, 0, 0, 0, 0, 0, 0])
    );
    b.poll_at(ms(2499));
    b.take();
    b.poll_at(ms(2500));
    assert_eq!(b.take(), vec![frame(SDO_TX, &abort(0x2200, 0, TIMEOUT))]);
}

#[test]
fn refused_writes_and_their_abort_codes() {
    let mut b = Bench::new();
    let rx = u32::from(SDO2_RX);
    let tx = u32::from(SDO2_TX);
    for sub in [1u8, 2] {
        let cases = [
            // 29-bit identifiers, and bits 11-28 of one.
            (0x2000_0690, INVALID_VALUE),
            (INVALID | 0x2000_0690, INVALID_VALUE),
            (0x0000_0800 | 0x690, INVALID_VALUE),
            // CiA 301's restricted identifiers; our default SDO pair and heartbeat among
            // them, which the restricted check refuses first.
            (0x000, INVALID_VALUE),
            (0x07F, INVALID_VALUE),
            (0x101, INVALID_VALUE),
            (0x180, INVALID_VALUE),
            (0x581, INVALID_VALUE),
            (u32::from(SDO_TX), INVALID_VALUE),
            (u32::from(SDO_RX), INVALID_VALUE),
            (0x67F, INVALID_VALUE),
            (0x6E0, INVALID_VALUE),
            (u32::from(HB), INVALID_VALUE),
            (0x7E5, INVALID_VALUE),
            // Identifiers of this node's other objects.
            (u32::from(TPDO1), INCOMPATIBLE),
            (u32::from(TPDO2), INCOMPATIBLE),
            (u32::from(EMCY), INCOMPATIBLE),
            (0x080, INCOMPATIBLE), // SYNC
        ];
        for (value, code) in cases {
            assert_eq!(
                b.download_u32(0x1201, sub, value),
                Err(code),
                "0x1201:{sub} = {value:#x}"
            );
            assert_eq!(b.upload_u32(0x1201, sub), INVALID, "unchanged");
        }
    }
    // The other direction of this very channel.
    b.download_u32(0x1201, 1, rx).unwrap();
    assert_eq!(b.download_u32(0x1201, 2, rx), Err(INCOMPATIBLE));
    b.download_u32(0x1201, 2, tx).unwrap();
    b.download_u32(0x1201, 1, INVALID | rx).unwrap();
    assert_eq!(b.download_u32(0x1201, 1, tx), Err(INCOMPATIBLE));
    // Parked on a used identifier while not valid, it cannot become valid there.
    b.download_u32(0x1201, 1, INVALID | u32::from(TPDO1))
        .unwrap();
    assert_eq!(
        b.download_u32(0x1201, 1, u32::from(TPDO1)),
        Err(INCOMPATIBLE)
    );
    // A valid entry's identifier may not change; given up first, it may.
    b.download_u32(0x1201, 1, rx).unwrap();
    assert_eq!(b.download_u32(0x1201, 1, rx + 1), Err(INVALID_VALUE));
    assert_eq!(b.download_u32(0x1201, 2, tx + 1), Err(INVALID_VALUE));
    b.download_u32(0x1201, 1, rx).unwrap(); // the same identifier again is no change
    assert_eq!(b.upload_u32(0x1201, 1), rx);
    b.download_u32(0x1201, 1, INVALID | (rx + 1)).unwrap();
    b.download_u32(0x1201, 1, rx + 1).unwrap();
    assert_eq!(params(&mut b), [rx + 1, tx, 0]);
    // The client's node-ID: 1..127, or 0 for none.
    assert_eq!(b.download(0x1201, 3, &[128]), Err(TOO_HIGH));
    assert_eq!(b.download(0x1201, 3, &[255]), Err(TOO_HIGH));
    assert_eq!(b.download(0x1201, 3, &[1, 0]), Err(0x0607_0012));
    b.download(0x1201, 3, &[127]).unwrap();
    assert_eq!(b.upload_u32(0x1201, 3), 127);
    b.download(0x1201, 3, &[0]).unwrap();
    assert_eq!(b.upload_u32(0x1201, 3), 0);
}

#[test]
fn other_identifiers_may_not_take_a_valid_second_sdo_identifier() {
    let mut b = Bench::new();
    let (rx, tx) = (0x1F5u32, 0x1F6u32);
    b.download_u32(0x1201, 1, rx).unwrap();
    b.download_u32(0x1201, 2, tx).unwrap();
    // Given up first: a valid one may not change its identifier anyway.
    b.download_u32(0x1800, 1, INVALID | u32::from(TPDO1))
        .unwrap();
    b.download_u32(0x1801, 1, INVALID | u32::from(TPDO2))
        .unwrap();
    b.download_u32(0x1014, 0, INVALID | u32::from(EMCY))
        .unwrap();
    for id in [rx, tx] {
        assert_eq!(b.download_u32(0x1800, 1, id), Err(INCOMPATIBLE), "TPDO1");
        assert_eq!(b.download_u32(0x1801, 1, id), Err(INCOMPATIBLE), "TPDO2");
        assert_eq!(b.download_u32(0x1014, 0, id), Err(INCOMPATIBLE), "EMCY");
        assert_eq!(b.download_u32(0x1005, 0, id), Err(INCOMPATIBLE), "SYNC");
    }
    assert_eq!(b.upload_u32(0x1005, 0), 0x080);
    assert_eq!(b.upload_u32(0x1014, 0), INVALID | u32::from(EMCY));
    // Given up by the SDO server, the identifier is free for TPDO1.
    b.download_u32(0x1201, 1, INVALID | rx).unwrap();
    b.download_u32(0x1800, 1, rx).unwrap();
    assert_eq!(b.upload_u32(0x1800, 1) & 0x7FF, rx);
    assert_eq!(b.download_u32(0x1201, 1, rx), Err(INCOMPATIBLE));
}

#[test]
fn resets_restore_the_defaults_and_0x1010_does_not_store_them() {
    let mut b = Bench::new();
    configure(&mut b);
    b.nmt(0x82, NODE);
    b.take();
    assert_eq!(params(&mut b), [INVALID, INVALID, 0]);
    assert_eq!(
        b.dev.rx_filter(),
        RxFilter::new(node()).with_rpdo(Some(RPDO1))
    );
    b.rx(frame(SDO2_RX, &req(0x40, 0x1000, 0, [0; 4])));
    assert_eq!(
        b.take(),
        vec![],
        "no second server after reset communication"
    );
    // Saved with everything else, it is still not restored.
    configure(&mut b);
    b.download_u32(0x1010, 1, 0x6576_6173).unwrap();
    b.nmt(0x81, NODE);
    b.take();
    assert_eq!(params(&mut b), [INVALID, INVALID, 0]);
    configure(&mut b);
    let storage = b.dev.storage().clone();
    let mut fresh = Bench::with_storage(storage);
    assert_eq!(params(&mut fresh), [INVALID, INVALID, 0], "power-on");
}

#[test]
fn the_acceptance_filter_takes_the_channel_while_it_is_valid() {
    let mut b = Bench::new();
    assert_eq!(
        b.dev.rx_filter(),
        RxFilter::new(node()).with_rpdo(Some(RPDO1))
    );
    configure(&mut b);
    let filter = b.dev.rx_filter();
    assert_eq!(filter.second_sdo_request(), SDO2_RX);
    assert!(filter.accepts(SDO2_RX));
    assert!(filter.accepts(SDO_RX) && filter.accepts(0x080));
    assert!(!filter.accepts(SDO2_TX), "replies are not received");
    assert_eq!(
        filter,
        RxFilter::new(node())
            .with_rpdo(Some(RPDO1))
            .with_second_sdo(Some(SDO2_RX))
    );
    // Not valid when either COB-ID is not.
    b.download_u32(0x1201, 2, INVALID | u32::from(SDO2_TX))
        .unwrap();
    assert_eq!(
        b.dev.rx_filter(),
        RxFilter::new(node()).with_rpdo(Some(RPDO1))
    );
    assert!(!b.dev.rx_filter().accepts(SDO2_RX));
}

#[test]
fn stopped_answers_on_neither_channel_and_drops_both_transfers() {
    let mut b = Bench::new();
    configure(&mut b);
    b.sdo_ids = SECOND;
    b.sdo(req(0x40, 0x1008, 0, [0; 4])).unwrap();
    b.sdo_ids = DEFAULT;
    b.sdo(req(0x40, 0x1009, 0, [0; 4])).unwrap();
    b.nmt(0x02, NODE);
    b.take();
    for ids in [DEFAULT, SECOND] {
        b.sdo_ids = ids;
        assert_eq!(b.sdo([0x60, 0, 0, 0, 0, 0, 0, 0]), None);
        assert_eq!(b.sdo(req(0x40, 0x1000, 0, [0; 4])), None);
    }
    b.nmt(0x80, NODE);
    b.take();
    for ids in [DEFAULT, SECOND] {
        b.sdo_ids = ids;
        assert_eq!(
            b.sdo([0x60, 0, 0, 0, 0, 0, 0, 0]),
            Some(abort(0, 0, UNKNOWN_COMMAND)),
            "the transfer was dropped"
        );
    }
    assert_eq!(b.upload_u32(0x1201, 2), u32::from(SDO2_TX), "kept");
}

#[test]
fn a_channel_made_not_valid_drops_its_transfer() {
    let mut b = Bench::new();
    configure(&mut b);
    b.now = ms(100);
    b.sdo_ids = SECOND;
    b.sdo(req(0x40, 0x1008, 0, [0; 4])).unwrap();
    assert_eq!(b.dev.next_deadline(), Some(ms(1000)), "the heartbeat first");
    // Given up over the default server: the transfer is gone, and no timeout follows.
    b.sdo_ids = DEFAULT;
    b.download_u32(0x1201, 1, INVALID | u32::from(SDO2_RX))
        .unwrap();
    b.poll_at(ms(1000));
    b.take();
    assert_eq!(b.dev.next_deadline(), Some(ms(2000)), "the next heartbeat");
    b.download_u32(0x1201, 1, u32::from(SDO2_RX)).unwrap();
    b.sdo_ids = SECOND;
    assert_eq!(
        b.sdo([0x60, 0, 0, 0, 0, 0, 0, 0]),
        Some(abort(0, 0, UNKNOWN_COMMAND))
    );
    // A write over the second server that gives up its own reply identifier is answered
    // there, and the server is deaf from then on.
    assert_eq!(
        b.download_u32(0x1201, 2, INVALID | u32::from(SDO2_TX)),
        Ok(())
    );
    b.rx(frame(SDO2_RX, &req(0x40, 0x1000, 0, [0; 4])));
    assert_eq!(b.take(), vec![]);
}
