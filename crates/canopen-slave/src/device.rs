//! The engine: one NMT state machine driving the SDO server, heartbeat, SYNC, RPDO, TPDO
//! and EMCY services over the object dictionary. Sans-I/O: frames come in through
//! [`Device::on_frame`], time through every call, frames go out to a [`FrameSink`].
//!
//! This file holds the device and its dispatch of frames and time; each service's part of
//! the engine is a submodule: `nmt` (boot and the one place of NMT transitions),
//! `objects` (the communication objects, one table row each), `sdo` (the object
//! dictionary as the SDO server sees it), `pdo` (the RPDO and TPDO services), `errors` (EMCY,
//! bus and heartbeat-loss policy); `objects::params` is 0x1010 store and 0x1011 restore.

mod errors;
mod nmt;
pub(crate) mod objects;
mod pdo;
mod sdo;

use crate::abort::SdoAbort;
use crate::cob_id::COB_INVALID;
use crate::emcy::Emcy;
use crate::filter::RxFilter;
use crate::frame::{cob, Frame, FrameSink, NodeId};
use crate::heartbeat::Heartbeat;
use crate::lss::{self, LssAction, LssAddress, LssSlave};
use crate::nmt::{NmtCommand, NmtState};
use crate::od::{Od, Value};
use crate::rpdo::{Rpdo, RPDOS};
use crate::sdo::SdoServer;
use crate::storage::Storage;
use crate::sync::SyncConsumer;
use crate::time::{earliest, Instant};
use crate::tpdo::{Tpdo, TPDOS};

use nmt::Boot;
use objects::{Comm, SDO2_DEFAULTS};

/// What the engine needs from the application. Objects outside 0x1000-0x1FFF whose table
/// entry says [`Value::App`] are read and written here; the hooks report engine events.
pub trait Application {
    /// Reads object `index:sub` as little-endian bytes into `buf`; returns the length,
    /// which must equal the size of numeric types. Also used to build TPDOs, so it must not
    /// have side effects that matter.
    fn read(&mut self, index: u16, sub: u8, buf: &mut [u8]) -> Result<usize, SdoAbort>;

    /// Writes object `index:sub`. The engine has already checked existence, access, length
    /// and the table's range; the application may still refuse (e.g. 0x06090030, or
    /// 0x08000022 in the wrong device state).
    fn write(&mut self, index: u16, sub: u8, data: &[u8]) -> Result<(), SdoAbort>;

    /// Whether [`Application::write`] would take `data` for `index:sub` now, without writing
    /// it: an RPDO is taken whole or not at all, so each of its values is checked here
    /// (after the table's checks) before any is written. `write` should then not refuse
    /// what this accepted; if it does, the rest of the frame is not written.
    fn check_write(&mut self, _index: u16, _sub: u8, _data: &[u8]) -> Result<(), SdoAbort> {
        Ok(())
    }

    /// RPDO `pdo` (1-based) was written to its mapped objects (at its reception, or at the
    /// SYNC after it for the synchronous types).
    fn on_rpdo(&mut self, _pdo: u8) {}

    /// Deadline monitoring: RPDO `pdo` (1-based) did not come within its event timer
    /// (0x1400+n:05) in Operational. Called once per timeout; monitoring starts again with
    /// the next frame. An application that drives outputs from the PDO puts them in a
    /// safe state here.
    fn on_rpdo_timeout(&mut self, _pdo: u8) {}

    /// Called after every NMT state change.
    fn on_nmt_state(&mut self, _state: NmtState) {}

    /// A master's SDO download of `index:sub` succeeded (any object, communication ones
    /// included): for an application whose guarantees rest on a configuration that a write
    /// may have changed.
    fn on_written(&mut self, _index: u16, _sub: u8) {}

    /// A monitored node's heartbeat timed out (once per loss).
    fn on_heartbeat_lost(&mut self, _node_id: u8) {}

    /// No consumed heartbeat is in timeout any more: every lost node was heard again, or
    /// its entry was reconfigured, or communication was reset. Called once per recovery,
    /// after the [`Application::on_heartbeat_lost`] calls it ends. Until then, an
    /// application that must not act without its master should refuse to (0x08000022).
    fn on_heartbeat_restored(&mut self) {}

    /// NMT reset node: put application state back to power-on values. Stored application
    /// parameters, if any, follow through [`Application::restore_application`].
    fn on_reset_application(&mut self) {}

    /// TPDO `pdo` (1-based) is about to be built and sent (an event, the event timer or a
    /// SYNC). Returning `false` withdraws it: nothing is sent. For PDOs that carry events
    /// rather than state, where a stale or repeated frame would be wrong.
    fn tpdo_ready(&mut self, _pdo: u8) -> bool {
        true
    }

    /// Reads object `index:sub` into TPDO `pdo` (1-based) being built. A PDO that carries
    /// state may carry a value the application held back for it (a state that ended while the
    /// bus took nothing) rather than the present one; SDO uploads always see the present one
    /// ([`Application::read`], which this defaults to).
    fn read_for_tpdo(
        &mut self,
        _pdo: u8,
        index: u16,
        sub: u8,
        buf: &mut [u8],
    ) -> Result<usize, SdoAbort> {
        self.read(index, sub, buf)
    }

    /// TPDO `pdo` (1-based) was handed to the sink.
    fn on_tpdo_sent(&mut self, _pdo: u8) {}

    /// Serialises the application's parameters for 0x1010 sub 1 or 3 into `buf` (at most
    /// [`APP_MAX`](crate::APP_MAX) bytes); returns the length.
    fn save_application(&self, _buf: &mut [u8]) -> usize {
        0
    }

    /// Applies stored application parameters, at start-up and after reset node. Not called
    /// when none are stored. `Err((index, sub))` names a stored value the application's
    /// checked write of that object would refuse: the application keeps its defaults, and
    /// the engine reports it as it reports a refused communication parameter (EMCY 0x6300).
    fn restore_application(&mut self, _data: &[u8]) -> Result<(), (u16, u8)> {
        Ok(())
    }

    /// Whether the parameter memory may be written now. Asked before every 0x1010 save,
    /// 0x1011 restore and LSS "store configuration": writing flash stalls the CPU (a page
    /// erase on an STM32F1 takes 20-40 ms), so an application whose real-time work must not
    /// stall refuses while it runs. Refused: SDO abort 0x08000022, LSS error 255 / spec 2.
    fn may_store(&mut self) -> bool {
        true
    }
}

/// Run-time configuration of the device.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Config {
    /// Our node-ID at power-on; `None`: unconfigured (CiA 305 node-ID 0xFF), the node sends
    /// no boot-up and answers only LSS until a master gives it a node-ID.
    pub node_id: Option<NodeId>,
    /// The CAN bit rate in force, as a CiA 301 bit-timing table index (0 = 1 Mbit/s), for
    /// LSS; [`lss::DEFAULT_BIT_TIMINGS`] by default.
    pub bit_timing: u8,
    /// Bit `i` set: the firmware can run at table index `i` (LSS configure bit timing).
    pub bit_timings: u16,
    /// 0x1018:04, e.g. a hash of the MCU's unique ID.
    pub serial_number: u32,
    /// An unfinished segmented SDO transfer is aborted (0x05040000) after this long.
    pub sdo_timeout_ms: u16,
}

impl Config {
    /// Serial number 0, SDO timeout 1 s, 1 Mbit/s.
    pub const fn new(node_id: NodeId) -> Self {
        Self::with_node(Some(node_id))
    }

    /// [`Config::new`] for a node that may be unconfigured (`None`).
    pub const fn with_node(node_id: Option<NodeId>) -> Self {
        Self {
            node_id,
            bit_timing: 0,
            bit_timings: lss::DEFAULT_BIT_TIMINGS,
            serial_number: 0,
            sdo_timeout_ms: 1000,
        }
    }
}

/// Counters of things that went wrong without stopping the engine.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Stats {
    /// Frames the sink refused. TPDOs and EMCYs are retried later; SDO replies,
    /// heartbeats and boot-ups are lost.
    pub tx_refused: u16,
    /// EMCY frames dropped because the EMCY queue was full.
    pub emcy_overflow: u16,
    /// TPDO events dropped because a mapped object could not be read.
    pub tpdo_errors: u16,
    /// RPDO frames not processed: shorter than their mapping, or a value refused.
    pub rpdo_errors: u16,
}

/// [`Device::request_tpdo`] was given a PDO number the device does not have.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct NoSuchPdo;

/// A CANopen device.
#[derive(Clone, Debug, PartialEq, Hash)]
pub struct Device<S> {
    /// The SDO servers: the default one (0x600 / 0x580 + node-ID) and the one of 0x1201,
    /// each with its own transfer and timeout.
    sdo: [SdoServer; 2],
    /// LSS (CiA 305): it also owns the node-ID the next reset of communication activates.
    lss: LssSlave,
    inner: Inner<S>,
}

/// Everything but the SDO server, so that the server can borrow the objects mutably while
/// it runs (the same split as smoltcp's `Interface` / `InterfaceInner`).
#[derive(Clone, Debug, PartialEq, Hash)]
struct Inner<S> {
    /// The NMT state and the communication objects' services.
    comm: Comm,
    storage: S,
    tx_refused: u16,
    tpdo_errors: u16,
    rpdo_errors: u16,
    /// The application was told of a heartbeat loss and not yet of the recovery.
    heartbeat_lost: bool,
}

impl<S: Storage> Device<S> {
    /// A device in `Initialising`; nothing happens on the bus before [`Device::start`].
    pub fn new(config: Config, od: Od, storage: S) -> Self {
        let identity = |sub| match od.find(0x1018, sub).map(|e| e.value()) {
            Ok(Value::Const(v)) => v,
            _ => 0,
        };
        let address = LssAddress {
            vendor_id: identity(1),
            product_code: identity(2),
            revision: identity(3),
            serial: config.serial_number,
        };
        let mut device = Self {
            sdo: [
                SdoServer::new(config.sdo_timeout_ms),
                SdoServer::new(config.sdo_timeout_ms),
            ],
            lss: LssSlave::new(
                address,
                config.node_id,
                config.bit_timing,
                config.bit_timings,
            ),
            inner: Inner {
                comm: Comm {
                    od,
                    node: config.node_id,
                    serial: config.serial_number,
                    state: NmtState::Initialising,
                    heartbeat: Heartbeat::new(),
                    sync: SyncConsumer::new(),
                    rpdos: [const { Rpdo::new() }; RPDOS],
                    tpdos: [const { Tpdo::new() }; TPDOS],
                    emcy: Emcy::new(),
                    sdo2: SDO2_DEFAULTS,
                },
                storage,
                tx_refused: 0,
                tpdo_errors: 0,
                rpdo_errors: 0,
                heartbeat_lost: false,
            },
        };
        // The table's defaults already, so that `rx_filter` before `start` (the filter a
        // firmware first programs) holds the default RPDO; `start` loads them again.
        device.inner.comm.load_defaults(Instant::ZERO);
        device
    }

    /// Power-on: loads stored parameters, sends the boot-up frame, enters Pre-operational.
    pub fn start(&mut self, now: Instant, app: &mut dyn Application, tx: &mut dyn FrameSink) {
        self.boot(now, Boot::PowerOn, app, tx);
    }

    /// Handles one received frame. Frames for other services or nodes, or with the wrong
    /// length, are ignored without any change of state. Time-driven work waits for `poll`.
    pub fn on_frame(
        &mut self,
        now: Instant,
        frame: &Frame,
        app: &mut dyn Application,
        tx: &mut dyn FrameSink,
    ) {
        if frame.id() == lss::LSS_REQUEST {
            self.on_lss(now, frame, app, tx);
            return;
        }
        let state = self.inner.comm.state;
        // An unconfigured node stays in Initialising: it answers LSS only.
        let (NmtState::PreOperational | NmtState::Operational | NmtState::Stopped, Some(node)) =
            (state, self.inner.comm.node)
        else {
            return;
        };
        let id = frame.id();
        if id == cob::NMT {
            if let Some(cmd) = NmtCommand::parse(frame, node) {
                self.on_nmt(now, cmd, app, tx);
            }
        } else if let Some(channel) =
            (0..2).find(|&c| self.inner.comm.sdo_ids(c).is_some_and(|(rx, _)| rx == id))
        {
            if frame.dlc() != 8 || !state.communicating() {
                return;
            }
            self.on_sdo_request(now, channel, frame, app, tx);
        } else if (cob::HEARTBEAT + 1..=cob::HEARTBEAT + 127).contains(&id) {
            if frame.dlc() == 1 {
                // The range check above makes this fit 7 bits.
                // The recovery of a lost node is noticed by `settle_heartbeat` below.
                self.inner
                    .comm
                    .heartbeat
                    .on_heartbeat(now, (id - cob::HEARTBEAT) as u8);
            }
        } else if let Some(pdo) = self.inner.rpdo_on(id) {
            self.inner.on_rpdo(now, pdo, frame, app);
        } else if self.inner.comm.sync.is_sync(frame) {
            self.inner.on_sync(now, app, tx);
        }
        // A heartbeat, or an SDO write of 0x1016, may have ended a loss.
        self.inner.settle_heartbeat(app);
    }

    /// Time-driven work: SDO timeout, heartbeat consumers and producer, RPDO deadline
    /// monitoring, TPDO event timers and inhibit times, queued EMCYs. Call it at [`Device::next_deadline`] at the latest.
    pub fn poll(&mut self, now: Instant, app: &mut dyn Application, tx: &mut dyn FrameSink) {
        if self.inner.comm.node.is_none() || self.inner.comm.state == NmtState::Initialising {
            return;
        }
        for (channel, server) in self.sdo.iter_mut().enumerate() {
            let ids = self.inner.comm.sdo_ids(channel);
            if let (Some(abort), Some((_, reply))) = (server.poll(now), ids) {
                self.inner.emit(tx, Frame::from_parts(reply, abort, 8));
            }
        }
        self.inner.check_heartbeats(now, app);
        if self.inner.comm.heartbeat.beat_due(now) {
            self.inner.send_heartbeat(tx);
        }
        self.inner.check_rpdo_deadlines(now, app);
        self.inner.service_tpdos(now, app, tx);
        self.inner.service_emcy(now, tx);
    }

    /// The earliest instant at which [`Device::poll`] has work; `None` if only a frame can
    /// create some. May be in the past (poll right away).
    #[must_use]
    pub fn next_deadline(&self) -> Option<Instant> {
        let comm = &self.inner.comm;
        if comm.state == NmtState::Initialising {
            return self.lss.deadline();
        }
        let [sdo, sdo2] = &self.sdo;
        let mut next = earliest(sdo.deadline(), sdo2.deadline());
        next = earliest(next, comm.heartbeat.deadline());
        next = earliest(next, self.lss.deadline());
        if comm.state == NmtState::Operational {
            for r in &comm.rpdos {
                next = earliest(next, r.deadline);
            }
            for t in &comm.tpdos {
                next = earliest(next, t.deadline());
            }
        }
        if comm.state.communicating() {
            next = earliest(next, comm.emcy.deadline());
        }
        next
    }

    /// Current NMT state.
    pub fn nmt_state(&self) -> NmtState {
        self.inner.comm.state
    }

    /// Our node-ID; `None` while unconfigured.
    pub fn node_id(&self) -> Option<NodeId> {
        self.inner.comm.node
    }

    /// The LSS slave: state, pending node-ID and bit timing.
    pub fn lss(&self) -> &LssSlave {
        &self.lss
    }

    /// After "activate bit timing" and its switch delay: the CiA 301 bit-timing table index
    /// the firmware must switch its CAN controller to now (once). Call it after `poll`;
    /// [`Device::next_deadline`] includes the moment.
    pub fn take_bit_timing_switch(&mut self, now: Instant) -> Option<u8> {
        let index = self.lss.take_bit_timing_switch(now)?;
        info!("LSS: switching to bit timing {=u8}", index);
        Some(index)
    }

    /// Error counters.
    pub fn stats(&self) -> Stats {
        Stats {
            tx_refused: self.inner.tx_refused,
            emcy_overflow: self.inner.comm.emcy.overflow(),
            tpdo_errors: self.inner.tpdo_errors,
            rpdo_errors: self.inner.rpdo_errors,
        }
    }

    /// The identifiers the device handles now (NMT, SYNC as 0x1005 says, this node's SDO
    /// requests on both servers, RPDO1 while it is received, heartbeats). The firmware
    /// reprograms its acceptance filter whenever this changes, e.g. after a write of 0x1005,
    /// 0x1201 or 0x1400 or a reset of communication.
    #[must_use]
    #[inline(always)]
    pub fn rx_filter(&self) -> RxFilter {
        let comm = &self.inner.comm;
        // 0x1005 and 0x1201 are checked to carry 11-bit identifiers; the filter keeps those.
        let sync = comm.sync.cob_id() as u16;
        // Read here, and the function inlined, rather than through `Comm::sdo_ids`: a call
        // with the device's address makes the firmware's init build the device on its stack
        // and copy it (1 KiB more stack).
        let [rx, tx, _] = comm.sdo2;
        let second = ((rx | tx) & COB_INVALID == 0).then_some(rx as u16);
        let [rpdo] = &comm.rpdos;
        let rpdo = rpdo.active().then(|| rpdo.can_id());
        match comm.node {
            Some(node) => RxFilter::with_sync(node, sync)
                .with_second_sdo(second)
                .with_rpdo(rpdo),
            None => RxFilter::unconfigured(),
        }
    }

    /// The parameter storage.
    pub fn storage(&self) -> &S {
        &self.inner.storage
    }

    /// The parameter storage, mutably.
    pub fn storage_mut(&mut self) -> &mut S {
        &mut self.inner.storage
    }

    /// An LSS request: the answer, and a reset of communication when an unconfigured node
    /// was given a node-ID.
    fn on_lss(
        &mut self,
        now: Instant,
        frame: &Frame,
        app: &mut dyn Application,
        tx: &mut dyn FrameSink,
    ) {
        let active = self.inner.comm.node;
        // Asked for every request (cheaper in flash than picking out "store configuration",
        // the only one that writes): without consent LSS answers a store with 255 / 2.
        let storage: Option<&mut dyn Storage> = app.may_store().then_some(&mut self.inner.storage);
        let (reply, action) = self.lss.on_frame(now, frame, active, storage);
        if let Some(reply) = reply {
            self.inner.emit(tx, reply);
        }
        if action == LssAction::ResetCommunication {
            self.boot(now, Boot::ResetCommunication, app, tx);
        }
    }
}

impl<S: Storage> Inner<S> {
    fn emit(&mut self, tx: &mut dyn FrameSink, frame: Frame) -> bool {
        let sent = tx.send(frame).is_ok();
        if !sent {
            self.tx_refused = self.tx_refused.saturating_add(1);
        }
        sent
    }

    fn send_heartbeat(&mut self, tx: &mut dyn FrameSink) {
        let Some(node) = self.comm.node else {
            return;
        };
        let id = node.cob_id(cob::HEARTBEAT);
        let byte = self.comm.state.heartbeat_byte();
        let frame = Frame::from_parts(id, [byte, 0, 0, 0, 0, 0, 0, 0], 1);
        self.emit(tx, frame);
    }
}
