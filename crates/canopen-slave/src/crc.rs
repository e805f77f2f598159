//! CRC-32 as in IEEE 802.3 and zlib's `crc32` (CRC-32/ISO-HDLC: reflected, polynomial
//! 0x04C11DB7, initial value and final XOR 0xFFFFFFFF), the one implementation of the
//! project: the stored parameter records, the serial number and the firmware image (the
//! loader's header) all use it. And the CRC-16 of CiA 301's SDO block transfer
//! ([`Crc16`]).
//!
//! Bitwise rather than table-driven: no 1 KiB table in either image. The loader's boot check
//! over a 40 KiB image is its largest user (about 2 M cycles).

/// The CRC-32 of `bytes`: `crc32(b"123456789") == 0xCBF4_3926`.
#[must_use]
pub fn crc32(bytes: &[u8]) -> u32 {
    Crc32::new().update(bytes).finish()
}

/// A CRC-32 computed over data that arrives in pieces (flash read in chunks).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Crc32(u32);

impl Default for Crc32 {
    fn default() -> Self {
        Self::new()
    }
}

impl Crc32 {
    /// The CRC of no bytes so far.
    pub const fn new() -> Self {
        Self(!0)
    }

    /// Takes in `bytes`.
    #[must_use]
    #[inline]
    pub fn update(mut self, bytes: &[u8]) -> Self {
        for &byte in bytes {
            self.0 ^= u32::from(byte);
            for _ in 0..8 {
                let lsb = self.0 & 1;
                self.0 = (self.0 >> 1) ^ (0xEDB8_8320 & lsb.wrapping_neg());
            }
        }
        self
    }

    /// The CRC of every byte taken in.
    #[must_use]
    pub const fn finish(self) -> u32 {
        !self.0
    }
}

/// The CRC of an SDO block transfer (CiA 301 7.2.4.3.16): CRC-16/XMODEM, polynomial 0x1021
/// (x^16 + x^12 + x^5 + 1), initial value 0, not reflected, no final XOR; the bytes of the
/// transfer in order. `Crc16::new().update(b"123456789").finish() == 0x31C3`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct Crc16(u16);

impl Crc16 {
    /// The CRC of no bytes so far.
    pub const fn new() -> Self {
        Self(0)
    }

    /// Takes in `bytes`.
    #[must_use]
    pub fn update(mut self, bytes: &[u8]) -> Self {
        for &byte in bytes {
            self.0 ^= u16::from(byte) << 8;
            for _ in 0..8 {
                let msb = self.0 >> 15;
                self.0 = (self.0 << 1) ^ (0x1021 & msb.wrapping_neg());
            }
        }
        self
    }

    /// The CRC of every byte taken in.
    #[must_use]
    pub const fn finish(self) -> u16 {
        self.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn known_vectors() {
        // zlib.crc32 of the same inputs.
        assert_eq!(crc32(b"123456789"), 0xCBF4_3926);
        assert_eq!(crc32(b""), 0);
        assert_eq!(crc32(b"a"), 0xE8B7_BE43);
        assert_eq!(
            crc32(b"The quick brown fox jumps over the lazy dog"),
            0x414F_A339
        );
        assert_eq!(crc32(&[0xFF; 4]), 0xFFFF_FFFF);
    }

    #[test]
    fn crc16_known_vectors() {
        // CRC-16/XMODEM's check value, and Python's `binascii.crc_hqx(data, 0)`.
        assert_eq!(Crc16::new().update(b"123456789").finish(), 0x31C3);
        assert_eq!(Crc16::new().finish(), 0);
        assert_eq!(Crc16::new().update(b"A").finish(), 0x58E5);
        let data: [u8; 100] = core::array::from_fn(|i| (i * 37 + 11) as u8);
        let (a, b) = data.split_at(33);
        assert_eq!(Crc16::new().update(a).update(b), Crc16::new().update(&data));
    }

    #[test]
    fn pieces_give_the_whole() {
        let data: [u8; 100] = core::array::from_fn(|i| (i * 37 + 11) as u8);
        for split in [0, 1, 7, 50, 99, 100] {
            let (a, b) = data.split_at(split);
            assert_eq!(Crc32::new().update(a).update(b).finish(), crc32(&data));
        }
    }
}
