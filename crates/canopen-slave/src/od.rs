//! The object dictionary: a static, sorted table of typed entries.
//!
//! The table describes every object (type, access, range, mappability) and says where its
//! value lives. It is declared by the application, usually as two parts: the standard
//! communication objects built by [`standard_objects`](crate::standard_objects) and the
//! application's own objects.
//! Lookup is a linear scan that stops at the first larger key, so each part must be sorted
//! by (index, sub-index) and the parts must follow one another in that order;
//! [`Od::checked`] verifies that at compile time.

use crate::abort::SdoAbort;
use crate::sdo::SDO_BUFFER;

/// CiA 301 basic data types supported by the engine.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u8)]
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

    /// The inverse of `self as u8` (only the low three bits count).
    const fn from_bits(bits: u8) -> Self {
        match bits & 7 {
            0 => Self::Boolean,
            1 => Self::I8,
            2 => Self::I16,
            3 => Self::I32,
            4 => Self::U8,
            5 => Self::U16,
            6 => Self::U32,
            _ => Self::VisibleString,
        }
    }

    /// Checks the length of a value about to be written: exactly the size of numbers, at
    /// most [`SDO_BUFFER`] bytes of a string.
    pub(crate) fn check_len(self, len: usize) -> Result<(), SdoAbort> {
        match self.size() {
            Some(n) if len > n => Err(SdoAbort::TooLong),
            Some(n) if len < n => Err(SdoAbort::TooShort),
            None if len > SDO_BUFFER => Err(SdoAbort::TooLong),
            _ => Ok(()),
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
#[repr(u8)]
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

    /// The inverse of `self as u8` (only the low two bits count).
    const fn from_bits(bits: u8) -> Self {
        match bits & 3 {
            0 => Self::Ro,
            1 => Self::Wo,
            2 => Self::Rw,
            _ => Self::Const,
        }
    }
}

/// What an object is (CiA 301 object code; CiA 306 writes it as `ObjectType`): one value, or
/// sub-indices after a sub-index 0 that counts them, all of one type (an array) or each of
/// its own (a record).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ObjectCode {
    /// VAR: one value, at sub-index 0.
    Var = 7,
    /// ARRAY: sub-indices 1 and up of one type.
    Array = 8,
    /// RECORD: sub-indices 1 and up, each of its own type.
    Record = 9,
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

/// The payload of a table row: a number (constant, default, or an application object's
/// packed write range) or a string. The string's non-null pointer is the niche that tells
/// the two apart, so this is 8 bytes on a 32-bit target.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
enum Slot {
    Num(u32),
    Str(&'static str),
}

/// `meta` layout: data type in bits 0..3, access in bits 3..5, mappable in bit 5, the kind
/// of value (for numbers) in bits 6..8.
const TYPE_SHIFT: u32 = 0;
const ACCESS_SHIFT: u32 = 3;
const MAPPABLE: u8 = 1 << 5;
const KIND_SHIFT: u32 = 6;
const KIND_CONST: u8 = 0;
const KIND_COMM: u8 = 1;
const KIND_COMM_PLUS_NODE_ID: u8 = 2;
const KIND_APP: u8 = 3;

/// The number of an application object without a range of its own: an empty range (1, 0),
/// which [`OdEntry::range`] never produces. Its type's full range then applies.
const NO_RANGE: u32 = 1;

/// One sub-index of the object dictionary: 12 bytes on a 32-bit target.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct OdEntry {
    index: u16,
    sub: u8,
    meta: u8,
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
        let (kind, slot) = match value {
            Value::Const(v) => (KIND_CONST, Slot::Num(v)),
            Value::Str(s) => (KIND_CONST, Slot::Str(s)),
            Value::Comm(v) => (KIND_COMM, Slot::Num(v)),
            Value::CommPlusNodeId(v) => (KIND_COMM_PLUS_NODE_ID, Slot::Num(v)),
            Value::App => (KIND_APP, Slot::Num(NO_RANGE)),
        };
        Self {
            index,
            sub,
            meta: (data_type as u8) << TYPE_SHIFT
                | (access as u8) << ACCESS_SHIFT
                | kind << KIND_SHIFT,
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
        self.meta |= MAPPABLE;
        self
    }

    /// Restricts writes of an application object to `min..=max` (signed for signed types).
    ///
    /// The bounds are kept in 16 bits: `i16` for signed types, `u16` for the others.
    ///
    /// # Panics
    ///
    /// On any other kind of entry, on bounds that do not fit 16 bits and on an empty range
    /// (`min > max`); in a `static` table that is a compile error, as intended:
    ///
    /// ```compile_fail
    /// use canopen_slave::{Access, DataType, OdEntry};
    /// static E: OdEntry = OdEntry::app(0x2000, 0, DataType::U32, Access::Rw).range(0, 100_000);
    /// ```
    pub const fn range(mut self, min: i64, max: i64) -> Self {
        assert!(
            self.kind() == KIND_APP,
            "only application objects take a range"
        );
        assert!(min <= max, "empty range");
        let (lo, hi) = if self.data_type().signed() {
            (i16::MIN as i64, i16::MAX as i64)
        } else {
            (0, u16::MAX as i64)
        };
        assert!(
            min >= lo && max <= hi,
            "range bounds must fit 16 bits (i16 for signed types, u16 otherwise)"
        );
        // Truncation to 16 bits is lossless after the check above.
        self.slot = Slot::Num((min as u16 as u32) | (max as u16 as u32) << 16);
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
        DataType::from_bits(self.meta >> TYPE_SHIFT)
    }

    /// Access rights.
    pub const fn access(&self) -> Access {
        Access::from_bits(self.meta >> ACCESS_SHIFT)
    }

    /// Whether the entry may be mapped into a PDO.
    pub const fn is_mappable(&self) -> bool {
        self.meta & MAPPABLE != 0
    }

    /// The write range of an application object ([`OdEntry::range`]); `None` without one.
    pub const fn limits(&self) -> Option<(i64, i64)> {
        match self.slot {
            Slot::Num(r) if self.kind() == KIND_APP && r != NO_RANGE => {
                Some(if self.data_type().signed() {
                    (r as u16 as i16 as i64, (r >> 16) as u16 as i16 as i64)
                } else {
                    ((r & 0xFFFF) as i64, (r >> 16) as i64)
                })
            }
            _ => None,
        }
    }

    const fn kind(&self) -> u8 {
        self.meta >> KIND_SHIFT
    }

    /// Where the value lives.
    pub const fn value(&self) -> Value {
        match (self.slot, self.kind()) {
            (Slot::Str(s), _) => Value::Str(s),
            (Slot::Num(v), KIND_CONST) => Value::Const(v),
            (Slot::Num(v), KIND_COMM) => Value::Comm(v),
            (Slot::Num(v), KIND_COMM_PLUS_NODE_ID) => Value::CommPlusNodeId(v),
            (Slot::Num(_), _) => Value::App,
        }
    }

    const fn key(&self) -> u32 {
        (self.index as u32) << 8 | self.sub as u32
    }

    /// Checks a value about to be written as an SDO download does: length against the type,
    /// then range. Returns the value as a raw 32-bit number (0 for strings).
    pub fn check_write(&self, data: &[u8]) -> Result<u32, SdoAbort> {
        let data_type = self.data_type();
        data_type.check_len(data.len())?;
        if data_type == DataType::VisibleString {
            return Ok(0);
        }
        let v = data_type.decode(data);
        let range = match self.slot {
            Slot::Num(r) if self.kind() == KIND_APP && r != NO_RANGE => r,
            // A value decoded from exactly its type's size is within the type's range; only
            // BOOLEAN is narrower than its byte.
            _ if data_type == DataType::Boolean && v > 1 => return Err(SdoAbort::ValueTooHigh),
            _ => return Ok(v),
        };
        let (above, below) = if data_type.signed() {
            let (min, max) = (
                range as u16 as i16 as i32,
                (range >> 16) as u16 as i16 as i32,
            );
            ((v as i32) > max, (v as i32) < min)
        } else {
            (v > range >> 16, v < range & 0xFFFF)
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
        let string = matches!(self.data_type(), DataType::VisibleString);
        let writable = self.access().writable();
        match (self.slot, self.kind()) {
            (Slot::Str(s), _) => string && !writable && s.len() <= SDO_BUFFER,
            (Slot::Num(_), KIND_CONST) => !string && !writable,
            (Slot::Num(_), KIND_APP) => !(string && self.is_mappable()),
            (Slot::Num(_), _) => !string && !self.is_mappable(),
        }
    }
}

#[cfg(target_pointer_width = "32")]
const _: () = assert!(core::mem::size_of::<OdEntry>() == 12);

/// Why a table was rejected.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
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
#[derive(Clone, Copy, PartialEq, Eq)]
pub struct Od {
    parts: &'static [&'static [OdEntry]],
}

/// The table is constant: the number of its parts stands for it (printing every entry made each
/// `Debug` of a device several kilobytes long).
impl core::fmt::Debug for Od {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Od")
            .field("parts", &self.parts.len())
            .finish()
    }
}

/// As its `Debug`: the number of parts stands for the constant table.
impl core::hash::Hash for Od {
    fn hash<H: core::hash::Hasher>(&self, state: &mut H) {
        self.parts.len().hash(state);
    }
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
    ///
    /// A linear scan that stops at the first larger key (the whole table is sorted, parts
    /// included): less code than a binary search per part, and under 80 rows it is fast.
    pub fn find(&self, index: u16, sub: u8) -> Result<&'static OdEntry, SdoAbort> {
        let key = u32::from(index) << 8 | u32::from(sub);
        let mut missing = SdoAbort::NoObject;
        for &part in self.parts {
            for e in part {
                let k = e.key();
                if k == key {
                    return Ok(e);
                }
                if e.index == index {
                    missing = SdoAbort::NoSubIndex;
                }
                if k > key {
                    return Err(missing);
                }
            }
        }
        Err(missing)
    }

    /// All entries in order.
    pub fn entries(&self) -> impl Iterator<Item = &'static OdEntry> {
        self.parts.iter().flat_map(|part| part.iter())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use DataType::*;

    #[test]
    fn packed_fields_round_trip() {
        let types = [Boolean, I8, I16, I32, U8, U16, U32, VisibleString];
        let accesses = [Access::Ro, Access::Wo, Access::Rw, Access::Const];
        for t in types {
            for a in accesses {
                for mappable in [false, true] {
                    let mut e = OdEntry::app(0xABCD, 0xEF, t, a);
                    if mappable {
                        e = e.mappable();
                    }
                    assert_eq!((e.index(), e.sub()), (0xABCD, 0xEF));
                    assert_eq!((e.data_type(), e.access()), (t, a));
                    assert_eq!((e.is_mappable(), e.value()), (mappable, Value::App));
                }
            }
        }
        for v in [
            Value::Const(u32::MAX),
            Value::Comm(0x8000_0180),
            Value::CommPlusNodeId(0x180),
            Value::Str("text"),
            Value::App,
        ] {
            let e = OdEntry::new(0x1000, 0, U32, Access::Ro, v);
            assert_eq!(e.value(), v);
        }
    }

    #[test]
    fn ranges_are_signed_or_unsigned_by_type() {
        let signed = OdEntry::app(0x2000, 0, I16, Access::Rw).range(-100, 100);
        assert_eq!(
            signed.check_write(&(-100i16).to_le_bytes()),
            Ok(-100i32 as u32)
        );
        assert_eq!(signed.check_write(&(100i16).to_le_bytes()), Ok(100));
        let low = signed.check_write(&(-101i16).to_le_bytes());
        assert_eq!(low, Err(SdoAbort::ValueTooLow));
        let high = signed.check_write(&(101i16).to_le_bytes());
        assert_eq!(high, Err(SdoAbort::ValueTooHigh));
        // 16-bit unsigned bounds, applied to a 32-bit object.
        let wide = OdEntry::app(0x2000, 0, U32, Access::Rw).range(10, 65_535);
        assert_eq!(wide.check_write(&65_535u32.to_le_bytes()), Ok(65_535));
        let high = wide.check_write(&65_536u32.to_le_bytes());
        assert_eq!(high, Err(SdoAbort::ValueTooHigh));
        assert_eq!(
            wide.check_write(&9u32.to_le_bytes()),
            Err(SdoAbort::ValueTooLow)
        );
        // A one-value range, and the (1, 0) pattern reserved for "no range" is not confused
        // with a real (0, 1).
        let single = OdEntry::app(0x2000, 0, U8, Access::Rw).range(0, 0);
        assert_eq!(single.check_write(&[1]), Err(SdoAbort::ValueTooHigh));
        let flag = OdEntry::app(0x2000, 0, U8, Access::Rw).range(0, 1);
        assert_eq!(flag.check_write(&[2]), Err(SdoAbort::ValueTooHigh));
        assert_eq!(flag.check_write(&[0]), Ok(0));
    }

    #[test]
    fn unranged_objects_accept_their_whole_type() {
        let e = OdEntry::app(0x2000, 0, I32, Access::Rw);
        assert_eq!(e.check_write(&i32::MIN.to_le_bytes()), Ok(i32::MIN as u32));
        let e = OdEntry::app(0x2000, 0, U32, Access::Rw);
        assert_eq!(e.check_write(&u32::MAX.to_le_bytes()), Ok(u32::MAX));
        let e = OdEntry::app(0x2000, 0, I8, Access::Rw);
        assert_eq!(e.check_write(&[0x80]), Ok(-128i32 as u32));
        let b = OdEntry::app(0x2000, 0, Boolean, Access::Rw);
        assert_eq!(b.check_write(&[1]), Ok(1));
        assert_eq!(b.check_write(&[2]), Err(SdoAbort::ValueTooHigh));
        let b = OdEntry::comm(0x1000, 0, Boolean, Access::Rw, 0);
        assert_eq!(b.check_write(&[2]), Err(SdoAbort::ValueTooHigh));
        assert_eq!(b.check_write(&[1, 0]), Err(SdoAbort::TooLong));
        assert_eq!(b.check_write(&[]), Err(SdoAbort::TooShort));
    }

    #[test]
    fn lookup_across_parts() {
        static A: [OdEntry; 2] = [
            OdEntry::highest_sub(0x1000, 2),
            OdEntry::constant(0x1000, 2, U8, 7),
        ];
        static B: [OdEntry; 2] = [
            OdEntry::app(0x2000, 1, U8, Access::Rw),
            OdEntry::app(0x2001, 0, U8, Access::Rw),
        ];
        static OD: Od = Od::checked(&[&A, &B]);
        assert_eq!(OD.find(0x1000, 2).map(OdEntry::sub), Ok(2));
        assert_eq!(OD.find(0x1000, 1), Err(SdoAbort::NoSubIndex));
        assert_eq!(OD.find(0x1000, 3), Err(SdoAbort::NoSubIndex));
        // The sub-index missing before the first present one of its object.
        assert_eq!(OD.find(0x2000, 0), Err(SdoAbort::NoSubIndex));
        assert_eq!(OD.find(0x2001, 0).map(OdEntry::index), Ok(0x2001));
        assert_eq!(OD.find(0x1FFF, 0), Err(SdoAbort::NoObject));
        assert_eq!(OD.find(0x2002, 0), Err(SdoAbort::NoObject));
        assert_eq!(OD.find(0x0FFF, 0), Err(SdoAbort::NoObject));
    }
}
