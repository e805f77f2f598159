//! The engine: one NMT state machine driving the SDO server, heartbeat, SYNC, TPDO and
//! EMCY services over the object dictionary. Sans-I/O: frames come in through
//! [`Device::on_frame`], time through every call, frames go out to a [`FrameSink`].

use crate::bus::{self, BusEvent};
use crate::emcy::{self, Emcy, EmcyError};
use crate::filter::RxFilter;
use crate::frame::{
    check_cob_id_write, cob, Frame, FrameSink, NodeId, COB_INVALID, MAX_STANDARD_ID,
};
use crate::heartbeat::Heartbeat;
use crate::indicators::ErrorIndication;
use crate::lss::{self, LssAction, LssAddress, LssSlave};
use crate::nmt::{NmtCommand, NmtState};
use crate::od::{Od, OdEntry, Value};
use crate::sdo::{ObjectAccess, SdoAbort, SdoServer};
use crate::storage::{self, Blob, Storage, LOAD_SIGNATURE, SAVE_SIGNATURE};
use crate::sync::SyncConsumer;
use crate::time::{earliest, Instant};
use crate::tpdo::{self, Tpdo, TPDOS};

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

    /// Called after every NMT state change.
    fn on_nmt_state(&mut self, _state: NmtState) {}

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

    /// TPDO `pdo` (1-based) was handed to the sink.
    fn on_tpdo_sent(&mut self, _pdo: u8) {}

    /// Serialises the application's parameters for 0x1010 sub 1 or 3 into `buf` (at most
    /// [`storage::APP_MAX`] bytes); returns the length.
    fn save_application(&self, _buf: &mut [u8]) -> usize {
        0
    }

    /// Applies stored application parameters, at start-up and after reset node. Not called
    /// when none are stored.
    fn restore_application(&mut self, _data: &[u8]) {}
}

/// Run-time configuration of the device.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
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
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Stats {
    /// Frames the sink refused. TPDOs and EMCYs are retried later; SDO replies,
    /// heartbeats and boot-ups are lost.
    pub tx_refused: u16,
    /// EMCY frames dropped because the EMCY queue was full.
    pub emcy_overflow: u16,
    /// TPDO events dropped because a mapped object could not be read.
    pub tpdo_errors: u16,
}

/// [`Device::request_tpdo`] was given a PDO number the device does not have.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct NoSuchPdo;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Boot {
    PowerOn,
    ResetNode,
    ResetCommunication,
}

/// A CANopen device.
#[derive(Clone, Debug, PartialEq)]
pub struct Device<S> {
    sdo: SdoServer,
    /// LSS (CiA 305): it also owns the node-ID the next reset of communication activates.
    lss: LssSlave,
    inner: Inner<S>,
}

/// Everything but the SDO server, so that the server can borrow the objects mutably while
/// it runs (the same split as smoltcp's `Interface` / `InterfaceInner`).
#[derive(Clone, Debug, PartialEq)]
struct Inner<S> {
    od: Od,
    /// The active node-ID; `None` while unconfigured (the NMT state is then Initialising).
    node: Option<NodeId>,
    serial: u32,
    state: NmtState,
    heartbeat: Heartbeat,
    sync: SyncConsumer,
    tpdos: [Tpdo; TPDOS],
    emcy: Emcy,
    storage: S,
    tx_refused: u16,
    tpdo_errors: u16,
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
        Self {
            sdo: SdoServer::new(config.sdo_timeout_ms),
            lss: LssSlave::new(
                address,
                config.node_id,
                config.bit_timing,
                config.bit_timings,
            ),
            inner: Inner {
                od,
                node: config.node_id,
                serial: config.serial_number,
                state: NmtState::Initialising,
                heartbeat: Heartbeat::new(),
                sync: SyncConsumer::new(),
                tpdos: [const { Tpdo::new() }; TPDOS],
                emcy: Emcy::new(),
                storage,
                tx_refused: 0,
                tpdo_errors: 0,
                heartbeat_lost: false,
            },
        }
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
        let state = self.inner.state;
        // An unconfigured node stays in Initialising: it answers LSS only.
        let (NmtState::PreOperational | NmtState::Operational | NmtState::Stopped, Some(node)) =
            (state, self.inner.node)
        else {
            return;
        };
        let id = frame.id();
        if id == cob::NMT {
            if let Some(cmd) = NmtCommand::parse(frame, node) {
                self.on_nmt(now, cmd, app, tx);
            }
        } else if id == node.cob_id(cob::SDO_RX) {
            if frame.dlc() != 8 || !state.communicating() {
                return;
            }
            let mut objects = Objects {
                inner: &mut self.inner,
                app,
                now,
            };
            if let Some(reply) = self.sdo.on_request(now, frame.raw_data(), &mut objects) {
                let reply = Frame::from_parts(node.cob_id(cob::SDO_TX), reply, 8);
                self.inner.emit(tx, reply);
            }
        } else if (cob::HEARTBEAT + 1..=cob::HEARTBEAT + 127).contains(&id) {
            if frame.dlc() == 1 {
                // The range check above makes this fit 7 bits.
                // The recovery of a lost node is noticed by `settle_heartbeat` below.
                self.inner
                    .heartbeat
                    .on_heartbeat(now, (id - cob::HEARTBEAT) as u8);
            }
        } else if self.inner.sync.is_sync(frame) {
            self.inner.on_sync(now, app, tx);
        }
        // A heartbeat, or an SDO write of 0x1016, may have ended a loss.
        self.inner.settle_heartbeat(app);
    }

    /// Time-driven work: SDO timeout, heartbeat consumers and producer, TPDO event timers
    /// and inhibit times, queued EMCYs. Call it at [`Device::next_deadline`] at the latest.
    pub fn poll(&mut self, now: Instant, app: &mut dyn Application, tx: &mut dyn FrameSink) {
        let Some(node) = self.inner.node else {
            return;
        };
        if self.inner.state == NmtState::Initialising {
            return;
        }
        if let Some(abort) = self.sdo.poll(now) {
            self.inner
                .emit(tx, Frame::from_parts(node.cob_id(cob::SDO_TX), abort, 8));
        }
        while let Some(lost) = self.inner.heartbeat.take_timeout(now) {
            warn!("heartbeat of node {=u8} lost", lost);
            let transmit = self.inner.state.communicating();
            // With the error list full the loss is still reported to the application.
            let _ = self.inner.emcy.raise(
                emcy::code::HEARTBEAT,
                emcy::register::COMMUNICATION,
                [lost, 0, 0, 0, 0],
                transmit,
            );
            self.inner.heartbeat_lost = true;
            app.on_heartbeat_lost(lost);
        }
        if self.inner.heartbeat.beat_due(now) {
            self.inner.send_heartbeat(tx);
        }
        self.inner.service_tpdos(now, app, tx);
        self.inner.service_emcy(now, tx);
    }

    /// The earliest instant at which [`Device::poll`] has work; `None` if only a frame can
    /// create some. May be in the past (poll right away).
    #[must_use]
    pub fn next_deadline(&self) -> Option<Instant> {
        let inner = &self.inner;
        if inner.state == NmtState::Initialising {
            return self.lss.deadline();
        }
        let mut next = earliest(self.sdo.deadline(), inner.heartbeat.deadline());
        next = earliest(next, self.lss.deadline());
        if inner.state == NmtState::Operational {
            for t in &inner.tpdos {
                next = earliest(next, t.deadline());
            }
        }
        if inner.state.communicating() {
            next = earliest(next, inner.emcy.deadline());
        }
        next
    }

    /// Mapped data of TPDO `pdo` (1-based) changed: an event-driven PDO goes out at the next
    /// `poll` the inhibit time allows, a type-0 PDO at the next SYNC. Ignored outside
    /// Operational and for cyclic types.
    pub fn request_tpdo(&mut self, pdo: u8) -> Result<(), NoSuchPdo> {
        let operational = self.inner.state == NmtState::Operational;
        let t = usize::from(pdo)
            .checked_sub(1)
            .and_then(|i| self.inner.tpdos.get_mut(i))
            .ok_or(NoSuchPdo)?;
        if operational {
            t.request();
        }
        Ok(())
    }

    /// Raises an error: recorded in 0x1001/0x1003 and announced by an EMCY at the next
    /// `poll` (not in Stopped, where only the record is kept). `info` are the five
    /// manufacturer-specific bytes. Raising an active code again does nothing.
    // Out of line: called from several places, inlined copies cost more flash.
    #[inline(never)]
    pub fn raise_error(
        &mut self,
        code: u16,
        register_bits: u8,
        info: [u8; 5],
    ) -> Result<(), EmcyError> {
        let transmit = self.inner.state != NmtState::Stopped;
        self.inner.emcy.raise(code, register_bits, info, transmit)
    }

    /// Clears an active error; returns whether it was active. Clearing the last one sends
    /// the error-reset EMCY (code 0x0000).
    pub fn clear_error(&mut self, code: u16) -> bool {
        let transmit = self.inner.state != NmtState::Stopped;
        self.inner.emcy.clear(code, transmit)
    }

    /// Raises and clears the EMCYs CiA 301 asks for when the CAN controller's error state
    /// changes: error passive is a condition (0x8120 raised, then cleared when it is over);
    /// a bus-off recovery is an event (0x8140 raised and cleared at once: the EMCY, then the
    /// error reset), and it ends error passive too. Warning and bus-off send nothing (the
    /// ERR LED shows them; nothing can be sent in bus-off anyway).
    pub fn on_bus_event(&mut self, event: BusEvent) {
        match event {
            BusEvent::ErrorPassive => {
                // An error already active or a full history only means no new frame.
                let _ = self.raise_error(
                    bus::EMCY_CAN_ERROR_PASSIVE,
                    emcy::register::COMMUNICATION,
                    [0; 5],
                );
            }
            BusEvent::ErrorActiveAgain => {
                self.clear_error(bus::EMCY_CAN_ERROR_PASSIVE);
            }
            BusEvent::BusOffRecovered => {
                // The recovery EMCY first, while 0x8120 still holds the error register, so
                // that the end of both is a single error reset.
                let code = bus::EMCY_BUS_OFF_RECOVERED;
                let raised = self
                    .raise_error(code, emcy::register::COMMUNICATION, [0; 5])
                    .is_ok();
                self.clear_error(bus::EMCY_CAN_ERROR_PASSIVE);
                if raised {
                    self.clear_error(code);
                }
            }
            BusEvent::WarningLimit | BusEvent::BusOff => {}
        }
    }

    /// Received frames were lost (controller or receive queue overrun): EMCY 0x8110, an
    /// event, raised and cleared at once.
    pub fn on_rx_overrun(&mut self) {
        self.error_event(bus::EMCY_CAN_OVERRUN);
    }

    /// An error that is over as soon as it is reported: the EMCY, then its clearing.
    fn error_event(&mut self, code: u16) {
        if self
            .raise_error(code, emcy::register::COMMUNICATION, [0; 5])
            .is_ok()
        {
            self.clear_error(code);
        }
    }

    /// Current NMT state.
    pub fn nmt_state(&self) -> NmtState {
        self.inner.state
    }

    /// Our node-ID; `None` while unconfigured.
    pub fn node_id(&self) -> Option<NodeId> {
        self.inner.node
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

    /// 0x1001.
    pub fn error_register(&self) -> u8 {
        self.inner.emcy.error_register()
    }

    /// What the ERR LED shows on account of the engine (heartbeat loss); the firmware adds
    /// its CAN controller's warning / bus-off conditions with `max`.
    pub fn error_indication(&self) -> ErrorIndication {
        if self.inner.heartbeat.any_lost() {
            ErrorIndication::ErrorControlEvent
        } else {
            ErrorIndication::NoError
        }
    }

    /// Error counters.
    pub fn stats(&self) -> Stats {
        Stats {
            tx_refused: self.inner.tx_refused,
            emcy_overflow: self.inner.emcy.overflow(),
            tpdo_errors: self.inner.tpdo_errors,
        }
    }

    /// Local read of any object, with the same checks as an SDO upload.
    pub fn read(
        &mut self,
        index: u16,
        sub: u8,
        buf: &mut [u8],
        app: &mut dyn Application,
    ) -> Result<usize, SdoAbort> {
        Objects {
            inner: &mut self.inner,
            app,
            now: Instant::ZERO,
        }
        .upload(index, sub, buf)
    }

    /// Local write of any object, with the same checks as an SDO download (e.g. for an
    /// application object that mirrors a communication parameter).
    pub fn write(
        &mut self,
        now: Instant,
        index: u16,
        sub: u8,
        data: &[u8],
        app: &mut dyn Application,
    ) -> Result<(), SdoAbort> {
        let written = self.inner.write_object(now, index, sub, data, app);
        self.inner.settle_heartbeat(app);
        written
    }

    /// The identifiers the device handles now (NMT, SYNC as 0x1005 says, this node's SDO
    /// requests, heartbeats). The firmware reprograms its acceptance filter whenever this
    /// changes, e.g. after a write of 0x1005 or a reset of communication.
    #[must_use]
    pub fn rx_filter(&self) -> RxFilter {
        // 0x1005 is checked to carry an 11-bit identifier; the mask keeps the cast exact.
        let sync = (self.inner.sync.cob_id() & u32::from(MAX_STANDARD_ID)) as u16;
        match self.inner.node {
            Some(node) => RxFilter::with_sync(node, sync),
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
        let active = self.inner.node;
        let (reply, action) = self
            .lss
            .on_frame(now, frame, active, &mut self.inner.storage);
        if let Some(reply) = reply {
            self.inner.emit(tx, reply);
        }
        if action == LssAction::ResetCommunication {
            self.boot(now, Boot::ResetCommunication, app, tx);
        }
    }

    fn on_nmt(
        &mut self,
        now: Instant,
        cmd: NmtCommand,
        app: &mut dyn Application,
        tx: &mut dyn FrameSink,
    ) {
        match cmd {
            NmtCommand::StartRemoteNode => self.set_state(now, NmtState::Operational, app, tx),
            NmtCommand::StopRemoteNode => self.set_state(now, NmtState::Stopped, app, tx),
            NmtCommand::EnterPreOperational => {
                self.set_state(now, NmtState::PreOperational, app, tx)
            }
            NmtCommand::ResetNode => self.boot(now, Boot::ResetNode, app, tx),
            NmtCommand::ResetCommunication => self.boot(now, Boot::ResetCommunication, app, tx),
        }
    }

    /// The one place where the NMT state changes.
    fn set_state(
        &mut self,
        now: Instant,
        next: NmtState,
        app: &mut dyn Application,
        tx: &mut dyn FrameSink,
    ) {
        let prev = self.inner.state;
        if prev == next {
            return;
        }
        info!("NMT {} -> {}", prev, next);
        self.inner.state = next;
        if !next.communicating() {
            self.sdo.reset();
        }
        if next == NmtState::Stopped {
            self.inner.emcy.discard_queue();
        }
        for (n, t) in self.inner.tpdos.iter_mut().enumerate() {
            if next == NmtState::Operational {
                // Only TPDO1 announces itself (CiA 406 does so for the position): a PDO
                // carrying events rather than state must not be repeated by a state change.
                t.start(now, n == 0);
            } else {
                t.stop();
            }
        }
        app.on_nmt_state(next);
        // Announce the new state at once, except right after the boot-up frame: some masters
        // miss a boot-up that is immediately followed by a heartbeat.
        if prev != NmtState::Initialising
            && next != NmtState::Initialising
            && self.inner.heartbeat.producer_ms() != 0
        {
            self.inner.send_heartbeat(tx);
            self.inner.heartbeat.restart(now);
        }
        // Entry to Operational sends TPDO1.
        self.inner.service_tpdos(now, app, tx);
    }

    /// Initialisation (power-on, reset node, reset communication) up to Pre-operational.
    fn boot(
        &mut self,
        now: Instant,
        kind: Boot,
        app: &mut dyn Application,
        tx: &mut dyn FrameSink,
    ) {
        self.set_state(now, NmtState::Initialising, app, tx);
        self.sdo.reset();
        // Every initialisation activates the LSS node-ID (at power-on, the configured one).
        self.inner.node = self.lss.pending_node_id();
        let Some(node) = self.inner.node else {
            info!("unconfigured (node-ID 0xFF): LSS only");
            return;
        };
        let blob = Blob::load(&mut self.inner.storage);
        if kind == Boot::ResetNode {
            self.inner.emcy.reset();
            app.on_reset_application();
        }
        if kind != Boot::ResetCommunication {
            if let Some(data) = blob.app() {
                app.restore_application(data);
            }
        }
        self.inner.load_defaults(now);
        if let Some(params) = blob.comm() {
            for (index, sub, value) in params {
                self.inner.set_param(now, index, sub, value);
            }
        }
        let bootup = Frame::from_parts(node.cob_id(cob::HEARTBEAT), [0; 8], 1);
        self.inner.emit(tx, bootup);
        self.inner.heartbeat.restart(now);
        // The consumers start over (waiting for a first heartbeat): no loss is pending.
        self.inner.settle_heartbeat(app);
        self.set_state(now, NmtState::PreOperational, app, tx);
    }
}

impl<S: Storage> Inner<S> {
    // Out of line: called from several places, inlined copies cost more flash.
    #[inline(never)]
    fn emit(&mut self, tx: &mut dyn FrameSink, frame: Frame) -> bool {
        let sent = tx.send(frame).is_ok();
        if !sent {
            self.tx_refused = self.tx_refused.saturating_add(1);
        }
        sent
    }

    fn send_heartbeat(&mut self, tx: &mut dyn FrameSink) {
        let Some(node) = self.node else {
            return;
        };
        let id = node.cob_id(cob::HEARTBEAT);
        let frame = Frame::from_parts(id, [self.state.heartbeat_byte(), 0, 0, 0, 0, 0, 0, 0], 1);
        self.emit(tx, frame);
    }

    /// Ends a reported heartbeat loss once no consumer is in timeout any more: clears
    /// EMCY 0x8130 and tells the application. The one place where a loss ends, whatever
    /// ended it (the node's heartbeat, a rewrite of 0x1016, a reset of communication).
    fn settle_heartbeat(&mut self, app: &mut dyn Application) {
        if !self.heartbeat_lost || self.heartbeat.any_lost() {
            return;
        }
        self.heartbeat_lost = false;
        debug!("heartbeat consumers healthy again");
        let transmit = self.state.communicating();
        self.emcy.clear(emcy::code::HEARTBEAT, transmit);
        app.on_heartbeat_restored();
    }

    fn on_sync(&mut self, now: Instant, app: &mut dyn Application, tx: &mut dyn FrameSink) {
        if self.state != NmtState::Operational {
            return;
        }
        for i in 0..TPDOS {
            if self.tpdos.get_mut(i).is_some_and(Tpdo::on_sync) {
                self.send_tpdo(i, now, app, tx);
            }
        }
    }

    fn service_tpdos(&mut self, now: Instant, app: &mut dyn Application, tx: &mut dyn FrameSink) {
        if self.state != NmtState::Operational {
            return;
        }
        for i in 0..TPDOS {
            if self.tpdos.get_mut(i).is_some_and(|t| t.event_due(now)) {
                self.send_tpdo(i, now, app, tx);
            }
        }
    }

    fn send_tpdo(
        &mut self,
        i: usize,
        now: Instant,
        app: &mut dyn Application,
        tx: &mut dyn FrameSink,
    ) {
        // i < TPDOS, so the PDO number fits a u8.
        let pdo = i as u8 + 1;
        if !app.tpdo_ready(pdo) {
            if let Some(t) = self.tpdos.get_mut(i) {
                t.withdrawn(now);
            }
            return;
        }
        let built = self.build_tpdo(i, app);
        let sent = match built {
            Ok(frame) => Some(self.emit(tx, frame)),
            Err(abort) => {
                // Repeats at the event timer's rate while the fault lasts: debug only, the
                // count is in `Stats::tpdo_errors`.
                debug!("TPDO{=u8} not built: {=u32:#x}", pdo, abort.code());
                self.tpdo_errors = self.tpdo_errors.saturating_add(1);
                None
            }
        };
        let Some(t) = self.tpdos.get_mut(i) else {
            return;
        };
        match sent {
            Some(false) => t.retry_later(now),
            Some(true) => {
                t.sent(now);
                app.on_tpdo_sent(pdo);
            }
            // Give this event up rather than retrying a mapping that cannot be read.
            None => t.sent(now),
        }
    }

    fn build_tpdo(&self, i: usize, app: &mut dyn Application) -> Result<Frame, SdoAbort> {
        let t = self.tpdos.get(i).ok_or(SdoAbort::NoObject)?;
        let mut data = [0u8; 8];
        let mut len = 0;
        for &entry in t.mapping() {
            // Stored or default mappings never went through the SDO checks: re-check here.
            let (e, size) = tpdo::check_mapping(&self.od, entry)?;
            let dst = data.get_mut(len..len + size).ok_or(SdoAbort::PdoTooLong)?;
            self.read_value(e, dst, app)?;
            len += size;
        }
        // len <= 8, checked by the slice above.
        Ok(Frame::from_parts(t.can_id(), data, len as u8))
    }

    fn service_emcy(&mut self, now: Instant, tx: &mut dyn FrameSink) {
        if !self.state.communicating() {
            return;
        }
        while let Some((id, payload)) = self.emcy.next_frame(now) {
            let sent = self.emit(tx, Frame::from_parts(id, payload, 8));
            self.emcy.sent(now, sent);
            if !sent {
                break;
            }
        }
    }

    /// Reads an entry's value into `buf` (no access check: PDOs and uploads check first).
    fn read_value(
        &self,
        e: &OdEntry,
        buf: &mut [u8],
        app: &mut dyn Application,
    ) -> Result<usize, SdoAbort> {
        let size = e.data_type().size();
        let raw = match e.value() {
            Value::Const(v) => v,
            Value::Comm(_) | Value::CommPlusNodeId(_) => self.param(e.index(), e.sub())?,
            Value::Str(s) => {
                let dst = buf.get_mut(..s.len()).ok_or(SdoAbort::OutOfMemory)?;
                dst.copy_from_slice(s.as_bytes());
                return Ok(s.len());
            }
            Value::App => {
                let n = app.read(e.index(), e.sub(), buf)?;
                // A wrong length is a bug in the application; never pass it on.
                if n > buf.len() || size.is_some_and(|s| s != n) {
                    return Err(SdoAbort::InternalIncompatible);
                }
                return Ok(n);
            }
        };
        // Od::new guarantees that constants and parameters are numeric.
        let n = size.unwrap_or(4);
        let bytes = raw.to_le_bytes();
        let dst = buf.get_mut(..n).ok_or(SdoAbort::OutOfMemory)?;
        dst.copy_from_slice(bytes.get(..n).ok_or(SdoAbort::InternalIncompatible)?);
        Ok(n)
    }

    /// The checked write path shared by SDO and local writes; changes nothing on failure.
    fn write_object(
        &mut self,
        now: Instant,
        index: u16,
        sub: u8,
        data: &[u8],
        app: &mut dyn Application,
    ) -> Result<(), SdoAbort> {
        let e = self.od.find(index, sub)?;
        if !e.access().writable() {
            return Err(SdoAbort::ReadOnly);
        }
        let value = e.check_write(data)?;
        match e.value() {
            Value::App => app.write(index, sub, data),
            Value::Comm(_) | Value::CommPlusNodeId(_) => {
                self.write_param(now, index, sub, value, app)
            }
            Value::Const(_) | Value::Str(_) => Err(SdoAbort::ReadOnly),
        }
    }

    /// Reads an engine-owned object.
    fn param(&self, index: u16, sub: u8) -> Result<u32, SdoAbort> {
        match index {
            0x1001 => Ok(self.emcy.error_register().into()),
            0x1003 | 0x1014 | 0x1015 => self.emcy.read(index, sub),
            0x1005 => Ok(self.sync.cob_id()),
            // Capability bit 0: parameters are saved / restored on command.
            0x1010 | 0x1011 => Ok(1),
            0x1016 => self.heartbeat.consumer(sub),
            0x1017 => Ok(self.heartbeat.producer_ms().into()),
            0x1018 => Ok(self.serial),
            0x1800..=0x19FF => self.tpdo(index - 0x1800)?.read_comm(sub),
            0x1A00..=0x1BFF => self.tpdo(index - 0x1A00)?.read_mapping(sub),
            _ => Err(SdoAbort::NoObject),
        }
    }

    /// Checked write of an engine-owned object (type and range already checked).
    fn write_param(
        &mut self,
        now: Instant,
        index: u16,
        sub: u8,
        value: u32,
        app: &dyn Application,
    ) -> Result<(), SdoAbort> {
        if let Some(slot) = cob_slot(index, sub) {
            self.check_cob_id(slot, value)?;
        }
        match index {
            // 0x1014 is checked above; `Emcy::write` only stores it.
            0x1003 | 0x1014 | 0x1015 => self.emcy.write(index, sub, value),
            0x1005 => {
                self.sync.set(value);
                Ok(())
            }
            0x1010 => self.store(sub, value, app),
            0x1011 => self.restore_defaults(sub, value),
            0x1016 => match self.node {
                Some(own) => self.heartbeat.write_consumer(sub, value, own),
                None => Err(SdoAbort::DeviceState),
            },
            0x1017 => {
                // Typed U16 in the table, so the truncation is lossless.
                self.heartbeat.set_producer(value as u16, now);
                Ok(())
            }
            0x1800..=0x19FF => {
                // Sub 1, the COB-ID, is checked above.
                let operational = self.state == NmtState::Operational;
                self.tpdo_mut(index - 0x1800)?
                    .write_comm(sub, value, now, operational)
            }
            0x1A00..=0x1BFF => {
                let od = self.od;
                self.tpdo_mut(index - 0x1A00)?
                    .write_mapping(sub, value, &od)
            }
            _ => Err(SdoAbort::ReadOnly),
        }
    }

    /// Unchecked write of a parameter: table defaults and stored values.
    fn set_param(&mut self, now: Instant, index: u16, sub: u8, value: u32) {
        match index {
            0x1005 => self.sync.set(value),
            0x1014 | 0x1015 => self.emcy.set(index, value),
            0x1016 => self.heartbeat.set_consumer(sub, value),
            0x1017 => self.heartbeat.set_producer(value as u16, now),
            0x1800..=0x19FF => {
                if let Ok(t) = self.tpdo_mut(index - 0x1800) {
                    t.set_comm(sub, value);
                }
            }
            0x1A00..=0x1BFF => {
                if let Ok(t) = self.tpdo_mut(index - 0x1A00) {
                    t.set_mapping(sub, value);
                }
            }
            _ => {}
        }
    }

    /// Communication parameters back to the table's defaults (reset communication).
    fn load_defaults(&mut self, now: Instant) {
        // Objects missing from the table stay disabled rather than keeping stale values.
        self.heartbeat = Heartbeat::new();
        self.sync = SyncConsumer::new();
        self.tpdos = [const { Tpdo::new() }; TPDOS];
        self.emcy.set(0x1014, COB_INVALID);
        self.emcy.set(0x1015, 0);
        let node = u32::from(self.node.map_or(0, NodeId::get));
        for e in self.od.entries() {
            match e.value() {
                Value::Comm(v) => self.set_param(now, e.index(), e.sub(), v),
                Value::CommPlusNodeId(v) => {
                    self.set_param(now, e.index(), e.sub(), v.wrapping_add(node))
                }
                _ => {}
            }
        }
    }

    /// Checks a write of the COB-ID in `slot` (see [`cob_slot`]): first the object's own
    /// rules (format, restricted identifiers, no change of CAN-ID while valid: 0x06090030),
    /// then that no other object of this node uses it (0x06040043), so that no frame of ours
    /// goes out where the network expects another kind (feed records read as emergencies, a
    /// TPDO taken for SYNC). An entry with bit 31 set claims nothing, except SYNC, which is
    /// always received (bit 31 means nothing to a consumer).
    fn check_cob_id(&self, slot: usize, value: u32) -> Result<(), SdoAbort> {
        let mut owners = [self.sync.cob_id() & !COB_INVALID, self.emcy.cob_id(), 0, 0];
        for (owner, t) in owners.iter_mut().skip(2).zip(&self.tpdos) {
            *owner = t.cob_id();
        }
        let value = if slot == SYNC_SLOT {
            SyncConsumer::check(value)?;
            value & !COB_INVALID
        } else {
            check_cob_id_write(owners.get(slot).copied().unwrap_or(0), value)?;
            value
        };
        let clash = value & COB_INVALID == 0
            && owners.iter().enumerate().any(|(other, &raw)| {
                other != slot && raw & COB_INVALID == 0 && (raw ^ value) & 0x7FF == 0
            });
        if clash {
            return Err(SdoAbort::ParameterIncompatible);
        }
        Ok(())
    }

    fn tpdo(&self, n: u16) -> Result<&Tpdo, SdoAbort> {
        self.tpdos.get(usize::from(n)).ok_or(SdoAbort::NoObject)
    }

    fn tpdo_mut(&mut self, n: u16) -> Result<&mut Tpdo, SdoAbort> {
        self.tpdos.get_mut(usize::from(n)).ok_or(SdoAbort::NoObject)
    }

    /// 0x1010: "save" stores communication (sub 2), application (sub 3) or both (sub 1).
    fn store(&mut self, sub: u8, signature: u32, app: &dyn Application) -> Result<(), SdoAbort> {
        if signature != SAVE_SIGNATURE {
            return Err(SdoAbort::CannotStore);
        }
        let sections = sections(sub)?;
        let mut blob = Blob::load(&mut self.storage);
        if sections & storage::COMM != 0 {
            blob.set_comm(|index, sub| self.param(index, sub).unwrap_or(0));
        }
        if sections & storage::APP != 0 {
            blob.set_app(|buf| app.save_application(buf));
        }
        blob.store(&mut self.storage)
            .map_err(|_| SdoAbort::Hardware)
    }

    /// 0x1011: "load" forgets stored values, so the next reset loads the defaults.
    fn restore_defaults(&mut self, sub: u8, signature: u32) -> Result<(), SdoAbort> {
        if signature != LOAD_SIGNATURE {
            return Err(SdoAbort::CannotStore);
        }
        let sections = sections(sub)?;
        let mut blob = Blob::load(&mut self.storage);
        blob.remove(sections);
        blob.store(&mut self.storage)
            .map_err(|_| SdoAbort::Hardware)
    }
}

/// `check_cob_id` keeps one slot per COB-ID entry: SYNC, EMCY and the two TPDOs.
const SYNC_SLOT: usize = 0;
const _: () = assert!(TPDOS == 2);

/// The slot of a COB-ID entry, `None` for every other object.
fn cob_slot(index: u16, sub: u8) -> Option<usize> {
    match (index, sub) {
        (0x1005, _) => Some(SYNC_SLOT),
        (0x1014, _) => Some(1),
        (0x1800, 1) => Some(2),
        (0x1801, 1) => Some(3),
        _ => None,
    }
}

/// Blob sections selected by sub-index 1 (all), 2 (communication), 3 (application).
fn sections(sub: u8) -> Result<u8, SdoAbort> {
    match sub {
        1 => Ok(storage::COMM | storage::APP),
        2 => Ok(storage::COMM),
        3 => Ok(storage::APP),
        _ => Err(SdoAbort::NoSubIndex),
    }
}

/// The object dictionary as the SDO server sees it.
struct Objects<'a, S> {
    inner: &'a mut Inner<S>,
    app: &'a mut dyn Application,
    now: Instant,
}

impl<S: Storage> ObjectAccess for Objects<'_, S> {
    fn upload(&mut self, index: u16, sub: u8, buf: &mut [u8]) -> Result<usize, SdoAbort> {
        debug!("SDO upload {=u16:#x}:{=u8}", index, sub);
        let e = self.inner.od.find(index, sub)?;
        if !e.access().readable() {
            return Err(SdoAbort::WriteOnly);
        }
        self.inner.read_value(e, buf, self.app)
    }

    fn size_of(&mut self, index: u16, sub: u8) -> Result<usize, SdoAbort> {
        let e = self.inner.od.find(index, sub)?;
        Ok(e.data_type().size().unwrap_or(4))
    }

    fn check_download(&mut self, index: u16, sub: u8, size: Option<u32>) -> Result<(), SdoAbort> {
        let e = self.inner.od.find(index, sub)?;
        if !e.access().writable() {
            return Err(SdoAbort::ReadOnly);
        }
        let Some(size) = size.map(|s| usize::try_from(s).unwrap_or(usize::MAX)) else {
            return Ok(());
        };
        e.data_type().check_len(size)
    }

    fn download(&mut self, index: u16, sub: u8, data: &[u8]) -> Result<(), SdoAbort> {
        self.inner
            .write_object(self.now, index, sub, data, self.app)?;
        // Refused writes are logged with their abort code by the SDO server.
        info!("SDO write {=u16:#x}:{=u8}", index, sub);
        Ok(())
    }
}
