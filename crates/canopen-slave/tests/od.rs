//! Object dictionary tables: validation and lookup.
mod common;
use canopen_slave::{Access, DataType, Od, OdEntry, OdError, SdoAbort, Value};
use common::*;

#[test]
fn standard_and_application_tables_are_valid() {
    static ONLY_STANDARD: [&[OdEntry]; 1] = [&STANDARD];
    assert!(Od::new(&ONLY_STANDARD).is_ok());
    assert_eq!(OD.entries().count(), STANDARD.len() + APP_OBJECTS.len());
    // Every default mapping of the test device survives the mapping checks.
    for e in OD
        .entries()
        .filter(|e| (0x1A00..0x1C00).contains(&e.index()) && e.sub() > 0)
    {
        if let Value::Comm(m) = e.value() {
            if m != 0 {
                let (index, sub) = ((m >> 16) as u16, (m >> 8) as u8);
                assert!(OD.find(index, sub).unwrap().is_mappable(), "{m:#x}");
            }
        }
    }
}

#[test]
fn unsorted_duplicate_and_inconsistent_tables_are_rejected() {
    static UNSORTED: [OdEntry; 2] = [
        OdEntry::app(0x2001, 0, DataType::U8, Access::Rw),
        OdEntry::app(0x2000, 0, DataType::U8, Access::Rw),
    ];
    static DUPLICATE: [OdEntry; 2] = [
        OdEntry::app(0x2000, 1, DataType::U8, Access::Rw),
        OdEntry::app(0x2000, 1, DataType::U8, Access::Rw),
    ];
    static LOW: [OdEntry; 1] = [OdEntry::app(0x1FFF, 0, DataType::U8, Access::Rw)];
    static WRITABLE_CONST: [OdEntry; 1] = [OdEntry::new(
        0x2000,
        0,
        DataType::U8,
        Access::Rw,
        Value::Const(1),
    )];
    static LONG: [OdEntry; 1] = [OdEntry::string(
        0x2000,
        0,
        "a string longer than thirty-two bytes",
    )];
    static MAPPABLE_STRING: [OdEntry; 1] =
        [OdEntry::app(0x2000, 0, DataType::VisibleString, Access::Ro).mappable()];
    static P1: [&[OdEntry]; 1] = [&UNSORTED];
    static P2: [&[OdEntry]; 1] = [&DUPLICATE];
    static P3: [&[OdEntry]; 2] = [&APP_OBJECTS, &LOW];
    static P4: [&[OdEntry]; 1] = [&WRITABLE_CONST];
    static P5: [&[OdEntry]; 1] = [&LONG];
    static P6: [&[OdEntry]; 1] = [&MAPPABLE_STRING];
    assert_eq!(Od::new(&P1), Err(OdError::Unsorted(0x2000, 0)));
    assert_eq!(Od::new(&P2), Err(OdError::Unsorted(0x2000, 1)));
    assert_eq!(Od::new(&P3), Err(OdError::Unsorted(0x1FFF, 0)));
    assert_eq!(Od::new(&P4), Err(OdError::BadEntry(0x2000, 0)));
    assert_eq!(Od::new(&P5), Err(OdError::BadEntry(0x2000, 0)));
    assert_eq!(Od::new(&P6), Err(OdError::BadEntry(0x2000, 0)));
}

#[test]
fn lookup_distinguishes_missing_object_and_sub_index() {
    assert_eq!(OD.find(0x1000, 0).unwrap().data_type(), DataType::U32);
    assert_eq!(OD.find(0x1000, 1), Err(SdoAbort::NoSubIndex));
    assert_eq!(OD.find(0x1004, 0), Err(SdoAbort::NoObject));
    assert_eq!(OD.find(0x1A01, 9), Err(SdoAbort::NoSubIndex));
    assert_eq!(OD.find(0x1800, 4), Err(SdoAbort::NoSubIndex));
    assert_eq!(OD.find(0x2100, 8), Err(SdoAbort::NoSubIndex));
    assert_eq!(OD.find(0x2100, 0).unwrap().value(), Value::Const(7));
    assert_eq!(OD.find(0x0000, 0), Err(SdoAbort::NoObject));
    assert_eq!(OD.find(0xFFFF, 0xFF), Err(SdoAbort::NoObject));
    assert!(!OD.find(0x6006, 0).unwrap().is_mappable());
    assert_eq!(SdoAbort::NoSubIndex.code(), 0x0609_0011);
}
