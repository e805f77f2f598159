//! The QEMU board's parameters: in RAM, the engine's own `MemoryStorage`.
//!
//! They survive NMT reset node and reset communication (the device object lives on), not a
//! restart of the emulator, which is a power cycle: every boot starts from the defaults.

use canopen_slave::{MemoryStorage, Storage, StorageError};

use crate::storage::{NodeSettings, Stored};

/// The QEMU board's "parameter page": nothing survives power-off, so nothing is ever found
/// at boot.
pub struct RamStorage {
    _private: (),
}

impl RamStorage {
    /// The empty parameter memory of a fresh boot.
    pub const fn new() -> Self {
        Self { _private: () }
    }

    /// Node-ID and bit rate stored with 0x1010 before this boot: never any in RAM.
    pub fn load(&self) -> Option<Stored<'static>> {
        None
    }
}

impl Default for RamStorage {
    fn default() -> Self {
        Self::new()
    }
}

/// The CANopen engine's storage on the QEMU board.
pub struct DeviceStorage {
    ram: MemoryStorage,
}

impl DeviceStorage {
    /// Empty RAM storage. The settings in force are not kept: they could only be found again
    /// at the next boot, and RAM does not survive it.
    pub fn new(_memory: RamStorage, _settings: NodeSettings) -> Self {
        Self {
            ram: MemoryStorage::new(),
        }
    }
}

impl Storage for DeviceStorage {
    fn load(&mut self, buf: &mut [u8]) -> usize {
        self.ram.load(buf)
    }

    fn store(&mut self, blob: &[u8]) -> Result<(), StorageError> {
        self.ram.store(blob)
    }
}
