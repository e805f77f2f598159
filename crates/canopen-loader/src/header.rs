//! The application's image header (docs/FIRMWARE-UPDATE.md, "The image header"): 32 bytes
//! little-endian at the start of the slot's header slot ([`HEADER_SLOT`] bytes, padded with
//! 0xFF).
//!
//! ```text
//! 0x00 magic u32          MAGIC, the validity mark, written last
//! 0x04 format u16         FORMAT
//! 0x06 header_size u16    HEADER_LEN
//! 0x08 vendor_id u32      the application's 0x1018:1
//! 0x0C product_code u32   the application's 0x1018:2
//! 0x10 version u32        the application's 0x1018:3
//! 0x14 length u32         image bytes after the header slot
//! 0x18 crc u32            CRC-32 (zlib) of those bytes
//! 0x1C reserved u32       0xFFFF_FFFF
//! ```

pub use canopen_slave::crc::{crc32, Crc32};

use crate::layout::{HEADER_SLOT, MAX_IMAGE};

/// The validity mark ("HWIM" in memory order).
pub const MAGIC: u32 = 0x4D49_5748;
/// The header format this loader knows.
pub const FORMAT: u16 = 1;
/// Bytes of the header proper (the rest of the header slot is padding).
pub const HEADER_LEN: usize = 32;
/// `length` and `crc` as the firmware source defines them, before the link step seals them.
pub const UNSET: u32 = 0xFFFF_FFFF;
/// The smallest image: its vector table's stack pointer and reset vector.
pub const MIN_IMAGE: usize = 8;

/// Offset of `magic` in the header.
pub const MAGIC_AT: usize = 0x00;
/// Offset of `format` in the header.
pub const FORMAT_AT: usize = 0x04;
/// Offset of `header_size` in the header.
pub const HEADER_SIZE_AT: usize = 0x06;
/// Offset of `vendor_id` in the header.
pub const VENDOR_ID_AT: usize = 0x08;
/// Offset of `product_code` in the header.
pub const PRODUCT_CODE_AT: usize = 0x0C;
/// Offset of `version` in the header.
pub const VERSION_AT: usize = 0x10;
/// Offset of `length` in the header.
pub const LENGTH_AT: usize = 0x14;
/// Offset of `crc` in the header.
pub const CRC_AT: usize = 0x18;
/// Offset of the reserved word in the header.
pub const RESERVED_AT: usize = 0x1C;

/// The header's fields in order, as the table above: name, offset, size in bytes. They tile
/// the [`HEADER_LEN`] bytes (a test checks it); `cargo xtask contract` hands them to Python.
pub const FIELDS: [(&str, usize, usize); 9] = [
    ("magic", MAGIC_AT, 4),
    ("format", FORMAT_AT, 2),
    ("header_size", HEADER_SIZE_AT, 2),
    ("vendor_id", VENDOR_ID_AT, 4),
    ("product_code", PRODUCT_CODE_AT, 4),
    ("version", VERSION_AT, 4),
    ("length", LENGTH_AT, 4),
    ("crc", CRC_AT, 4),
    ("reserved", RESERVED_AT, 4),
];

/// Which application an image is for (0x1018:1 and :2 of the application).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DeviceId {
    /// 0x1018:1.
    pub vendor_id: u32,
    /// 0x1018:2 (of the application, without the loader's bit 31).
    pub product_code: u32,
}

/// The handwheel: the application's 0x1018:1 and :2, the identity its images carry and the
/// only one the loader takes (the loader's own product code adds
/// [`LOADER_PRODUCT_BIT`](crate::node::LOADER_PRODUCT_BIT)).
pub const PRODUCT: DeviceId = DeviceId {
    vendor_id: 0,
    product_code: 1,
};

/// The header's fields past the mark, format and size (which [`ImageHeader::parse`] checks).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ImageHeader {
    /// 0x1018:1 of the application.
    pub vendor_id: u32,
    /// 0x1018:2 of the application.
    pub product_code: u32,
    /// 0x1018:3 of the application.
    pub version: u32,
    /// Image bytes after the header slot.
    pub length: u32,
    /// CRC-32 of those bytes.
    pub crc: u32,
}

/// Why a header is refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum HeaderError {
    /// Fewer than [`HEADER_LEN`] bytes.
    Truncated,
    /// The first word is not [`MAGIC`].
    Magic,
    /// Unknown `format` or `header_size`.
    Format,
    /// The image is for another device (vendor or product code).
    Device,
    /// `length` is shorter than a vector table ([`MIN_IMAGE`]).
    Length,
    /// `length` does not fit the slot ([`MAX_IMAGE`]).
    TooLarge,
}

fn word(bytes: &[u8], at: usize) -> u32 {
    let mut w = [0; 4];
    if let Some(src) = bytes.get(at..at + 4) {
        w.copy_from_slice(src);
    }
    u32::from_le_bytes(w)
}

fn half(bytes: &[u8], at: usize) -> u16 {
    let mut h = [0; 2];
    if let Some(src) = bytes.get(at..at + 2) {
        h.copy_from_slice(src);
    }
    u16::from_le_bytes(h)
}

impl ImageHeader {
    /// A header as the firmware source defines it: `length` and `crc` [`UNSET`].
    #[must_use]
    pub const fn unsealed(vendor_id: u32, product_code: u32, version: u32) -> Self {
        Self {
            vendor_id,
            product_code,
            version,
            length: UNSET,
            crc: UNSET,
        }
    }

    /// Reads a header from the first [`HEADER_LEN`] bytes of `bytes`, checking the mark,
    /// `format` and `header_size` (not the device nor the length: [`check`](Self::check)).
    pub fn parse(bytes: &[u8]) -> Result<Self, HeaderError> {
        if bytes.len() < HEADER_LEN {
            return Err(HeaderError::Truncated);
        }
        if word(bytes, MAGIC_AT) != MAGIC {
            return Err(HeaderError::Magic);
        }
        if half(bytes, FORMAT_AT) != FORMAT
            || usize::from(half(bytes, HEADER_SIZE_AT)) != HEADER_LEN
        {
            return Err(HeaderError::Format);
        }
        Ok(Self {
            vendor_id: word(bytes, VENDOR_ID_AT),
            product_code: word(bytes, PRODUCT_CODE_AT),
            version: word(bytes, VERSION_AT),
            length: word(bytes, LENGTH_AT),
            crc: word(bytes, CRC_AT),
        })
    }

    /// Whether the image is for `device` and its length fits the slot.
    pub fn check(&self, device: DeviceId) -> Result<(), HeaderError> {
        if self.vendor_id != device.vendor_id || self.product_code != device.product_code {
            return Err(HeaderError::Device);
        }
        match self.image_len() {
            n if n > MAX_IMAGE => Err(HeaderError::TooLarge),
            n if n < MIN_IMAGE => Err(HeaderError::Length),
            _ => Ok(()),
        }
    }

    /// `length` in bytes (saturating on a 16-bit `usize`, where it cannot fit anyway).
    #[must_use]
    pub fn image_len(&self) -> usize {
        usize::try_from(self.length).unwrap_or(usize::MAX)
    }

    /// The header's [`HEADER_LEN`] bytes, mark included.
    #[must_use]
    pub const fn to_bytes(&self) -> [u8; HEADER_LEN] {
        let mut out = [0xFF; HEADER_LEN];
        let fields = [
            (MAGIC_AT, MAGIC),
            // `format` and `header_size` in one word.
            (FORMAT_AT, FORMAT as u32 | (HEADER_LEN as u32) << 16),
            (VENDOR_ID_AT, self.vendor_id),
            (PRODUCT_CODE_AT, self.product_code),
            (VERSION_AT, self.version),
            (LENGTH_AT, self.length),
            (CRC_AT, self.crc),
        ];
        let mut f = 0;
        while f < fields.len() {
            let (at, value) = fields[f];
            let bytes = u32::to_le_bytes(value);
            let mut i = 0;
            while i < 4 {
                out[at + i] = bytes[i];
                i += 1;
            }
            f += 1;
        }
        out
    }

    /// The whole header slot: the header, then 0xFF up to [`HEADER_SLOT`] bytes (what the
    /// application places at `HEADER`).
    #[must_use]
    pub const fn to_slot(&self) -> [u8; HEADER_SLOT] {
        let mut out = [0xFF; HEADER_SLOT];
        let header = self.to_bytes();
        let mut i = 0;
        while i < HEADER_LEN {
            out[i] = header[i];
            i += 1;
        }
        out
    }
}

/// Why [`seal`] refused its buffer.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SealError {
    /// Shorter than the header slot plus a vector table.
    TooShort,
    /// The header slot does not start with a header (mark, format, size).
    Header(HeaderError),
    /// The image does not fit the slot.
    TooLarge,
}

/// Seals an update file: `slot` is the header slot followed by the image (the slot's bytes
/// from `HEADER`'s origin to the image's end); fills the header's `length` (the bytes after
/// the header slot) and `crc` (their CRC-32) and returns the header. Sealing again gives the
/// same bytes.
pub fn seal(slot: &mut [u8]) -> Result<ImageHeader, SealError> {
    if slot.len() < HEADER_SLOT + MIN_IMAGE {
        return Err(SealError::TooShort);
    }
    let (head, image) = slot.split_at_mut(HEADER_SLOT);
    let mut header = ImageHeader::parse(head).map_err(SealError::Header)?;
    if image.len() > MAX_IMAGE {
        return Err(SealError::TooLarge);
    }
    // image.len() <= MAX_IMAGE: fits a u32.
    header.length = image.len() as u32;
    header.crc = crc32(image);
    let bytes = header.to_bytes();
    for at in [LENGTH_AT, CRC_AT] {
        if let (Some(dst), Some(src)) = (head.get_mut(at..at + 4), bytes.get(at..at + 4)) {
            dst.copy_from_slice(src);
        }
    }
    Ok(header)
}

#[cfg(test)]
mod tests {
    use super::*;

    const DEVICE: DeviceId = DeviceId {
        vendor_id: 0x1234,
        product_code: 0x5678,
    };

    #[test]
    fn layout_is_the_contracts() {
        let h = ImageHeader {
            vendor_id: 0x1122_3344,
            product_code: 0x5566_7788,
            version: 0x0001_0002,
            length: 0x0000_9ABC,
            crc: 0xDEAD_BEEF,
        };
        let b = h.to_bytes();
        assert_eq!(&b[0..4], b"HWIM");
        assert_eq!(&b[4..8], &[1, 0, 32, 0]);
        assert_eq!(&b[8..12], &[0x44, 0x33, 0x22, 0x11]);
        assert_eq!(&b[0x14..0x18], &[0xBC, 0x9A, 0, 0]);
        assert_eq!(&b[0x18..0x1C], &[0xEF, 0xBE, 0xAD, 0xDE]);
        assert_eq!(&b[0x1C..0x20], &[0xFF; 4]);
        assert_eq!(ImageHeader::parse(&b), Ok(h));
        let slot = h.to_slot();
        assert_eq!(&slot[..32], &b);
        assert!(slot[32..].iter().all(|&x| x == 0xFF));
    }

    /// The field table tiles the header in order, and each field is where `to_bytes` puts it.
    #[test]
    fn fields_tile_the_header_where_to_bytes_puts_them() {
        let mut at = 0;
        for (name, offset, size) in FIELDS {
            assert_eq!(offset, at, "{name}");
            at += size;
        }
        assert_eq!(at, HEADER_LEN);
        assert_eq!(HEADER_SIZE_AT, FORMAT_AT + 2);
        let h = ImageHeader {
            vendor_id: 0x1111_1111,
            product_code: 0x2222_2222,
            version: 0x3333_3333,
            length: 0x4444_4444,
            crc: 0x5555_5555,
        };
        let b = h.to_bytes();
        let field = |name: &str| {
            let &(_, offset, size) = FIELDS.iter().find(|(n, ..)| *n == name).unwrap();
            let mut v = [0u8; 4];
            v[..size].copy_from_slice(&b[offset..offset + size]);
            u32::from_le_bytes(v)
        };
        assert_eq!(
            [
                "magic",
                "format",
                "header_size",
                "vendor_id",
                "product_code",
                "version",
                "length",
                "crc",
                "reserved",
            ]
            .map(field),
            [
                MAGIC,
                u32::from(FORMAT),
                HEADER_LEN as u32,
                h.vendor_id,
                h.product_code,
                h.version,
                h.length,
                h.crc,
                UNSET,
            ]
        );
    }

    #[test]
    fn parse_refuses() {
        let b = ImageHeader::unsealed(1, 2, 3).to_bytes();
        assert_eq!(ImageHeader::parse(&b[..31]), Err(HeaderError::Truncated));
        let mut bad = b;
        bad[3] = 0x4E;
        assert_eq!(ImageHeader::parse(&bad), Err(HeaderError::Magic));
        let mut bad = b;
        bad[4] = 2;
        assert_eq!(ImageHeader::parse(&bad), Err(HeaderError::Format));
        let mut bad = b;
        bad[6] = 64;
        assert_eq!(ImageHeader::parse(&bad), Err(HeaderError::Format));
    }

    #[test]
    fn check_device_and_length() {
        let mut h = ImageHeader::unsealed(0x1234, 0x5678, 1);
        h.length = MAX_IMAGE as u32;
        assert_eq!(h.check(DEVICE), Ok(()));
        h.length += 1;
        assert_eq!(h.check(DEVICE), Err(HeaderError::TooLarge));
        h.length = 7;
        assert_eq!(h.check(DEVICE), Err(HeaderError::Length));
        h.length = 8;
        h.product_code |= 1 << 31;
        assert_eq!(h.check(DEVICE), Err(HeaderError::Device));
    }

    #[test]
    fn seal_fills_length_and_crc() {
        let mut file = ImageHeader::unsealed(0x1234, 0x5678, 7).to_slot().to_vec();
        file.extend_from_slice(b"123456789");
        let header = seal(&mut file).unwrap();
        assert_eq!((header.length, header.crc), (9, 0xCBF4_3926));
        assert_eq!(&file[0x14..0x1C], &[9, 0, 0, 0, 0x26, 0x39, 0xF4, 0xCB]);
        assert_eq!(ImageHeader::parse(&file), Ok(header));
        let again = file.clone();
        assert_eq!(seal(&mut file), Ok(header));
        assert_eq!(file, again);

        assert_eq!(
            seal(&mut file[..HEADER_SLOT + MIN_IMAGE - 1]),
            Err(SealError::TooShort)
        );
        let mut big = ImageHeader::unsealed(1, 2, 3).to_slot().to_vec();
        big.resize(HEADER_SLOT + MAX_IMAGE + 1, 0);
        assert_eq!(seal(&mut big), Err(SealError::TooLarge));
        let mut plain = vec![0u8; HEADER_SLOT + 100];
        assert_eq!(seal(&mut plain), Err(SealError::Header(HeaderError::Magic)));
    }
}
