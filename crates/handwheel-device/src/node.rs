//! The handwheel node as one step function: everything the firmware's `canopen` task decides,
//! host-tested here, so that the task is a loop of I/O.
//!
//! [`Node::poll`] takes the time, the CAN port ([`CanIo`]: received frames, the controller's
//! error state, lost frames, the transmit path's state, the bit-rate switch's steps; frames go
//! out through its [`FrameSink`]), the switch lines and the wheel, does one round and returns
//! [`Outputs`]: the LED and digital output levels, the acceptance filter to program, what to log and how long the
//! caller may sleep. The caller polls again when that time is up or an interrupt raised an
//! event, whichever comes first; polling earlier is always allowed.
//!
//! A round at power-on first waits for the controller to join the bus (the firmware only asked
//! it to in `init`): on a dominant bus (no transceiver, a short) that lasts as long as the
//! fault; the device is held back meanwhile (its boot-up must be the first frame it sends).
//! Past [`SYNC_LIMIT_MS`](crate::rate_switch::SYNC_LIMIT_MS) the node counts as off the bus:
//! the log says so once and the ERR LED is on (CiA 303-3 bus-off; RUN stays dark, the device
//! is not initialised yet). Once the controller is on the bus, the device starts.
//!
//! Each later round, in this order: the wheel's new motion taken in ([`Intake::RoundStart`];
//! the device takes it in again right before each change of what motion counts for and for
//! TPDO1's record, see [`handwheel_core::wheel`]), the switch sample, the received frames, the
//! new selection (after the frames, so an SDO request that came first is answered under the
//! old one), the bus state, lost frames and illegal quadrature transitions (the engine decides
//! the EMCYs), the device's time-driven work, the transmit path's stall watch, an LSS
//! bit-rate switch (one step per round), the acceptance filter (when a write of 0x1005 or a
//! reset of communication moved SYNC), the LEDs, then the digital outputs (every round, so
//! that an error reaction reaches the pins in the round that learnt of the error). The round
//! runs at its `now_ms`, except the stall watch, which dates the transmit path's state when
//! the port read it ([`CanIo::dated_transmit_state`]).

use canopen_slave::{BusEvent, BusState, Frame, FrameSink, RxFilter, Storage, WideClock};
use handwheel_core::{BitRate, Intake, Selection, SelectorInput, Wheel};

use crate::duties::{Duties, RECOVERY_POLL_MS};
use crate::rate_switch::RateSwitch;
use crate::{DigitalOutputs, HandwheelDevice, TransmitState};

/// The CAN port as the step function sees it; frames go out through its [`FrameSink`].
pub trait CanIo: FrameSink {
    /// The next received frame, if any.
    fn receive(&mut self) -> Option<Frame>;
    /// The controller's error state now.
    fn bus_state(&mut self) -> BusState;
    /// Frames lost on receive since power-on (wrapping).
    fn rx_overruns(&mut self) -> u32;
    /// Whether frames wait for the bus, and how many left the transmit path.
    fn transmit_state(&mut self) -> TransmitState;
    /// [`CanIo::transmit_state`] with the millisecond tick (as [`Node::poll`]'s `now_ms`) at
    /// which it was read, for the stall watch. A round is held up by whatever preempts it (an
    /// interrupt storm), while the transmit interrupt keeps draining the path: the state
    /// read after that is newer than the round's `now_ms`, and dated with it a path that ran
    /// empty and was refilled at the end of the round would count as waiting since its
    /// start. The firmware reads its tick together with the state (under the one lock, so
    /// that nothing comes between them); the default, a port without a clock, dates it
    /// `now_ms` (rounds that take no time).
    fn dated_transmit_state(&mut self, now_ms: u32) -> (TransmitState, u32) {
        (self.transmit_state(), now_ms)
    }
    /// One step of the controller's switch to `rate`, never a wait: `true` once it is on the
    /// bus at `rate`.
    fn switch_bit_rate(&mut self, rate: BitRate) -> bool;
    /// Whether a frame of ours was acknowledged on the bus since start-up: another node took
    /// it, so the node talks at the bus's bit rate.
    fn frame_acknowledged(&mut self) -> bool;
}

/// What one round found worth a log line. The caller prints them; the lines' texts are the
/// firmware's.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct LogEvents {
    /// The controller found no 11 recessive bits at this rate within
    /// [`SYNC_LIMIT_MS`](crate::rate_switch::SYNC_LIMIT_MS): at boot (`true`, the node waits
    /// for the bus) or after an LSS switch (`false`, off the bus until it is free).
    pub no_recessive_bits: Option<(BitRate, bool)>,
    /// The controller joined the bus after a wait that was reported at boot.
    pub on_bus: bool,
    /// The bus state changed (with the EMCY the engine decides).
    pub bus: Option<BusEvent>,
    /// Frames lost on receive since the previous round.
    pub rx_lost: u32,
    /// Illegal quadrature transitions since the previous round, and since boot.
    pub illegal_transitions: Option<(u32, u32)>,
    /// The debounced switch selection changed to this.
    pub selection: Option<Selection>,
    /// The wheel stood still off its rest and the decoder learnt the rest anew.
    pub rest_learnt: bool,
    /// An LSS bit-rate switch to this rate began.
    pub bit_rate: Option<BitRate>,
}

/// What the caller applies after a round.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct Outputs {
    /// The RUN and ERR LED levels, when they are due.
    pub leds: Option<(bool, bool)>,
    /// The digital outputs' levels, every round: all off until the device has started, so
    /// that an error reaction or a write reaches the pins in the round that made it.
    pub digital: DigitalOutputs,
    /// The acceptance filter to program, when the device's identifiers changed.
    pub rx_filter: Option<RxFilter>,
    /// How long the caller may sleep, from the `now_ms` of the round, before the next one.
    pub sleep_ms: u32,
    /// What to log.
    pub log: LogEvents,
    /// A master stopped the application (0x1F51:1 = 0) and its answer is in the transmit
    /// path: the caller lets the path drain, then resets into the resident loader
    /// (docs/FIRMWARE-UPDATE.md). Once set, every later round says so again.
    pub enter_loader: bool,
    /// The image is healthy on the bus: the caller ends the loader's trial boot now
    /// (docs/FIRMWARE-UPDATE.md, "Trial boot"). Set in exactly one round of a start: the
    /// first in which the device runs and a frame of it was acknowledged by another node, or
    /// a master confirmed the image (0x1F51:1 = 0x80, as CiA 302-3 masters do after an
    /// update's boot-up).
    pub confirm_trial: bool,
}

/// Where the node is in its life.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
enum Phase {
    /// Not polled yet.
    PowerOn,
    /// Waiting for the controller to join the bus; `reported`: its wait was logged.
    Joining { reported: bool },
    /// The device runs.
    Running,
}

/// The handwheel node: the device and everything the firmware loop decides around it.
#[derive(Clone, Debug, Hash)]
pub struct Node<S> {
    device: HandwheelDevice<S>,
    phase: Phase,
    /// The bit rate the controller was started at, which the node waits to join.
    bit_rate: BitRate,
    clock: WideClock,
    duties: Duties,
    /// The controller's join at power-on, then LSS bit-rate switches.
    rate_switch: RateSwitch,
    /// The acceptance filter the CAN port has now.
    rx_filter: RxFilter,
    /// The bus state, lost frames and illegal transitions as last seen.
    bus: BusState,
    rx_overruns: u32,
    illegal_transitions: u32,
    /// The image's start is still unconfirmed ([`Outputs::confirm_trial`]).
    on_trial: bool,
}

impl<S: Storage> Node<S> {
    /// `device` not started yet, its controller asked to join the bus at `bit_rate` with the
    /// filter [`Node::rx_filter`] returns now.
    pub fn new(device: HandwheelDevice<S>, bit_rate: BitRate) -> Self {
        let rx_filter = device.rx_filter();
        Self {
            device,
            phase: Phase::PowerOn,
            bit_rate,
            clock: WideClock::new(),
            duties: Duties::new(0),
            rate_switch: RateSwitch::new(),
            rx_filter,
            bus: BusState::ErrorActive,
            rx_overruns: 0,
            illegal_transitions: 0,
            on_trial: true,
        }
    }

    /// The acceptance filter the CAN port must have: the firmware starts its controller with
    /// it; later changes come as [`Outputs::rx_filter`].
    pub fn rx_filter(&self) -> RxFilter {
        self.rx_filter
    }

    /// The device.
    pub fn device(&self) -> &HandwheelDevice<S> {
        &self.device
    }

    /// The device, for what is no part of a round (tests, the checker's power cycle).
    pub fn device_mut(&mut self) -> &mut HandwheelDevice<S> {
        &mut self.device
    }

    /// One round at `now_ms` (a wrapping millisecond tick).
    pub fn poll(
        &mut self,
        now_ms: u32,
        io: &mut impl CanIo,
        switches: &mut impl SelectorInput,
        wheel: &mut impl Wheel,
    ) -> Outputs {
        let mut out = Outputs::default();
        if let Phase::PowerOn = self.phase {
            self.duties = Duties::new(now_ms);
            self.rate_switch.start(self.bit_rate, now_ms);
            self.phase = Phase::Joining { reported: false };
        }
        if let Phase::Joining { reported } = self.phase {
            if !self.join(now_ms, reported, io, wheel, &mut out) {
                return out;
            }
        } else {
            self.round(now_ms, io, switches, wheel, &mut out);
        }
        out.digital = self.device.digital_outputs(wheel);
        let now = self.clock.now(now_ms);
        // A feed record made due after the device's last service (a transmit stall's stop)
        // goes out in the next round, at once.
        let record_due = wheel.lock(|w| w.feed.record_due());
        let deadline = match record_due {
            true => Some(now),
            false => self.device.next_deadline(),
        };
        out.sleep_ms = self
            .duties
            .sleep_ms(now_ms, now, deadline, self.bus)
            .min(self.rate_switch.sleep_cap_ms());
        out.enter_loader = self.device.loader_requested();
        out.confirm_trial = self.on_trial
            && matches!(self.phase, Phase::Running)
            && (self.device.start_confirmed() || io.frame_acknowledged());
        self.on_trial &= !out.confirm_trial;
        out
    }

    /// A round while the controller joins the bus; `true` once it has and the device started.
    fn join(
        &mut self,
        now_ms: u32,
        reported: bool,
        io: &mut impl CanIo,
        wheel: &mut impl Wheel,
        out: &mut Outputs,
    ) -> bool {
        let late = self
            .rate_switch
            .poll(now_ms, |rate| io.switch_bit_rate(rate));
        out.log.no_recessive_bits = late.map(|rate| (rate, true));
        let reported = reported || late.is_some();
        if !self.rate_switch.under_way() {
            out.log.on_bus = reported;
            self.phase = Phase::Running;
            let now = self.clock.now(now_ms);
            // A stored 0x1005 reaches the filter in the first round (at once: the sampling
            // duty is due immediately).
            self.device.start(now, wheel, io);
            return true;
        }
        self.phase = Phase::Joining { reported };
        let bus = if self.rate_switch.off_bus() {
            BusState::BusOff
        } else {
            BusState::ErrorActive
        };
        out.leds = self.duties.leds(
            now_ms,
            self.device.nmt_state(),
            self.device.error_indication(),
            bus,
        );
        out.sleep_ms = self.rate_switch.sleep_cap_ms().min(RECOVERY_POLL_MS);
        false
    }

    /// A round of the running device (the order of the module docs).
    fn round(
        &mut self,
        now_ms: u32,
        io: &mut impl CanIo,
        switches: &mut impl SelectorInput,
        wheel: &mut impl Wheel,
        out: &mut Outputs,
    ) {
        let now = self.clock.now(now_ms);
        let device = &mut self.device;
        wheel.take_motion(Intake::RoundStart);
        let sample = self.duties.sample(now_ms, switches, wheel);
        while let Some(frame) = io.receive() {
            device.on_frame(now, &frame, wheel, io);
        }
        if let Some(sample) = sample {
            out.log.rest_learnt = sample.rest_learnt;
            out.log.selection = sample.selection;
            if let Some(selection) = sample.selection {
                device.set_selection(selection, wheel);
            }
        }
        // A bit-rate switch keeps the node off the bus, which counts as bus-off: the ERR LED
        // is on, and its end is a recovery (EMCY 0x8140).
        let mut bus = io.bus_state();
        if self.rate_switch.off_bus() {
            bus = BusState::BusOff;
        }
        out.log.bus = canopen_slave::bus::transition(self.bus, bus);
        self.bus = bus;
        if let Some(event) = out.log.bus {
            device.engine().on_bus_event(event);
        }
        let overruns = io.rx_overruns();
        out.log.rx_lost = overruns.wrapping_sub(self.rx_overruns);
        self.rx_overruns = overruns;
        if out.log.rx_lost != 0 {
            device.engine().on_rx_overrun();
        }
        let illegal = wheel.lock(|w| w.illegal_transitions());
        let new_illegal = illegal.wrapping_sub(self.illegal_transitions);
        self.illegal_transitions = illegal;
        out.log.illegal_transitions = (new_illegal != 0).then_some((new_illegal, illegal));
        device.poll(now, wheel, io);
        // The stall watch dates the state when it was read, which a held-up round reads later
        // than `now_ms` (never earlier: a tick behind it counts as `now_ms`).
        let (transmit, read_ms) = io.dated_transmit_state(now_ms);
        let late_ms = match read_ms.wrapping_sub(now_ms) {
            behind if behind >= 1 << 31 => 0,
            late => late,
        };
        device.watch_transmit(now.add_millis(u64::from(late_ms)), transmit, wheel, io);
        if let Some(rate) = device.take_bit_rate_switch(now) {
            out.log.bit_rate = Some(rate);
            self.rate_switch.start(rate, now_ms);
        }
        // One step per round: meanwhile the round repeats every millisecond, then, once the
        // node counts as off the bus, every `RECOVERY_POLL_MS` (its bus state is bus-off).
        let late = self
            .rate_switch
            .poll(now_ms, |rate| io.switch_bit_rate(rate));
        out.log.no_recessive_bits = late.map(|rate| (rate, false));
        let wanted = device.rx_filter();
        if wanted != self.rx_filter {
            self.rx_filter = wanted;
            out.rx_filter = Some(wanted);
        }
        out.leds = self.duties.leds(
            now_ms,
            device.nmt_state(),
            device.error_indication(),
            self.bus,
        );
    }
}
