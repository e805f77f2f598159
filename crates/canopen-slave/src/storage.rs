//! Non-volatile parameters (0x1010 store, 0x1011 restore defaults).
//!
//! The engine serialises its communication parameters and the application's parameters
//! into one small versioned blob and hands it to a [`Storage`] (flash on the board, RAM in
//! tests). CiA 301 semantics: stored values are loaded at every reset (power-on and reset
//! node load both parts, reset communication the communication part only), and "restore
//! defaults" only takes effect at the next reset.
//!
//! The blob's layout is 0x1010's (`device::objects::params::blob`).
//!
//! Writing the medium may be refused: by the application while it must not stall
//! ([`Application::may_store`](crate::Application::may_store), [`StorageError::DeviceState`])
//! and by the storage itself when its wear budget is spent ([`StorageError::WearLimit`]).
//! Either way nothing is written, and the master gets a defined answer: SDO abort 0x08000022
//! or 0x08000020, LSS error 255 with [`lss::spec`](crate::lss::spec) 2 or 1.

use crate::time::Instant;

/// Signature to write to 0x1010 ("save", little-endian).
pub const SAVE_SIGNATURE: u32 = 0x6576_6173;
/// Signature to write to 0x1011 ("load", little-endian).
pub const LOAD_SIGNATURE: u32 = 0x6461_6F6C;

/// The storage refused or failed to write.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum StorageError {
    /// The medium could not be written (flash error, blob too large). SDO abort 0x06060000,
    /// LSS error 2.
    WriteFailed,
    /// The storage does not keep this kind of data (LSS node settings). LSS error 1.
    Unsupported,
    /// The medium's wear budget is spent for now (e.g. flash erases per time): nothing was
    /// written, a later store may succeed. SDO abort 0x08000020, LSS error 255 / spec 1.
    WearLimit,
    /// The application does not allow writing now ([`Application::may_store`]): nothing was
    /// written. SDO abort 0x08000022, LSS error 255 / spec 2.
    ///
    /// [`Application::may_store`]: crate::Application::may_store
    DeviceState,
}

/// Non-volatile memory for one parameter blob, implemented by the firmware. `now` is the
/// engine's time, for storages that bound their writes per time.
pub trait Storage {
    /// Copies the stored blob into `buf` and returns its length (0 when nothing is stored).
    fn load(&mut self, buf: &mut [u8]) -> usize;
    /// Replaces the stored blob; an empty `blob` erases it. Storing what is stored already
    /// should write nothing (flash wears).
    fn store(&mut self, now: Instant, blob: &[u8]) -> Result<(), StorageError>;

    /// LSS "store configuration" (CiA 305): keeps `node_id` (1..=127, or
    /// [`UNCONFIGURED`](crate::lss::UNCONFIGURED)) and the bit-timing table index
    /// `bit_timing` (CiA 301 table, 0 = 1 Mbit/s ... 8 = 10 kbit/s) for the next power-on.
    /// Where they go (e.g. beside the blob on the same flash page) is the firmware's choice.
    /// The default keeps nothing: the LSS master is told "store configuration not supported".
    fn store_node(
        &mut self,
        _now: Instant,
        _node_id: u8,
        _bit_timing: u8,
    ) -> Result<(), StorageError> {
        Err(StorageError::Unsupported)
    }
}

/// A [`Storage`] in RAM: for tests, and for boards that keep parameters only until power
/// is lost (they still survive NMT resets).
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub struct MemoryStorage {
    data: [u8; MemoryStorage::CAPACITY],
    len: usize,
    writes: u32,
    node: Option<(u8, u8)>,
}

impl MemoryStorage {
    /// The longest blob it keeps: at least the engine's [`BLOB_MAX`](crate::BLOB_MAX), which
    /// the engine checks at compile time.
    pub const CAPACITY: usize = 256;

    /// Empty storage.
    pub const fn new() -> Self {
        Self {
            data: [0; Self::CAPACITY],
            len: 0,
            writes: 0,
            node: None,
        }
    }

    /// Node-ID and bit-timing index of the last LSS "store configuration", if any.
    pub const fn node(&self) -> Option<(u8, u8)> {
        self.node
    }

    /// The stored bytes.
    pub fn bytes(&self) -> &[u8] {
        self.data.get(..self.len).unwrap_or(&[])
    }

    /// Mutable stored bytes, to simulate corruption in tests.
    pub fn bytes_mut(&mut self) -> &mut [u8] {
        self.data.get_mut(..self.len).unwrap_or(&mut [])
    }

    /// How many times [`Storage::store`] succeeded.
    pub const fn writes(&self) -> u32 {
        self.writes
    }
}

impl Default for MemoryStorage {
    fn default() -> Self {
        Self::new()
    }
}

impl Storage for MemoryStorage {
    fn load(&mut self, buf: &mut [u8]) -> usize {
        let n = self.len.min(buf.len());
        if let (Some(dst), Some(src)) = (buf.get_mut(..n), self.data.get(..n)) {
            dst.copy_from_slice(src);
        }
        n
    }

    fn store(&mut self, _now: Instant, blob: &[u8]) -> Result<(), StorageError> {
        let dst = self
            .data
            .get_mut(..blob.len())
            .ok_or(StorageError::WriteFailed)?;
        dst.copy_from_slice(blob);
        self.len = blob.len();
        self.writes = self.writes.wrapping_add(1);
        Ok(())
    }

    fn store_node(
        &mut self,
        _now: Instant,
        node_id: u8,
        bit_timing: u8,
    ) -> Result<(), StorageError> {
        self.node = Some((node_id, bit_timing));
        Ok(())
    }
}

/// The stored blob's checksum, CRC-16/CCITT-FALSE (public for tests that craft stored blobs).
pub fn crc16(data: &[u8]) -> u16 {
    // CRC-16/CCITT-FALSE, bitwise: a table would cost 512 bytes of flash for no gain here.
    data.iter().fold(0xFFFF, |mut crc: u16, &b| {
        crc ^= u16::from(b) << 8;
        for _ in 0..8 {
            crc = if crc & 0x8000 != 0 {
                (crc << 1) ^ 0x1021
            } else {
                crc << 1
            };
        }
        crc
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crc_matches_the_ccitt_false_check_value() {
        assert_eq!(crc16(b"123456789"), 0x29B1);
    }
}
