//! The loader's CANopen node (docs/FIRMWARE-UPDATE.md, "The loader on the bus"), sans-I/O
//! like the engine: frames in through [`LoaderNode::on_frame`], time through every call,
//! frames out through a [`FrameSink`], flash through a [`Flash`].
//!
//! Boot-up, NMT slave, heartbeat producer (0x1017, not stored), the engine's SDO server
//! (expedited, segmented and block download; 0x1F50:1 streamed into the slot segment by
//! segment, or sub-block by sub-block before each is acknowledged) and the
//! objects 0x1000, 0x1001, 0x1017, 0x1018, 0x1F50, 0x1F51, 0x1F56, 0x1F57. No PDOs, no EMCY.

use canopen_slave::frame::cob;
use canopen_slave::sdo::{ObjectAccess, SdoServer};
use canopen_slave::{Frame, FrameSink, Instant, NmtCommand, NmtState, NodeId, SdoAbort};

use crate::header::DeviceId;
use crate::program::{ControlAction, Flash, Program};

/// 0x1000 of the loader: "BOOT".
pub const DEVICE_TYPE: u32 = 0x544F_4F42;
/// 0x1018:2 of the loader is the application's product code with this bit set.
pub const LOADER_PRODUCT_BIT: u32 = 1 << 31;

/// What the loader is and how it talks.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LoaderConfig {
    /// The node-ID (the application's, chosen the same way).
    pub node_id: NodeId,
    /// The application's vendor-ID and product code: images must be for it, and 0x1018
    /// reports it (product code with [`LOADER_PRODUCT_BIT`]).
    pub device: DeviceId,
    /// 0x1018:3: the loader's revision.
    pub revision: u32,
    /// 0x1018:4: the serial number (the application's).
    pub serial: u32,
    /// 0x1017 after boot-up and reset communication, ms (0 = off).
    pub heartbeat_ms: u16,
    /// An SDO transfer left unfinished this long is aborted.
    pub sdo_timeout_ms: u16,
}

impl LoaderConfig {
    /// The defaults of the application: heartbeat every 1000 ms, SDO timeout 1000 ms.
    #[must_use]
    pub const fn new(node_id: NodeId, device: DeviceId, revision: u32, serial: u32) -> Self {
        Self {
            node_id,
            device,
            revision,
            serial,
            heartbeat_ms: 1000,
            sdo_timeout_ms: 1000,
        }
    }
}

/// What the node asks of its shell after a call.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Request {
    /// Send every frame queued so far (the SDO answer of a "start"), then reset the system:
    /// the boot decision runs again (NMT reset node, or 0x1F51 = 1 with a valid
    /// application).
    Reset,
}

/// The loader's objects and the state they read.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Object {
    DeviceType,
    ErrorRegister,
    Heartbeat,
    /// 0x1018:0 (4) and the sub-index counts of 0x1F50/51/56/57 (1).
    Count(u8),
    Identity(u32),
    ProgramData,
    ProgramControl,
    SoftwareId,
    FlashStatus,
}

impl Object {
    /// Bytes of the value (a DOMAIN's expedited download takes up to 4).
    const fn size(self) -> usize {
        match self {
            Self::ErrorRegister | Self::Count(_) | Self::ProgramControl => 1,
            Self::Heartbeat => 2,
            _ => 4,
        }
    }

    const fn writable(self) -> bool {
        matches!(
            self,
            Self::Heartbeat | Self::ProgramData | Self::ProgramControl
        )
    }
}

/// The state besides the SDO server (which the objects are reached through).
#[derive(Clone, Debug, PartialEq, Eq)]
struct Inner {
    config: LoaderConfig,
    state: NmtState,
    heartbeat_ms: u16,
    next_beat: Option<Instant>,
    program: Program,
    /// A "start" was answered: reset once the answer is out.
    start: bool,
}

impl Inner {
    fn object(&self, index: u16, sub: u8) -> Result<Object, SdoAbort> {
        let c = &self.config;
        let object = match (index, sub) {
            (0x1000, 0) => Object::DeviceType,
            (0x1001, 0) => Object::ErrorRegister,
            (0x1017, 0) => Object::Heartbeat,
            (0x1018, 0) => Object::Count(4),
            (0x1018, 1) => Object::Identity(c.device.vendor_id),
            (0x1018, 2) => Object::Identity(c.device.product_code | LOADER_PRODUCT_BIT),
            (0x1018, 3) => Object::Identity(c.revision),
            (0x1018, 4) => Object::Identity(c.serial),
            (0x1F50 | 0x1F51 | 0x1F56 | 0x1F57, 0) => Object::Count(1),
            (0x1F50, 1) => Object::ProgramData,
            (0x1F51, 1) => Object::ProgramControl,
            (0x1F56, 1) => Object::SoftwareId,
            (0x1F57, 1) => Object::FlashStatus,
            (0x1000 | 0x1001 | 0x1017 | 0x1018 | 0x1F50 | 0x1F51 | 0x1F56 | 0x1F57, _) => {
                return Err(SdoAbort::NoSubIndex)
            }
            _ => return Err(SdoAbort::NoObject),
        };
        Ok(object)
    }

    fn restart_heartbeat(&mut self, now: Instant) {
        self.next_beat =
            (self.heartbeat_ms != 0).then(|| now.add_millis(u64::from(self.heartbeat_ms)));
    }

    fn heartbeat(&self) -> Frame {
        let id = self.config.node_id.cob_id(cob::HEARTBEAT);
        // An 11-bit COB-ID and one byte: always a valid frame.
        Frame::new(id, &[self.state.heartbeat_byte()]).unwrap_or_else(|_| unreachable!())
    }
}

/// The object dictionary as the SDO server reaches it.
struct Objects<'a, F> {
    inner: &'a mut Inner,
    flash: &'a mut F,
    now: Instant,
}

impl<F: Flash> ObjectAccess for Objects<'_, F> {
    fn upload(&mut self, index: u16, sub: u8, buf: &mut [u8]) -> Result<usize, SdoAbort> {
        let inner = &*self.inner;
        let value = match inner.object(index, sub)? {
            Object::DeviceType => DEVICE_TYPE,
            // No error is ever reported: the loader has no EMCY.
            Object::ErrorRegister => 0,
            Object::Heartbeat => u32::from(inner.heartbeat_ms),
            Object::Count(n) => u32::from(n),
            Object::Identity(v) => v,
            Object::ProgramData => return Err(SdoAbort::WriteOnly),
            Object::ProgramControl => inner.program.control() as u32,
            Object::SoftwareId => inner.program.software_id(),
            Object::FlashStatus => inner.program.flash_status(),
        };
        let n = inner.object(index, sub)?.size();
        let dst = buf.get_mut(..n).ok_or(SdoAbort::OutOfMemory)?;
        dst.copy_from_slice(value.to_le_bytes().get(..n).unwrap_or(&[]));
        Ok(n)
    }

    fn size_of(&mut self, index: u16, sub: u8) -> Result<usize, SdoAbort> {
        Ok(self.inner.object(index, sub)?.size())
    }

    fn check_download(&mut self, index: u16, sub: u8, size: Option<u32>) -> Result<(), SdoAbort> {
        let object = self.inner.object(index, sub)?;
        if !object.writable() {
            return Err(SdoAbort::ReadOnly);
        }
        if object == Object::ProgramData {
            return self.inner.program.begin(size);
        }
        match size.map(|s| usize::try_from(s).unwrap_or(usize::MAX)) {
            Some(n) if n > object.size() => Err(SdoAbort::TooLong),
            Some(n) if n < object.size() => Err(SdoAbort::TooShort),
            _ => Ok(()),
        }
    }

    fn download(&mut self, index: u16, sub: u8, data: &[u8]) -> Result<(), SdoAbort> {
        let object = self.inner.object(index, sub)?;
        if !object.writable() {
            return Err(SdoAbort::ReadOnly);
        }
        if object == Object::ProgramData {
            // An expedited download: a whole (and far too short) stream.
            let program = &mut self.inner.program;
            // At most 4 bytes.
            program.begin(Some(data.len() as u32))?;
            program.write(data, self.flash)?;
            return program.finish(self.flash);
        }
        match data.len() {
            n if n > object.size() => return Err(SdoAbort::TooLong),
            n if n < object.size() => return Err(SdoAbort::TooShort),
            _ => {}
        }
        match (object, data) {
            (Object::Heartbeat, &[lo, hi]) => {
                self.inner.heartbeat_ms = u16::from_le_bytes([lo, hi]);
                self.inner.restart_heartbeat(self.now);
                Ok(())
            }
            (Object::ProgramControl, &[value]) => {
                if self.inner.state != NmtState::PreOperational {
                    return Err(SdoAbort::DeviceState);
                }
                let action = self.inner.program.write_control(value, self.flash)?;
                self.inner.start = action == ControlAction::Start;
                Ok(())
            }
            _ => Err(SdoAbort::General),
        }
    }

    fn streams(&mut self, index: u16, sub: u8) -> bool {
        (index, sub) == (0x1F50, 1)
    }

    fn download_chunk(
        &mut self,
        _index: u16,
        _sub: u8,
        data: &[u8],
        last: bool,
    ) -> Result<(), SdoAbort> {
        let program = &mut self.inner.program;
        program.write(data, self.flash)?;
        if last {
            program.finish(self.flash)?;
        }
        Ok(())
    }
}

/// The block download's buffer: a sub-block of 127 segments (CiA 301's largest), taken into
/// RAM and written to flash before its acknowledgement, while the client waits.
pub const SDO_BLOCK_BYTES: usize = 127 * 7;

/// The loader's node.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct LoaderNode {
    sdo: SdoServer<SDO_BLOCK_BYTES>,
    inner: Inner,
}

impl LoaderNode {
    /// The node before its boot-up, over the slot as it is (0x1F56 and 0x1F57 from the
    /// boot check).
    #[must_use]
    pub fn new(config: LoaderConfig, flash: &impl Flash) -> Self {
        Self {
            sdo: SdoServer::new(config.sdo_timeout_ms),
            inner: Inner {
                config,
                state: NmtState::Initialising,
                heartbeat_ms: config.heartbeat_ms,
                next_beat: None,
                program: Program::new(config.device, flash),
                start: false,
            },
        }
    }

    /// The node-ID.
    #[must_use]
    pub const fn node_id(&self) -> NodeId {
        self.inner.config.node_id
    }

    /// The NMT state.
    #[must_use]
    pub const fn state(&self) -> NmtState {
        self.inner.state
    }

    /// The program download state.
    #[must_use]
    pub const fn program(&self) -> &Program {
        &self.inner.program
    }

    /// The loader stayed because the application failed its trial boot: 0x1F57 says so.
    pub fn report_failed_trial(&mut self) {
        self.inner.program.report_failed_trial();
    }

    /// Boots: the boot-up message, then Pre-operational (also after a reset communication).
    pub fn start(&mut self, now: Instant, tx: &mut impl FrameSink) {
        self.sdo = SdoServer::new(self.inner.config.sdo_timeout_ms);
        self.inner.program.abandon();
        self.inner.heartbeat_ms = self.inner.config.heartbeat_ms;
        self.inner.state = NmtState::Initialising;
        let _ = tx.send(self.inner.heartbeat());
        self.inner.state = NmtState::PreOperational;
        self.inner.restart_heartbeat(now);
    }

    fn set_state(&mut self, now: Instant, next: NmtState, tx: &mut impl FrameSink) {
        if self.inner.state == next {
            return;
        }
        self.inner.state = next;
        self.sdo.on_nmt_state(next);
        if self.inner.heartbeat_ms != 0 {
            // A state change is announced at once, and the period starts over.
            let _ = tx.send(self.inner.heartbeat());
            self.inner.restart_heartbeat(now);
        }
    }

    /// A frame from the bus. Frames this node does not consume are ignored.
    pub fn on_frame(
        &mut self,
        now: Instant,
        frame: &Frame,
        flash: &mut impl Flash,
        tx: &mut impl FrameSink,
    ) -> Option<Request> {
        let node = self.inner.config.node_id;
        let mut request = None;
        if let Some(cmd) = NmtCommand::parse(frame, node) {
            match cmd {
                NmtCommand::StartRemoteNode => self.set_state(now, NmtState::Operational, tx),
                NmtCommand::StopRemoteNode => self.set_state(now, NmtState::Stopped, tx),
                NmtCommand::EnterPreOperational => {
                    self.set_state(now, NmtState::PreOperational, tx);
                }
                NmtCommand::ResetNode => request = Some(Request::Reset),
                NmtCommand::ResetCommunication => {
                    tx.discard_pending();
                    self.start(now, tx);
                }
            }
        } else if frame.id() == node.cob_id(cob::SDO_RX)
            && frame.dlc() == 8
            && matches!(
                self.inner.state,
                NmtState::PreOperational | NmtState::Operational
            )
        {
            let mut objects = Objects {
                inner: &mut self.inner,
                flash,
                now,
            };
            if let Some(reply) = self.sdo.on_request(now, frame.raw_data(), &mut objects) {
                let id = node.cob_id(cob::SDO_TX);
                // An 11-bit COB-ID and 8 bytes: always a valid frame.
                let _ = tx.send(Frame::new(id, &reply).unwrap_or_else(|_| unreachable!()));
            }
            if core::mem::take(&mut self.inner.start) {
                request = Some(Request::Reset);
            }
        }
        self.settle();
        request
    }

    /// Timers: the heartbeat and the SDO timeout.
    pub fn poll(&mut self, now: Instant, tx: &mut impl FrameSink) {
        if let Some(reply) = self.sdo.poll(now) {
            let id = self.inner.config.node_id.cob_id(cob::SDO_TX);
            let _ = tx.send(Frame::new(id, &reply).unwrap_or_else(|_| unreachable!()));
        }
        if let Some(due) = self.inner.next_beat {
            if now >= due {
                let _ = tx.send(self.inner.heartbeat());
                let next = due.add_millis(u64::from(self.inner.heartbeat_ms));
                // Drift-free, but no burst after a late poll.
                self.inner.next_beat = Some(if next <= now {
                    now.add_millis(u64::from(self.inner.heartbeat_ms))
                } else {
                    next
                });
            }
        }
        self.settle();
    }

    /// When [`poll`](Self::poll) has something to do next.
    #[must_use]
    pub fn next_deadline(&self) -> Option<Instant> {
        match (self.inner.next_beat, self.sdo.deadline()) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }

    /// A download whose transfer ended without its last segment (client abort, timeout,
    /// another request, NMT) has failed.
    fn settle(&mut self) {
        if self.inner.program.in_progress() && self.sdo.deadline().is_none() {
            self.inner.program.abandon();
        }
    }
}
