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
    /// Node-ID and bit rate of the last LSS "store configuration".
    node: Option<NodeSettings>,
}

impl DeviceStorage {
    /// Empty RAM storage. The settings in force are not kept: they could only be found again
    /// at the next boot, and RAM does not survive it.
    pub fn new(_memory: RamStorage, _settings: NodeSettings) -> Self {
        Self {
            ram: MemoryStorage::new(),
            node: None,
        }
    }
}

impl Storage for DeviceStorage {
    /// Called at every initialisation (NMT reset node or communication), the QEMU board's
    /// "boot": the stored node settings are reported here, as the board's boot line reports
    /// them after a power-on.
    fn load(&mut self, buf: &mut [u8]) -> usize {
        if let Some(settings) = self.node {
            defmt::info!("stored node settings: {} (LSS, RAM)", settings);
        }
        self.ram.load(buf)
    }

    fn store_node(&mut self, node_id: u8, bit_timing: u8) -> Result<(), StorageError> {
        let settings =
            NodeSettings::from_lss(node_id, bit_timing).ok_or(StorageError::Unsupported)?;
        defmt::info!("LSS stored {} (no bit rate on the serial line)", settings);
        self.node = Some(settings);
        Ok(())
    }

    fn store(&mut self, blob: &[u8]) -> Result<(), StorageError> {
        self.ram.store(blob)
    }
}
