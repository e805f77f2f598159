//! The three ways of turning a trace into frames, and what a host makes of them.
//!
//! - [`Scheme::Paper`]: the originating paper. Rising edge of B counts (A high = forward),
//!   an unbounded step counter, one 1-byte frame per unit step sent as fast as the bus takes
//!   them (inhibit time 0, one frame in the controller at a time).
//! - [`Scheme::Compat`]: this project's paper-compatible mode: the Gray-code decoder, the
//!   bounded unit-step backlog (40) and the same 1-byte format, paced by the 2 ms inhibit.
//! - [`Scheme::Record`]: this project's default: the 8-byte feed record with the absolute
//!   position, event-driven with a 2 ms inhibit time and a 100 ms event timer.
//!
//! Decoding, accumulation and encoding use `handwheel-core` itself; only the paper's
//! rising-edge decoder and unbounded counter, which this project does not ship, are modelled
//! here.

use handwheel_core::{
    AbLevels, Axis, CounterStride, DecoderConfig, EdgeState, FeedRecord, Intake, LinkedWheel,
    Mutex, Selection, UnitStep, UnitStepEncoder, Wheel,
};

use crate::bus::Bus;
use crate::trace::{Rng, Trace};

/// TPDO inhibit time of this project's default configuration.
pub const INHIBIT_US: f64 = 2_000.0;
/// TPDO1 event timer of this project's default configuration.
pub const EVENT_TIMER_US: f64 = 100_000.0;
/// How long after the wheel stops the simulation keeps the device running.
pub const TAIL_US: f64 = 1_000_000.0;

/// A way of sending feed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Scheme {
    /// The paper's design.
    Paper,
    /// This project's paper-compatible unit-step mode.
    Compat,
    /// This project's feed record.
    Record,
}

impl Scheme {
    /// All schemes, in table order.
    pub const ALL: [Scheme; 3] = [Scheme::Paper, Scheme::Compat, Scheme::Record];

    /// Name for tables.
    pub fn name(self) -> &'static str {
        match self {
            Self::Paper => "paper",
            Self::Compat => "compat",
            Self::Record => "record",
        }
    }
}

/// One frame as sent: when the host has it and its payload.
#[derive(Clone, Debug)]
pub struct Sent {
    /// End of transmission, µs.
    pub at_us: f64,
    /// The payload bytes.
    pub data: Vec<u8>,
}

/// Runs `scheme` over `trace` on a bus of `bitrate`; returns the bus (with its log) and the
/// frames in order.
pub fn run(scheme: Scheme, trace: &Trace, bitrate: u32) -> (Bus, Vec<Sent>) {
    let mut bus = Bus::new(bitrate);
    let frames = match scheme {
        Scheme::Paper => paper(trace, &mut bus),
        Scheme::Compat => compat(trace, &mut bus),
        Scheme::Record => record(trace, &mut bus),
    };
    (bus, frames)
}

fn selected(trace: &Trace) -> Selection {
    Selection {
        axis: Some(Axis::X),
        multiplier: trace.multiplier,
    }
}

fn send(bus: &mut Bus, frames: &mut Vec<Sent>, at_us: f64, data: Vec<u8>) -> f64 {
    let t = bus.send(at_us, data.len() as u32);
    frames.push(Sent {
        at_us: t.end_us,
        data,
    });
    t.end_us
}

/// The paper's device: rising edge of B, an unbounded step counter, one frame in the
/// controller at a time.
struct PaperDevice {
    encoder: UnitStepEncoder,
    backlog: i64,
    frames: Vec<Sent>,
}

impl PaperDevice {
    fn send_step(&mut self, at: f64, bus: &mut Bus) {
        let byte = self.encoder.encode(UnitStep {
            axis: Axis::X,
            forward: self.backlog > 0,
        });
        send(bus, &mut self.frames, at, vec![byte]);
        self.backlog -= self.backlog.signum();
    }

    /// Sends the steps whose turn on the bus comes before `until`.
    fn drain(&mut self, until: f64, bus: &mut Bus) {
        while self.backlog != 0 && bus.free_at() <= until {
            self.send_step(bus.free_at(), bus);
        }
    }
}

fn paper(trace: &Trace, bus: &mut Bus) -> Vec<Sent> {
    let factor = i64::from(trace.multiplier.factor());
    let mut device = PaperDevice {
        encoder: UnitStepEncoder::new(CounterStride::One),
        backlog: 0,
        frames: Vec::new(),
    };
    let mut previous = AbLevels::from_bits(0);
    for edge in &trace.edges {
        let t = edge.t_us as f64;
        device.drain(t, bus);
        if !previous.b() && edge.levels.b() {
            // The paper: on B rising, A high is forward.
            device.backlog += if edge.levels.a() { factor } else { -factor };
            if device.backlog != 0 && bus.free_at() < t {
                // Idle bus: the first frame goes at once.
                device.send_step(t, bus);
            }
        }
        previous = edge.levels;
    }
    device.drain(f64::INFINITY, bus);
    device.frames
}

/// This project's unit-step mode: the real decoder and bounded backlog, paced by inhibit.
struct CompatDevice {
    wheel: LinkedWheel<EdgeState>,
    encoder: UnitStepEncoder,
    next_allowed: f64,
    frames: Vec<Sent>,
}

impl CompatDevice {
    fn pump(&mut self, until: f64, bus: &mut Bus) {
        while self.next_allowed <= until {
            // A round in which a step may go: it takes the wheel's motion in first.
            self.wheel.take_motion(Intake::RoundStart);
            let Some(step) = self.wheel.lock(|w| w.feed.take_unit_step()) else {
                break;
            };
            let at = self.next_allowed;
            let byte = self.encoder.encode(step);
            send(bus, &mut self.frames, at, vec![byte]);
            self.next_allowed = at + INHIBIT_US;
        }
    }
}

fn compat(trace: &Trace, bus: &mut Bus) -> Vec<Sent> {
    let mut wheel = LinkedWheel::local(DecoderConfig::default(), AbLevels::from_bits(0));
    wheel.lock(|w| {
        w.feed.set_unit_step_mode(true);
        w.feed.set_selection(selected(trace));
        w.feed.set_enabled(true);
    });
    let mut device = CompatDevice {
        wheel,
        encoder: UnitStepEncoder::new(CounterStride::One),
        next_allowed: 0.0,
        frames: Vec::new(),
    };
    for edge in &trace.edges {
        let t = edge.t_us as f64;
        device.pump(t, bus);
        device.next_allowed = device.next_allowed.max(t);
        let _ = device.wheel.edge().on_edge(edge.levels);
        device.pump(t, bus);
    }
    device.pump(f64::INFINITY, bus);
    device.frames
}

/// This project's default: TPDO1 with the feed record, event-driven with inhibit time and
/// event timer, as `canopen-slave` schedules it.
struct RecordDevice {
    wheel: LinkedWheel<EdgeState>,
    sequence: u16,
    pending: bool,
    inhibit_end: f64,
    event_at: f64,
    frames: Vec<Sent>,
}

impl RecordDevice {
    fn emit(&mut self, at: f64, bus: &mut Bus) {
        let feed = self.wheel.feed();
        let record = FeedRecord {
            state: feed.state(),
            sequence: self.sequence,
        };
        self.sequence = self.sequence.wrapping_add(1);
        send(bus, &mut self.frames, at, record.to_bytes().to_vec());
        self.pending = false;
        self.inhibit_end = at + INHIBIT_US;
        self.event_at = at + EVENT_TIMER_US;
    }

    /// Time-driven sends (an event waiting for the inhibit time, the event timer) up to
    /// `until`.
    fn timers(&mut self, until: f64, bus: &mut Bus) {
        loop {
            let due = if self.pending {
                self.inhibit_end
            } else {
                self.event_at.max(self.inhibit_end)
            };
            if due > until {
                break;
            }
            self.emit(due, bus);
        }
    }

    fn edge(&mut self, t: f64, levels: AbLevels, bus: &mut Bus) {
        self.timers(t, bus);
        let _ = self.wheel.edge().on_edge(levels);
        // The edge wakes a round, which takes its motion in.
        self.wheel.take_motion(Intake::RoundStart);
        if self.wheel.lock(|w| w.feed.take_record_due()) && !self.pending {
            self.pending = true;
            // The event is at `t`: an inhibit time that ran out earlier does not date it.
            self.inhibit_end = self.inhibit_end.max(t);
        }
        self.timers(t, bus);
    }
}

fn record(trace: &Trace, bus: &mut Bus) -> Vec<Sent> {
    let mut wheel = LinkedWheel::local(DecoderConfig::default(), AbLevels::from_bits(0));
    wheel.lock(|w| {
        w.feed.set_selection(selected(trace));
        w.feed.set_enabled(true);
        // Set up before the trace: only the wheel's motion makes records.
        let _ = w.feed.take_record_due();
    });
    let mut device = RecordDevice {
        wheel,
        sequence: 0,
        pending: false,
        inhibit_end: 0.0,
        event_at: EVENT_TIMER_US,
        frames: Vec::new(),
    };
    for edge in &trace.edges {
        device.edge(edge.t_us as f64, edge.levels, bus);
    }
    device.timers(trace.motion_end_us as f64 + TAIL_US, bus);
    device.frames
}

/// The host's final feed (multiplied units) after receiving `frames` with each frame lost
/// with probability `drop`, and when its last change of position arrived (µs).
pub fn host(scheme: Scheme, frames: &[Sent], drop: f64, rng: &mut Rng) -> (i64, f64) {
    let mut position: i64 = 0;
    let mut last_change = 0.0;
    for f in frames {
        if drop > 0.0 && rng.unit() < drop {
            continue;
        }
        let before = position;
        match scheme {
            Scheme::Record => {
                let bytes: [u8; 8] = f.data.as_slice().try_into().expect("8-byte record");
                let rec = FeedRecord::from_bytes(bytes).expect("valid record");
                // Start at 0 and apply wrapping deltas: what a host does.
                let delta = rec.state.position.wrapping_sub(position as i32);
                position += i64::from(delta);
            }
            Scheme::Paper | Scheme::Compat => {
                let (step, _counter) = UnitStepEncoder::decode(f.data[0]).expect("valid byte");
                position += if step.forward { 1 } else { -1 };
            }
        }
        if position != before {
            last_change = f.at_us;
        }
    }
    (position, last_change)
}
