//! RPDO1 (0x1400 / 0x1600): the objects and their checked writes, reception in Operational
//! through the application's checked writes, length errors, SYNC, deadline monitoring, the
//! acceptance filter, and storage (including a blob stored before the RPDO existed).
mod common;
use canopen_slave::storage::crc16;
use canopen_slave::{MemoryStorage, NodeId, RxFilter, Storage};
use common::*;

const SAVE: u32 = 0x6576_6173;
const LOAD: u32 = 0x6461_6F6C;
/// EMCY error register with an RPDO error active: generic and communication.
const REG: u8 = 0x11;

fn node() -> NodeId {
    NodeId::new(NODE).unwrap()
}

/// The CiA 301 re-mapping procedure: invalid, count 0, entries, count, valid on `cob_id`.
fn remap(b: &mut Bench, entries: &[u32], cob_id: u32) {
    b.download_u32(0x1400, 1, 0x8000_0000 | cob_id).unwrap();
    b.download(0x1600, 0, &[0]).unwrap();
    for (k, &e) in entries.iter().enumerate() {
        b.download_u32(0x1600, k as u8 + 1, e).unwrap();
    }
    b.download(0x1600, 0, &[entries.len() as u8]).unwrap();
    b.download_u32(0x1400, 1, cob_id).unwrap();
}

/// Polls at `t` and returns the EMCY payloads sent.
fn emcys_at(b: &mut Bench, t: u64) -> Vec<Vec<u8>> {
    b.poll_at(ms(t));
    b.take()
        .iter()
        .filter(|f| f.id() == EMCY)
        .map(|f| f.data().to_vec())
        .collect()
}

#[test]
fn objects_read_their_defaults() {
    let mut b = Bench::new();
    assert_eq!(b.upload_u32(0x1400, 0), 5);
    assert_eq!(b.upload_u32(0x1400, 1), u32::from(RPDO1));
    assert_eq!(b.upload_u32(0x1400, 2), 255);
    assert_eq!(b.upload_u32(0x1400, 5), 0);
    assert_eq!(b.upload(0x1400, 3), Err(0x0609_0011));
    assert_eq!(b.upload(0x1400, 4), Err(0x0609_0011));
    assert_eq!(b.upload_u32(0x1600, 0), 1);
    assert_eq!(b.upload_u32(0x1600, 1), 0x6200_0108);
    assert_eq!(b.upload_u32(0x1600, 2), 0);
    assert_eq!(b.upload(0x1401, 1), Err(0x0602_0000));
    assert_eq!(b.upload(0x1601, 0), Err(0x0602_0000));
    assert_eq!(b.download(0x1400, 0, &[5]), Err(0x0601_0002));
}

#[test]
fn a_frame_in_operational_is_written_with_its_exact_bytes() {
    let mut b = Bench::operational();
    b.rx_at(ms(1), frame(RPDO1, &[0x5A]));
    assert_eq!(b.app.writes, vec![(0x6200, 1, vec![0x5A])]);
    assert_eq!(b.app.outputs, 0x5A);
    assert_eq!(b.app.rpdos, vec![1]);
    assert!(emcys_at(&mut b, 1).is_empty());
    assert_eq!(b.upload(0x6200, 1), Ok(vec![0x5A]));
}

#[test]
fn outside_operational_frames_are_ignored() {
    let mut b = Bench::new();
    let before = b.dev.clone();
    b.rx_at(ms(1), frame(RPDO1, &[0x5A]));
    assert_eq!(b.dev, before, "Pre-operational");
    b.nmt(0x02, NODE);
    b.take();
    let before = b.dev.clone();
    b.rx_at(ms(2), frame(RPDO1, &[0x5A]));
    b.rx_at(ms(3), frame(RPDO1, &[]));
    assert_eq!(b.dev, before, "Stopped");
    assert!(b.app.writes.is_empty() && b.app.rpdos.is_empty());
    assert!(b.take().is_empty());
}

#[test]
fn several_objects_and_a_dummy_entry_are_decoded_in_order() {
    let mut b = Bench::operational();
    // INTEGER16, a skipped UNSIGNED8 (dummy 0x0005), UNSIGNED32 (write-only), UNSIGNED8.
    let entries = [0x6201_0010, 0x0005_0008, 0x6202_0020, 0x6200_0108];
    remap(&mut b, &entries, u32::from(RPDO1));
    assert_eq!(b.upload_u32(0x1600, 0), 4);
    b.rx_at(ms(1), frame(RPDO1, &[0x9C, 0xFF, 0xEE, 1, 2, 3, 4, 0x81]));
    assert_eq!(
        b.app.writes,
        vec![
            (0x6201, 0, vec![0x9C, 0xFF]),
            (0x6202, 0, vec![1, 2, 3, 4]),
            (0x6200, 1, vec![0x81]),
        ]
    );
    assert_eq!(
        (b.app.level, b.app.word, b.app.outputs),
        (-100, 0x0403_0201, 0x81)
    );
    // Every dummy type, at its size only.
    b.download_u32(0x1400, 1, 0x8000_0000 | u32::from(RPDO1))
        .unwrap();
    b.download(0x1600, 0, &[0]).unwrap();
    for (k, dummy) in [
        0x0002_0008,
        0x0003_0010,
        0x0004_0020,
        0x0006_0010,
        0x0007_0020,
    ]
    .into_iter()
    .enumerate()
    {
        b.download_u32(0x1600, k as u8 + 1, dummy).unwrap();
    }
    assert_eq!(b.download_u32(0x1600, 6, 0x0005_0010), Err(0x0604_0041));
    assert_eq!(b.download_u32(0x1600, 6, 0x0005_0108), Err(0x0604_0041));
    assert_eq!(b.download_u32(0x1600, 6, 0x0001_0001), Err(0x0602_0000));
}

#[test]
fn mapping_writes_follow_the_re_mapping_procedure() {
    let mut b = Bench::new();
    // Valid: nothing of the mapping changes.
    assert_eq!(b.download(0x1600, 0, &[0]), Err(0x0601_0000));
    assert_eq!(b.download_u32(0x1600, 1, 0x6201_0010), Err(0x0601_0000));
    b.download_u32(0x1400, 1, 0x8000_0000 | u32::from(RPDO1))
        .unwrap();
    // Invalid but sub 0 not 0: entries stay.
    assert_eq!(b.download_u32(0x1600, 1, 0x6201_0010), Err(0x0601_0000));
    b.download(0x1600, 0, &[0]).unwrap();
    for (entry, code) in [
        (0x7000_0008, 0x0602_0000), // no such object
        (0x6200_0208, 0x0609_0011), // no such sub-index
        (0x6005_0008, 0x0604_0041), // read-only
        (0x6204_0008, 0x0604_0041), // not mappable
        (0x6200_0110, 0x0604_0041), // not its size
        (0x2200_0008, 0x0604_0041), // a string
        (0x1017_0010, 0x0604_0041), // a communication parameter
    ] {
        assert_eq!(b.download_u32(0x1600, 1, entry), Err(code), "{entry:#x}");
    }
    assert_eq!(b.download_u32(0x1600, 9, 0x6200_0108), Err(0x0609_0011));
    for k in 1..=3 {
        b.download_u32(0x1600, k, 0x6202_0020).unwrap();
    }
    assert_eq!(b.download(0x1600, 0, &[3]), Err(0x0604_0042), "96 bits");
    assert_eq!(b.download(0x1600, 0, &[9]), Err(0x0604_0042));
    assert_eq!(b.download(0x1600, 0, &[2]), Ok(()), "64 bits");
    b.download(0x1600, 0, &[0]).unwrap();
    // A count past a cleared entry.
    b.download_u32(0x1600, 2, 0).unwrap();
    assert_eq!(b.download(0x1600, 0, &[2]), Err(0x0602_0000));
    assert_eq!(b.upload_u32(0x1600, 0), 0);
    b.download(0x1600, 0, &[1]).unwrap();
    assert_eq!(b.upload_u32(0x1600, 1), 0x6202_0020);
}

#[test]
fn cob_id_writes_are_checked_as_the_tpdos_are() {
    let mut b = Bench::new();
    let rpdo = u32::from(RPDO1);
    assert_eq!(
        b.download_u32(0x1400, 1, rpdo + 1),
        Err(0x0609_0030),
        "valid"
    );
    assert_eq!(b.download_u32(0x1400, 1, rpdo), Ok(()), "unchanged");
    assert_eq!(
        b.download_u32(0x1400, 1, 0x2000_0000 | rpdo),
        Err(0x0609_0030)
    );
    b.download_u32(0x1400, 1, 0x8000_0000 | rpdo).unwrap();
    for (value, code) in [
        (0xA000_0305, 0x0609_0030), // 29-bit
        (0x0000_0805, 0x0609_0030), // bits 11..28
        (0x0000_0000, 0x0609_0030), // NMT
        (0x0000_0705, 0x0609_0030), // heartbeat
        (0x0000_0605, 0x0609_0030), // SDO
        (0x0000_0080, 0x0604_0043), // SYNC
        (u32::from(EMCY), 0x0604_0043),
        (u32::from(TPDO1), 0x0604_0043),
        (u32::from(TPDO2), 0x0604_0043),
    ] {
        assert_eq!(b.download_u32(0x1400, 1, value), Err(code), "{value:#x}");
    }
    assert_eq!(b.upload_u32(0x1400, 1), 0x8000_0000 | rpdo);
    b.download_u32(0x1400, 1, 0x305).unwrap();
    assert_eq!(b.upload_u32(0x1400, 1), 0x305);
    // Now others may not take it.
    b.download_u32(0x1800, 1, 0xC000_0000 | u32::from(TPDO1))
        .unwrap();
    assert_eq!(b.download_u32(0x1800, 1, 0x305), Err(0x0604_0043));
    assert_eq!(b.download_u32(0x1201, 1, 0x305), Err(0x0604_0043));
    assert_eq!(b.download_u32(0x1005, 0, 0x305), Err(0x0604_0043));
    // Transmission types: 0..=240, 254, 255.
    for t in [0u8, 1, 240, 254, 255] {
        assert_eq!(b.download(0x1400, 2, &[t]), Ok(()), "{t}");
    }
    for t in [241u8, 250, 252, 253] {
        assert_eq!(b.download(0x1400, 2, &[t]), Err(0x0609_0030), "{t}");
    }
    assert_eq!(b.download(0x1400, 3, &[0, 0]), Err(0x0609_0011));
}

#[test]
fn a_moved_cob_id_moves_the_filter_and_the_reception() {
    let mut b = Bench::operational();
    assert!(b.dev.rx_filter().accepts(RPDO1));
    b.download_u32(0x1400, 1, 0x8000_0000 | u32::from(RPDO1))
        .unwrap();
    assert_eq!(b.dev.rx_filter(), RxFilter::new(node()), "invalid: dropped");
    b.rx_at(ms(1), frame(RPDO1, &[1]));
    assert!(b.app.writes.is_empty());
    b.download_u32(0x1400, 1, 0x305).unwrap();
    let filter = b.dev.rx_filter();
    assert_eq!(filter.rpdo(), 0x305);
    assert!(filter.accepts(0x305) && !filter.accepts(RPDO1));
    b.rx_at(ms(2), frame(RPDO1, &[2]));
    b.rx_at(ms(3), frame(0x305, &[3]));
    assert_eq!(b.app.writes, vec![(0x6200, 1, vec![3])]);
    // Valid but mapping nothing: not received, not in the filter.
    b.download_u32(0x1400, 1, 0x8000_0305).unwrap();
    b.download(0x1600, 0, &[0]).unwrap();
    b.download_u32(0x1400, 1, 0x305).unwrap();
    assert_eq!(b.dev.rx_filter(), RxFilter::new(node()));
    // Reset communication: the default again.
    b.nmt(0x82, NODE);
    assert_eq!(
        b.dev.rx_filter(),
        RxFilter::new(node()).with_rpdo(Some(RPDO1))
    );
}

#[test]
fn length_errors_raise_one_emcy_each_until_a_good_frame() {
    let mut b = Bench::operational();
    remap(&mut b, &[0x6200_0108, 0x6201_0010], u32::from(RPDO1));
    b.take();
    // Short: not processed, 0x8210 (PDO 1, 3 bytes mapped, 2 received).
    b.rx_at(ms(1), frame(RPDO1, &[1, 2]));
    b.rx_at(ms(2), frame(RPDO1, &[1]));
    assert!(b.app.writes.is_empty());
    assert_eq!(
        emcys_at(&mut b, 2),
        vec![vec![0x10, 0x82, REG, 1, 3, 2, 0, 0]]
    );
    assert_eq!(b.dev.stats().rpdo_errors, 2);
    // Exact: written, the error reset.
    b.rx_at(ms(3), frame(RPDO1, &[7, 5, 0]));
    assert_eq!(b.app.writes.len(), 2);
    assert_eq!(emcys_at(&mut b, 3), vec![vec![0; 8]]);
    // Long: written, 0x8220 once.
    b.rx_at(ms(4), frame(RPDO1, &[8, 6, 0, 0xFF, 0xFF]));
    b.rx_at(ms(5), frame(RPDO1, &[9, 6, 0, 0xFF]));
    assert_eq!((b.app.outputs, b.app.level), (9, 6));
    assert_eq!(
        emcys_at(&mut b, 5),
        vec![vec![0x20, 0x82, REG, 1, 3, 5, 0, 0]]
    );
    // Short after long: one condition replaces the other.
    b.rx_at(ms(6), frame(RPDO1, &[]));
    assert_eq!(
        emcys_at(&mut b, 6),
        vec![vec![0x10, 0x82, REG, 1, 3, 0, 0, 0]]
    );
    assert_eq!(b.upload_u32(0x1001, 0), u32::from(REG));
    assert_eq!(b.dev.stats().rpdo_errors, 3);
    assert_eq!(b.app.rpdos, vec![1, 1, 1]);
}

#[test]
fn a_refused_value_refuses_the_whole_frame() {
    let mut b = Bench::operational();
    remap(&mut b, &[0x6200_0108, 0x6201_0010], u32::from(RPDO1));
    // 0x6201 takes -100..=100: 200 is out of the table's range; 0x6200 is not written.
    b.rx_at(ms(1), frame(RPDO1, &[0x11, 200, 0]));
    assert!(b.app.writes.is_empty());
    assert_eq!(b.app.outputs, 0);
    assert!(b.app.rpdos.is_empty());
    assert_eq!(b.dev.stats().rpdo_errors, 1);
    assert_eq!(
        emcys_at(&mut b, 1),
        vec![vec![0x00, 0x82, REG, 1, 0x01, 0x62, 0x00, 0]]
    );
    // The application's own refusal (0x6203 = 0xEE): checked before anything is written.
    remap(&mut b, &[0x6200_0108, 0x6203_0008], u32::from(RPDO1));
    b.rx_at(ms(2), frame(RPDO1, &[0x22, 0xEE]));
    assert!(b.app.writes.is_empty());
    assert_eq!(b.dev.stats().rpdo_errors, 2);
    assert!(
        emcys_at(&mut b, 2).is_empty(),
        "the condition is still active"
    );
    b.rx_at(ms(3), frame(RPDO1, &[0x22, 0xED]));
    assert_eq!(
        b.app.writes,
        vec![(0x6200, 1, vec![0x22]), (0x6203, 0, vec![0xED])]
    );
    assert_eq!(emcys_at(&mut b, 3), vec![vec![0; 8]]);
}

#[test]
fn synchronous_types_act_at_the_next_sync() {
    for t in [0u8, 1, 240] {
        let mut b = Bench::operational();
        b.download(0x1400, 2, &[t]).unwrap();
        b.rx_at(ms(1), frame(RPDO1, &[1]));
        b.rx_at(ms(2), frame(RPDO1, &[2]));
        assert!(b.app.writes.is_empty(), "type {t}");
        b.rx_at(ms(3), frame(0x080, &[]));
        assert_eq!(b.app.writes, vec![(0x6200, 1, vec![2])], "the newest, once");
        assert_eq!(b.app.rpdos, vec![1]);
        b.rx_at(ms(4), frame(0x080, &[]));
        assert_eq!(b.app.writes.len(), 1);
        // Held data does not survive leaving Operational.
        b.rx_at(ms(5), frame(RPDO1, &[3]));
        b.nmt(0x80, NODE);
        b.nmt(0x01, NODE);
        b.rx_at(ms(6), frame(0x080, &[]));
        b.take();
        assert_eq!(b.app.writes.len(), 1);
        // A refusal at the SYNC: nothing written, EMCY 0x8200.
        remap(&mut b, &[0x6203_0008], u32::from(RPDO1));
        b.take();
        b.rx_at(ms(7), frame(RPDO1, &[0xEE]));
        b.rx_at(ms(8), frame(0x080, &[]));
        assert_eq!(b.app.writes.len(), 1);
        assert_eq!(
            emcys_at(&mut b, 8),
            vec![vec![0x00, 0x82, REG, 1, 0x03, 0x62, 0x00, 0]]
        );
    }
}

#[test]
fn deadline_monitoring_starts_at_the_first_frame() {
    let mut b = Bench::operational();
    b.download(0x1400, 5, &100u16.to_le_bytes()).unwrap();
    b.take();
    // No frame yet: no monitoring.
    assert!(emcys_at(&mut b, 500).is_empty());
    assert!(b.app.rpdo_timeouts.is_empty());
    b.rx_at(ms(600), frame(RPDO1, &[1]));
    assert!(b.dev.next_deadline() <= Some(ms(700)));
    b.rx_at(ms(650), frame(RPDO1, &[2]));
    assert!(emcys_at(&mut b, 749).is_empty());
    assert_eq!(
        emcys_at(&mut b, 750),
        vec![vec![0x50, 0x82, REG, 1, 0, 0, 0, 0]]
    );
    assert_eq!(b.app.rpdo_timeouts, vec![1]);
    // Once per timeout.
    assert!(emcys_at(&mut b, 2000).is_empty());
    assert_eq!(b.app.rpdo_timeouts, vec![1]);
    // The next frame ends it and restarts monitoring.
    b.rx_at(ms(2100), frame(RPDO1, &[3]));
    assert_eq!(emcys_at(&mut b, 2100), vec![vec![0; 8]]);
    assert_eq!(b.upload_u32(0x1001, 0), 0);
    // Leaving Operational stops it.
    b.nmt(0x80, NODE);
    b.take();
    assert!(emcys_at(&mut b, 3000).is_empty());
    assert_eq!(b.app.rpdo_timeouts, vec![1]);
    // A short frame is not a reception: it does not restart the deadline.
    b.nmt(0x01, NODE);
    b.rx_at(ms(3000), frame(RPDO1, &[4]));
    b.rx_at(ms(3050), frame(RPDO1, &[]));
    b.poll_at(ms(3100));
    assert_eq!(b.app.rpdo_timeouts, vec![1, 1]);
}

#[test]
fn reset_communication_clears_the_rpdo_errors() {
    let mut b = Bench::operational();
    b.rx_at(ms(1), frame(RPDO1, &[]));
    assert_eq!(b.upload_u32(0x1001, 0), u32::from(REG));
    b.nmt(0x82, NODE);
    b.take();
    assert_eq!(b.upload_u32(0x1001, 0), 0);
}

/// RPDO1 on 0x305, synchronous, monitored, mapping 0x6201.
fn customise_rpdo(b: &mut Bench) {
    remap(b, &[0x6201_0010], 0x305);
    b.download(0x1400, 2, &[0]).unwrap();
    b.download(0x1400, 5, &50u16.to_le_bytes()).unwrap();
}

fn assert_rpdo(b: &mut Bench, cob_id: u32, kind: u32, timer: u32, mapping: &[u32]) {
    assert_eq!(b.upload_u32(0x1400, 1), cob_id);
    assert_eq!(b.upload_u32(0x1400, 2), kind);
    assert_eq!(b.upload_u32(0x1400, 5), timer);
    assert_eq!(b.upload_u32(0x1600, 0), mapping.len() as u32);
    for (k, &e) in mapping.iter().enumerate() {
        assert_eq!(b.upload_u32(0x1600, k as u8 + 1), e);
    }
}

#[test]
fn stored_restored_at_reset_and_power_on_and_defaults_by_0x1011() {
    let mut b = Bench::new();
    customise_rpdo(&mut b);
    b.download_u32(0x1010, 2, SAVE).unwrap();
    b.download_u32(0x1400, 1, 0x8000_0305).unwrap();
    b.nmt(0x82, NODE);
    b.take();
    assert_rpdo(&mut b, 0x305, 0, 50, &[0x6201_0010]);
    assert_eq!(b.dev.rx_filter().rpdo(), 0x305);
    let mut b = Bench::with_storage(b.dev.storage().clone());
    assert_rpdo(&mut b, 0x305, 0, 50, &[0x6201_0010]);
    b.download_u32(0x1011, 1, LOAD).unwrap();
    assert_rpdo(&mut b, 0x305, 0, 50, &[0x6201_0010]);
    b.nmt(0x82, NODE);
    b.take();
    assert_rpdo(&mut b, u32::from(RPDO1), 255, 0, &[0x6200_0108]);
}

#[test]
fn a_blob_stored_before_the_rpdo_restores_all_it_holds() {
    // Today's blob of a customised device: heartbeat, a consumer, TPDO settings, the
    // application's two bytes, and RPDO changes that the older layout cannot hold.
    let mut b = Bench::new();
    b.download(0x1017, 0, &250u16.to_le_bytes()).unwrap();
    b.download_u32(0x1016, 1, 0x0007_0064).unwrap();
    b.download(0x1800, 5, &50u16.to_le_bytes()).unwrap();
    b.download_u32(0x1801, 1, 0x8000_0285).unwrap();
    b.download(0x1A01, 0, &[0]).unwrap();
    b.download_u32(0x1A01, 1, 0x6004_0020).unwrap();
    b.download(0x1A01, 0, &[1]).unwrap();
    b.download(0x2000, 0, &[1]).unwrap();
    b.download(0x2100, 5, &[9]).unwrap();
    customise_rpdo(&mut b);
    b.download_u32(0x1010, 1, SAVE).unwrap();
    let today = b.dev.storage().bytes().to_vec();
    // Version 2: header, 32 parameters of version 1, the application, 12 RPDO parameters.
    assert_eq!(today[..4], [0xC0, 2, 3, 2]);
    assert_eq!(today.len(), 4 + 32 * 4 + 2 + 12 * 4 + 2);
    assert_eq!(today[4 + 5 * 4..4 + 6 * 4], 250u32.to_le_bytes(), "0x1017");
    assert_eq!(today[4 + 32 * 4..4 + 32 * 4 + 2], [1, 9], "application");
    assert_eq!(today[134..138], 0x305u32.to_le_bytes(), "0x1400:1");

    // The same parameters as firmware before the RPDO stored them: version 1, no RPDO.
    let mut old = vec![0xC0, 1, 3, 2];
    old.extend_from_slice(&today[4..4 + 32 * 4 + 2]);
    let crc = crc16(&old);
    old.extend_from_slice(&crc.to_le_bytes());
    let mut storage = MemoryStorage::new();
    storage.store(ms(0), &old).unwrap();

    let mut b = Bench::with_storage(storage);
    assert_eq!(b.upload_u32(0x1017, 0), 250);
    assert_eq!(b.upload_u32(0x1016, 1), 0x0007_0064);
    assert_eq!(b.upload_u32(0x1800, 5), 50);
    assert_eq!(b.upload_u32(0x1801, 1), 0xC000_0285);
    assert_eq!(b.upload_u32(0x1A01, 0), 1);
    assert_eq!(b.upload_u32(0x1A01, 1), 0x6004_0020);
    assert_eq!((b.app.flag, b.app.vars[5]), (1, 9));
    assert_rpdo(&mut b, u32::from(RPDO1), 255, 0, &[0x6200_0108]);
    assert_eq!(b.upload_u32(0x1001, 0), 0, "nothing refused");
    // Received at once on its default identifier.
    b.nmt(0x01, NODE);
    b.rx_at(ms(1), frame(RPDO1, &[0x42]));
    assert_eq!(b.app.outputs, 0x42);
    assert!(b.take().iter().all(|f| f.id() != EMCY));

    // Saving the application only keeps the older layout; saving communication moves on.
    b.download_u32(0x1010, 3, SAVE).unwrap();
    assert_eq!(b.dev.storage().bytes()[1], 1);
    assert_eq!(b.dev.storage().bytes().len(), old.len());
    b.nmt(0x82, NODE);
    b.take();
    assert_eq!(b.upload_u32(0x1017, 0), 250);
    // So does saving communication with the RPDO at its defaults (a restore gives them
    // anyway); a changed RPDO moves on to version 2.
    b.download_u32(0x1010, 2, SAVE).unwrap();
    assert_eq!(b.dev.storage().bytes()[1], 1);
    assert_eq!(b.dev.storage().bytes().len(), old.len());
    customise_rpdo(&mut b);
    b.download_u32(0x1010, 2, SAVE).unwrap();
    assert_eq!(b.dev.storage().bytes()[1], 2);
    assert_eq!(b.dev.storage().bytes().len(), today.len());
    let mut b = Bench::with_storage(b.dev.storage().clone());
    assert_eq!(b.upload_u32(0x1017, 0), 250);
    assert_eq!((b.app.flag, b.app.vars[5]), (1, 9));
    assert_rpdo(&mut b, 0x305, 0, 50, &[0x6201_0010]);

    // An unknown version still reads as nothing stored.
    let mut newer = old.clone();
    newer[1] = 3;
    let body = newer.len() - 2;
    let crc = crc16(&newer[..body]);
    newer[body..].copy_from_slice(&crc.to_le_bytes());
    let mut storage = MemoryStorage::new();
    storage.store(ms(0), &newer).unwrap();
    let mut b = Bench::with_storage(storage);
    assert_eq!(b.upload_u32(0x1017, 0), 1000);
}
