//! Stored values are checked as SDO writes are: a page whose CRCs are valid but whose values
//! a master could not have written (a crafted page, one left by firmware with other rules, a
//! bug in the store path) restores every other object, keeps the refused object's default,
//! and reports it with EMCY 0x6300 (manufacturer bytes: the object's index and sub-index,
//! then how many objects were refused).

mod flash_bench;

use flash_bench::{CutFlash, Node, SAVE};
use handwheel_storage::page::{Flash, PAGE_SIZE};
use handwheel_storage::record::{self, NodeSettings, RECORD_MAX};

/// The engine blob's communication section, blob VERSION 1 (canopen-slave's storage tests
/// pin it): a 4-byte header, then one little-endian U32 per stored parameter in this order.
fn slot(index: u16, sub: u8) -> usize {
    let single = [
        (0x1005, 0),
        (0x1014, 0),
        (0x1015, 0),
        (0x1016, 1),
        (0x1016, 2),
        (0x1017, 0),
    ];
    let k = match single.iter().position(|&e| e == (index, sub)) {
        Some(k) => k,
        None => {
            let pdo = usize::from(index & 0x1FF);
            let per_pdo = 4 + 9;
            let within = if index & 0xFE00 == 0x1800 {
                [1, 2, 3, 5].iter().position(|&s| s == sub).unwrap()
            } else {
                4 + usize::from(sub)
            };
            single.len() + pdo * per_pdo + within
        }
    };
    4 + 4 * k
}

/// The blob a 0x1010 save of everything writes with the defaults in force, and the
/// producer heartbeat changed to 250 ms (to see that the rest is restored).
fn saved_blob() -> Vec<u8> {
    let mut node = Node::boot(flash_bench::erased_pages());
    node.write_u16(0x1017, 0, 250).unwrap();
    node.write_u32(0x1010, 1, SAVE).unwrap();
    let flash = node.flash();
    let page = handwheel_storage::page::ParameterPage::new(flash);
    page.stored().unwrap().1.to_vec()
}

/// A flash whose one record holds the saved blob with `changes` made, under valid CRCs.
fn crafted(changes: &[(u16, u8, u32)]) -> CutFlash {
    crafted_bytes(changes, &[])
}

/// [`crafted`], and bytes of the blob at given offsets set (the application section).
fn crafted_bytes(changes: &[(u16, u8, u32)], bytes: &[(usize, u8)]) -> CutFlash {
    let mut blob = saved_blob();
    for &(index, sub, value) in changes {
        let at = slot(index, sub);
        blob[at..at + 4].copy_from_slice(&value.to_le_bytes());
    }
    for &(at, value) in bytes {
        blob[at] = value;
    }
    let body = blob.len() - 2;
    let crc = canopen_slave::storage::crc16(&blob[..body]);
    blob[body..].copy_from_slice(&crc.to_le_bytes());
    let mut out = [0u8; RECORD_MAX];
    let len = record::encode(Some(NodeSettings::DEFAULT), &blob, 0, &mut out).unwrap();
    let mut flash = flash_bench::erased_pages();
    flash.bytes[..len].copy_from_slice(&out[..len]);
    assert_eq!(flash.page(0).len(), PAGE_SIZE);
    flash
}

/// Boots over `flash`; returns the node and the EMCYs (node 16: 0x090) of the boot.
fn boot(flash: CutFlash) -> (Node, Vec<[u8; 8]>) {
    let mut node = Node::boot(flash);
    // Sent at the boot or at the first poll after it.
    let mut frames = node.booted.clone();
    frames.extend(node.exchange(0x000, &[0x80, 0]));
    let emcys = frames
        .iter()
        .filter(|f| f.id() == 0x090)
        .map(|f| f.data().try_into().unwrap())
        .collect();
    (node, emcys)
}

fn read_u32(node: &mut Node, index: u16, sub: u8) -> u32 {
    let [i0, i1] = index.to_le_bytes();
    let data = node.sdo([0x40, i0, i1, sub, 0, 0, 0, 0]).unwrap();
    u32::from_le_bytes(data[4..8].try_into().unwrap())
}

/// Asserts the EMCY 0x6300 for `(index, sub)` and `count` refused objects, then its reset.
fn assert_reported(emcys: &[[u8; 8]], index: u16, sub: u8, count: u8) {
    let [lo, hi] = index.to_le_bytes();
    assert_eq!(emcys.len(), 2, "{emcys:02x?}");
    assert_eq!(emcys[0][..2], [0x00, 0x63]);
    assert_eq!(emcys[0][2] & 1, 1, "generic error bit");
    assert_eq!(emcys[0][3..], [lo, hi, sub, count, 0]);
    assert_eq!(emcys[1][..3], [0, 0, 0], "the error reset follows");
}

#[test]
fn the_saved_blob_restores_without_a_report() {
    let (mut node, emcys) = boot(crafted(&[]));
    assert!(emcys.is_empty(), "{emcys:02x?}");
    assert_eq!(node.read_u16(0x1017, 0), 250);
    assert_eq!(read_u32(&mut node, 0x1800, 1), 0x4000_0190);
}

#[test]
fn a_tpdo_cob_id_the_sdo_path_refuses_keeps_the_default() {
    // 0x000 (NMT), the master's heartbeat 0x701, the node's own EMCY 0x090, bit 29 set:
    // each as a valid PDO (bit 31 clear; bit 30 as a save stores it).
    for (cob, abort) in [
        (0x4000_0000, 0x0609_0030),
        (0x4000_0701, 0x0609_0030),
        (0x4000_0090, 0x0604_0043),
        (0x6000_0190, 0x0609_0030),
    ] {
        let (mut node, emcys) = boot(crafted(&[(0x1800, 1, cob)]));
        assert_reported(&emcys, 0x1800, 1, 1);
        assert_eq!(read_u32(&mut node, 0x1800, 1), 0x4000_0190, "{cob:#x}");
        // The rest of the page is restored.
        assert_eq!(node.read_u16(0x1017, 0), 250, "{cob:#x}");
        // And a master writing the same value gets the abort the restore applied.
        let disabled = node.write_u32(0x1800, 1, 0xC000_0190);
        assert_eq!(disabled, Ok(()));
        assert_eq!(node.write_u32(0x1800, 1, cob), Err(abort), "{cob:#x}");
    }
}

#[test]
fn a_mapping_of_eight_64_bit_entries_keeps_the_default_mapping() {
    let mut changes = vec![(0x1A00, 0, 8)];
    for sub in 1..=8 {
        changes.push((0x1A00, sub, 0x6004_0040));
    }
    let (mut node, emcys) = boot(crafted(&changes));
    assert_reported(&emcys, 0x1A00, 1, 1);
    assert_eq!(read_u32(&mut node, 0x1A00, 0), 4);
    assert_eq!(read_u32(&mut node, 0x1A00, 1), 0x6004_0020);
    assert_eq!(read_u32(&mut node, 0x1A00, 4), 0x2031_0010);
    assert_eq!(read_u32(&mut node, 0x1A00, 5), 0);
    // The PDO is still valid on its default identifier.
    assert_eq!(read_u32(&mut node, 0x1800, 1), 0x4000_0190);
}

#[test]
fn a_consumer_heartbeat_of_the_node_itself_and_an_emcy_cob_id_clash_are_refused() {
    // 0x1016:1 watching node 16 (this node), 0x1014 on TPDO1's identifier: two objects.
    let (mut node, emcys) = boot(crafted(&[(0x1016, 1, 0x0010_03E8), (0x1014, 0, 0x190)]));
    assert_reported(&emcys, 0x1016, 1, 2);
    assert_eq!(read_u32(&mut node, 0x1016, 1), 0);
    assert_eq!(read_u32(&mut node, 0x1014, 0), 0x090);
    assert_eq!(read_u32(&mut node, 0x1800, 1), 0x4000_0190);
}

#[test]
fn legitimate_moves_of_identifiers_are_restored() {
    // TPDO1 on TPDO2's default identifier and TPDO2 elsewhere: valid only together, as a
    // master sets them up (TPDO2 moved away first). The restore must not refuse either.
    let (mut node, emcys) = boot(crafted(&[
        (0x1800, 1, 0x4000_0290),
        (0x1801, 1, 0x4000_0391),
        (0x1014, 0, 0x0000_00A0),
    ]));
    assert!(emcys.is_empty(), "{emcys:02x?}");
    assert_eq!(read_u32(&mut node, 0x1800, 1), 0x4000_0290);
    assert_eq!(read_u32(&mut node, 0x1801, 1), 0x4000_0391);
    assert_eq!(read_u32(&mut node, 0x1014, 0), 0xA0);
}

#[test]
fn an_application_value_out_of_range_keeps_the_application_defaults() {
    // The application section follows the communication section (32 parameters): version,
    // unit-step mode, counts per detent, invert, backlog bound. Counts per detent 3 is what
    // an SDO write of 0x2020:3 refuses.
    let app = 4 + 4 * 32;
    let (mut node, emcys) = boot(crafted_bytes(&[], &[(app + 2, 3)]));
    assert_reported(&emcys, 0x2020, 3, 1);
    assert_eq!(node.read_u16(0x2020, 3) & 0xFF, 4, "the default");
    assert_eq!(
        node.read_u16(0x1017, 0),
        250,
        "the communication parameters are restored"
    );
    // The application section as saved restores without a report.
    let (mut node, emcys) = boot(crafted_bytes(&[], &[(app + 2, 2)]));
    assert!(emcys.is_empty(), "{emcys:02x?}");
    assert_eq!(node.read_u16(0x2020, 3) & 0xFF, 2);
}
