//! The handwheel's application objects (0x2000 and up, 0x6004) over the shared wheel, and
//! the application's side of CiA 302-3 program download (0x1F51, 0x1F56, 0x1F57).

use canopen_slave::{Application, NmtState, SdoAbort};
use handwheel_core::{
    CounterStride, CountsPerDetent, DecoderConfig, FeedRecord, Handwheel, Intake, StopReason,
    UnitStep, UnitStepEncoder, Wheel,
};

use crate::od::{
    stored_slot, Program, StoredParameter, APP_OBJECTS, ENCODER, FEED_DIAGNOSTICS, FEED_ENABLE,
    FEED_FORMAT, FEED_SESSION, OD, OUTPUTS, OUTPUT_ERROR_MODE, OUTPUT_ERROR_VALUE, PROGRAM_OBJECTS,
    SEQUENCE_PROBE, SESSION_KEY, STEP_BYTE, STORED, STORED_BYTES, STORED_LEN, UPTIME, WHEEL_READS,
    WHEEL_WRITES, WRITE_OUTPUTS,
};

/// Application parameters that 0x1010 stores: everything the integrator configures about
/// the wheel, never the feed enable (a handwheel must not power up live). Which objects they
/// are, their defaults, limits and refused values are the rows of [`APP_OBJECTS`] marked
/// stored; they are kept as the stored section lays them out ([`STORED`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct WheelParameters {
    bytes: [u8; STORED_BYTES],
}

/// The application section's first byte: a new [`STORED`] layout needs a new version.
/// Version 2 added the outputs' error mode and value (0x6A06:1, 0x6A07:1).
const BLOB_VERSION: u8 = 2;

/// How many of [`STORED`]'s parameters each earlier version holds, as its first ones: a new
/// stored row sorts after the old ones, so an old section is a prefix of the new layout and
/// restores all it holds, the newer parameters at their defaults. A layout that does not
/// keep the old rows first needs its own reading here.
const EARLIER_VERSIONS: [(u8, usize); 1] = [(1, const { stored_slot(FEED_DIAGNOSTICS, 3) } + 1)];

const _: () = assert!(
    stored_slot(OUTPUT_ERROR_MODE, 1) == EARLIER_VERSIONS[0].1,
    "version 1's parameters come first, the outputs' after them"
);

impl WheelParameters {
    /// Factory settings: the stored rows' defaults.
    pub const DEFAULT: Self = {
        let mut p = Self {
            bytes: [0; STORED_BYTES],
        };
        let mut i = 0;
        while i < APP_OBJECTS.len() {
            let o = &APP_OBJECTS[i];
            if o.is_stored() && p.set(o.index, o.sub, o.default).is_err() {
                panic!("a stored row's default is not a value of its parameter");
            }
            i += 1;
        }
        p
    };

    /// Parameter `k` of [`STORED`].
    #[inline(always)]
    const fn value(&self, k: usize) -> u32 {
        let p = &STORED[k];
        let at = p.offset as usize;
        let b = &self.bytes;
        // One load per size (a loop over the bytes stays a loop at opt-level "z").
        match p.size {
            1 => b[at] as u32,
            2 => u16::from_le_bytes([b[at], b[at + 1]]) as u32,
            _ => u32::from_le_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]]),
        }
    }

    /// Parameter `INDEX:SUB`; an object that is no stored row fails the build.
    const fn param<const INDEX: u16, const SUB: u8>(&self) -> u32 {
        self.value(const { stored_slot(INDEX, SUB) })
    }

    /// 0x2001 = 1: the paper's unit-step stream instead of the feed record.
    pub(crate) const fn unit_steps(&self) -> bool {
        self.param::<FEED_FORMAT, 0>() == 1
    }

    /// The decoder settings of 0x2020:3 and :4.
    pub(crate) const fn decoder(&self) -> DecoderConfig {
        let counts = self.param::<ENCODER, 3>() as u8;
        DecoderConfig {
            // The row refuses every other value on the way in.
            counts_per_detent: match CountsPerDetent::from_u8(counts) {
                Some(cpd) => cpd,
                None => CountsPerDetent::Four,
            },
            invert: self.param::<ENCODER, 4>() == 1,
        }
    }

    /// 0x6A06:1 and 0x6A07:1: which outputs an error sets, and to what.
    pub(crate) const fn output_error(&self) -> (u8, u8) {
        (
            self.param::<OUTPUT_ERROR_MODE, 1>() as u8,
            self.param::<OUTPUT_ERROR_VALUE, 1>() as u8,
        )
    }

    /// Parameter `index:sub` and its size in bytes; `None` for other objects.
    fn get(&self, index: u16, sub: u8) -> Option<(u32, u8)> {
        let k = STORED
            .iter()
            .position(|p| (p.index, p.sub) == (index, sub))?;
        Some((self.value(k), STORED[k].size))
    }

    /// Sets parameter `index:sub` to `value`, which the table's limits have checked;
    /// 0x06090030 for a value its row refuses, 0x06010002 for an object that is not a
    /// parameter. Changes nothing on failure.
    #[inline(never)]
    const fn set(&mut self, index: u16, sub: u8, value: u32) -> Result<(), SdoAbort> {
        let mut k = 0;
        while k < STORED_LEN {
            let p = &STORED[k];
            if p.index == index && p.sub == sub {
                if value < 16 && p.refused >> value & 1 == 1 {
                    return Err(SdoAbort::InvalidValue);
                }
                let mut i = 0;
                while i < p.size as usize {
                    self.bytes[p.offset as usize + i] = (value >> (8 * i)) as u8;
                    i += 1;
                }
                return Ok(());
            }
            k += 1;
        }
        Err(SdoAbort::ReadOnly)
    }

    /// The application section: the version, then each stored parameter in [`STORED`]'s
    /// order, little-endian in its type's size. Returns its length, 0 if `buf` is too short.
    ///
    /// The oldest layout that holds every parameter not at its default is written
    /// ([`EARLIER_VERSIONS`]): with the outputs' error reaction at its defaults, the section
    /// is the previous firmware's, byte for byte, so a record keeps its size (six to a
    /// parameter page) and an update stores nothing new.
    fn save(&self, buf: &mut [u8]) -> usize {
        let (version, len) = EARLIER_VERSIONS
            .iter()
            .map(|&(version, held)| (version, STORED[held].offset as usize))
            .find(|&(_, len)| self.bytes[len..] == Self::DEFAULT.bytes[len..])
            .unwrap_or((BLOB_VERSION, STORED_BYTES));
        let section = buf.get_mut(..1 + len);
        let Some((first, bytes)) = section.and_then(|s| s.split_first_mut()) else {
            return 0;
        };
        *first = version;
        bytes.copy_from_slice(&self.bytes[..len]);
        1 + len
    }

    /// The parameters of a stored section, each checked as its SDO write is, or the first
    /// object whose value that write refuses (0x1010:3, the application's section, for a
    /// section of another version or length).
    /// A section of an earlier version restores the parameters it holds, the rest keep their
    /// defaults ([`EARLIER_VERSIONS`]).
    fn load(blob: &[u8]) -> Result<Self, (u16, u8)> {
        let whole = (0x1010, 3);
        let Some((&version, mut rest)) = blob.split_first() else {
            return Err(whole);
        };
        let held = match version {
            BLOB_VERSION => STORED_LEN,
            _ => {
                let earlier = EARLIER_VERSIONS.iter().find(|&&(v, _)| v == version);
                earlier.ok_or(whole)?.1
            }
        };
        let mut p = Self::DEFAULT;
        for &StoredParameter {
            index, sub, size, ..
        } in &STORED[..held]
        {
            let (bytes, tail) = rest.split_at_checked(usize::from(size)).ok_or(whole)?;
            let value = OD
                .find(index, sub)
                .and_then(|e| e.check_write(bytes))
                .and_then(|v| p.set(index, sub, v));
            value.map_err(|_| (index, sub))?;
            rest = tail;
        }
        if rest.is_empty() {
            Ok(p)
        } else {
            Err(whole)
        }
    }

    /// Pushes the parameters into the wheel.
    pub(crate) fn apply(self, wheel: &mut Handwheel) {
        wheel.configure_decoder(self.decoder());
        // The bound was validated on its way in; a rejected bound keeps the previous one.
        let _ = wheel
            .feed
            .set_backlog_bound(self.param::<FEED_DIAGNOSTICS, 3>() as u16);
        wheel.feed.set_unit_step_mode(self.unit_steps());
    }
}

/// What the application keeps between engine calls.
#[derive(Clone, Debug, Hash)]
pub struct FeedApp {
    pub(crate) parameters: WheelParameters,
    pub(crate) nmt: NmtState,
    pub(crate) encoder: UnitStepEncoder,
    /// The unit step waiting for TPDO2; its byte is in 0x2032 until it is sent.
    pub(crate) step_in_flight: Option<UnitStep>,
    /// 0x2032: the last unit-step byte handed to TPDO2.
    pub(crate) step_byte: u8,
    /// A consumed heartbeat is in timeout: feed may not be enabled until the engine reports
    /// every monitored node back.
    pub(crate) master_lost: bool,
    /// The transmit path was found blocked and has not run empty since: feed may not be
    /// enabled (its records would reach the host late).
    pub(crate) transmit_blocked: bool,
    /// The feed record TPDO1 is being built from: one snapshot, taken when the engine asks
    /// whether TPDO1 is ready, so that every mapped object reads the same record however the
    /// edge task moves the wheel meanwhile.
    pub(crate) record: Option<FeedRecord>,
    /// 0x1F56:1: the CRC-32 of the image that runs, its header's `crc`.
    pub(crate) software_id: u32,
    /// 0x1F51:1 = 0 ("stop") was answered: the firmware is to reset into the loader.
    pub(crate) enter_loader: bool,
    /// 0x1F51:1 = 0x80 ("confirm", as Zephyr's CiA 302-3 master writes it after an update)
    /// was answered: a master says the image runs well; the firmware ends its trial boot.
    pub(crate) start_confirmed: bool,
    /// The device started less than [`SESSION_DELAY_MS`](crate::od::SESSION_DELAY_MS) ago:
    /// no session opens yet.
    pub(crate) young: bool,
    /// 0x2035: milliseconds since the device started (wrapping).
    pub(crate) uptime_ms: u32,
    /// 0x6A00:1: the digital outputs as driven (bit n = output n + 1 of CiA 401's numbering).
    pub(crate) outputs: u8,
    /// The bug the feed checker's mutation tests run, if any.
    #[cfg(feature = "mutants")]
    pub(crate) mutant: Option<crate::mutant::Mutant>,
}

impl FeedApp {
    pub(crate) const fn new() -> Self {
        Self {
            parameters: WheelParameters::DEFAULT,
            nmt: NmtState::Initialising,
            encoder: UnitStepEncoder::new(CounterStride::One),
            step_in_flight: None,
            step_byte: 0,
            master_lost: false,
            transmit_blocked: false,
            record: None,
            software_id: 0,
            enter_loader: false,
            start_confirmed: false,
            young: true,
            uptime_ms: 0,
            outputs: 0,
            #[cfg(feature = "mutants")]
            mutant: None,
        }
    }
}

/// The application as the engine sees it during one call: the kept state plus access to
/// the shared wheel.
pub(crate) struct AppContext<'a, W: Wheel> {
    pub app: &'a mut FeedApp,
    pub wheel: &'a mut W,
}

fn put(buf: &mut [u8], bytes: &[u8]) -> Result<usize, SdoAbort> {
    let dst = buf.get_mut(..bytes.len()).ok_or(SdoAbort::OutOfMemory)?;
    dst.copy_from_slice(bytes);
    Ok(bytes.len())
}

impl<W: Wheel> Application for AppContext<'_, W> {
    fn read(&mut self, index: u16, sub: u8, buf: &mut [u8]) -> Result<usize, SdoAbort> {
        self.read_object(index, sub, buf, false)
    }

    fn write(&mut self, index: u16, sub: u8, data: &[u8]) -> Result<(), SdoAbort> {
        // The engine checked length and the table's range; every application object is
        // unsigned.
        let mut bytes = [0; 4];
        for (dst, &src) in bytes.iter_mut().zip(data) {
            *dst = src;
        }
        let value = u32::from_le_bytes(bytes);
        if PROGRAM_OBJECTS
            .iter()
            .any(|&(i, s, p)| (i, s, p) == (index, sub, Program::Control))
        {
            return self.program_control(value);
        }
        if (index, sub) == OUTPUTS {
            self.app.outputs = value as u8;
            return Ok(());
        }
        if let Some(route) = WHEEL_WRITES
            .iter()
            .find(|r| (r.index, r.sub) == (index, sub))
        {
            if route.enables_feed && value == 1 && !self.feed_may_run() {
                return Err(SdoAbort::DeviceState);
            }
            if route.opens_session && value != 0 && self.app.young {
                return Err(SdoAbort::DeviceState);
            }
            let write = route.write;
            #[cfg(feature = "mutants")]
            let value = if index == SEQUENCE_PROBE
                && self.mutant(crate::mutant::Mutant::SessionUnguarded)
            {
                value & 0xFFFF
            } else {
                value
            };
            #[cfg(feature = "mutants")]
            if route.enables_feed && self.mutant(crate::mutant::Mutant::EnableWithoutIntake) {
                return self.wheel.lock(|w| write(w, value));
            }
            return self.wheel.change(|w| write(w, value));
        }
        let mut parameters = self.app.parameters;
        parameters.set(index, sub, value)?;
        self.set_parameters(parameters);
        Ok(())
    }

    fn on_written(&mut self, index: u16, _sub: u8) {
        // The master's session stands for the configuration it made: any write that may
        // change what it relies on ends it (the feed stops, and records carry no session
        // until the master opens one again). Enabling, the session itself, clearing the
        // error history, the store commands and the sequence probe change nothing it relies
        // on.
        #[cfg(feature = "mutants")]
        if (index == 0x1016 && self.mutant(crate::mutant::Mutant::ConsumerWriteKeepsSession))
            || (matches!(index, 0x1800 | 0x1A00)
                && self.mutant(crate::mutant::Mutant::TpdoWriteKeepsSession))
        {
            return;
        }
        // The outputs and their error reaction are the CNC's, apart from the feed: a master
        // drives them all the time, and none of them shapes motion.
        if !matches!(
            index,
            FEED_ENABLE
                | FEED_SESSION
                | SEQUENCE_PROBE
                | SESSION_KEY
                | 0x1003
                | 0x1010
                | 0x1011
                | WRITE_OUTPUTS
                | OUTPUT_ERROR_MODE
                | OUTPUT_ERROR_VALUE
        ) {
            self.end_session();
        }
    }

    fn on_nmt_state(&mut self, state: NmtState) {
        if state == NmtState::Initialising {
            // Power-on, reset node, reset communication: every configuration is gone.
            self.end_session();
        }
        self.app.nmt = state;
        if state == NmtState::Operational {
            self.wheel.lock(|w| w.feed.start_records());
        } else {
            if state == NmtState::Stopped {
                self.output_error_reaction();
            }
            self.stop(StopReason::NotOperational);
            #[cfg(feature = "mutants")]
            if self.mutant(crate::mutant::Mutant::NmtStopKeepsHeld) {
                self.wheel
                    .lock(|w| w.feed.mutant_stop_records_keeping_held());
                return;
            }
            // PDOs stop here: what was not reported by now (the stopped epoch's final state
            // among it) would reach the host only at the next start, as stale motion. It is
            // dropped, and the sequence gap makes the host start afresh.
            self.wheel.lock(|w| w.feed.stop_records());
        }
    }

    fn on_heartbeat_lost(&mut self, _node_id: u8) {
        self.output_error_reaction();
        self.app.master_lost = true;
        self.stop(StopReason::MasterLost);
    }

    fn on_rpdo_timeout(&mut self, _pdo: u8) {
        // The master's outputs stopped coming: CiA 401's error reaction, as on master loss.
        self.output_error_reaction();
    }

    fn on_heartbeat_restored(&mut self) {
        // Feed stays off (status bit 3 stays set) until the master enables it again.
        self.app.master_lost = false;
    }

    fn on_reset_application(&mut self) {
        let (nmt, master_lost) = (self.app.nmt, self.app.master_lost);
        let transmit_blocked = self.app.transmit_blocked;
        let software_id = self.app.software_id;
        let (young, uptime_ms) = (self.app.young, self.app.uptime_ms);
        #[cfg(feature = "mutants")]
        let mutant = self.app.mutant;
        *self.app = FeedApp::new();
        // A reset is no new power life: the age stays the device's.
        self.app.young = young;
        self.app.uptime_ms = uptime_ms;
        // Engine and port state, not application state: the engine ends the loss itself, the
        // stall watch the block. The image's CRC is the image's.
        self.app.nmt = nmt;
        self.app.master_lost = master_lost;
        self.app.transmit_blocked = transmit_blocked;
        self.app.software_id = software_id;
        #[cfg(feature = "mutants")]
        {
            self.app.mutant = mutant;
        }
        self.wheel.change(|w| {
            w.reset_decoder(const { WheelParameters::DEFAULT.decoder() });
            w.feed.reset();
        });
    }

    fn tpdo_ready(&mut self, pdo: u8) -> bool {
        #[cfg(feature = "mutants")]
        if pdo == 1 && self.mutant(crate::mutant::Mutant::TpdoReadAtSend) {
            self.app.record = None;
            return true;
        }
        if pdo == 1 {
            self.wheel.take_motion(Intake::RecordSnapshot);
            self.app.record = Some(self.wheel.lock(|w| w.feed.record()));
        }
        // TPDO2 carries unit steps, i.e. motion: it may only go out with a step in flight.
        // A step withdrawn by a stop or an axis change, an event timer or a SYNC an
        // integrator configured, must never repeat the last byte.
        pdo != 2 || self.app.step_in_flight.is_some()
    }

    fn read_for_tpdo(
        &mut self,
        pdo: u8,
        index: u16,
        sub: u8,
        buf: &mut [u8],
    ) -> Result<usize, SdoAbort> {
        #[cfg(feature = "mutants")]
        if pdo == 1 && self.mutant(crate::mutant::Mutant::TpdoReadAtSend) {
            self.wheel.take_motion(Intake::RecordSnapshot);
        }
        self.read_object(index, sub, buf, pdo == 1)
    }

    fn on_tpdo_sent(&mut self, pdo: u8) {
        if pdo == 1 {
            let record = self.app.record.take();
            // The number the record took may be beyond the pace, which ends the session.
            self.wheel.change(|w| {
                let sent = record.map_or_else(|| w.feed.record_to_send(), |r| r.state);
                w.feed.record_sent(sent);
            });
        } else if pdo == 2 && self.app.step_in_flight.take().is_some() {
            // `tpdo_ready` let TPDO2 go only with a step in flight: that step is on the bus.
            self.app.encoder.advance();
        }
    }

    fn save_application(&self, buf: &mut [u8]) -> usize {
        self.app.parameters.save(buf)
    }

    fn restore_application(&mut self, data: &[u8]) -> Result<(), (u16, u8)> {
        let parameters = WheelParameters::load(data)?;
        self.set_parameters(parameters);
        Ok(())
    }

    fn may_store(&mut self) -> bool {
        // Writing flash stalls the CPU, edge interrupt included (a page erase takes 20-40 ms
        // on the F103): edges in that window would be lost. Store only with the feed off.
        !self.wheel.lock(|w| w.feed.enabled())
    }
}

impl<W: Wheel> AppContext<'_, W> {
    #[cfg(feature = "mutants")]
    fn mutant(&self, m: crate::mutant::Mutant) -> bool {
        self.app.mutant == Some(m)
    }

    /// Reads an application object. `record`: for the feed record (TPDO1), whose state
    /// objects carry what the outbox sends next (a closed epoch's final state while one is
    /// held) rather than the present state, whatever the master mapped.
    fn read_object(
        &mut self,
        index: u16,
        sub: u8,
        buf: &mut [u8],
        record: bool,
    ) -> Result<usize, SdoAbort> {
        // Every application object is an integer of 1, 2 or 4 bytes: pick the value and its
        // size as its row says, then copy once.
        let app = &*self.app;
        // TPDO1's objects are slices of one encoded snapshot (`handwheel-core` lays it out).
        if let Some((bytes, range)) = app
            .record
            .filter(|_| record)
            .and_then(|r| r.field(index, sub))
        {
            return put(buf, bytes.get(range).unwrap_or_default());
        }
        let (value, size) = match app.parameters.get(index, sub) {
            Some(parameter) => parameter,
            None if (index, sub) == STEP_BYTE => (app.step_byte.into(), 1),
            None if (index, sub) == UPTIME => (app.uptime_ms, 4),
            None if (index, sub) == OUTPUTS => (app.outputs.into(), 1),
            None if index & 0xFFF0 == 0x1F50 => {
                let &(.., program) = PROGRAM_OBJECTS
                    .iter()
                    .find(|&&(i, s, _)| (i, s) == (index, sub))
                    .ok_or(SdoAbort::NoObject)?;
                match program {
                    // The application runs: "started".
                    Program::Control => (1, 1),
                    Program::SoftwareId => (app.software_id, 4),
                    // No download in progress, no error: downloads are the loader's.
                    Program::FlashStatus => (0, 4),
                }
            }
            None => {
                let route = WHEEL_READS
                    .iter()
                    .find(|r| (r.index, r.sub) == (index, sub))
                    .ok_or(SdoAbort::NoObject)?;
                let value = self.wheel.lock(|w| {
                    let state = match app.record.filter(|_| record) {
                        Some(r) => r.state,
                        None if record => w.feed.record_to_send(),
                        None => w.feed.state(),
                    };
                    (route.read)(&state, w)
                });
                (value, route.size)
            }
        };
        put(
            buf,
            value
                .to_le_bytes()
                .get(..usize::from(size))
                .unwrap_or_default(),
        )
    }

    /// Whether the feed may be enabled now. Feed only runs while PDOs flow: enabling in
    /// Pre-operational would let the position move unseen and jump at the next start.
    /// Nor while a master we monitor is silent: a wheel enabled by a write that arrives while
    /// the master is lost would move an axis nobody supervises. Nor while the transmit path
    /// has not drained since it was found blocked: the records would queue behind it and
    /// move the axis late.
    fn feed_may_run(&self) -> bool {
        self.app.nmt == NmtState::Operational && !self.app.master_lost && !self.app.transmit_blocked
    }

    /// 0x1F51:1 program control written with `value` (docs/FIRMWARE-UPDATE.md). Every write
    /// is refused outside Pre-operational (0x08000022), as CiA 302-3 has it; values that mean
    /// nothing to the application are refused in any state (0x06090030). "Stop" (0) is the
    /// way into the loader: only with the feed disabled, like a store (the reset ends the
    /// wheel's service); the SDO answer goes out first, then the firmware resets
    /// ([`HandwheelDevice::loader_requested`](crate::HandwheelDevice::loader_requested)).
    /// "Confirm" (0x80, Zephyr's manufacturer value, which its master writes after an update's
    /// boot-up) confirms the trial boot as the image's own confirmation does
    /// ([`HandwheelDevice::start_confirmed`](crate::HandwheelDevice::start_confirmed)).
    fn program_control(&mut self, value: u32) -> Result<(), SdoAbort> {
        const STOP: u32 = 0;
        const START: u32 = 1;
        const CLEAR: u32 = 3;
        const CONFIRM: u32 = 0x80;
        if !matches!(value, STOP | START | CLEAR | CONFIRM) {
            return Err(SdoAbort::InvalidValue);
        }
        if self.app.nmt != NmtState::PreOperational {
            return Err(SdoAbort::DeviceState);
        }
        match value {
            STOP if self.wheel.lock(|w| w.feed.enabled()) => Err(SdoAbort::DeviceState),
            STOP => {
                self.app.enter_loader = true;
                Ok(())
            }
            // Already started: the application is the program that runs.
            START => Ok(()),
            CONFIRM => {
                self.app.start_confirmed = true;
                Ok(())
            }
            // Clearing the slot is the loader's: stop first.
            _ => Err(SdoAbort::DeviceState),
        }
    }

    fn set_parameters(&mut self, parameters: WheelParameters) {
        self.app.parameters = parameters;
        self.app.step_in_flight = None;
        self.wheel.change(|w| {
            parameters.apply(w);
            w.feed.request_record();
        });
    }

    /// CiA 401's error reaction: every output whose 0x6A06:1 bit is set takes its 0x6A07:1
    /// bit; the others keep theirs. The outputs stay so until a master writes 0x6A00:1
    /// again: a recovery (the master's heartbeat back, Operational again) changes nothing.
    /// Called on the master's heartbeat lost, on NMT Stopped and when an RPDO misses its
    /// deadline (0x1400:05, `Application::on_rpdo_timeout`).
    pub(crate) fn output_error_reaction(&mut self) {
        let (mode, value) = self.app.parameters.output_error();
        self.app.outputs = self.app.outputs & !mode | value & mode;
    }

    fn end_session(&mut self) {
        self.wheel.change(|w| w.feed.set_session(0));
    }

    fn stop(&mut self, reason: StopReason) {
        // A step that has not reached the bus is withdrawn with the rest of the backlog.
        self.app.step_in_flight = None;
        self.wheel.change(|w| w.feed.stop(reason));
    }
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use std::vec::Vec;

    fn save(p: WheelParameters) -> Vec<u8> {
        let mut buf = [0; 32];
        let n = p.save(&mut buf);
        buf[..n].to_vec()
    }

    #[test]
    fn parameter_blob_round_trips() {
        let mut p = WheelParameters::DEFAULT;
        for (index, sub, value) in [
            (0x2001, 0, 1),
            (0x2020, 3, 2),
            (0x2020, 4, 1),
            (0x2040, 3, 300),
        ] {
            p.set(index, sub, value).unwrap();
        }
        assert!(p.unit_steps());
        let decoder = DecoderConfig {
            counts_per_detent: CountsPerDetent::Two,
            invert: true,
        };
        assert_eq!(p.decoder(), decoder);
        // The layout of the records already in the field: version 1, 0x2001, 0x2020:3,
        // 0x2020:4, 0x2040:3 (little-endian U16), while the outputs' parameters are at their
        // defaults.
        assert_eq!(save(p), [1, 1, 2, 1, 0x2C, 0x01]);
        assert_eq!(WheelParameters::load(&save(p)), Ok(p));
        // Version 2 adds 0x6A06:1 and 0x6A07:1.
        p.set(0x6A07, 1, 0x80).unwrap();
        assert_eq!(save(p), [2, 1, 2, 1, 0x2C, 0x01, 0xFF, 0x80]);
        assert_eq!(WheelParameters::load(&save(p)), Ok(p));
        assert_eq!(p.save(&mut [0; 7]), 0, "a short buffer takes nothing");
    }

    #[test]
    fn a_section_the_previous_firmware_stored_restores_all_it_holds() {
        // Version 1, as the firmware before the outputs stored it: the unit-step format,
        // 2 counts per detent, inverted, a backlog bound of 300.
        let old = [1, 1, 2, 1, 0x2C, 0x01];
        let p = WheelParameters::load(&old).unwrap();
        assert!(p.unit_steps());
        assert_eq!(p.decoder().counts_per_detent, CountsPerDetent::Two);
        assert!(p.decoder().invert);
        assert_eq!(p.get(0x2040, 3), Some((300, 2)));
        assert_eq!(p.output_error(), (0xFF, 0x00), "the outputs' defaults");
        // Checked as before, and only its own length.
        assert_eq!(
            WheelParameters::load(&[1, 0, 3, 0, 40, 0]),
            Err((0x2020, 3))
        );
        assert_eq!(WheelParameters::load(&old[..5]), Err((0x1010, 3)));
        let v1_with_v2_length = [1, 1, 2, 1, 0x2C, 0x01, 0xFF, 0];
        assert_eq!(WheelParameters::load(&v1_with_v2_length), Err((0x1010, 3)));
        assert_eq!(
            WheelParameters::load(&[3, 0, 4, 0, 40, 0, 0xFF, 0]),
            Err((0x1010, 3))
        );
        // Saved again as it was; with an error mode of its own, as version 2.
        assert_eq!(save(p), old);
        let mut q = p;
        q.set(0x6A06, 1, 0x0F).unwrap();
        assert_eq!(save(q), [2, 1, 2, 1, 0x2C, 0x01, 0x0F, 0]);
        assert_eq!(WheelParameters::load(&save(q)), Ok(q));
    }

    #[test]
    fn the_defaults_are_the_stored_rows_defaults() {
        let p = WheelParameters::DEFAULT;
        assert!(!p.unit_steps());
        let decoder = DecoderConfig {
            counts_per_detent: CountsPerDetent::Four,
            invert: false,
        };
        assert_eq!(p.decoder(), decoder);
        assert_eq!(
            p.get(0x2040, 3),
            Some((u32::from(handwheel_core::DEFAULT_STEP_BACKLOG), 2))
        );
        for o in APP_OBJECTS.iter().filter(|o| o.is_stored()) {
            let value = p.get(o.index, o.sub).map(|(value, _)| value);
            assert_eq!(value, Some(o.default), "{:#06x}:{}", o.index, o.sub);
        }
    }

    #[test]
    fn a_refused_value_or_another_object_changes_nothing() {
        let mut p = WheelParameters::DEFAULT;
        assert_eq!(p.set(0x2020, 3, 3), Err(SdoAbort::InvalidValue));
        assert_eq!(p.set(0x2000, 0, 1), Err(SdoAbort::ReadOnly));
        assert_eq!(p, WheelParameters::DEFAULT);
        for counts in [1, 2, 4] {
            assert_eq!(p.set(0x2020, 3, counts), Ok(()));
            assert_eq!(p.decoder().counts_per_detent.get(), counts as u8);
        }
    }

    #[test]
    fn bad_blobs_are_refused_naming_the_object() {
        assert_eq!(save(WheelParameters::DEFAULT), [1, 0, 4, 0, 40, 0]);
        let mut p = WheelParameters::DEFAULT;
        p.set(0x6A06, 1, 0).unwrap();
        let good = save(p);
        assert_eq!(good, [2, 0, 4, 0, 40, 0, 0, 0]);
        let bad = [
            (0, 3, (0x1010, 3)),
            (1, 2, (0x2001, 0)),
            (2, 3, (0x2020, 3)),
            (2, 5, (0x2020, 3)),
            (3, 7, (0x2020, 4)),
            (4, 0, (0x2040, 3)),
        ];
        for (i, value, object) in bad {
            let mut blob = good.clone();
            blob[i] = value;
            assert_eq!(
                WheelParameters::load(&blob),
                Err(object),
                "byte {i} = {value}"
            );
        }
        let mut above = good.clone();
        above[4..6].copy_from_slice(&1001u16.to_le_bytes());
        assert_eq!(WheelParameters::load(&above), Err((0x2040, 3)));
        assert_eq!(WheelParameters::load(&good[..7]), Err((0x1010, 3)));
        assert_eq!(
            WheelParameters::load(&[good.as_slice(), &[0]].concat()),
            Err((0x1010, 3))
        );
        assert_eq!(WheelParameters::load(&[]), Err((0x1010, 3)));
    }
}
