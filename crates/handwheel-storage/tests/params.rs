//! The stored parameter record and the boot-time choice of node-ID and bit rate.
//!
//! The record comes back from flash, which may hold anything (erased, half-written, damaged,
//! another layout): decoding must refuse all of it rather than guess, and never panic. How
//! records are written to the page (log, wear budget) is `tests/page.rs`.

use canopen_slave::NodeId;
use handwheel_core::BitRate;
use handwheel_storage::node_config::{select, Source};
use handwheel_storage::record::{
    crc32, decode, encode, scan, NodeSettings, Record, BLOB_MAX, RECORD_MAX,
};
use proptest::prelude::*;

const SETTINGS: NodeSettings = NodeSettings {
    node_id: id(42),
    bit_rate: BitRate::Kbit250,
};

const fn id(n: u8) -> Option<NodeId> {
    match NodeId::new(n) {
        Ok(id) => Some(id),
        Err(_) => None,
    }
}

fn encoded(settings: NodeSettings, blob: &[u8]) -> Vec<u8> {
    encoded_with(Some(settings), blob, 0)
}

fn encoded_with(settings: Option<NodeSettings>, blob: &[u8], debt: u16) -> Vec<u8> {
    let mut out = [0u8; RECORD_MAX];
    let len = encode(settings, blob, debt, &mut out).expect("blob fits");
    out[..len].to_vec()
}

/// The stored state of a record: settings and blob.
fn state(bytes: &[u8]) -> Option<(NodeSettings, &[u8])> {
    let r = decode(bytes)?;
    Some((r.settings?, r.blob))
}

#[test]
fn crc32_is_the_ieee_one() {
    // The standard check value of CRC-32/ISO-HDLC (zlib, Ethernet).
    assert_eq!(crc32(b"123456789"), 0xCBF4_3926);
    assert_eq!(crc32(b""), 0);
}

#[test]
fn the_layout_is_the_documented_one() {
    let bytes = encoded_with(Some(SETTINGS), &[0xA5, 0x01, 0x02], 0x1234);
    // 10 header + 3 blob + 4 CRC = 17, padded to 18 with 0xFF.
    assert_eq!(bytes.len(), 18);
    assert_eq!(&bytes[..4], b"HWP2");
    assert_eq!(bytes[4], 42);
    assert_eq!(bytes[5], BitRate::Kbit250.code());
    assert_eq!(&bytes[6..8], &[3, 0]);
    assert_eq!(&bytes[8..10], &[0x34, 0x12]);
    assert_eq!(&bytes[10..13], &[0xA5, 0x01, 0x02]);
    assert_eq!(&bytes[13..17], &crc32(&bytes[..13]).to_le_bytes());
    assert_eq!(bytes[17], 0xFF);
    let record = decode(&bytes).unwrap();
    assert_eq!(record.debt, 0x1234);
    // "Nothing stored": node-ID 0, code 0, no blob.
    let cleared = encoded_with(None, &[], 7);
    assert_eq!(&cleared[4..10], &[0, 0, 0, 0, 7, 0]);
    assert_eq!(
        decode(&cleared),
        Some(Record {
            settings: None,
            blob: &[],
            debt: 7,
            generation: 0
        })
    );
}

#[test]
fn an_even_record_has_no_pad_byte() {
    assert_eq!(encoded(SETTINGS, &[1, 2]).len(), 16);
    assert_eq!(encoded(SETTINGS, &[]).len(), 14);
    assert_eq!(encoded(SETTINGS, &[0; BLOB_MAX]).len(), RECORD_MAX);
}

#[test]
fn an_oversized_blob_is_refused() {
    let mut out = [0u8; RECORD_MAX];
    assert_eq!(
        encode(Some(SETTINGS), &[0; BLOB_MAX + 1], 0, &mut out),
        None
    );
}

#[test]
fn an_erased_or_short_page_holds_nothing() {
    assert_eq!(decode(&[0xFF; 1024]), None);
    assert_eq!(decode(&[0x00; 1024]), None);
    assert_eq!(decode(&encoded(SETTINGS, &[1, 2, 3])[..12]), None);
    assert_eq!(decode(&[]), None);
    let empty = scan(&[0xFF; 1024]);
    assert_eq!((empty.newest, empty.free), (None, 0));
}

#[test]
fn a_record_with_a_valid_crc_but_impossible_settings_is_refused() {
    // Node-ID 0 is "nothing stored" only with code 0 and no blob.
    for (node_id, code, blob) in [
        (0u8, 1u8, &[][..]),
        (0, 0, &[5][..]),
        (128, 0, &[]),
        (254, 0, &[]),
        (16, 8, &[]),
    ] {
        let mut bytes = encoded(SETTINGS, blob);
        bytes[4] = node_id;
        bytes[5] = code;
        let body = 10 + blob.len();
        let crc = crc32(&bytes[..body]).to_le_bytes();
        bytes[body..body + 4].copy_from_slice(&crc);
        assert_eq!(decode(&bytes), None, "node {node_id} code {code}");
    }
}

#[test]
fn an_unconfigured_node_id_is_stored_as_0xff() {
    let unconfigured = NodeSettings::from_parts(0xFF, 3).unwrap();
    assert_eq!(unconfigured.node_id, None);
    let bytes = encoded(unconfigured, &[7]);
    assert_eq!(bytes[4], 0xFF);
    assert_eq!(state(&bytes), Some((unconfigured, &[7u8][..])));
    assert_eq!(SETTINGS.node_id_byte(), 42);
}

#[test]
fn the_last_intact_record_of_the_log_is_the_stored_state() {
    let other = NodeSettings::from_parts(7, 0).unwrap();
    let mut page = encoded(SETTINGS, &[1, 2, 3]);
    let second = page.len();
    page.extend(encoded(other, &[4]));
    page.extend(encoded_with(None, &[], 3));
    let end = page.len();
    page.resize(1024, 0xFF);
    let log = scan(&page);
    assert_eq!(log.free, end);
    assert_eq!(log.newest.map(|r| (r.settings, r.debt)), Some((None, 3)));
    // The last one damaged (a store cut off by a power loss): the one before counts, and
    // the next record goes after the damaged one.
    page[end - 5] ^= 0x10;
    let log = scan(&page);
    assert_eq!(log.free, end);
    assert_eq!(
        log.newest.map(|r| (r.settings, r.blob)),
        Some((Some(other), &[4u8][..]))
    );
    // An unreadable header: what came before still counts, and nothing can be appended.
    page[second] = 0;
    let log = scan(&page);
    assert_eq!(log.free, 1024);
    assert_eq!(log.newest.map(|r| r.blob), Some(&[1u8, 2, 3][..]));
}

#[test]
fn lss_bit_timing_indices_map_onto_the_dip_table() {
    use handwheel_storage::node_config::{bit_rate_from_lss, lss_bit_timing};
    let kbit = [1000, 800, 500, 250, 125, 0, 50, 20, 10];
    for (index, &k) in kbit.iter().enumerate() {
        let index = index as u8;
        match bit_rate_from_lss(index) {
            Some(rate) => {
                assert_eq!(rate.kbit_per_second(), k);
                assert_eq!(lss_bit_timing(rate), index);
            }
            None => assert_eq!(index, 5),
        }
    }
    assert_eq!(bit_rate_from_lss(9), None);
    for rate in BitRate::ALL {
        assert_eq!(bit_rate_from_lss(lss_bit_timing(rate)), Some(rate));
    }
    // What the device tells its LSS slave it supports: 0-8 without 5.
    assert_eq!(
        handwheel_storage::node_config::LSS_BIT_TIMINGS,
        0b1_1101_1111
    );
}

#[test]
fn lss_store_configuration_settings() {
    use handwheel_storage::record::NodeSettings;
    let s = NodeSettings::from_lss(5, 2).unwrap();
    assert_eq!((s.node_id, s.bit_rate), (id(5), BitRate::Kbit500));
    assert_eq!(NodeSettings::from_lss(0xFF, 0).unwrap().node_id, None);
    assert_eq!(
        NodeSettings::from_lss(5, 5),
        None,
        "100 kbit/s is not in the DIP table"
    );
    assert_eq!(NodeSettings::from_lss(5, 9), None);
    assert_eq!(NodeSettings::from_lss(0, 0), None);
    assert_eq!(NodeSettings::from_lss(128, 0), None);
}

#[test]
fn a_blob_length_beyond_the_maximum_is_refused() {
    let mut bytes = vec![0xFF; 1024];
    bytes[..10].copy_from_slice(b"HWP2\x10\x00\x01\x01\x00\x00"); // 257 bytes of blob
    let crc = crc32(&bytes[..10 + 257]).to_le_bytes();
    bytes[10 + 257..10 + 261].copy_from_slice(&crc);
    assert_eq!(decode(&bytes), None);
    assert_eq!(scan(&bytes).free, 1024, "no record boundary to trust");
}

#[test]
fn dip_all_off_uses_the_stored_settings_or_the_default() {
    assert_eq!(select(0, Some(SETTINGS)), (SETTINGS, Source::Stored));
    assert_eq!(
        select(0, None),
        (
            NodeSettings {
                node_id: id(16),
                bit_rate: BitRate::Kbit1000
            },
            Source::Default
        )
    );
}

#[test]
fn dip_node_switches_set_the_node_id_and_rate_switches_the_rate() {
    // Switches 1 and 3 on (node 5), switch 7 on (code 2 = 500 kbit/s).
    let dip = 0b0100_0101;
    assert_eq!(
        select(dip, Some(SETTINGS)),
        (
            NodeSettings {
                node_id: id(5),
                bit_rate: BitRate::Kbit500
            },
            Source::Dip
        )
    );
    // Node switches off, switch 6 on (code 1 = 800 kbit/s): stored node-ID at that rate.
    assert_eq!(
        select(0b0010_0000, Some(SETTINGS)),
        (
            NodeSettings {
                node_id: id(42),
                bit_rate: BitRate::Kbit800
            },
            Source::DipBitRate
        )
    );
    assert_eq!(
        select(0b0010_0000, None).0,
        NodeSettings {
            node_id: id(16),
            bit_rate: BitRate::Kbit800
        }
    );
}

fn any_settings() -> impl Strategy<Value = NodeSettings> {
    (1u8..=127, 0u8..=7).prop_map(|(node_id, code)| NodeSettings {
        node_id: id(node_id),
        bit_rate: BitRate::from_code(code),
    })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]

    #[test]
    fn records_round_trip(
        settings in any_settings(),
        blob in proptest::collection::vec(any::<u8>(), 0..=BLOB_MAX),
        page_tail in any::<u8>(),
    ) {
        let mut page = encoded(settings, &blob);
        // Whatever follows the record on the page does not matter.
        page.resize(1024, page_tail);
        prop_assert_eq!(state(&page), Some((settings, &blob[..])));
    }

    #[test]
    fn any_damage_to_a_record_is_detected(
        settings in any_settings(),
        blob in proptest::collection::vec(any::<u8>(), 0..=32),
        at in any::<prop::sample::Index>(),
        flip in 1u8..=255,
    ) {
        let mut bytes = encoded(settings, &blob);
        // Only the bytes the CRC covers or holds; a pad byte is not part of the record.
        let covered = 10 + blob.len() + 4;
        bytes[at.index(covered)] ^= flip;
        prop_assert_eq!(decode(&bytes), None);
    }

    #[test]
    fn decoding_arbitrary_bytes_never_panics_and_only_accepts_valid_settings(
        page in proptest::collection::vec(any::<u8>(), 0..300),
    ) {
        if let Some(record) = decode(&page) {
            prop_assert!(record.settings.is_none_or(|s| s.node_id.is_some()));
            prop_assert!(record.blob.len() <= BLOB_MAX);
        }
        let log = scan(&page);
        prop_assert!(log.free <= page.len() + 1);
    }

    #[test]
    fn the_node_id_in_force_is_always_valid(dip in any::<u8>(), stored in proptest::option::of(any_settings())) {
        let (settings, source) = select(dip, stored);
        prop_assert!(settings.node_id.is_some());
        let expected_source = match (dip, dip & 0x1F, stored) {
            (0, _, Some(_)) => Source::Stored,
            (0, _, None) => Source::Default,
            (_, 0, _) => Source::DipBitRate,
            _ => Source::Dip,
        };
        prop_assert_eq!(source, expected_source);
        if dip != 0 {
            prop_assert_eq!(settings.bit_rate, BitRate::from_code(dip >> 5));
        }
    }
}
