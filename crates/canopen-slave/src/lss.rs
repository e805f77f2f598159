//! Layer setting services (CiA 305): the LSS slave.
//!
//! A master configures the node-ID and bit rate of a node it addresses by its LSS address,
//! the identity object 0x1018:1-4 (vendor-ID, product code, revision number, serial
//! number). Requests arrive on 0x7E5 and answers go out on 0x7E4, always eight bytes.
//!
//! Sans-I/O like the rest of the engine: [`LssSlave::on_frame`] takes a request and returns
//! what to send and what the device must do. The states are CiA 305's: *LSS waiting* and
//! *LSS configuration*. Configured values are *pending* until they become *active*: the
//! node-ID at the next reset of communication (or reset node), the bit timing at "activate
//! bit timing" after its switch delay. "Store configuration" hands the pending values to
//! [`Storage::store_node`].
//!
//! A node whose active node-ID is [`UNCONFIGURED`] (0xFF) sends no boot-up and answers only
//! LSS; fastscan (0x51) and "identify non-configured remote slave" (0x4C) are for such nodes.

use crate::frame::{Frame, NodeId};
use crate::storage::{Storage, StorageError};
use crate::time::Instant;

/// LSS requests, master to slave.
pub const LSS_REQUEST: u16 = 0x7E5;
/// LSS answers, slave to master.
pub const LSS_RESPONSE: u16 = 0x7E4;
/// The node-ID of a node that has none ("unconfigured", CiA 305).
pub const UNCONFIGURED: u8 = 0xFF;
/// Bit-timing table indices of CiA 301/305 table 0 that are supported by default: all but
/// index 5 (100 kbit/s, which CiA 301 marks as not recommended / reserved).
pub const DEFAULT_BIT_TIMINGS: u16 = 0x01DF;

/// Command specifiers (CiA 305).
pub mod cs {
    /// Switch state global (no answer).
    pub const SWITCH_STATE_GLOBAL: u8 = 0x04;
    /// Configure node-ID.
    pub const CONFIGURE_NODE_ID: u8 = 0x11;
    /// Configure bit timing.
    pub const CONFIGURE_BIT_TIMING: u8 = 0x13;
    /// Activate bit timing (no answer).
    pub const ACTIVATE_BIT_TIMING: u8 = 0x15;
    /// Store configuration.
    pub const STORE_CONFIGURATION: u8 = 0x17;
    /// Switch state selective: vendor-ID (0x41 product, 0x42 revision, 0x43 serial follow).
    pub const SWITCH_SELECTIVE_VENDOR: u8 = 0x40;
    /// Switch state selective: serial number, the last part.
    pub const SWITCH_SELECTIVE_SERIAL: u8 = 0x43;
    /// Answer to a complete switch state selective.
    pub const SWITCH_SELECTIVE_RESPONSE: u8 = 0x44;
    /// Identify remote slave: vendor-ID (0x47 product, 0x48/0x49 revision low/high,
    /// 0x4A/0x4B serial low/high follow).
    pub const IDENTIFY_VENDOR: u8 = 0x46;
    /// Identify remote slave: serial number high, the last part.
    pub const IDENTIFY_SERIAL_HIGH: u8 = 0x4B;
    /// Identify non-configured remote slave.
    pub const IDENTIFY_NON_CONFIGURED: u8 = 0x4C;
    /// Identify slave: answer to identify remote slave and fastscan.
    pub const IDENTIFY_SLAVE: u8 = 0x4F;
    /// Identify non-configured slave: answer to 0x4C.
    pub const IDENTIFY_NON_CONFIGURED_SLAVE: u8 = 0x50;
    /// Fastscan.
    pub const FASTSCAN: u8 = 0x51;
    /// Inquire vendor-ID (0x5B product, 0x5C revision, 0x5D serial follow).
    pub const INQUIRE_VENDOR: u8 = 0x5A;
    /// Inquire serial number.
    pub const INQUIRE_SERIAL: u8 = 0x5D;
    /// Inquire node-ID.
    pub const INQUIRE_NODE_ID: u8 = 0x5E;
}

/// Error codes of the configure and store answers (byte 1).
pub mod error {
    /// Success.
    pub const OK: u8 = 0;
    /// Configure node-ID: out of range; configure bit timing: not supported; store: not
    /// supported.
    pub const REFUSED: u8 = 1;
    /// Store configuration: storage media access error.
    pub const STORAGE_ACCESS: u8 = 2;
    /// Implementation-specific error: byte 2 says which ([`spec`](super::spec)).
    pub const SPECIFIC: u8 = 255;
}

/// The implementation-specific errors of "store configuration" (byte 2 with error 255).
pub mod spec {
    /// The storage's wear budget is spent for now; nothing was stored
    /// ([`StorageError::WearLimit`](crate::StorageError::WearLimit)).
    pub const WEAR_LIMIT: u8 = 1;
    /// The application does not allow storing now, e.g. while the device's real-time work
    /// runs ([`StorageError::DeviceState`](crate::StorageError::DeviceState)).
    pub const DEVICE_STATE: u8 = 2;
}

/// Fastscan's "bit check" value that resets the scan.
const FASTSCAN_RESET: u8 = 0x80;

/// The LSS slave's state (CiA 305).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum LssState {
    /// Only switch state, identify and fastscan are served.
    Waiting,
    /// Configure, store and inquire are served too.
    Configuration,
}

/// The LSS address: 0x1018 sub 1-4.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct LssAddress {
    /// Vendor-ID, 0x1018:1.
    pub vendor_id: u32,
    /// Product code, 0x1018:2.
    pub product_code: u32,
    /// Revision number, 0x1018:3.
    pub revision: u32,
    /// Serial number, 0x1018:4.
    pub serial: u32,
}

impl LssAddress {
    /// Part `i` (0 vendor, 1 product, 2 revision, 3 serial); 0 beyond.
    pub const fn part(&self, i: u8) -> u32 {
        match i {
            0 => self.vendor_id,
            1 => self.product_code,
            2 => self.revision,
            3 => self.serial,
            _ => 0,
        }
    }
}

/// What the device must do after a request, besides sending the answer.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum LssAction {
    /// Nothing.
    None,
    /// Reset communication: an unconfigured node was given a node-ID and sent back to
    /// waiting (CiA 305: it then initialises with the new node-ID).
    ResetCommunication,
}

/// A pending bit-rate switch (activate bit timing).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
struct Switch {
    index: u8,
    at: Instant,
}

/// The LSS slave.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub struct LssSlave {
    address: LssAddress,
    state: LssState,
    /// The node-ID the next reset of communication activates (`None`: unconfigured).
    pending: Option<NodeId>,
    /// Bit-timing table index in force, and the one configured.
    active_bit_timing: u8,
    pending_bit_timing: u8,
    supported_bit_timings: u16,
    /// How many parts of a switch state selective matched so far (0..=3).
    selective: u8,
    /// How many parts of an identify remote slave matched so far (0..=5).
    identify: u8,
    /// The LSS-sub fastscan expects next; `None` until a reset (bit check 0x80).
    fastscan: Option<u8>,
    switch: Option<Switch>,
}

impl LssSlave {
    /// A slave in Waiting with `node` pending (and, at power-on, active) and bit-timing
    /// table index `bit_timing` in force; `supported` has bit `i` set for each table index
    /// `i` the device can run at.
    pub const fn new(
        address: LssAddress,
        node: Option<NodeId>,
        bit_timing: u8,
        supported: u16,
    ) -> Self {
        Self {
            address,
            state: LssState::Waiting,
            pending: node,
            active_bit_timing: bit_timing,
            pending_bit_timing: bit_timing,
            supported_bit_timings: supported,
            selective: 0,
            identify: 0,
            fastscan: None,
            switch: None,
        }
    }

    /// The LSS state.
    pub const fn state(&self) -> LssState {
        self.state
    }

    /// The node-ID a reset of communication activates (`None`: unconfigured).
    pub const fn pending_node_id(&self) -> Option<NodeId> {
        self.pending
    }

    /// The bit-timing table index configured (what "store configuration" stores).
    pub const fn pending_bit_timing(&self) -> u8 {
        self.pending_bit_timing
    }

    /// The bit-timing table index in force.
    pub const fn active_bit_timing(&self) -> u8 {
        self.active_bit_timing
    }

    /// When a bit-rate switch is due (see [`LssSlave::take_bit_timing_switch`]).
    pub fn deadline(&self) -> Option<Instant> {
        self.switch.map(|s| s.at)
    }

    /// The bit-timing table index to switch the CAN controller to, once the switch delay
    /// of "activate bit timing" has passed; `None` before and after.
    pub fn take_bit_timing_switch(&mut self, now: Instant) -> Option<u8> {
        let s = self.switch.filter(|s| now >= s.at)?;
        self.switch = None;
        self.active_bit_timing = s.index;
        Some(s.index)
    }

    /// Handles an LSS request (`frame.id()` must be [`LSS_REQUEST`]; other frames and
    /// requests that are not 8 bytes long are ignored). `active` is the node-ID in force
    /// (`None`: unconfigured). `storage` takes "store configuration"; `None`: the device
    /// does not allow storing now (answer 255 / [`spec::DEVICE_STATE`]). Returns the answer,
    /// if any, and what the device must do.
    pub fn on_frame(
        &mut self,
        now: Instant,
        frame: &Frame,
        active: Option<NodeId>,
        storage: Option<&mut dyn Storage>,
    ) -> (Option<Frame>, LssAction) {
        if frame.id() != LSS_REQUEST || frame.dlc() != 8 {
            return (None, LssAction::None);
        }
        let d = *frame.raw_data();
        let value = u32::from_le_bytes([d[1], d[2], d[3], d[4]]);
        let configuring = self.state == LssState::Configuration;
        let mut action = LssAction::None;
        let reply: Option<[u8; 8]> = match d[0] {
            cs::SWITCH_STATE_GLOBAL => {
                match d[1] {
                    0 => {
                        if configuring && active.is_none() && self.pending.is_some() {
                            action = LssAction::ResetCommunication;
                        }
                        self.enter(LssState::Waiting);
                    }
                    1 => self.enter(LssState::Configuration),
                    _ => {}
                }
                None
            }
            c @ cs::SWITCH_SELECTIVE_VENDOR..=cs::SWITCH_SELECTIVE_SERIAL if !configuring => {
                let part = c - cs::SWITCH_SELECTIVE_VENDOR;
                let matched = self.selective == part && value == self.address.part(part);
                self.selective = if matched { part + 1 } else { 0 };
                if matched && c == cs::SWITCH_SELECTIVE_SERIAL {
                    self.enter(LssState::Configuration);
                    Some(answer(cs::SWITCH_SELECTIVE_RESPONSE, [0; 7]))
                } else {
                    None
                }
            }
            c @ cs::IDENTIFY_VENDOR..=cs::IDENTIFY_SERIAL_HIGH => {
                let step = c - cs::IDENTIFY_VENDOR;
                let a = &self.address;
                let ok = match step {
                    0 => value == a.vendor_id,
                    1 => value == a.product_code,
                    2 => a.revision >= value,
                    3 => a.revision <= value,
                    4 => a.serial >= value,
                    _ => a.serial <= value,
                };
                let matched = self.identify == step && ok;
                self.identify = if matched { step + 1 } else { 0 };
                if matched && c == cs::IDENTIFY_SERIAL_HIGH {
                    self.identify = 0;
                    Some(answer(cs::IDENTIFY_SLAVE, [0; 7]))
                } else {
                    None
                }
            }
            cs::IDENTIFY_NON_CONFIGURED => active
                .is_none()
                .then(|| answer(cs::IDENTIFY_NON_CONFIGURED_SLAVE, [0; 7])),
            cs::FASTSCAN if !configuring && active.is_none() => {
                self.fastscan(value, d[5], d[6], d[7])
            }
            cs::CONFIGURE_NODE_ID if configuring => {
                let code = match d[1] {
                    UNCONFIGURED => {
                        self.pending = None;
                        error::OK
                    }
                    id => match NodeId::new(id) {
                        Ok(node) => {
                            self.pending = Some(node);
                            error::OK
                        }
                        Err(_) => error::REFUSED,
                    },
                };
                Some(answer(cs::CONFIGURE_NODE_ID, [code, 0, 0, 0, 0, 0, 0]))
            }
            cs::CONFIGURE_BIT_TIMING if configuring => {
                let (selector, index) = (d[1], d[2]);
                let supported =
                    selector == 0 && index < 16 && self.supported_bit_timings & (1 << index) != 0;
                let code = if supported {
                    self.pending_bit_timing = index;
                    error::OK
                } else {
                    error::REFUSED
                };
                Some(answer(cs::CONFIGURE_BIT_TIMING, [code, 0, 0, 0, 0, 0, 0]))
            }
            cs::ACTIVATE_BIT_TIMING if configuring => {
                let delay = u16::from_le_bytes([d[1], d[2]]);
                self.switch = Some(Switch {
                    index: self.pending_bit_timing,
                    at: now.add_millis(u64::from(delay)),
                });
                None
            }
            cs::STORE_CONFIGURATION if configuring => {
                let node = self.pending.map_or(UNCONFIGURED, NodeId::get);
                let stored = match storage {
                    Some(storage) => storage.store_node(now, node, self.pending_bit_timing),
                    None => Err(StorageError::DeviceState),
                };
                let (code, spec) = match stored {
                    Ok(()) => (error::OK, 0),
                    Err(StorageError::Unsupported) => (error::REFUSED, 0),
                    Err(StorageError::WriteFailed) => (error::STORAGE_ACCESS, 0),
                    Err(StorageError::WearLimit) => (error::SPECIFIC, spec::WEAR_LIMIT),
                    Err(StorageError::DeviceState) => (error::SPECIFIC, spec::DEVICE_STATE),
                };
                Some(answer(cs::STORE_CONFIGURATION, [code, spec, 0, 0, 0, 0, 0]))
            }
            c @ cs::INQUIRE_VENDOR..=cs::INQUIRE_SERIAL if configuring => {
                let v = self.address.part(c - cs::INQUIRE_VENDOR).to_le_bytes();
                Some(answer(c, [v[0], v[1], v[2], v[3], 0, 0, 0]))
            }
            cs::INQUIRE_NODE_ID if configuring => {
                let id = active.map_or(UNCONFIGURED, NodeId::get);
                Some(answer(cs::INQUIRE_NODE_ID, [id, 0, 0, 0, 0, 0, 0]))
            }
            _ => None,
        };
        let reply = reply.map(|data| Frame::from_parts(LSS_RESPONSE, data, 8));
        (reply, action)
    }

    fn enter(&mut self, state: LssState) {
        if state != self.state {
            debug!("LSS state {}", state);
        }
        self.state = state;
        self.selective = 0;
    }

    /// One fastscan step: `id` is the master's guess for LSS address part `sub`, whose
    /// bits `bit_check..=31` must match ours for us to answer.
    fn fastscan(&mut self, id: u32, bit_check: u8, sub: u8, next: u8) -> Option<[u8; 8]> {
        if bit_check == FASTSCAN_RESET {
            self.fastscan = Some(0);
            return Some(answer(cs::IDENTIFY_SLAVE, [0; 7]));
        }
        if bit_check > 31 || sub > 3 || next > 3 || self.fastscan != Some(sub) {
            return None;
        }
        let mask = u32::MAX << bit_check;
        if (id ^ self.address.part(sub)) & mask != 0 {
            return None;
        }
        if bit_check == 0 {
            self.fastscan = Some(next);
            if next < sub {
                // The whole address is confirmed: this node alone is selected.
                self.fastscan = None;
                self.enter(LssState::Configuration);
            }
        }
        Some(answer(cs::IDENTIFY_SLAVE, [0; 7]))
    }
}

const fn answer(command: u8, rest: [u8; 7]) -> [u8; 8] {
    [
        command, rest[0], rest[1], rest[2], rest[3], rest[4], rest[5], rest[6],
    ]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::storage::MemoryStorage;

    const ADDRESS: LssAddress = LssAddress {
        vendor_id: 0x0000_0123,
        product_code: 0x0000_0406,
        revision: 0x0001_0002,
        serial: 0xDEAD_BEEF,
    };

    fn slave(node: Option<u8>) -> LssSlave {
        let node = node.map(|n| NodeId::new(n).unwrap());
        LssSlave::new(ADDRESS, node, 0, DEFAULT_BIT_TIMINGS)
    }

    fn req(data: [u8; 8]) -> Frame {
        Frame::new(LSS_REQUEST, &data).unwrap()
    }

    fn send(s: &mut LssSlave, active: Option<u8>, data: [u8; 8]) -> Option<[u8; 8]> {
        let active = active.map(|n| NodeId::new(n).unwrap());
        let (reply, _) = s.on_frame(
            Instant::ZERO,
            &req(data),
            active,
            Some(&mut MemoryStorage::new()),
        );
        reply.map(|f| {
            assert_eq!((f.id(), f.dlc()), (LSS_RESPONSE, 8));
            *f.raw_data()
        })
    }

    fn addr_req(c: u8, v: u32) -> [u8; 8] {
        let b = v.to_le_bytes();
        [c, b[0], b[1], b[2], b[3], 0, 0, 0]
    }

    #[test]
    fn switch_state_global() {
        let mut s = slave(Some(16));
        assert_eq!(send(&mut s, Some(16), [0x04, 1, 0, 0, 0, 0, 0, 0]), None);
        assert_eq!(s.state(), LssState::Configuration);
        assert_eq!(send(&mut s, Some(16), [0x04, 0, 0, 0, 0, 0, 0, 0]), None);
        assert_eq!(s.state(), LssState::Waiting);
        // A mode other than 0 and 1 is ignored.
        assert_eq!(send(&mut s, Some(16), [0x04, 2, 0, 0, 0, 0, 0, 0]), None);
        assert_eq!(s.state(), LssState::Waiting);
    }

    #[test]
    fn switch_state_selective_needs_all_four_parts_in_order() {
        let mut s = slave(Some(16));
        assert_eq!(send(&mut s, Some(16), addr_req(0x40, 0x123)), None);
        assert_eq!(send(&mut s, Some(16), addr_req(0x41, 0x406)), None);
        assert_eq!(send(&mut s, Some(16), addr_req(0x42, 0x1_0002)), None);
        assert_eq!(
            send(&mut s, Some(16), addr_req(0x43, 0xDEAD_BEEF)),
            Some([0x44, 0, 0, 0, 0, 0, 0, 0])
        );
        assert_eq!(s.state(), LssState::Configuration);
        // A wrong part or a wrong order does not select.
        let mut s = slave(Some(16));
        send(&mut s, Some(16), addr_req(0x40, 0x123));
        send(&mut s, Some(16), addr_req(0x41, 0x407));
        send(&mut s, Some(16), addr_req(0x42, 0x1_0002));
        assert_eq!(send(&mut s, Some(16), addr_req(0x43, 0xDEAD_BEEF)), None);
        let mut s = slave(Some(16));
        assert_eq!(send(&mut s, Some(16), addr_req(0x43, 0xDEAD_BEEF)), None);
        assert_eq!(s.state(), LssState::Waiting);
    }

    #[test]
    fn configure_node_id_and_error_codes() {
        let mut s = slave(Some(16));
        // Ignored in Waiting.
        assert_eq!(send(&mut s, Some(16), [0x11, 5, 0, 0, 0, 0, 0, 0]), None);
        send(&mut s, Some(16), [0x04, 1, 0, 0, 0, 0, 0, 0]);
        assert_eq!(
            send(&mut s, Some(16), [0x11, 5, 0, 0, 0, 0, 0, 0]),
            Some([0x11, 0, 0, 0, 0, 0, 0, 0])
        );
        assert_eq!(s.pending_node_id(), NodeId::new(5).ok());
        for bad in [0, 128, 0xFE] {
            assert_eq!(
                send(&mut s, Some(16), [0x11, bad, 0, 0, 0, 0, 0, 0]),
                Some([0x11, 1, 0, 0, 0, 0, 0, 0])
            );
        }
        assert_eq!(s.pending_node_id(), NodeId::new(5).ok());
        assert_eq!(
            send(&mut s, Some(16), [0x11, 0xFF, 0, 0, 0, 0, 0, 0]),
            Some([0x11, 0, 0, 0, 0, 0, 0, 0])
        );
        assert_eq!(s.pending_node_id(), None);
    }

    #[test]
    fn configure_and_activate_bit_timing() {
        let mut s = slave(Some(16));
        send(&mut s, Some(16), [0x04, 1, 0, 0, 0, 0, 0, 0]);
        assert_eq!(
            send(&mut s, Some(16), [0x13, 0, 3, 0, 0, 0, 0, 0]),
            Some([0x13, 0, 0, 0, 0, 0, 0, 0])
        );
        for (selector, index) in [(0, 5), (0, 9), (1, 3), (0, 0xFF)] {
            assert_eq!(
                send(&mut s, Some(16), [0x13, selector, index, 0, 0, 0, 0, 0]),
                Some([0x13, 1, 0, 0, 0, 0, 0, 0])
            );
        }
        assert_eq!(s.pending_bit_timing(), 3);
        let (reply, _) = s.on_frame(
            Instant::from_millis(10),
            &req([0x15, 0x64, 0, 0, 0, 0, 0, 0]),
            NodeId::new(16).ok(),
            Some(&mut MemoryStorage::new()),
        );
        assert_eq!(reply, None);
        assert_eq!(s.deadline(), Some(Instant::from_millis(110)));
        assert_eq!(s.take_bit_timing_switch(Instant::from_millis(109)), None);
        assert_eq!(s.take_bit_timing_switch(Instant::from_millis(110)), Some(3));
        assert_eq!(s.take_bit_timing_switch(Instant::from_millis(200)), None);
        assert_eq!(s.active_bit_timing(), 3);
    }

    #[test]
    fn store_configuration_goes_to_storage() {
        let mut s = slave(Some(16));
        let mut storage = MemoryStorage::new();
        let node = NodeId::new(16).ok();
        let run = |s: &mut LssSlave, st: &mut MemoryStorage, d| {
            s.on_frame(Instant::ZERO, &req(d), node, Some(st))
                .0
                .map(|f| *f.raw_data())
        };
        run(&mut s, &mut storage, [0x04, 1, 0, 0, 0, 0, 0, 0]);
        run(&mut s, &mut storage, [0x11, 5, 0, 0, 0, 0, 0, 0]);
        run(&mut s, &mut storage, [0x13, 0, 4, 0, 0, 0, 0, 0]);
        assert_eq!(
            run(&mut s, &mut storage, [0x17, 0, 0, 0, 0, 0, 0, 0]),
            Some([0x17, 0, 0, 0, 0, 0, 0, 0])
        );
        assert_eq!(storage.node(), Some((5, 4)));

        // A storage without node settings: "not supported"; a failing one: access error; one
        // out of wear budget or refusing for the device state: 255 with the reason.
        struct NoNode;
        impl Storage for NoNode {
            fn load(&mut self, _: &mut [u8]) -> usize {
                0
            }
            fn store(&mut self, _: Instant, _: &[u8]) -> Result<(), StorageError> {
                Ok(())
            }
        }
        struct Failing(StorageError);
        impl Storage for Failing {
            fn load(&mut self, _: &mut [u8]) -> usize {
                0
            }
            fn store(&mut self, _: Instant, _: &[u8]) -> Result<(), StorageError> {
                Err(self.0)
            }
            fn store_node(&mut self, _: Instant, _: u8, _: u8) -> Result<(), StorageError> {
                Err(self.0)
            }
        }
        let store = req([0x17, 0, 0, 0, 0, 0, 0, 0]);
        let (r, _) = s.on_frame(Instant::ZERO, &store, node, Some(&mut NoNode));
        assert_eq!(r.unwrap().raw_data(), &[0x17, 1, 0, 0, 0, 0, 0, 0]);
        for (error, code, spec) in [
            (StorageError::WriteFailed, 2, 0),
            (StorageError::Unsupported, 1, 0),
            (StorageError::WearLimit, 255, 1),
            (StorageError::DeviceState, 255, 2),
        ] {
            let (r, _) = s.on_frame(Instant::ZERO, &store, node, Some(&mut Failing(error)));
            assert_eq!(
                r.unwrap().raw_data(),
                &[0x17, code, spec, 0, 0, 0, 0, 0],
                "{error:?}"
            );
        }
        // No storage handed over: the device does not allow storing now.
        let (r, _) = s.on_frame(Instant::ZERO, &store, node, None);
        assert_eq!(r.unwrap().raw_data(), &[0x17, 255, 2, 0, 0, 0, 0, 0]);
    }

    #[test]
    fn inquire_services() {
        let mut s = slave(Some(16));
        // Not in Waiting.
        assert_eq!(send(&mut s, Some(16), [0x5A, 0, 0, 0, 0, 0, 0, 0]), None);
        send(&mut s, Some(16), [0x04, 1, 0, 0, 0, 0, 0, 0]);
        assert_eq!(
            send(&mut s, Some(16), [0x5A, 0, 0, 0, 0, 0, 0, 0]),
            Some([0x5A, 0x23, 0x01, 0, 0, 0, 0, 0])
        );
        assert_eq!(
            send(&mut s, Some(16), [0x5B, 0, 0, 0, 0, 0, 0, 0]),
            Some([0x5B, 0x06, 0x04, 0, 0, 0, 0, 0])
        );
        assert_eq!(
            send(&mut s, Some(16), [0x5C, 0, 0, 0, 0, 0, 0, 0]),
            Some([0x5C, 0x02, 0, 0x01, 0, 0, 0, 0])
        );
        assert_eq!(
            send(&mut s, Some(16), [0x5D, 0, 0, 0, 0, 0, 0, 0]),
            Some([0x5D, 0xEF, 0xBE, 0xAD, 0xDE, 0, 0, 0])
        );
        // The active node-ID, not the pending one.
        send(&mut s, Some(16), [0x11, 5, 0, 0, 0, 0, 0, 0]);
        assert_eq!(
            send(&mut s, Some(16), [0x5E, 0, 0, 0, 0, 0, 0, 0]),
            Some([0x5E, 16, 0, 0, 0, 0, 0, 0])
        );
        assert_eq!(
            send(&mut s, None, [0x5E, 0, 0, 0, 0, 0, 0, 0]),
            Some([0x5E, 0xFF, 0, 0, 0, 0, 0, 0])
        );
    }

    #[test]
    fn identify_remote_slave_by_ranges() {
        let identify = |s: &mut LssSlave, rev: (u32, u32), ser: (u32, u32)| {
            send(s, Some(16), addr_req(0x46, 0x123));
            send(s, Some(16), addr_req(0x47, 0x406));
            send(s, Some(16), addr_req(0x48, rev.0));
            send(s, Some(16), addr_req(0x49, rev.1));
            send(s, Some(16), addr_req(0x4A, ser.0));
            send(s, Some(16), addr_req(0x4B, ser.1))
        };
        let mut s = slave(Some(16));
        let yes = Some([0x4F, 0, 0, 0, 0, 0, 0, 0]);
        assert_eq!(identify(&mut s, (0, u32::MAX), (0, u32::MAX)), yes);
        assert_eq!(
            identify(&mut s, (0x1_0002, 0x1_0002), (0xDEAD_BEEF, 0xDEAD_BEEF)),
            yes
        );
        assert_eq!(identify(&mut s, (0x1_0003, u32::MAX), (0, u32::MAX)), None);
        assert_eq!(identify(&mut s, (0, u32::MAX), (0, 0xDEAD_BEEE)), None);
        // Works in Configuration too.
        send(&mut s, Some(16), [0x04, 1, 0, 0, 0, 0, 0, 0]);
        assert_eq!(identify(&mut s, (0, u32::MAX), (0, u32::MAX)), yes);
    }

    #[test]
    fn identify_non_configured() {
        let mut s = slave(None);
        let q = [0x4C, 0, 0, 0, 0, 0, 0, 0];
        assert_eq!(send(&mut s, None, q), Some([0x50, 0, 0, 0, 0, 0, 0, 0]));
        assert_eq!(send(&mut s, Some(16), q), None);
    }

    /// python-canopen's `LssMaster.fast_scan`, against one slave: the address it finds and
    /// the number of requests it sent.
    fn fast_scan(s: &mut LssSlave) -> (Option<[u32; 4]>, usize) {
        let mut sent = 0;
        let mut ask = |s: &mut LssSlave, id: u32, bit: u8, sub: u8, next: u8| {
            sent += 1;
            let b = id.to_le_bytes();
            send(s, None, [0x51, b[0], b[1], b[2], b[3], bit, sub, next])
                .inspect(|r| assert_eq!(r, &[0x4F, 0, 0, 0, 0, 0, 0, 0]))
                .is_some()
        };
        let mut id = [0u32; 4];
        let mut next = 0;
        if !ask(s, 0, 0x80, 0, next) {
            return (None, sent);
        }
        for sub in 0..4u8 {
            // As python-canopen does: the last LSS-next goes along with the bit checks.
            for bit in (0..32u8).rev() {
                if !ask(s, id[usize::from(sub)], bit, sub, next) {
                    id[usize::from(sub)] |= 1 << bit;
                }
            }
            next = (sub + 1) & 3;
            if !ask(s, id[usize::from(sub)], 0, sub, next) {
                return (None, sent);
            }
        }
        (Some(id), sent)
    }

    #[test]
    fn fastscan_finds_an_unconfigured_node() {
        let mut s = slave(None);
        let (found, sent) = fast_scan(&mut s);
        assert_eq!(found, Some([0x123, 0x406, 0x1_0002, 0xDEAD_BEEF]));
        assert_eq!(sent, 1 + 4 * 33);
        assert_eq!(s.state(), LssState::Configuration);
    }

    #[test]
    fn fastscan_is_for_unconfigured_nodes_in_waiting() {
        let mut s = slave(Some(16));
        assert_eq!(send(&mut s, Some(16), [0x51, 0, 0, 0, 0, 0x80, 0, 0]), None);
        let mut s = slave(None);
        // No step before a reset.
        assert_eq!(send(&mut s, None, [0x51, 0x23, 1, 0, 0, 0, 0, 1]), None);
        send(&mut s, None, [0x04, 1, 0, 0, 0, 0, 0, 0]);
        assert_eq!(send(&mut s, None, [0x51, 0, 0, 0, 0, 0x80, 0, 0]), None);
    }

    #[test]
    fn unconfigured_node_given_an_id_resets_communication_on_waiting() {
        let mut s = slave(None);
        send(&mut s, None, [0x04, 1, 0, 0, 0, 0, 0, 0]);
        send(&mut s, None, [0x11, 7, 0, 0, 0, 0, 0, 0]);
        let (reply, action) = s.on_frame(
            Instant::ZERO,
            &req([0x04, 0, 0, 0, 0, 0, 0, 0]),
            None,
            Some(&mut MemoryStorage::new()),
        );
        assert_eq!((reply, action), (None, LssAction::ResetCommunication));
        // A configured node just goes back to waiting.
        let mut s = slave(Some(16));
        send(&mut s, Some(16), [0x04, 1, 0, 0, 0, 0, 0, 0]);
        send(&mut s, Some(16), [0x11, 7, 0, 0, 0, 0, 0, 0]);
        let (_, action) = s.on_frame(
            Instant::ZERO,
            &req([0x04, 0, 0, 0, 0, 0, 0, 0]),
            NodeId::new(16).ok(),
            Some(&mut MemoryStorage::new()),
        );
        assert_eq!(action, LssAction::None);
    }

    #[test]
    fn short_requests_are_ignored() {
        let mut s = slave(None);
        let f = Frame::new(LSS_REQUEST, &[0x4C]).unwrap();
        let (r, _) = s.on_frame(Instant::ZERO, &f, None, Some(&mut MemoryStorage::new()));
        assert_eq!(r, None);
    }

    mod props {
        use super::*;
        use proptest::prelude::*;

        fn allowed_answer(request: u8, answer: &[u8; 8]) -> bool {
            let zeros = |from: usize| answer[from..].iter().all(|&b| b == 0);
            match request {
                0x40..=0x43 => answer[0] == 0x44 && zeros(1),
                0x46..=0x4B | 0x51 => answer[0] == 0x4F && zeros(1),
                0x4C => answer[0] == 0x50 && zeros(1),
                0x11 | 0x13 | 0x17 => answer[0] == request && answer[1] <= 2 && zeros(2),
                0x5A..=0x5D => answer[0] == request && zeros(5),
                0x5E => answer[0] == 0x5E && zeros(2),
                _ => false,
            }
        }

        proptest! {
            #[test]
            fn random_requests_never_answer_outside_the_spec(
                frames in proptest::collection::vec(
                    (prop_oneof![
                        Just(0x04u8), Just(0x11), Just(0x13), Just(0x15), Just(0x17),
                        0x40u8..=0x4C, Just(0x51), 0x5Au8..=0x5E, any::<u8>()
                    ], any::<[u8; 7]>(), 0u8..=8),
                    1..64),
                configured in any::<bool>(),
            ) {
                let mut s = slave(configured.then_some(16));
                let active = configured.then(|| NodeId::new(16).unwrap());
                let mut storage = MemoryStorage::new();
                for (c, rest, dlc) in frames {
                    let data = answer(c, rest);
                    let f = Frame::new(LSS_REQUEST, &data[..usize::from(dlc)]).unwrap();
                    let (reply, action) = s.on_frame(Instant::ZERO, &f, active, Some(&mut storage));
                    if let Some(r) = reply {
                        prop_assert_eq!(dlc, 8);
                        prop_assert_eq!((r.id(), r.dlc()), (LSS_RESPONSE, 8));
                        prop_assert!(allowed_answer(c, r.raw_data()), "{:02x?} -> {:02x?}", data, r.raw_data());
                    }
                    if action == LssAction::ResetCommunication {
                        prop_assert!(!configured && c == 0x04);
                    }
                }
            }

            #[test]
            fn fastscan_converges_on_any_identity(address in any::<[u32; 4]>()) {
                let address = LssAddress {
                    vendor_id: address[0],
                    product_code: address[1],
                    revision: address[2],
                    serial: address[3],
                };
                let mut s = LssSlave::new(address, None, 0, DEFAULT_BIT_TIMINGS);
                let (found, sent) = fast_scan(&mut s);
                prop_assert_eq!(
                    found,
                    Some([address.vendor_id, address.product_code, address.revision, address.serial])
                );
                prop_assert_eq!(sent, 133);
                prop_assert_eq!(s.state(), LssState::Configuration);
            }
        }
    }
}
