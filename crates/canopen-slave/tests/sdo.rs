//! SDO server: every transfer kind and every abort of the conformance table, exact bytes.
mod common;
use common::*;

#[test]
fn expedited_upload_of_each_type() {
    let mut b = Bench::new();
    // Constants and engine-owned parameters.
    assert_eq!(
        b.sdo(req(0x40, 0x1000, 0, [0; 4])),
        Some([0x43, 0x00, 0x10, 0x00, 0x96, 0x01, 0x02, 0x00])
    );
    assert_eq!(
        b.sdo(req(0x40, 0x1001, 0, [0; 4])),
        Some([0x4F, 0x01, 0x10, 0x00, 0x00, 0, 0, 0])
    );
    assert_eq!(
        b.sdo(req(0x40, 0x1017, 0, [0; 4])),
        Some([0x4B, 0x17, 0x10, 0x00, 0xE8, 0x03, 0, 0])
    );
    assert_eq!(
        b.sdo(req(0x40, 0x1018, 4, [0; 4])),
        Some([0x43, 0x18, 0x10, 0x04, 0xEF, 0xBE, 0xAD, 0xDE])
    );
    // Application objects of every numeric type.
    b.app.vars = [
        0,
        1,
        (-5i8) as u32,
        (-100i16) as u32,
        (-2i32) as u32,
        200,
        0xBEEF,
        999,
    ];
    let expect: [(u8, &[u8]); 7] = [
        (1, &[0x01]),
        (2, &[0xFB]),
        (3, &[0x9C, 0xFF]),
        (4, &[0xFE, 0xFF, 0xFF, 0xFF]),
        (5, &[200]),
        (6, &[0xEF, 0xBE]),
        (7, &[0xE7, 0x03, 0, 0]),
    ];
    for (sub, bytes) in expect {
        let r = b.sdo(req(0x40, 0x2100, sub, [0; 4])).unwrap();
        let mut want = [0u8; 8];
        want[0] = 0x43 | ((4 - bytes.len() as u8) << 2);
        want[1..4].copy_from_slice(&[0x00, 0x21, sub]);
        want[4..4 + bytes.len()].copy_from_slice(bytes);
        assert_eq!(r, want, "0x2100:{sub}");
    }
}

#[test]
fn expedited_download_of_each_type() {
    let mut b = Bench::new();
    assert_eq!(
        b.sdo(req(0x2F, 0x2100, 1, [1, 0, 0, 0])),
        Some([0x60, 0x00, 0x21, 0x01, 0, 0, 0, 0])
    );
    assert_eq!(b.app.vars[1], 1);
    b.download(0x2100, 2, &[0x80]).unwrap();
    assert_eq!(b.app.vars[2], 0x80);
    b.download(0x2100, 3, &(-100i16).to_le_bytes()).unwrap();
    assert_eq!(b.app.vars[3], 0xFF9C);
    b.download(0x2100, 4, &i32::MIN.to_le_bytes()).unwrap();
    assert_eq!(b.app.vars[4], 0x8000_0000);
    b.download(0x2100, 5, &[255]).unwrap();
    b.download(0x2100, 6, &0xFFFFu16.to_le_bytes()).unwrap();
    b.download(0x2100, 7, &1000u32.to_le_bytes()).unwrap();
    assert_eq!(
        b.app.vars,
        [0, 1, 0x80, 0xFF9C, 0x8000_0000, 255, 0xFFFF, 1000]
    );
    // Engine-owned parameter.
    b.download(0x1017, 0, &250u16.to_le_bytes()).unwrap();
    assert_eq!(b.upload_u32(0x1017, 0), 250);
}

#[test]
fn expedited_download_without_size_takes_the_object_size() {
    let mut b = Bench::new();
    assert_eq!(
        b.sdo([0x22, 0x17, 0x10, 0x00, 0xF4, 0x01, 0xAA, 0xBB]),
        Some([0x60, 0x17, 0x10, 0x00, 0, 0, 0, 0])
    );
    assert_eq!(b.upload_u32(0x1017, 0), 500);
    assert_eq!(
        b.sdo([0x22, 0x00, 0x20, 0x00, 0x01, 0xFF, 0xFF, 0xFF]),
        Some([0x60, 0x00, 0x20, 0x00, 0, 0, 0, 0])
    );
    assert_eq!(b.app.flag, 1);
    // Strings take all four bytes.
    b.sdo([0x22, 0x00, 0x22, 0x00, b'a', b'b', b'c', b'd'])
        .unwrap();
    assert_eq!(b.app.text, b"abcd");
    assert_eq!(
        b.sdo([0x22, 0x04, 0x10, 0x00, 1, 2, 3, 4]),
        Some(abort(0x1004, 0, 0x0602_0000))
    );
    assert_eq!(
        b.sdo([0x22, 0x00, 0x10, 0x00, 1, 2, 3, 4]),
        Some(abort(0x1000, 0, 0x0601_0002))
    );
}

#[test]
fn segmented_upload_of_device_name_exact_frames() {
    let mut b = Bench::new();
    assert_eq!(
        b.sdo(req(0x40, 0x1008, 0, [0; 4])),
        Some([0x41, 0x08, 0x10, 0x00, 18, 0, 0, 0])
    );
    assert_eq!(
        b.sdo([0x60, 0, 0, 0, 0, 0, 0, 0]),
        Some([0x00, b'T', b'e', b's', b't', b' ', b'h', b'a'])
    );
    assert_eq!(
        b.sdo([0x70, 0, 0, 0, 0, 0, 0, 0]),
        Some([0x10, b'n', b'd', b'w', b'h', b'e', b'e', b'l'])
    );
    // 4 bytes left: n = 3 unused, c = 1.
    assert_eq!(
        b.sdo([0x60, 0, 0, 0, 0, 0, 0, 0]),
        Some([0x07, b' ', b'M', b'P', b'G', 0, 0, 0])
    );
    // The transfer is over: another segment request is an unknown command.
    assert_eq!(
        b.sdo([0x70, 0, 0, 0, 0, 0, 0, 0]),
        Some(abort(0, 0, 0x0504_0001))
    );
}

#[test]
fn all_strings_upload() {
    let mut b = Bench::new();
    assert_eq!(b.upload(0x1008, 0).unwrap(), b"Test handwheel MPG");
    assert_eq!(b.upload(0x1009, 0).unwrap(), b"HW rev B");
    assert_eq!(b.upload(0x100A, 0).unwrap(), b"1.2.3");
    b.app.text = b"abc".to_vec();
    assert_eq!(b.upload(0x2200, 0).unwrap(), b"abc");
}

#[test]
fn empty_string_uploads_segmented_with_size_zero() {
    let mut b = Bench::new();
    assert_eq!(
        b.sdo(req(0x40, 0x2200, 0, [0; 4])),
        Some([0x41, 0x00, 0x22, 0x00, 0, 0, 0, 0])
    );
    assert_eq!(
        b.sdo([0x60, 0, 0, 0, 0, 0, 0, 0]),
        Some([0x0F, 0, 0, 0, 0, 0, 0, 0])
    );
}

#[test]
fn segmented_upload_wrong_toggle_aborts() {
    let mut b = Bench::new();
    b.sdo(req(0x40, 0x1008, 0, [0; 4])).unwrap();
    assert_eq!(
        b.sdo([0x70, 0, 0, 0, 0, 0, 0, 0]),
        Some(abort(0x1008, 0, 0x0503_0000))
    );
    // Later in the transfer too.
    b.sdo(req(0x40, 0x1008, 0, [0; 4])).unwrap();
    b.sdo([0x60, 0, 0, 0, 0, 0, 0, 0]).unwrap();
    assert_eq!(
        b.sdo([0x60, 0, 0, 0, 0, 0, 0, 0]),
        Some(abort(0x1008, 0, 0x0503_0000))
    );
}

#[test]
fn segmented_download_of_two_bytes_to_heartbeat_time() {
    let mut b = Bench::new();
    assert_eq!(
        b.sdo([0x21, 0x17, 0x10, 0x00, 2, 0, 0, 0]),
        Some([0x60, 0x17, 0x10, 0x00, 0, 0, 0, 0])
    );
    // t = 0, n = 5 unused, c = 1.
    assert_eq!(
        b.sdo([0x0B, 0xF4, 0x01, 0, 0, 0, 0, 0]),
        Some([0x20, 0, 0, 0, 0, 0, 0, 0])
    );
    assert_eq!(b.upload_u32(0x1017, 0), 500);
}

#[test]
fn segmented_download_of_a_string_without_size() {
    let mut b = Bench::new();
    assert_eq!(
        b.sdo([0x20, 0x00, 0x22, 0x00, 0, 0, 0, 0]),
        Some([0x60, 0x00, 0x22, 0x00, 0, 0, 0, 0])
    );
    assert_eq!(
        b.sdo([0x00, b'h', b'e', b'l', b'l', b'o', b' ', b'w']),
        Some([0x20, 0, 0, 0, 0, 0, 0, 0])
    );
    assert_eq!(b.app.text, b"", "nothing written before the last segment");
    // 5 bytes, n = 2, c = 1, t = 1.
    assert_eq!(
        b.sdo([0x15, b'o', b'r', b'l', b'd', b'!', 0, 0]),
        Some([0x30, 0, 0, 0, 0, 0, 0, 0])
    );
    assert_eq!(b.app.text, b"hello world!");
}

#[test]
fn segmented_download_errors() {
    let mut b = Bench::new();
    // Wrong toggle: the abort names the transfer's object.
    b.sdo([0x21, 0x00, 0x22, 0x00, 10, 0, 0, 0]).unwrap();
    assert_eq!(
        b.sdo([0x10, 1, 2, 3, 4, 5, 6, 7]),
        Some(abort(0x2200, 0, 0x0503_0000))
    );
    // Indicated size does not match what came.
    b.sdo([0x21, 0x00, 0x22, 0x00, 3, 0, 0, 0]).unwrap();
    assert_eq!(
        b.sdo([0x0B, b'a', b'b', 0, 0, 0, 0, 0]),
        Some(abort(0x2200, 0, 0x0607_0010))
    );
    // Indicated size wrong for the type.
    assert_eq!(
        b.sdo([0x21, 0x17, 0x10, 0x00, 4, 0, 0, 0]),
        Some(abort(0x1017, 0, 0x0607_0012))
    );
    assert_eq!(
        b.sdo([0x21, 0x17, 0x10, 0x00, 1, 0, 0, 0]),
        Some(abort(0x1017, 0, 0x0607_0013))
    );
    assert_eq!(
        b.sdo([0x21, 0x00, 0x22, 0x00, 33, 0, 0, 0]),
        Some(abort(0x2200, 0, 0x0607_0012))
    );
    // Unsized, then more than the buffer holds.
    b.sdo([0x20, 0x00, 0x22, 0x00, 0, 0, 0, 0]).unwrap();
    let mut t = 0u8;
    let mut last = None;
    for _ in 0..5 {
        last = b.sdo([t, 1, 2, 3, 4, 5, 6, 7]);
        t ^= 0x10;
    }
    assert_eq!(last, Some(abort(0x2200, 0, 0x0607_0012)));
    // Unsized segmented download of a wrong length to a U16 is checked at the end.
    b.sdo([0x20, 0x17, 0x10, 0x00, 0, 0, 0, 0]).unwrap();
    assert_eq!(
        b.sdo([0x09, 1, 2, 3, 0, 0, 0, 0]),
        Some(abort(0x1017, 0, 0x0607_0012))
    );
    assert_eq!(b.app.text, b"");
    assert_eq!(b.upload_u32(0x1017, 0), 1000);
    // A segment without a transfer.
    assert_eq!(
        b.sdo([0x00, 0x17, 0x10, 0x00, 0, 0, 0, 0]),
        Some(abort(0x1017, 0, 0x0504_0001))
    );
}

#[test]
fn conformance_table_aborts() {
    let mut b = Bench::new();
    let cases: [([u8; 8], [u8; 8]); 12] = [
        // Write to a read-only object.
        (
            req(0x23, 0x1000, 0, [1, 2, 3, 4]),
            abort(0x1000, 0, 0x0601_0002),
        ),
        // Read of a missing sub-index.
        (req(0x40, 0x1000, 1, [0; 4]), abort(0x1000, 1, 0x0609_0011)),
        // Read of a missing object.
        (req(0x40, 0x1004, 0, [0; 4]), abort(0x1004, 0, 0x0602_0000)),
        // Command byte 0xE0.
        (req(0xE0, 0x1000, 0, [0; 4]), abort(0x1000, 0, 0x0504_0001)),
        // 4-byte write to a U8 object.
        (
            req(0x23, 0x2000, 0, [1, 0, 0, 0]),
            abort(0x2000, 0, 0x0607_0012),
        ),
        // 1-byte write to a U32 object.
        (
            req(0x2F, 0x2100, 7, [1, 0, 0, 0]),
            abort(0x2100, 7, 0x0607_0013),
        ),
        // Out of range, above and below.
        (
            req(0x2F, 0x2000, 0, [2, 0, 0, 0]),
            abort(0x2000, 0, 0x0609_0031),
        ),
        (
            req(0x23, 0x2100, 7, [5, 0, 0, 0]),
            abort(0x2100, 7, 0x0609_0032),
        ),
        (
            req(0x2B, 0x2100, 3, [101, 0, 0, 0]),
            abort(0x2100, 3, 0x0609_0031),
        ),
        (
            req(0x2B, 0x2100, 3, [0x9B, 0xFF, 0, 0]),
            abort(0x2100, 3, 0x0609_0032),
        ),
        // BOOLEAN accepts 0 and 1 only.
        (
            req(0x2F, 0x2100, 1, [2, 0, 0, 0]),
            abort(0x2100, 1, 0x0609_0031),
        ),
        // Read of a write-only object.
        (req(0x40, 0x2001, 0, [0; 4]), abort(0x2001, 0, 0x0601_0001)),
    ];
    for (request, reply) in cases {
        assert_eq!(b.sdo(request), Some(reply), "request {request:02x?}");
    }
    // Write-only objects can be written.
    b.download(0x2001, 0, &0x1234u16.to_le_bytes()).unwrap();
    assert_eq!(b.app.write_only, 0x1234);
}

#[test]
fn write_to_missing_objects() {
    let mut b = Bench::new();
    assert_eq!(b.download(0x1004, 0, &[1]), Err(0x0602_0000));
    assert_eq!(b.download(0x2100, 8, &[1]), Err(0x0609_0011));
    assert_eq!(b.download(0x1018, 5, &[1]), Err(0x0609_0011));
    assert_eq!(b.download(0x1018, 1, &[1, 0, 0, 0]), Err(0x0601_0002));
    assert_eq!(b.download(0x1018, 0, &[1]), Err(0x0601_0002));
}

#[test]
fn block_transfer_and_unknown_commands_abort() {
    let mut b = Bench::new();
    for cmd in (0xA0..=0xA4).chain(0xC0..=0xC6).chain(0xE0..=0xFF) {
        assert_eq!(
            b.sdo(req(cmd, 0x1008, 0, [0; 4])),
            Some(abort(0x1008, 0, 0x0504_0001)),
            "command {cmd:#x}"
        );
    }
}

#[test]
fn application_may_refuse_a_write() {
    let mut b = Bench::new();
    assert_eq!(b.download(0x2300, 0, &[7]), Err(0x0800_0022));
    assert_eq!(b.app.guarded, 0);
    b.download(0x2300, 0, &[8]).unwrap();
    assert_eq!(b.app.guarded, 8);
}

#[test]
fn unfinished_transfer_times_out() {
    let mut b = Bench::new();
    b.now = ms(100);
    b.sdo(req(0x40, 0x1008, 0, [0; 4])).unwrap();
    b.sdo([0x60, 0, 0, 0, 0, 0, 0, 0]).unwrap();
    assert_eq!(
        b.dev.next_deadline(),
        Some(ms(1000)),
        "the heartbeat comes first"
    );
    b.poll_at(ms(1000));
    b.take();
    assert_eq!(b.dev.next_deadline(), Some(ms(1100)));
    b.poll_at(ms(1099));
    assert_eq!(b.take(), vec![]);
    b.poll_at(ms(1100));
    assert_eq!(
        b.take(),
        vec![frame(SDO_TX, &abort(0x1008, 0, 0x0504_0000))]
    );
    assert_eq!(
        b.sdo([0x70, 0, 0, 0, 0, 0, 0, 0]),
        Some(abort(0, 0, 0x0504_0001))
    );
    // Download too, and each segment restarts the timer.
    b.now = ms(2000);
    b.sdo([0x21, 0x00, 0x22, 0x00, 10, 0, 0, 0]).unwrap();
    b.now = ms(2900);
    b.sdo([0x00, 1, 2, 3, 4, 5, 6, 7]).unwrap();
    b.poll_at(ms(3000));
    b.take();
    b.poll_at(ms(3899));
    assert_eq!(b.take(), vec![]);
    b.poll_at(ms(3900));
    assert_eq!(
        b.take(),
        vec![frame(SDO_TX, &abort(0x2200, 0, 0x0504_0000))]
    );
}

#[test]
fn client_abort_cancels_silently() {
    let mut b = Bench::new();
    b.sdo(req(0x40, 0x1008, 0, [0; 4])).unwrap();
    assert_eq!(b.sdo(abort(0x1008, 0, 0x0504_0000)), None);
    assert_eq!(
        b.sdo([0x60, 0, 0, 0, 0, 0, 0, 0]),
        Some(abort(0, 0, 0x0504_0001))
    );
    b.sdo([0x21, 0x17, 0x10, 0x00, 2, 0, 0, 0]).unwrap();
    assert_eq!(b.sdo(abort(0x1017, 0, 0x0800_0000)), None);
    assert_eq!(b.upload_u32(0x1017, 0), 1000);
    assert_eq!(b.dev.next_deadline(), Some(ms(1000)));
}

#[test]
fn requests_with_wrong_dlc_are_ignored() {
    let mut b = Bench::new();
    let before = b.dev.clone();
    for len in 0..8 {
        let data = [0x2F, 0x00, 0x20, 0x00, 1, 0, 0, 0];
        b.rx(frame(SDO_RX, &data[..len]));
        assert_eq!(b.take(), vec![]);
    }
    assert_eq!(b.dev, before);
    assert_eq!(b.app.flag, 0);
}

#[test]
fn sdo_in_stopped_gets_no_answer_and_cancels_transfers() {
    let mut b = Bench::new();
    b.sdo(req(0x40, 0x1008, 0, [0; 4])).unwrap();
    b.nmt(0x02, NODE);
    b.take();
    assert_eq!(b.sdo([0x60, 0, 0, 0, 0, 0, 0, 0]), None);
    assert_eq!(b.sdo(req(0x40, 0x1000, 0, [0; 4])), None);
    b.nmt(0x80, NODE);
    b.take();
    assert_eq!(
        b.sdo([0x60, 0, 0, 0, 0, 0, 0, 0]),
        Some(abort(0, 0, 0x0504_0001))
    );
}

#[test]
fn rejected_writes_leave_the_dictionary_unchanged() {
    let mut b = Bench::operational();
    let before = b.snapshot();
    let bad: [[u8; 8]; 16] = [
        req(0x2F, 0x2000, 0, [2, 0, 0, 0]),
        req(0x23, 0x2000, 0, [1, 0, 0, 0]),
        req(0x2B, 0x2100, 3, [0x00, 0x80, 0, 0]),
        req(0x2F, 0x1017, 0, [1, 0, 0, 0]),
        req(0x23, 0x1800, 1, [0x86, 0x01, 0, 0]),
        req(0x2B, 0x1800, 3, [1, 0, 0, 0]),
        req(0x2F, 0x1800, 2, [241, 0, 0, 0]),
        req(0x2F, 0x1A00, 0, [0, 0, 0, 0]),
        req(0x23, 0x1A00, 1, [0x08, 0x00, 0x05, 0x60]),
        req(0x2F, 0x1003, 0, [1, 0, 0, 0]),
        req(0x23, 0x1010, 1, [0x73, 0x61, 0x76, 0x66]),
        req(0x23, 0x1011, 1, [0, 0, 0, 0]),
        req(0x23, 0x1005, 0, [0x80, 0, 0, 0x40]),
        req(0x23, 0x1014, 0, [0x86, 0, 0, 0]),
        req(0x2F, 0x2300, 0, [7, 0, 0, 0]),
        req(0x23, 0x1016, 1, [0x64, 0, 0x20, 0]),
    ];
    b.download_u32(0x1016, 2, 0x0020_0064).unwrap();
    let before_consumer = b.snapshot();
    assert_ne!(before, before_consumer);
    for request in bad {
        let reply = b.sdo(request).unwrap();
        assert_eq!(reply[0], 0x80, "request {request:02x?} must be refused");
        assert_eq!(b.snapshot(), before_consumer, "request {request:02x?}");
    }
}

#[test]
fn identity_objects() {
    let mut b = Bench::new();
    assert_eq!(b.upload_u32(0x1018, 0), 4);
    assert_eq!(b.upload_u32(0x1018, 1), 0x123);
    assert_eq!(b.upload_u32(0x1018, 2), 0x4711);
    assert_eq!(b.upload_u32(0x1018, 3), 0x0001_0002);
    assert_eq!(b.upload_u32(0x1018, 4), 0xDEAD_BEEF);
    assert_eq!(b.upload_u32(0x1014, 0), 0x85);
    assert_eq!(b.upload_u32(0x1005, 0), 0x80);
    assert_eq!(b.upload_u32(0x1800, 1), 0x4000_0185);
    assert_eq!(b.upload_u32(0x1801, 1), 0x4000_0285);
    assert_eq!(b.upload_u32(0x1800, 0), 5);
    assert_eq!(b.upload_u32(0x1A00, 0), 2);
    assert_eq!(b.upload_u32(0x1A00, 1), 0x6004_0020);
    assert_eq!(b.upload_u32(0x1A00, 3), 0);
    assert_eq!(b.upload(0x1800, 4), Err(0x0609_0011));
    assert_eq!(b.upload(0x1802, 1), Err(0x0602_0000));
}
