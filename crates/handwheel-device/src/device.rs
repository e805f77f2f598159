//! The handwheel device: the CANopen engine, the handwheel's dictionary and the feed logic
//! that runs between engine calls.

use canopen_slave::{
    Config, Device, ErrorIndication, Frame, FrameSink, Instant, NmtState, NodeId, RxFilter, Storage,
};
use handwheel_core::{BitRate, FeedStatus, Selection, StopReason, Wheel};

use crate::app::{AppContext, FeedApp};
use crate::od::{OD, SESSION_DELAY_MS};
use handwheel_core::bittiming::{bit_rate_from_lss, lss_bit_timing, LSS_BIT_TIMINGS};

/// EMCY code raised while an illegal quadrature transition is latched in the feed status
/// (CiA 301 "sensor" class). It clears with the epoch, i.e. when the operator re-selects.
pub const EMCY_ENCODER: u16 = 0x7300;
/// Error register bit for the encoder error: generic only, CiA 301 has no sensor bit.
const ERROR_REGISTER_GENERIC: u8 = 0x01;

/// EMCY code of a feed stopped because the device's frames could not reach the bus for
/// [`TRANSMIT_STALL_MS`] (CiA 301 "communication, generic"; manufacturer byte 0 =
/// [`TRANSMIT_BLOCKED_INFO`]). An event: it is queued after what was discarded, so it goes out
/// once frames get onto the bus again, followed by the error reset.
pub const EMCY_TRANSMIT_BLOCKED: u16 = 0x8100;
/// Manufacturer byte 0 of [`EMCY_TRANSMIT_BLOCKED`]: the transmit path was blocked.
pub const TRANSMIT_BLOCKED_INFO: u8 = 0x01;
/// Error register bit 4: communication error.
const ERROR_REGISTER_COMMUNICATION: u8 = 0x10;

/// How long the transmit path may hold waiting frames without once running empty before the
/// device counts it as blocked: it then stops the feed, discards what waits and breaks the
/// record sequence, so that no motion reaches the host later than this after it was reported.
/// Counted from the last time the path was empty, not from the last frame that got out: a bus
/// that takes a frame now and then lets a queue grow whose records arrive ever later.
pub const TRANSMIT_STALL_MS: u64 = 100;

/// What the firmware's transmit path reports each round.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct TransmitState {
    /// Frames wait for the bus (in the queue or the controller).
    pub waiting: bool,
    /// The path ran empty since the last report, however briefly (the transmit interrupt
    /// drained it while the rounds were held up, say), whatever waits now.
    pub ran_empty: bool,
}

/// The board's digital outputs as the device decides them.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct DigitalOutputs {
    /// "Jog live" (0x2036): a detent turned now moves the feed position. The device's own
    /// output (board output 1), which no object a master writes drives.
    pub jog_live: bool,
    /// 0x6A00:1 as driven: the CNC's outputs, bit n = the object's output n + 1 (the board
    /// has pins for bits 0..6, as its outputs 2..8).
    pub written: u8,
}

/// Notices a transmit path that has not run empty for [`TRANSMIT_STALL_MS`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
struct StallWatch {
    /// Since when frames wait, the path not empty once.
    since: Option<Instant>,
    /// The path was found blocked and has not run empty since: the feed may not start again
    /// (what it sends would queue behind a path that does not drain).
    blocked: bool,
    /// Frames that left the path as last told ([`Mutant::StallCompletions`]).
    ///
    /// [`Mutant::StallCompletions`]: crate::mutant::Mutant::StallCompletions
    #[cfg(feature = "mutants")]
    completed: u32,
}

impl StallWatch {
    /// Whether the path counts as blocked now (once, until it runs empty).
    fn observe(&mut self, now: Instant, state: TransmitState) -> bool {
        if !state.waiting || state.ran_empty {
            *self = Self {
                #[cfg(feature = "mutants")]
                completed: self.completed,
                ..Self::default()
            };
            if !state.waiting {
                return false;
            }
        }
        let since = *self.since.get_or_insert(now);
        if self.blocked || now.as_micros() < since.as_micros() + TRANSMIT_STALL_MS * 1000 {
            return false;
        }
        self.blocked = true;
        true
    }

    /// When the path counts as blocked if it does not run empty.
    fn deadline(&self) -> Option<Instant> {
        self.since
            .filter(|_| !self.blocked)
            .map(|since| since.add_millis(TRANSMIT_STALL_MS))
    }
}

/// A sink that keeps what waits when asked to discard it ([`Mutant::ResetKeepsPending`]).
///
/// [`Mutant::ResetKeepsPending`]: crate::mutant::Mutant::ResetKeepsPending
#[cfg(feature = "mutants")]
struct KeepPending<'a>(&'a mut dyn FrameSink);

#[cfg(feature = "mutants")]
impl FrameSink for KeepPending<'_> {
    fn send(&mut self, frame: Frame) -> Result<(), canopen_slave::SinkFull> {
        self.0.send(frame)
    }
}

/// The CANopen handwheel. `S` stores 0x1010 parameters (flash on the board, RAM in tests);
/// the wheel (the CAN side's half, linked to the edge interrupt) lives outside and is reached
/// through its RTIC [`Mutex`](handwheel_core::Mutex) on every call ([`Wheel`]: the device
/// takes the edge's motion in before each change of what it counts for, and for TPDO1's
/// record).
#[derive(Clone, Debug, Hash)]
pub struct HandwheelDevice<S> {
    engine: Device<S>,
    app: FeedApp,
    encoder_error_raised: bool,
    stall: StallWatch,
    /// When [`HandwheelDevice::start`] ran: a session opens only [`SESSION_DELAY_MS`] after
    /// it.
    started: Option<Instant>,
    /// Up to when (µs) the device's age (0x2035) has counted its milliseconds.
    aged_to_us: u64,
}

impl<S: Storage> HandwheelDevice<S> {
    /// A device in Initialising; nothing is sent before [`HandwheelDevice::start`].
    pub fn new(node_id: NodeId, serial_number: u32, storage: S) -> Self {
        Self::with_settings(Some(node_id), BitRate::Kbit1000, serial_number, storage)
    }

    /// [`HandwheelDevice::new`] for the firmware: `node_id` `None` starts unconfigured
    /// (LSS only), `bit_rate` is the rate in force, for LSS.
    pub fn with_settings(
        node_id: Option<NodeId>,
        bit_rate: BitRate,
        serial_number: u32,
        storage: S,
    ) -> Self {
        let mut config = Config::with_node(node_id);
        config.serial_number = serial_number;
        config.bit_timing = lss_bit_timing(bit_rate);
        config.bit_timings = LSS_BIT_TIMINGS;
        Self {
            engine: Device::new(config, OD, storage),
            app: FeedApp::new(),
            encoder_error_raised: false,
            stall: StallWatch::default(),
            started: None,
            aged_to_us: 0,
        }
    }

    /// The device with `crc` as 0x1F56:1 (program software identification): the `crc` of
    /// the running image's header (docs/FIRMWARE-UPDATE.md), which the firmware reads from
    /// flash; 0 until set.
    #[must_use]
    pub fn with_software_id(mut self, crc: u32) -> Self {
        self.app.software_id = crc;
        self
    }

    /// 0x1F51:1 = 0 ("stop") was answered: the firmware must reset into the resident loader
    /// once the answer has left ([`Outputs::enter_loader`](crate::Outputs::enter_loader)).
    pub fn loader_requested(&self) -> bool {
        self.app.enter_loader
    }

    /// 0x1F51:1 = 0x80 ("confirm") was answered: a master confirmed the image after its
    /// start ([`Outputs::confirm_trial`](crate::Outputs::confirm_trial)).
    pub fn start_confirmed(&self) -> bool {
        self.app.start_confirmed
    }

    /// Power-on: applies stored parameters, sends the boot-up frame, enters Pre-operational.
    pub fn start(&mut self, now: Instant, wheel: &mut impl Wheel, tx: &mut dyn FrameSink) {
        self.started = Some(now);
        self.aged_to_us = now.as_micros();
        self.age(now);
        let mut ctx = AppContext {
            app: &mut self.app,
            wheel: &mut *wheel,
        };
        // Stored application parameters arrive through `restore_application`; without
        // any, the factory settings must still reach the wheel.
        let params = ctx.app.parameters;
        ctx.wheel.lock(|w| params.apply(w));
        self.engine.start(now, &mut ctx, tx);
        self.service(now, wheel);
    }

    /// One received frame.
    pub fn on_frame(
        &mut self,
        now: Instant,
        frame: &Frame,
        wheel: &mut impl Wheel,
        tx: &mut dyn FrameSink,
    ) {
        self.age(now);
        #[cfg(feature = "mutants")]
        if self.app.mutant == Some(crate::mutant::Mutant::ResetKeepsPending) {
            let mut ctx = AppContext {
                app: &mut self.app,
                wheel: &mut *wheel,
            };
            self.engine
                .on_frame(now, frame, &mut ctx, &mut KeepPending(tx));
            self.service(now, wheel);
            return;
        }
        let mut ctx = AppContext {
            app: &mut self.app,
            wheel: &mut *wheel,
        };
        self.engine.on_frame(now, frame, &mut ctx, tx);
        self.service(now, wheel);
    }

    /// Runs the bug `mutant` from now on (`None`: the real code). For the feed checker's
    /// mutation tests only; the firmware never has this.
    #[cfg(feature = "mutants")]
    #[doc(hidden)]
    pub fn set_mutant(&mut self, mutant: Option<crate::mutant::Mutant>) {
        self.app.mutant = mutant;
    }

    /// Frames that left the transmit path so far (wrapping), before a round: what the old
    /// stall watch counted. Only [`Mutant::StallCompletions`](crate::mutant::Mutant) reads it.
    #[cfg(feature = "mutants")]
    #[doc(hidden)]
    pub fn mutant_transmit_completed(&mut self, completed: u32) {
        if self.app.mutant == Some(crate::mutant::Mutant::StallCompletions)
            && completed != self.stall.completed
        {
            // A frame got out: the 100 ms start again, and the block ends.
            self.stall.completed = completed;
            self.stall.since = None;
            self.stall.blocked = false;
        }
    }

    /// Time-driven work, and a feed record for what changed: call at
    /// [`HandwheelDevice::next_deadline`] at the latest, after the wheel's new motion was
    /// taken in ([`Intake::RoundStart`](handwheel_core::Intake::RoundStart)), and after
    /// [`HandwheelDevice::set_selection`].
    pub fn poll(&mut self, now: Instant, wheel: &mut impl Wheel, tx: &mut dyn FrameSink) {
        self.age(now);
        self.service(now, wheel);
        let mut ctx = AppContext {
            app: &mut self.app,
            wheel: &mut *wheel,
        };
        self.engine.poll(now, &mut ctx, tx);
        self.service(now, wheel);
    }

    /// The device's age at `now` (0x2035), and whether a session may open: not before
    /// [`SESSION_DELAY_MS`] after the start (a new power life), so that no record of the new
    /// life carries a session while a host's probe answered before the power cycle still
    /// dates records.
    fn age(&mut self, now: Instant) {
        if self.started.is_some() {
            // Whole milliseconds since the last count, by the MCU's 32-bit divide (a 64-bit
            // one costs about 1 KiB of flash). The device polls far more often than every
            // 71 minutes; a longer gap would only count short. Wrapping after 49.7 days: a
            // master's check errs towards "a new life" then.
            let since = now.as_micros().saturating_sub(self.aged_to_us);
            let ms = since.min(u64::from(u32::MAX)) as u32 / 1000;
            self.app.uptime_ms = self.app.uptime_ms.wrapping_add(ms);
            self.aged_to_us += u64::from(ms) * 1000;
        }
        self.app.young = self.started.is_none_or(|started| {
            now.as_micros().saturating_sub(started.as_micros()) < SESSION_DELAY_MS * 1000
        });
        #[cfg(feature = "mutants")]
        if self.app.mutant == Some(crate::mutant::Mutant::SessionUnguarded) {
            self.app.young = false;
        }
    }

    /// The debounced selector changed.
    pub fn set_selection(&mut self, selection: Selection, wheel: &mut impl Wheel) {
        let changed = wheel.change(|w| w.feed.set_selection(selection));
        if changed {
            // Pending unit steps were for the old selection: a prepared one goes too.
            self.app.step_in_flight = None;
        }
    }

    /// The transmit path's state, after every round: frames that wait for the bus for
    /// [`TRANSMIT_STALL_MS`] without the path once running empty would carry stale motion. The feed stops
    /// (as on master loss: disabled, status bit 3), what waits is discarded and the record
    /// sequence breaks, so the host never credits motion that left the device that late.
    /// Returns `true` when that happened.
    pub fn watch_transmit(
        &mut self,
        now: Instant,
        state: TransmitState,
        wheel: &mut impl Wheel,
        tx: &mut dyn FrameSink,
    ) -> bool {
        let tripped = self.stall.observe(now, state);
        self.app.transmit_blocked = self.stall.blocked;
        if !tripped {
            return false;
        }
        #[cfg(feature = "defmt")]
        defmt::warn!(
            "CAN: frames waited {=u64} ms for the bus: feed stopped",
            TRANSMIT_STALL_MS
        );
        let operational = self.engine.nmt_state() == NmtState::Operational;
        self.app.step_in_flight = None;
        wheel.change(|w| {
            w.feed.stop(StopReason::TransmitBlocked);
            // What is held and queued is stale now: dropped, and a break, as when
            // leaving Operational and entering it again.
            w.feed.stop_records();
            if operational {
                w.feed.start_records();
            }
            w.feed.break_records();
        });
        tx.discard_pending();
        let info = [TRANSMIT_BLOCKED_INFO, 0, 0, 0, 0];
        let code = EMCY_TRANSMIT_BLOCKED;
        if self
            .engine
            .raise_error(code, ERROR_REGISTER_COMMUNICATION, info)
            .is_ok()
        {
            self.engine.clear_error(code);
        }
        true
    }

    /// When [`HandwheelDevice::poll`] (or [`HandwheelDevice::watch_transmit`]) has work next,
    /// besides a feed record that is due
    /// ([`FeedAccumulator::take_record_due`](handwheel_core::FeedAccumulator::take_record_due):
    /// at once).
    pub fn next_deadline(&self) -> Option<Instant> {
        match (self.engine.next_deadline(), self.stall.deadline()) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }

    /// After LSS "activate bit timing" and its switch delay: the bit rate to switch the CAN
    /// controller to now (once). Call after `poll`.
    pub fn take_bit_rate_switch(&mut self, now: Instant) -> Option<BitRate> {
        self.engine
            .take_bit_timing_switch(now)
            .and_then(bit_rate_from_lss)
    }

    /// The identifiers the device handles now; the firmware reprograms its acceptance
    /// filter when this changes (a write of 0x1005 or 0x1201, a reset of communication).
    /// Inlined, as the engine's: a call with the device's address makes the firmware's init
    /// build the device on its stack and copy it (1 KiB more stack).
    #[inline(always)]
    pub fn rx_filter(&self) -> RxFilter {
        self.engine.rx_filter()
    }

    /// The digital outputs to drive now: "jog live" from the wheel's own rule
    /// ([`FeedAccumulator::takes_motion`](handwheel_core::FeedAccumulator::takes_motion)) and
    /// 0x6A00:1 as the master wrote it or an error reaction left it.
    pub fn digital_outputs(&self, wheel: &mut impl Wheel) -> DigitalOutputs {
        DigitalOutputs {
            jog_live: wheel.lock(|w| w.feed.takes_motion()),
            written: self.app.outputs,
        }
    }

    /// NMT state.
    pub fn nmt_state(&self) -> NmtState {
        self.engine.nmt_state()
    }

    /// What the ERR LED shows on account of the protocol (heartbeat loss).
    pub fn error_indication(&self) -> ErrorIndication {
        self.engine.error_indication()
    }

    /// The engine, for errors the firmware raises itself (CAN controller EMCYs) and
    /// statistics.
    pub fn engine(&mut self) -> &mut Device<S> {
        &mut self.engine
    }

    /// Work between engine calls: paces the record sequence, requests the TPDOs that are
    /// due, prepares the next unit step, and keeps the encoder EMCY in step with the feed
    /// status.
    fn service(&mut self, now: Instant, wheel: &mut impl Wheel) {
        let operational = self.engine.nmt_state() == NmtState::Operational;
        if wheel.lock(|w| {
            w.feed.tick(now.as_micros());
            w.feed.take_record_due()
        }) {
            // Outside Operational the request is dropped by design: entering Operational
            // sends TPDO1 with the present values anyway.
            let _ = self.engine.request_tpdo(1);
        }
        if operational && self.app.parameters.unit_steps() {
            if self.app.step_in_flight.is_none() {
                if let Some(step) = wheel.lock(|w| w.feed.take_unit_step()) {
                    self.app.step_byte = self.app.encoder.peek(step);
                    self.app.step_in_flight = Some(step);
                }
            }
            if self.app.step_in_flight.is_some() {
                let _ = self.engine.request_tpdo(2);
            }
        }
        let (status, illegal) =
            wheel.lock(|w| (w.feed.status(), w.illegal_transitions().to_le_bytes()));
        let encoder_error = status.contains(FeedStatus::ENCODER_ERROR);
        if encoder_error != self.encoder_error_raised {
            if encoder_error {
                let info = [illegal[0], illegal[1], illegal[2], illegal[3], 0];
                self.encoder_error_raised = self
                    .engine
                    .raise_error(EMCY_ENCODER, ERROR_REGISTER_GENERIC, info)
                    .is_ok();
            } else {
                self.engine.clear_error(EMCY_ENCODER);
                self.encoder_error_raised = false;
            }
        }
    }
}
