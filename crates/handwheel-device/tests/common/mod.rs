//! A test bench: one device, its wheel, a clock and a record of every frame sent.
#![allow(dead_code)]

use canopen_slave::{Frame, FrameSink, Instant, MemoryStorage, NodeId, SinkFull};
use handwheel_core::{
    AbLevels, Axis, DecoderConfig, EdgeState, FeedRecord, Intake, LinkedWheel, Multiplier,
    Selection, Wheel,
};
use handwheel_device::od::SESSION_DELAY_MS;
use handwheel_device::HandwheelDevice;

pub const NODE: u8 = 16;
pub const SDO_RX: u16 = 0x600 + NODE as u16;
pub const SDO_TX: u16 = 0x580 + NODE as u16;
pub const TPDO1: u16 = 0x180 + NODE as u16;
pub const TPDO2: u16 = 0x280 + NODE as u16;
pub const EMCY: u16 = 0x080 + NODE as u16;
pub const HEARTBEAT: u16 = 0x700 + NODE as u16;

/// The frames one device call sends; refuses them beyond `room` (a transmit queue that the
/// blocked bus does not drain).
pub struct Recorder(pub Vec<Frame>, usize);

impl Default for Recorder {
    fn default() -> Self {
        Self(Vec::new(), usize::MAX)
    }
}

impl FrameSink for Recorder {
    fn send(&mut self, frame: Frame) -> Result<(), SinkFull> {
        if self.0.len() >= self.1 {
            return Err(SinkFull);
        }
        self.0.push(frame);
        Ok(())
    }
}

/// A frame as seen on the bus, with the time it was sent.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Seen {
    pub at_us: u64,
    pub id: u16,
    pub data: Vec<u8>,
}

pub struct Bench {
    pub device: HandwheelDevice<MemoryStorage>,
    pub wheel: LinkedWheel<EdgeState>,
    pub now_us: u64,
    pub levels: AbLevels,
    pub seen: Vec<Seen>,
    /// While the bus is blocked: the transmit queue's size and the frames waiting in it.
    pub blocked: Option<(usize, Vec<Frame>)>,
}

impl Bench {
    /// Booted: boot-up sent, Pre-operational.
    pub fn new() -> Self {
        Self::with_storage(MemoryStorage::new())
    }

    pub fn with_storage(storage: MemoryStorage) -> Self {
        Self::with_serial(storage, 0xC0FF_EE00)
    }

    pub fn with_serial(storage: MemoryStorage, serial: u32) -> Self {
        Self::with_device(HandwheelDevice::new(
            NodeId::new(NODE).unwrap(),
            serial,
            storage,
        ))
    }

    /// `device` (node-ID [`NODE`]) booted.
    pub fn with_device(device: HandwheelDevice<MemoryStorage>) -> Self {
        let levels = AbLevels::from_bits(0);
        let mut bench = Self {
            device,
            wheel: LinkedWheel::local(DecoderConfig::default(), levels),
            now_us: 0,
            levels,
            seen: Vec::new(),
            blocked: None,
        };
        let mut tx = Recorder::default();
        bench
            .device
            .start(Instant::from_micros(0), &mut bench.wheel, &mut tx);
        bench.record(tx);
        bench
    }

    fn sink(&self) -> Recorder {
        let room = match &self.blocked {
            Some((size, queued)) => size - queued.len(),
            None => usize::MAX,
        };
        Recorder(Vec::new(), room)
    }

    /// The bus takes nothing from now on: frames wait in a transmit queue of `size` frames,
    /// and the device's sends are refused once it is full.
    pub fn block_bus(&mut self, size: usize) {
        self.blocked = Some((size, Vec::new()));
    }

    /// The bus is back: the queued frames go out (in order), then the device is polled.
    pub fn unblock_bus(&mut self) {
        if let Some((_, queued)) = self.blocked.take() {
            self.record(Recorder(queued, usize::MAX));
        }
        self.poll();
    }

    fn record(&mut self, tx: Recorder) {
        if let Some((_, queued)) = &mut self.blocked {
            queued.extend(tx.0);
            return;
        }
        let at_us = self.now_us;
        self.seen.extend(tx.0.into_iter().map(|f| Seen {
            at_us,
            id: f.id(),
            data: f.data().to_vec(),
        }));
    }

    /// Delivers a frame from the bus, then polls: a round of the firmware's loop, which takes
    /// the wheel's motion in first.
    pub fn receive(&mut self, id: u16, data: &[u8]) {
        let frame = Frame::new(id, data).unwrap();
        let mut tx = self.sink();
        let now = Instant::from_micros(self.now_us);
        self.wheel.take_motion(Intake::RoundStart);
        self.device.on_frame(now, &frame, &mut self.wheel, &mut tx);
        self.device.poll(now, &mut self.wheel, &mut tx);
        self.record(tx);
    }

    /// Lets time pass in 100 µs steps, polling at each (the firmware polls at deadlines;
    /// polling more often must not change what is sent).
    pub fn advance_ms(&mut self, ms: u64) {
        for _ in 0..ms * 10 {
            self.now_us += 100;
            self.poll();
        }
    }

    /// Opens session `token` (0x2002), first letting the device grow as old as a session
    /// needs ([`SESSION_DELAY_MS`] after its start) if it is younger.
    pub fn open_session(&mut self, token: u8) {
        let from = SESSION_DELAY_MS * 1000;
        if self.now_us < from {
            self.now_us = from;
            self.poll();
        }
        assert_eq!(
            self.sdo_write(0x2002, 0, &[token]),
            Ok(()),
            "0x2002 = {token}"
        );
    }

    /// A round without a frame: the wheel's motion taken in, then the device polled.
    pub fn poll(&mut self) {
        let mut tx = self.sink();
        self.wheel.take_motion(Intake::RoundStart);
        self.device
            .poll(Instant::from_micros(self.now_us), &mut self.wheel, &mut tx);
        self.record(tx);
    }

    /// Frames seen since the last call.
    pub fn take(&mut self) -> Vec<Seen> {
        std::mem::take(&mut self.seen)
    }

    pub fn take_id(&mut self, id: u16) -> Vec<Seen> {
        self.take().into_iter().filter(|s| s.id == id).collect()
    }

    pub fn nmt(&mut self, command: u8) {
        self.receive(0x000, &[command, NODE]);
    }

    /// SDO expedited download; `Err(abort code)` on abort.
    pub fn sdo_write(&mut self, index: u16, sub: u8, value: &[u8]) -> Result<(), u32> {
        assert!(value.len() <= 4);
        let cmd = 0x23 | (((4 - value.len()) as u8) << 2);
        let mut data = [cmd, index as u8, (index >> 8) as u8, sub, 0, 0, 0, 0];
        data[4..4 + value.len()].copy_from_slice(value);
        self.receive(SDO_RX, &data);
        let reply = self.sdo_reply(index, sub);
        match reply[0] {
            0x60 => Ok(()),
            0x80 => Err(u32::from_le_bytes([reply[4], reply[5], reply[6], reply[7]])),
            other => panic!("unexpected SDO reply {other:#04x}"),
        }
    }

    /// SDO upload of any size: expedited or segmented.
    pub fn sdo_upload(&mut self, index: u16, sub: u8) -> Result<Vec<u8>, u32> {
        self.receive(
            SDO_RX,
            &[0x40, index as u8, (index >> 8) as u8, sub, 0, 0, 0, 0],
        );
        let reply = self.sdo_reply(index, sub);
        match reply[0] {
            0x80 => Err(u32::from_le_bytes([reply[4], reply[5], reply[6], reply[7]])),
            c if c & 0xF3 == 0x43 => Ok(reply[4..8 - ((c >> 2) & 3) as usize].to_vec()),
            0x41 => {
                let size = u32::from_le_bytes([reply[4], reply[5], reply[6], reply[7]]) as usize;
                let mut out = Vec::new();
                let mut toggle = 0u8;
                loop {
                    self.receive(SDO_RX, &[0x60 | toggle, 0, 0, 0, 0, 0, 0, 0]);
                    let segs: Vec<Seen> = self
                        .seen
                        .iter()
                        .filter(|s| s.id == SDO_TX)
                        .cloned()
                        .collect();
                    self.seen.retain(|s| s.id != SDO_TX);
                    assert_eq!(segs.len(), 1);
                    let seg = &segs[0].data;
                    assert_eq!(seg[0] & 0xE0, 0, "upload segment response");
                    assert_eq!(seg[0] & 0x10, toggle, "toggle alternates");
                    let unused = ((seg[0] >> 1) & 7) as usize;
                    out.extend_from_slice(&seg[1..8 - unused]);
                    if seg[0] & 1 == 1 {
                        break;
                    }
                    toggle ^= 0x10;
                }
                assert_eq!(out.len(), size, "indicated size");
                Ok(out)
            }
            other => panic!("unexpected SDO reply {other:#04x}"),
        }
    }

    fn sdo_reply(&mut self, index: u16, sub: u8) -> Vec<u8> {
        let replies: Vec<Seen> = self
            .seen
            .iter()
            .filter(|s| s.id == SDO_TX)
            .cloned()
            .collect();
        self.seen.retain(|s| s.id != SDO_TX);
        assert_eq!(replies.len(), 1, "exactly one SDO reply");
        let r = replies[0].data.clone();
        assert_eq!(r.len(), 8);
        assert_eq!((u16::from_le_bytes([r[1], r[2]]), r[3]), (index, sub));
        r
    }

    pub fn read_u32(&mut self, index: u16, sub: u8) -> u32 {
        let mut b = self.sdo_upload(index, sub).unwrap();
        b.resize(4, 0);
        u32::from_le_bytes([b[0], b[1], b[2], b[3]])
    }

    /// Turns the wheel by whole detents (4 counts each), edge by edge, as the EXTI task
    /// would see it, and tells the device after each detent.
    pub fn turn(&mut self, detents: i32) {
        for _ in 0..detents.unsigned_abs() {
            for _ in 0..4 {
                self.levels = if detents > 0 {
                    self.levels.next_forward()
                } else {
                    self.levels.next_reverse()
                };
                self.edge(self.levels);
            }
        }
    }

    /// One EXTI edge with the given levels.
    pub fn edge(&mut self, levels: AbLevels) {
        // The firmware polls the device after any edge that pends its wake-up; polling after
        // every edge also shows that the others change nothing.
        let _ = self.wheel.edge().on_edge(levels);
        self.poll();
    }

    pub fn select(&mut self, axis: Option<Axis>, multiplier: Multiplier) {
        self.device
            .set_selection(Selection { axis, multiplier }, &mut self.wheel);
        self.poll();
    }

    /// Operational, axis selected, feed enabled; frames so far discarded.
    pub fn operational_enabled(axis: Axis, multiplier: Multiplier) -> Self {
        let mut b = Self::new();
        b.select(Some(axis), multiplier);
        b.nmt(0x01);
        b.sdo_write(0x2000, 0, &[1]).unwrap();
        b.advance_ms(5);
        b.take();
        b
    }
}

/// The feed record a frame carries, decoded by `handwheel-core` (the one statement of its
/// layout).
pub fn feed_record(s: &Seen) -> FeedRecord {
    let bytes: [u8; 8] = s
        .data
        .as_slice()
        .try_into()
        .expect("a feed record is 8 bytes");
    FeedRecord::from_bytes(bytes).expect("a feed record the device may send")
}

/// A feed record as (position, axis (0 none, 1..5), multiplier factor, status flags,
/// sequence).
pub fn record(s: &Seen) -> (i32, u8, u8, u8, u16) {
    let r = feed_record(s).state;
    (
        r.position,
        Axis::option_value(r.axis),
        r.multiplier.factor(),
        r.status.bits(),
        feed_record(s).sequence,
    )
}

/// A feed record's epoch bits (the low three bits of 0x2010:3).
pub fn record_epoch(s: &Seen) -> u8 {
    feed_record(s).state.epoch
}
