//! `eds/handwheel.eds` against the running device. `cargo xtask eds` writes the file from the
//! object table (type, access and PDO mapping straight from its entries; `cargo xtask eds
//! --check` keeps it so); these tests check what the generator adds to the table against the
//! engine itself: a fresh device answers an SDO upload with every EDS default, every EDS
//! limit is one the device enforces, and the LSS support the EDS claims is there.

mod common;

use std::collections::BTreeMap;

use canopen_slave::MemoryStorage;
use common::*;

#[derive(Debug)]
struct EdsEntry {
    data_type: u16,
    access: String,
    default: String,
    pdo_mapping: bool,
    limits: Option<(i64, i64)>,
}

fn parse_number(text: &str) -> i64 {
    let text = text.trim();
    let (text, node) = match text.strip_prefix("$NODEID+") {
        Some(rest) => (rest, i64::from(NODE)),
        None => (text, 0),
    };
    let value = match text.strip_prefix("0x").or_else(|| text.strip_prefix("0X")) {
        Some(hex) => i64::from_str_radix(hex, 16).unwrap(),
        None => text.parse().unwrap(),
    };
    value + node
}

/// Sections of the EDS as key/value maps.
fn sections() -> BTreeMap<String, BTreeMap<String, String>> {
    let text = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../eds/handwheel.eds"
    ))
    .expect("eds/handwheel.eds is readable");
    let mut out: BTreeMap<String, BTreeMap<String, String>> = BTreeMap::new();
    let mut current = None;
    for line in text.lines().map(str::trim) {
        if line.is_empty() || line.starts_with(';') {
            continue;
        }
        if let Some(name) = line.strip_prefix('[').and_then(|l| l.strip_suffix(']')) {
            current = Some(name.to_string());
            out.entry(name.to_string()).or_default();
        } else if let (Some(section), Some((k, v))) = (&current, line.split_once('=')) {
            out.get_mut(section)
                .unwrap()
                .insert(k.trim().to_string(), v.trim().to_string());
        }
    }
    out
}

/// Every variable of the EDS by (index, sub).
fn eds_entries() -> BTreeMap<(u16, u8), EdsEntry> {
    let sections = sections();
    let mut entries = BTreeMap::new();
    for (name, keys) in &sections {
        let (index, sub) = match name.split_once("sub") {
            Some((i, s)) => (i, u8::from_str_radix(s, 16)),
            None => (name.as_str(), Ok(0)),
        };
        let (Ok(index), Ok(sub)) = (u16::from_str_radix(index, 16), sub) else {
            continue; // FileInfo, DeviceInfo and the like
        };
        if keys.get("ObjectType").map(String::as_str) != Some("0x7") {
            continue; // an array or record header; its subs are sections of their own
        }
        let limits = match (keys.get("LowLimit"), keys.get("HighLimit")) {
            (Some(lo), Some(hi)) => Some((parse_number(lo), parse_number(hi))),
            (None, None) => None,
            _ => panic!("{name}: LowLimit without HighLimit"),
        };
        entries.insert(
            (index, sub),
            EdsEntry {
                data_type: parse_number(&keys["DataType"]) as u16,
                access: keys["AccessType"].to_lowercase(),
                default: keys.get("DefaultValue").cloned().unwrap_or_default(),
                pdo_mapping: keys.get("PDOMapping").map(String::as_str) == Some("1"),
                limits,
            },
        );
    }
    entries
}

#[test]
fn a_fresh_device_answers_the_eds_defaults() {
    // Serial number 0, so the runtime-supplied 0x1018:4 matches the EDS default too.
    let mut b = Bench::with_serial(MemoryStorage::new(), 0);
    let eds = eds_entries();
    let mut checked = 0;
    for (&(index, sub), d) in &eds {
        if d.access == "wo" {
            continue;
        }
        if index == 0x1003 && sub > 0 {
            // CiA 301: entries above the error count hold no data yet.
            assert_eq!(b.sdo_upload(index, sub), Err(0x0800_0024), "1003sub{sub}");
            continue;
        }
        let value = b
            .sdo_upload(index, sub)
            .unwrap_or_else(|abort| panic!("{index:04X}sub{sub}: abort {abort:#010x}"));
        if d.data_type == 0x0009 {
            assert_eq!(
                String::from_utf8(value).unwrap(),
                d.default,
                "{index:04X}sub{sub}"
            );
        } else {
            let mut raw = value.clone();
            let negative =
                matches!(d.data_type, 2..=4) && raw.last().is_some_and(|b| b & 0x80 != 0);
            raw.resize(8, if negative { 0xFF } else { 0 });
            let got = i64::from_le_bytes(raw.try_into().unwrap());
            assert_eq!(got, parse_number(&d.default), "{index:04X}sub{sub}");
        }
        checked += 1;
    }
    assert!(checked > 60, "only {checked} objects read");
}

#[test]
fn eds_limits_are_the_limits_the_device_enforces() {
    let eds = eds_entries();
    let mut b = Bench::new();
    // (A mapping's count has no EDS limit: its own check answers 0x06040042, CANopenNode's.)
    let mut checked = 0;
    for (&(index, sub), d) in &eds {
        let Some((lo, hi)) = d.limits else { continue };
        assert_eq!(
            d.access, "rw",
            "{index:04X}sub{sub}: limits only on writable objects"
        );
        let size = match d.data_type {
            0x0005 => 1,
            0x0006 => 2,
            0x0007 => 4,
            t => panic!("limits on type {t:#x} not covered"),
        };
        let bytes = |v: i64| v.to_le_bytes()[..size].to_vec();
        let restore = b.sdo_upload(index, sub).unwrap();
        assert_eq!(
            b.sdo_write(index, sub, &bytes(hi + 1)),
            Err(0x0609_0031),
            "{index:04X}sub{sub} above"
        );
        if lo > 0 {
            assert_eq!(
                b.sdo_write(index, sub, &bytes(lo - 1)),
                Err(0x0609_0032),
                "{index:04X}sub{sub} below"
            );
        }
        assert_eq!(
            b.sdo_upload(index, sub).unwrap(),
            restore,
            "rejected writes change nothing"
        );
        checked += 1;
    }
    assert!(checked >= 5, "only {checked} limited objects");
}

#[test]
fn eds_pdo_mapping_is_what_the_device_maps() {
    let eds = eds_entries();
    let mut b = Bench::new();
    // TPDO2's mapping may only change while the PDO is invalid (CiA 301 procedure).
    let id = b.read_u32(0x1801, 1) | 0x8000_0000;
    b.sdo_write(0x1801, 1, &id.to_le_bytes()).unwrap();
    b.sdo_write(0x1A01, 0, &[0]).unwrap();
    let (mut mappable, mut refused) = (0, 0);
    for (&(index, sub), d) in &eds {
        let bits: u32 = match d.data_type {
            0x0001 | 0x0002 | 0x0005 => 8,
            0x0003 | 0x0006 => 16,
            0x0004 | 0x0007 => 32,
            _ => continue, // strings: never mappable here
        };
        let entry = u32::from(index) << 16 | u32::from(sub) << 8 | bits;
        let written = b.sdo_write(0x1A01, 1, &entry.to_le_bytes());
        if d.pdo_mapping {
            assert_eq!(written, Ok(()), "{index:04X}sub{sub} is mappable");
            mappable += 1;
        } else {
            assert_eq!(written, Err(0x0604_0041), "{index:04X}sub{sub} is not");
            refused += 1;
        }
    }
    assert!(
        mappable >= 9 && refused >= 40,
        "{mappable} mapped, {refused} refused"
    );
}

/// `LSS_Supported=1` is a promise: the device answers LSS (CiA 305) with the identity of
/// 0x1018 as its LSS address.
#[test]
fn eds_lss_support_is_true() {
    let info = &sections()["DeviceInfo"];
    assert_eq!(info.get("LSS_Supported").map(String::as_str), Some("1"));
    let mut b = Bench::new();
    b.take();
    b.receive(0x7E5, &[0x04, 1, 0, 0, 0, 0, 0, 0]);
    b.receive(0x7E5, &[0x5A, 0, 0, 0, 0, 0, 0, 0]);
    let vendor = b.read_u32(0x1018, 1).to_le_bytes();
    let answers = b.take_id(0x7E4);
    assert_eq!(answers.len(), 1);
    assert_eq!(
        &answers[0].data[..],
        &[0x5A, vendor[0], vendor[1], vendor[2], vendor[3], 0, 0, 0][..]
    );
}
