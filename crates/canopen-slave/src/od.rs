//! The object dictionary: a static, sorted table of typed entries.
//!
//! The table describes every object (type, access, range, mappability) and says where its
//! value lives. It is declared by the application, usually as two parts: the standard
//! communication objects built by [`standard_objects`] and the application's own objects.
//! Lookup is a binary search, so each part must be sorted by (index, sub-index);
//! [`Od::checked`] verifies that at compile time.

use crate::identity::{CommDefaults, Identity};
use crate::sdo::{SdoAbort, SDO_BUFFER};

/// CiA 301 basic data types supported by the engine.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum DataType {
    /// BOOLEAN (one byte, 0 or 1).
    Boolean,
    /// INTEGER8.
    I8,
    /// INTEGER16.
    I16,
    /// INTEGER32.
    I32,
    /// UNSIGNED8.
    U8,
    /// UNSIGNED16.
    U16,
    /// UNSIGNED32.
    U32,
    /// VISIBLE_STRING (at most [`SDO_BUFFER`] bytes).
    VisibleString,
}

impl DataType {
    /// Size in bytes; `None` for strings, whose length is that of the value.
    pub const fn size(self) -> Option<usize> {
        match self {
            Self::Boolean | Self::I8 | Self::U8 => Some(1),
            Self::I16 | Self::U16 => Some(2),
            Self::I32 | Self::U32 => Some(4),
            Self::VisibleString => None,
        }
    }

    const fn signed(self) -> bool {
        matches!(self, Self::I8 | Self::I16 | Self::I32)
    }

    /// The full value range as raw 32-bit patterns (sign-extended for signed types).
    const fn bounds(self) -> (u32, u32) {
        match self {
            Self::Boolean => (0, 1),
            Self::I8 => (i8::MIN as i32 as u32, i8::MAX as u32),
            Self::I16 => (i16::MIN as i32 as u32, i16::MAX as u32),
            Self::I32 => (i32::MIN as u32, i32::MAX as u32),
            Self::U8 => (0, u8::MAX as u32),
            Self::U16 => (0, u16::MAX as u32),
            Self::U32 | Self::VisibleString => (0, u32::MAX),
        }
    }

    /// Decodes little-endian bytes of exactly this type's size into a raw 32-bit value
    /// (sign-extended for signed types).
    pub(crate) fn decode(self, data: &[u8]) -> u32 {
        let mut raw = [0u8; 4];
        for (dst, src) in raw.iter_mut().zip(data) {
            *dst = *src;
        }
        let v = u32::from_le_bytes(raw);
        match self {
            Self::I8 => v as u8 as i8 as i32 as u32,
            Self::I16 => v as u16 as i16 as i32 as u32,
            _ => v,
        }
    }
}

/// Access rights, from the SDO client's point of view.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Access {
    /// Read-only (the device may change the value).
    Ro,
    /// Write-only.
    Wo,
    /// Read and write.
    Rw,
    /// Read-only and never changes.
    Const,
}

impl Access {
    /// Whether an SDO upload is allowed.
    pub const fn readable(self) -> bool {
        !matches!(self, Self::Wo)
    }

    /// Whether an SDO download is allowed.
    pub const fn writable(self) -> bool {
        matches!(self, Self::Wo | Self::Rw)
    }
}

/// Where an entry's value lives.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Value {
    /// A number fixed at build time.
    Const(u32),
    /// A string fixed at build time.
    Str(&'static str),
    /// A communication parameter owned by the engine; the number is its default, loaded at
    /// every reset communication (unless parameters were stored).
    Comm(u32),
    /// Like [`Value::Comm`], with the node-ID added to the default (COB-IDs).
    CommPlusNodeId(u32),
    /// Owned by the application and reached through [`Application`](crate::Application).
    App,
}

/// Compact form of [`Value`]: the write range lives in the application variant, the only
/// one that needs it (engine parameters are range-checked in code), which keeps a table row
/// at 20 bytes on a 32-bit target.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
enum Slot {
    Const(u32),
    Str(&'static str),
    Comm(u32),
    CommPlusNodeId(u32),
    App { min: u32, max: u32 },
}

/// One sub-index of the object dictionary.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct OdEntry {
    index: u16,
    sub: u8,
    data_type: DataType,
    access: Access,
    mappable: bool,
    slot: Slot,
}

impl OdEntry {
    /// An entry, not PDO-mappable; application objects accept the full range of their type.
    pub const fn new(
        index: u16,
        sub: u8,
        data_type: DataType,
        access: Access,
        value: Value,
    ) -> Self {
        let slot = match value {
            Value::Const(v) => Slot::Const(v),
            Value::Str(s) => Slot::Str(s),
            Value::Comm(v) => Slot::Comm(v),
            Value::CommPlusNodeId(v) => Slot::CommPlusNodeId(v),
            Value::App => {
                let (min, max) = data_type.bounds();
                Slot::App { min, max }
            }
        };
        Self {
            index,
            sub,
            data_type,
            access,
            mappable: false,
            slot,
        }
    }

    /// An application-owned object.
    pub const fn app(index: u16, sub: u8, data_type: DataType, access: Access) -> Self {
        Self::new(index, sub, data_type, access, Value::App)
    }

    /// A numeric constant.
    pub const fn constant(index: u16, sub: u8, data_type: DataType, value: u32) -> Self {
        Self::new(index, sub, data_type, Access::Const, Value::Const(value))
    }

    /// A constant VISIBLE_STRING.
    pub const fn string(index: u16, sub: u8, value: &'static str) -> Self {
        Self::new(
            index,
            sub,
            DataType::VisibleString,
            Access::Const,
            Value::Str(value),
        )
    }

    /// Sub-index 0 of a record or array: "highest sub-index supported".
    pub const fn highest_sub(index: u16, highest: u8) -> Self {
        Self::constant(index, 0, DataType::U8, highest as u32)
    }

    /// An engine-owned communication parameter with its default.
    pub const fn comm(
        index: u16,
        sub: u8,
        data_type: DataType,
        access: Access,
        default: u32,
    ) -> Self {
        Self::new(index, sub, data_type, access, Value::Comm(default))
    }

    /// Marks the entry PDO-mappable.
    pub const fn mappable(mut self) -> Self {
        self.mappable = true;
        self
    }

    /// Restricts writes of an application object to `min..=max` (signed for signed types).
    ///
    /// # Panics
    ///
    /// On any other kind of entry; in a `static` table that is a compile error, as intended.
    pub const fn range(mut self, min: i64, max: i64) -> Self {
        assert!(
            matches!(self.slot, Slot::App { .. }),
            "only application objects take a range"
        );
        // Truncation to the raw 32-bit pattern is intended: it is how values are compared.
        self.slot = Slot::App {
            min: min as u32,
            max: max as u32,
        };
        self
    }

    /// Object index.
    pub const fn index(&self) -> u16 {
        self.index
    }

    /// Sub-index.
    pub const fn sub(&self) -> u8 {
        self.sub
    }

    /// Data type.
    pub const fn data_type(&self) -> DataType {
        self.data_type
    }

    /// Access rights.
    pub const fn access(&self) -> Access {
        self.access
    }

    /// Whether the entry may be mapped into a PDO.
    pub const fn is_mappable(&self) -> bool {
        self.mappable
    }

    /// Where the value lives.
    pub const fn value(&self) -> Value {
        match self.slot {
            Slot::Const(v) => Value::Const(v),
            Slot::Str(s) => Value::Str(s),
            Slot::Comm(v) => Value::Comm(v),
            Slot::CommPlusNodeId(v) => Value::CommPlusNodeId(v),
            Slot::App { .. } => Value::App,
        }
    }

    const fn key(&self) -> u32 {
        (self.index as u32) << 8 | self.sub as u32
    }

    /// Checks a value about to be written: length against the type, then range. Returns the
    /// value as a raw 32-bit number (0 for strings).
    pub(crate) fn check_write(&self, data: &[u8]) -> Result<u32, SdoAbort> {
        match self.data_type.size() {
            Some(n) if data.len() > n => return Err(SdoAbort::TooLong),
            Some(n) if data.len() < n => return Err(SdoAbort::TooShort),
            Some(_) => {}
            None if data.len() > SDO_BUFFER => return Err(SdoAbort::TooLong),
            None => return Ok(0),
        }
        let v = self.data_type.decode(data);
        let (min, max) = match self.slot {
            Slot::App { min, max } => (min, max),
            _ => self.data_type.bounds(),
        };
        let (above, below) = if self.data_type.signed() {
            ((v as i32) > (max as i32), (v as i32) < (min as i32))
        } else {
            (v > max, v < min)
        };
        if above {
            Err(SdoAbort::ValueTooHigh)
        } else if below {
            Err(SdoAbort::ValueTooLow)
        } else {
            Ok(v)
        }
    }

    /// Const checks of one entry (see [`OdError::BadEntry`]).
    const fn is_consistent(&self) -> bool {
        let string = matches!(self.data_type, DataType::VisibleString);
        match self.slot {
            Slot::Str(s) => string && !self.access.writable() && s.len() <= SDO_BUFFER,
            Slot::Const(_) => !string && !self.access.writable(),
            Slot::Comm(_) | Slot::CommPlusNodeId(_) => !string && !self.mappable,
            Slot::App { .. } => !(string && self.mappable),
        }
    }
}

/// Why a table was rejected.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum OdError {
    /// Entries out of (index, sub-index) order or duplicated, across all parts; the entry
    /// named is the first one out of place.
    Unsorted(u16, u8),
    /// A constant that is writable, a string that is not a string type, too long (longer
    /// than [`SDO_BUFFER`]) or mappable, or an engine-owned string.
    BadEntry(u16, u8),
}

/// An object dictionary: parts of sorted entries, the parts themselves in ascending order.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Od {
    parts: &'static [&'static [OdEntry]],
}

impl Od {
    /// Validates and wraps `parts`.
    pub const fn new(parts: &'static [&'static [OdEntry]]) -> Result<Self, OdError> {
        let mut last: Option<u32> = None;
        let mut p = 0;
        while p < parts.len() {
            let part = parts[p];
            let mut i = 0;
            while i < part.len() {
                let e = &part[i];
                if let Some(k) = last {
                    if e.key() <= k {
                        return Err(OdError::Unsorted(e.index, e.sub));
                    }
                }
                if !e.is_consistent() {
                    return Err(OdError::BadEntry(e.index, e.sub));
                }
                last = Some(e.key());
                i += 1;
            }
            p += 1;
        }
        Ok(Self { parts })
    }

    /// Like [`Od::new`] but panics on an invalid table: use it in a `static` or `const`
    /// initialiser so that an unsorted table fails the build.
    pub const fn checked(parts: &'static [&'static [OdEntry]]) -> Self {
        match Self::new(parts) {
            Ok(od) => od,
            Err(_) => panic!("object dictionary unsorted or with an inconsistent entry"),
        }
    }

    /// Finds an entry: 0x06020000 if the index is unknown, 0x06090011 if only the sub-index.
    pub fn find(&self, index: u16, sub: u8) -> Result<&'static OdEntry, SdoAbort> {
        let key = u32::from(index) << 8 | u32::from(sub);
        let mut index_exists = false;
        for &part in self.parts {
            match part.binary_search_by(|e| e.key().cmp(&key)) {
                Ok(i) => return part.get(i).ok_or(SdoAbort::NoObject),
                Err(i) => {
                    // Sorted order puts the other sub-indices of `index` next to the gap.
                    let before = i.checked_sub(1).and_then(|j| part.get(j));
                    index_exists |= [before, part.get(i)]
                        .into_iter()
                        .flatten()
                        .any(|e| e.index == index);
                }
            }
        }
        Err(if index_exists {
            SdoAbort::NoSubIndex
        } else {
            SdoAbort::NoObject
        })
    }

    /// All entries in order.
    pub fn entries(&self) -> impl Iterator<Item = &'static OdEntry> {
        self.parts.iter().flat_map(|part| part.iter())
    }
}

/// Number of entries [`standard_objects`] returns.
pub const STANDARD_OBJECTS: usize = 58;

const fn mapping_default(map: &[u32], sub: usize) -> u32 {
    if sub >= 1 && sub <= map.len() {
        map[sub - 1]
    } else {
        0
    }
}

/// The communication profile area (0x1000-0x1FFF) the engine implements, ready to be the
/// first part of an application's [`Od`]:
/// 0x1000, 0x1001, 0x1003 (4 entries), 0x1005, 0x1008-0x100A, 0x1010, 0x1011, 0x1014,
/// 0x1015, 0x1016 (2 consumers), 0x1017, 0x1018, TPDO1/2 (0x1800/0x1801, 0x1A00/0x1A01).
pub const fn standard_objects(id: &Identity, d: &CommDefaults) -> [OdEntry; STANDARD_OBJECTS] {
    use Access::{Ro, Rw};
    use DataType::{U16, U32, U8};
    let t1 = &d.tpdo[0];
    let t2 = &d.tpdo[1];
    let m1 = t1.mapping;
    let m2 = t2.mapping;
    assert!(
        m1.len() <= 8 && m2.len() <= 8,
        "a PDO maps at most 8 objects"
    );
    [
        OdEntry::constant(0x1000, 0, U32, id.device_type),
        OdEntry::comm(0x1001, 0, U8, Ro, 0),
        OdEntry::comm(0x1003, 0, U8, Rw, 0),
        OdEntry::comm(0x1003, 1, U32, Ro, 0),
        OdEntry::comm(0x1003, 2, U32, Ro, 0),
        OdEntry::comm(0x1003, 3, U32, Ro, 0),
        OdEntry::comm(0x1003, 4, U32, Ro, 0),
        OdEntry::comm(0x1005, 0, U32, Rw, 0x80),
        OdEntry::string(0x1008, 0, id.device_name),
        OdEntry::string(0x1009, 0, id.hardware_version),
        OdEntry::string(0x100A, 0, id.software_version),
        OdEntry::highest_sub(0x1010, 3),
        OdEntry::comm(0x1010, 1, U32, Rw, 0),
        OdEntry::comm(0x1010, 2, U32, Rw, 0),
        OdEntry::comm(0x1010, 3, U32, Rw, 0),
        OdEntry::highest_sub(0x1011, 3),
        OdEntry::comm(0x1011, 1, U32, Rw, 0),
        OdEntry::comm(0x1011, 2, U32, Rw, 0),
        OdEntry::comm(0x1011, 3, U32, Rw, 0),
        OdEntry::new(0x1014, 0, U32, Rw, Value::CommPlusNodeId(0x80)),
        OdEntry::comm(0x1015, 0, U16, Rw, d.emcy_inhibit_100us as u32),
        OdEntry::highest_sub(0x1016, 2),
        OdEntry::comm(0x1016, 1, U32, Rw, d.heartbeat_consumers[0]),
        OdEntry::comm(0x1016, 2, U32, Rw, d.heartbeat_consumers[1]),
        OdEntry::comm(0x1017, 0, U16, Rw, d.heartbeat_ms as u32),
        OdEntry::highest_sub(0x1018, 4),
        OdEntry::constant(0x1018, 1, U32, id.vendor_id),
        OdEntry::constant(0x1018, 2, U32, id.product_code),
        OdEntry::constant(0x1018, 3, U32, id.revision),
        OdEntry::comm(0x1018, 4, U32, Ro, 0),
        OdEntry::highest_sub(0x1800, 5),
        OdEntry::new(0x1800, 1, U32, Rw, Value::CommPlusNodeId(t1.cob_id_base)),
        OdEntry::comm(0x1800, 2, U8, Rw, t1.transmission_type as u32),
        OdEntry::comm(0x1800, 3, U16, Rw, t1.inhibit_100us as u32),
        OdEntry::comm(0x1800, 5, U16, Rw, t1.event_timer_ms as u32),
        OdEntry::highest_sub(0x1801, 5),
        OdEntry::new(0x1801, 1, U32, Rw, Value::CommPlusNodeId(t2.cob_id_base)),
        OdEntry::comm(0x1801, 2, U8, Rw, t2.transmission_type as u32),
        OdEntry::comm(0x1801, 3, U16, Rw, t2.inhibit_100us as u32),
        OdEntry::comm(0x1801, 5, U16, Rw, t2.event_timer_ms as u32),
        OdEntry::comm(0x1A00, 0, U8, Rw, m1.len() as u32),
        OdEntry::comm(0x1A00, 1, U32, Rw, mapping_default(m1, 1)),
        OdEntry::comm(0x1A00, 2, U32, Rw, mapping_default(m1, 2)),
        OdEntry::comm(0x1A00, 3, U32, Rw, mapping_default(m1, 3)),
        OdEntry::comm(0x1A00, 4, U32, Rw, mapping_default(m1, 4)),
        OdEntry::comm(0x1A00, 5, U32, Rw, mapping_default(m1, 5)),
        OdEntry::comm(0x1A00, 6, U32, Rw, mapping_default(m1, 6)),
        OdEntry::comm(0x1A00, 7, U32, Rw, mapping_default(m1, 7)),
        OdEntry::comm(0x1A00, 8, U32, Rw, mapping_default(m1, 8)),
        OdEntry::comm(0x1A01, 0, U8, Rw, m2.len() as u32),
        OdEntry::comm(0x1A01, 1, U32, Rw, mapping_default(m2, 1)),
        OdEntry::comm(0x1A01, 2, U32, Rw, mapping_default(m2, 2)),
        OdEntry::comm(0x1A01, 3, U32, Rw, mapping_default(m2, 3)),
        OdEntry::comm(0x1A01, 4, U32, Rw, mapping_default(m2, 4)),
        OdEntry::comm(0x1A01, 5, U32, Rw, mapping_default(m2, 5)),
        OdEntry::comm(0x1A01, 6, U32, Rw, mapping_default(m2, 6)),
        OdEntry::comm(0x1A01, 7, U32, Rw, mapping_default(m2, 7)),
        OdEntry::comm(0x1A01, 8, U32, Rw, mapping_default(m2, 8)),
    ]
}
