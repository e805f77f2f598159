//! Where a round takes the wheel's motion in (`handwheel_core::wheel`, "Where motion is taken
//! in"): each named intake point, shown by a detent that comes just before it. Without the
//! point, the detent is taken in later, after the change or the record, and the test fails.

use std::collections::VecDeque;

use canopen_slave::{BusState, Frame, FrameSink, MemoryStorage, NodeId, SinkFull};
use handwheel_core::{
    AbLevels, Axis, BitRate, DecoderConfig, EdgeState, FeedRecord, Handwheel, Intake, LinkedWheel,
    Mutex, SelectorInput, Wheel,
};
use handwheel_device::od::SESSION_DELAY_MS;
use handwheel_device::{CanIo, HandwheelDevice, Node, TransmitState};

const NODE: u8 = 5;
const TPDO1: u16 = 0x180 + NODE as u16;

/// A CAN port on a free bus that takes every frame.
#[derive(Clone, Default)]
struct Port {
    rx: VecDeque<Frame>,
    sent: Vec<Frame>,
}

impl FrameSink for Port {
    fn send(&mut self, frame: Frame) -> Result<(), SinkFull> {
        self.sent.push(frame);
        Ok(())
    }
}

impl CanIo for Port {
    fn receive(&mut self) -> Option<Frame> {
        self.rx.pop_front()
    }

    fn bus_state(&mut self) -> BusState {
        BusState::ErrorActive
    }

    fn rx_overruns(&mut self) -> u32 {
        0
    }

    fn transmit_state(&mut self) -> TransmitState {
        TransmitState::default()
    }

    fn switch_bit_rate(&mut self, _: BitRate) -> bool {
        true
    }
    fn frame_acknowledged(&mut self) -> bool {
        true
    }
}

/// The switch lines: the axis and multiplier positions as read (one bit each).
#[derive(Clone)]
struct Lines(u8, u8);

impl SelectorInput for Lines {
    fn read_lines(&mut self) -> (u8, u8) {
        (self.0, self.1)
    }
}

/// The CAN side's wheel, with an edge task that turns one detent forward right after an
/// intake: before whatever the round does next with the wheel.
#[derive(Clone)]
struct TurningWheel {
    wheel: LinkedWheel<EdgeState>,
    levels: AbLevels,
    /// Turn at the first access after the next intake at this point.
    after: Option<Intake>,
    /// Turn at the next access.
    now: bool,
}

impl TurningWheel {
    fn turn(&mut self) {
        for _ in 0..4 {
            self.levels = self.levels.next_forward();
            let _ = self.wheel.edge().on_edge(self.levels);
        }
    }

    fn access(&mut self) {
        if std::mem::take(&mut self.now) {
            self.turn();
        }
    }
}

impl Mutex for TurningWheel {
    type T = Handwheel;

    fn lock<R>(&mut self, f: impl FnOnce(&mut Handwheel) -> R) -> R {
        self.access();
        self.wheel.lock(f)
    }
}

impl Wheel for TurningWheel {
    fn take_motion(&mut self, at: Intake) {
        self.access();
        self.wheel.take_motion(at);
        if self.after == Some(at) {
            self.after = None;
            self.now = true;
        }
    }
}

#[derive(Clone)]
struct Rig {
    node: Node<MemoryStorage>,
    port: Port,
    lines: Lines,
    wheel: TurningWheel,
    ms: u32,
}

impl Rig {
    /// Operational, X at x1 selected, the feed enabled or not; frames so far dropped.
    fn operational(enabled: bool) -> Self {
        let node_id = NodeId::new(NODE).unwrap();
        let device = HandwheelDevice::new(node_id, 0x1234_5678, MemoryStorage::new());
        let levels = AbLevels::from_bits(0);
        let mut r = Self {
            node: Node::new(device, BitRate::Kbit1000),
            port: Port::default(),
            lines: Lines(1, 1),
            wheel: TurningWheel {
                wheel: LinkedWheel::local(DecoderConfig::default(), levels),
                levels,
                after: None,
                now: false,
            },
            ms: 0,
        };
        // Four switch samples, 5 ms apart, take the selection.
        for _ in 0..5 {
            r.round();
        }
        r.receive(&[0x01, NODE], 0x000);
        if enabled {
            r.write_feed_enable(1);
        }
        let feed = r.wheel.wheel.feed();
        let selected = feed.selection().axis;
        assert_eq!((selected, feed.enabled()), (Some(Axis::X), enabled));
        r.port.sent.clear();
        r
    }

    /// A round 5 ms after the last one (a switch sample in each).
    fn round(&mut self) -> Vec<FeedRecord> {
        let records = self.round_at_once();
        self.ms += 5;
        records
    }

    /// A round at the time of the last one; the feed records it sent.
    fn round_at_once(&mut self) -> Vec<FeedRecord> {
        let sent = self.port.sent.len();
        let out = self
            .node
            .poll(self.ms, &mut self.port, &mut self.lines, &mut self.wheel);
        assert!(self.wheel.after.is_none() && !self.wheel.now, "{out:?}");
        let records = self.port.sent[sent..].iter().filter(|f| f.id() == TPDO1);
        records
            .map(|f| FeedRecord::from_bytes(f.data().try_into().unwrap()).unwrap())
            .collect()
    }

    fn receive(&mut self, data: &[u8], id: u16) -> Vec<FeedRecord> {
        self.port.rx.push_back(Frame::new(id, data).unwrap());
        self.round()
    }

    fn write_feed_enable(&mut self, value: u8) -> Vec<FeedRecord> {
        let request = [0x2F, 0x00, 0x20, 0, value, 0, 0, 0];
        self.receive(&request, 0x600 + u16::from(NODE))
    }

    /// Opens session `token`, once the device is old enough to take one.
    fn write_session(&mut self, token: u8) {
        self.ms = self.ms.max(SESSION_DELAY_MS as u32);
        let request = [0x2F, 0x02, 0x20, 0, token, 0, 0, 0];
        self.receive(&request, 0x600 + u16::from(NODE));
        let answer = self
            .port
            .sent
            .iter()
            .rev()
            .find(|f| f.id() == 0x580 + u16::from(NODE));
        assert_eq!(answer.map(|f| f.data()[0]), Some(0x60), "0x2002 = {token}");
    }

    /// TPDO1 without its inhibit time (it may change only while the PDO is invalid).
    fn no_inhibit_time(&mut self) {
        let cob_id = |flags: u32| (flags | 0x180 | u32::from(NODE)).to_le_bytes();
        let [i0, i1, i2, i3] = cob_id(0x8000_0000);
        let [v0, v1, v2, v3] = cob_id(0);
        for request in [
            [0x23, 0x00, 0x18, 1, i0, i1, i2, i3],
            [0x2B, 0x00, 0x18, 3, 0, 0, 0, 0],
            [0x23, 0x00, 0x18, 1, v0, v1, v2, v3],
        ] {
            self.receive(&request, 0x600 + u16::from(NODE));
            let answer = self.port.sent.last().map(|f| f.data()[0]);
            assert_eq!(answer, Some(0x60), "{request:02x?}");
        }
    }

    /// The wheel's position, ignored detents and whether the feed is enabled.
    fn feed(&self) -> (i32, u32, bool) {
        let feed = self.wheel.wheel.feed();
        (feed.position(), feed.ignored_detents(), feed.enabled())
    }
}

/// [`Intake::RoundStart`]: a detent turned between two rounds goes out in the next one.
#[test]
fn motion_between_rounds_is_taken_in_when_the_next_round_starts() {
    let mut r = Rig::operational(true);
    r.wheel.turn();
    let records = r.round();
    let positions: Vec<i32> = records.iter().map(|r| r.state.position).collect();
    assert_eq!(positions, [1]);
}

/// [`Intake::BeforeChange`] before an enable: a detent that comes while the write is on its
/// way was turned with the feed off, and never becomes feed.
#[test]
fn motion_before_an_enable_is_not_feed() {
    let mut r = Rig::operational(false);
    r.wheel.after = Some(Intake::RoundStart);
    r.write_feed_enable(1);
    r.round();
    assert_eq!(r.feed(), (0, 1, true), "(position, ignored, enabled)");
}

/// [`Intake::BeforeChange`] before a disable: a detent that comes while the write is on its
/// way was turned with the feed on: it is feed, in the last record of the enabled epoch.
#[test]
fn motion_before_a_disable_is_feed_of_the_enabled_epoch() {
    let mut r = Rig::operational(true);
    r.wheel.after = Some(Intake::RoundStart);
    let mut records = r.write_feed_enable(0);
    records.extend(r.round());
    assert_eq!(r.feed(), (1, 0, false), "(position, ignored, enabled)");
    let enabled = |r: &&FeedRecord| r.state.status.contains(handwheel_core::FeedStatus::ENABLED);
    let last_enabled = records.iter().rfind(enabled);
    assert_eq!(last_enabled.map(|r| r.state.position), Some(1));
}

/// [`Intake::BeforeChange`] before a new selection: a detent that comes in the round the
/// debouncer takes a new axis was turned before the device changed axis: it goes to the old
/// one, in its epoch's last record, and the new axis' records start from there.
#[test]
fn motion_before_a_selection_change_goes_to_the_old_axis() {
    let mut r = Rig::operational(true);
    r.lines = Lines(2, 1);
    // The round in which the debouncer takes Y: found on a copy of the rig.
    let mut probe = r.clone();
    let rounds = (1..10)
        .find(|_| probe.round().iter().any(|r| r.state.axis == Some(Axis::Y)))
        .expect("Y is taken within ten samples");
    for _ in 1..rounds {
        assert!(r.round().is_empty());
    }
    r.wheel.after = Some(Intake::RoundStart);
    let mut records = r.round();
    records.extend(r.round());
    let on = |axis| {
        let positions = records.iter().filter(move |r| r.state.axis == Some(axis));
        positions.map(|r| r.state.position).collect::<Vec<i32>>()
    };
    assert_eq!((on(Axis::X), on(Axis::Y)), (vec![1], vec![1]));
    assert!(records[0].state.axis == Some(Axis::X));
}

/// [`Intake::RecordSnapshot`]: a record carries the motion up to when it is taken, not only
/// up to the round's start.
#[test]
fn a_record_carries_the_motion_up_to_when_it_is_taken() {
    let mut r = Rig::operational(true);
    r.wheel.turn();
    r.wheel.after = Some(Intake::RoundStart);
    let records = r.round();
    assert_eq!(records.first().map(|r| r.state.position), Some(2));
}

/// [`Intake::BeforeChange`] before a sent record is counted: its number may be beyond the
/// pace, which ends the session and stops the feed. A detent that came while the record was
/// built was turned with the feed on: it is feed of the session's last epoch.
#[test]
fn motion_before_the_pace_ends_the_session_is_feed_of_the_session() {
    let mut r = Rig::operational(false);
    r.no_inhibit_time();
    r.write_session(3);
    r.write_feed_enable(1);
    // A record per round, all at one instant: the bucket runs empty, and the round whose
    // record overdraws it ends the session (found on a copy of the rig).
    let mut probe = r.clone();
    let rounds = (1..200)
        .find(|_| {
            probe.wheel.turn();
            probe.round_at_once();
            probe.wheel.wheel.feed().session() == 0
        })
        .expect("the pace runs out");
    for _ in 1..rounds {
        r.wheel.turn();
        assert_eq!(r.round_at_once().len(), 1);
    }
    r.wheel.turn();
    r.wheel.after = Some(Intake::RecordSnapshot);
    r.round_at_once();
    assert_eq!(r.wheel.wheel.feed().session(), 0);
    r.round_at_once();
    let position = rounds + 1;
    assert_eq!(
        r.feed(),
        (position, 0, false),
        "(position, ignored, enabled)"
    );
}
