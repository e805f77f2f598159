//! The model: the real device as the firmware runs it (`Node::poll`, the step function, over
//! `HandwheelDevice` with its engine, accumulator and outbox), a transmit path of bounded size in front of the bus, a channel that passes, loses,
//! duplicates and replays frames, the host's rule ([`HostRule`]) and the truth: every detent
//! the device counted, on which axis and when.
//!
//! Every action is one thing the outside world can do: the operator turns or switches, a
//! master sends NMT or writes 0x2000, the device loses power, time passes, the bus takes a
//! frame (or loses, doubles or replays one), the host stalls or resumes. Not taking a frame
//! is the bus being held. The property is checked in every state the actions reach, within
//! the budgets of a [`Bounds`].

use std::collections::VecDeque;
use std::fmt::{self, Write as _};
use std::hash::{Hash, Hasher};

use canopen_slave::{BusState, Frame, FrameSink, MemoryStorage, NodeId, SinkFull};
use handwheel_core::{
    AbLevels, BitRate, DecoderConfig, EdgeState, LinkedWheel, Mutex, SelectorInput, SequencePace,
};
use handwheel_device::{CanIo, HandwheelDevice, Node, Outputs, TransmitState};
use stateright::{Model, Property};

use crate::host::{Credit, HostRule, RuleConfig, AXES};

/// The device's node-ID in the model.
pub const NODE: u8 = 16;
const TPDO1: u16 = 0x180 + NODE as u16;
const HEARTBEAT: u16 = 0x700 + NODE as u16;
const SDO_RX: u16 = 0x600 + NODE as u16;

/// NMT commands a master may send.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Nmt {
    /// 0x01.
    Start,
    /// 0x02.
    Stop,
    /// 0x80.
    PreOperational,
    /// 0x81.
    ResetNode,
    /// 0x82.
    ResetCommunication,
}

impl Nmt {
    /// Every command.
    pub const ALL: [Self; 5] = [
        Self::Start,
        Self::Stop,
        Self::PreOperational,
        Self::ResetNode,
        Self::ResetCommunication,
    ];

    const fn byte(self) -> u8 {
        match self {
            Self::Start => 0x01,
            Self::Stop => 0x02,
            Self::PreOperational => 0x80,
            Self::ResetNode => 0x81,
            Self::ResetCommunication => 0x82,
        }
    }
}

/// One thing the world does.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Action {
    /// The operator turns one detent forward.
    Turn,
    /// The operator moves the axis switch to the other axis (X <-> Y).
    SwitchAxis,
    /// A master writes 0x2000 = 1 (without waiting for the answer).
    Enable,
    /// A master writes 0x2000 = 0.
    Disable,
    /// A master sends an NMT command.
    Nmt(Nmt),
    /// The device loses power and boots again (what waits for the bus is lost with it).
    PowerCycle,
    /// Time passes by the bounds' tick.
    Tick,
    /// The bus takes the next frame and the host receives it.
    Pass,
    /// The bus takes the next frame and the host never receives it.
    Lose,
    /// The bus takes the next frame and the host receives it twice.
    Duplicate,
    /// The host receives an exact copy of the feed record it received this many records ago
    /// (any record it received within the contract's copy age, [`Bounds::copy_age_ms`]).
    Copy(u8),
    /// The host configures the device (the component's `Configure`, when its rule asks for
    /// one): the bounds' settings written again, then a session token, then NMT start.
    Configure,
    /// The host stops reading (frozen, starved): frames wait in its socket.
    HostStall,
    /// The host reads again: the backlog, then its receive path is empty.
    HostResume,
    /// The master's heartbeat (node 1) reaches the device; without it for the consumer time
    /// the device counts the master as lost. A stalled host sends none.
    MasterBeat,
}

/// What one exploration may do: how often each kind of action, and the settings.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Bounds {
    /// A name for the report.
    pub name: &'static str,
    /// The host's rule and its widths.
    pub rule: RuleConfig,
    /// Frames the transmit path holds (software queue and mailboxes: 16 + 3 on the board).
    pub transmit_capacity: usize,
    /// Detents turned at most.
    pub turns: u8,
    /// Axis switch moves at most.
    pub switches: u8,
    /// 0x2000 writes at most.
    pub feed_writes: u8,
    /// NMT commands at most.
    pub nmt: u8,
    /// Power cycles at most.
    pub power_cycles: u8,
    /// Ticks at most, and how long one is.
    pub ticks: u8,
    /// Milliseconds per tick.
    pub tick_ms: u64,
    /// The device's TPDO1 event timer (0x1800:5), ms; 0: none.
    pub event_timer_ms: u16,
    /// TPDO1's inhibit time (0x1800:3), 100 us; 20 by default. 0 lets every change go at
    /// once, which fills the transmit path in fewer steps.
    pub inhibit_100us: u16,
    /// Frames lost, duplicated or replayed at most.
    pub channel_faults: u8,
    /// How far back a copy may reach, in feed records delivered (bounds the state; the age
    /// limit below is the contract's).
    pub copy_depth: u8,
    /// The contract's age of copies (model ms): a record delivered longer ago is never copied.
    pub copy_age_ms: u64,
    /// The device's pace (narrowed with the sequence the host sees).
    pub pace: SequencePace,
    /// Host stalls at most.
    pub host_stalls: u8,
    /// Master heartbeats at most; with any, the device watches the master (0x1016:1, node 1,
    /// [`Bounds::consumer_ms`]).
    pub master_beats: u8,
    /// The device's heartbeat consumer time for the master, ms.
    pub consumer_ms: u16,
    /// Configurations by the host (after the first) at most.
    pub configures: u8,
    /// The bound the property sets on lateness: nothing is credited later than this after
    /// it was turned.
    pub late_ms: u64,
    /// Detents turned (and their records received) before the exploration starts, one initial
    /// state for each: where the sequence stands when the trouble begins.
    pub warmups: &'static [u8],
}

/// Where a frame came from, which the host cannot see.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Tag {
    /// Which run of positions: +1 at every power cycle and reset node (the position
    /// restarts at 0).
    pub era: u8,
    /// When the device made the frame.
    pub made_ms: u64,
}

#[derive(Clone, Debug, PartialEq, Eq, Hash)]
struct Wire {
    id: u16,
    data: [u8; 8],
    len: u8,
    tag: Tag,
}

/// The node and its wheel: real code, compared and hashed through their `Debug` form
/// (neither needs `Hash` for the firmware's sake).
#[derive(Clone)]
struct Real {
    node: Node<MemoryStorage>,
    wheel: LinkedWheel<EdgeState>,
    levels: AbLevels,
}

impl Real {
    fn fingerprint(&self) -> String {
        let mut s = String::with_capacity(4096);
        let _ = write!(s, "{:?}{:?}{:?}", self.node, self.wheel, self.levels);
        s
    }
}

impl PartialEq for Real {
    fn eq(&self, other: &Self) -> bool {
        self.fingerprint() == other.fingerprint()
    }
}

impl Hash for Real {
    fn hash<H: Hasher>(&self, state: &mut H) {
        self.fingerprint().hash(state);
    }
}

impl fmt::Debug for Real {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("device")
    }
}

/// Detents the device counted, per era, by position: the axis (index into [`AXES`]) and
/// when.
#[derive(Clone, Debug, PartialEq, Eq, Hash, Default)]
struct Truth {
    moves: Vec<Vec<(usize, u64)>>,
    /// Per era, the position up to which motion was credited.
    credited_upto: Vec<i32>,
}

/// One state of the world.
#[derive(Clone, Debug, PartialEq, Hash)]
pub struct World {
    real: Real,
    now_ms: u64,
    era: u8,
    axis: usize,
    /// Frames the device handed out that the bus has not taken.
    transmit: VecDeque<Wire>,
    /// Feed records the host received and when (ms), newest last, for copies.
    delivered: VecDeque<(Wire, u64)>,
    host: HostRule<Tag>,
    host_stalled: bool,
    host_backlog: VecDeque<Wire>,
    truth: Truth,
    used: [u8; 10],
    /// The first breach of the property, if any.
    pub violation: Option<String>,
    /// What the host was given, in order, when recording test vectors (`None` while
    /// checking, so that it does not tell equal states apart).
    pub log: Option<Vec<HostEvent>>,
}

/// One event of the host's input, for the vectors `core.py` replays.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub enum HostEvent {
    /// A frame handed to the host at a time (ms).
    Frame {
        /// Identifier.
        id: u16,
        /// Payload.
        data: Vec<u8>,
        /// When, ms.
        at_ms: u64,
    },
    /// The host found its receive path empty (ms).
    Drained(u64),
    /// The host configured the device, whose 0x2002 read this, at a time (ms).
    Configure(u8, u64),
}

impl World {
    /// The host's counts per axis (X, Y).
    pub fn host_counts(&self) -> [i32; AXES] {
        self.host.counts
    }

    /// The host's session.
    pub fn host_session(&self) -> Option<u8> {
        self.host.session()
    }

    /// The device's session.
    pub fn device_session(&self) -> u8 {
        let mut wheel = self.real.wheel.clone();
        wheel.lock(|h| h.feed.session())
    }
}

impl Eq for World {}

/// Budget slots in [`World::used`].
#[derive(Clone, Copy)]
enum Budget {
    Turns,
    Switches,
    FeedWrites,
    Nmt,
    PowerCycles,
    Ticks,
    ChannelFaults,
    HostStalls,
    MasterBeats,
    Configures,
}

/// A transmit path of bounded size.
/// The CAN port of one round: at most one received frame, the transmit path, a controller
/// that is always on the bus and error-active.
struct Port<'a> {
    rx: Option<Frame>,
    queue: &'a mut VecDeque<Wire>,
    capacity: usize,
    tag: Tag,
}

impl CanIo for Port<'_> {
    fn receive(&mut self) -> Option<Frame> {
        self.rx.take()
    }

    fn bus_state(&mut self) -> BusState {
        BusState::ErrorActive
    }

    fn rx_overruns(&mut self) -> u32 {
        0
    }

    fn transmit_state(&mut self) -> TransmitState {
        TransmitState {
            waiting: !self.queue.is_empty(),
        }
    }

    fn switch_bit_rate(&mut self, _: BitRate) -> bool {
        true
    }
}

/// The switch lines: the model's axis (X or Y) at x1.
struct Lines(usize);

impl SelectorInput for Lines {
    fn read_lines(&mut self) -> (u8, u8) {
        (1 << self.0, 1)
    }
}

impl FrameSink for Port<'_> {
    fn send(&mut self, frame: Frame) -> Result<(), SinkFull> {
        if self.queue.len() >= self.capacity {
            return Err(SinkFull);
        }
        let mut data = [0; 8];
        data[..frame.data().len()].copy_from_slice(frame.data());
        self.queue.push_back(Wire {
            id: frame.id(),
            data,
            len: frame.data().len() as u8,
            tag: self.tag,
        });
        Ok(())
    }

    fn discard_pending(&mut self) {
        self.queue.clear();
    }
}

/// A node as the firmware makes it at power-on, with `storage` as its parameter page.
fn new_node(storage: MemoryStorage) -> Node<MemoryStorage> {
    let node_id = NodeId::new(NODE).expect("a valid node-ID");
    Node::new(
        HandwheelDevice::new(node_id, 0x5EED, storage),
        BitRate::Kbit1000,
    )
}

/// The model of one [`Bounds`].
#[derive(Clone, Debug)]
pub struct FeedModel {
    /// Its bounds.
    pub bounds: Bounds,
}

impl FeedModel {
    fn budget(&self, b: Budget) -> u8 {
        match b {
            Budget::Turns => self.bounds.turns,
            Budget::Switches => self.bounds.switches,
            Budget::FeedWrites => self.bounds.feed_writes,
            Budget::Nmt => self.bounds.nmt,
            Budget::PowerCycles => self.bounds.power_cycles,
            Budget::Ticks => self.bounds.ticks,
            Budget::ChannelFaults => self.bounds.channel_faults,
            Budget::HostStalls => self.bounds.host_stalls,
            Budget::MasterBeats => self.bounds.master_beats,
            Budget::Configures => self.bounds.configures,
        }
    }

    /// The world after boot and a master's configuration: X selected at x1, event timer,
    /// no inhibit time, no producer heartbeat, Operational, feed enabled, and everything
    /// the device said received by the host.
    pub fn initial(&self) -> World {
        self.initial_with(None)
    }

    /// [`FeedModel::initial`], recording the host's input in `log` if given.
    pub fn initial_with(&self, log: Option<Vec<HostEvent>>) -> World {
        let levels = AbLevels::from_bits(0);
        let real = Real {
            node: new_node(MemoryStorage::new()),
            wheel: LinkedWheel::local(DecoderConfig::default(), levels),
            levels,
        };
        let mut w = World {
            real,
            now_ms: 0,
            era: 0,
            axis: 0,
            transmit: VecDeque::new(),
            delivered: VecDeque::new(),
            host: HostRule::new(self.bounds.rule),
            host_stalled: false,
            host_backlog: VecDeque::new(),
            truth: Truth {
                moves: vec![Vec::new()],
                credited_upto: vec![0],
            },
            used: [0; 10],
            violation: None,
            log,
        };
        // The first round joins the bus and starts the device.
        self.pace(&mut w);
        self.step(&mut w, None);
        self.select(&mut w);
        self.pass_all(&mut w);
        self.configure(&mut w);
        self.pass_all(&mut w);
        // The pace's bucket full again before the exploration starts.
        w.now_ms +=
            u64::from(self.bounds.pace.us_per_number) * u64::from(self.bounds.pace.burst) / 1000;
        self.step(&mut w, None);
        self.pass_all(&mut w);
        self.sdo_write(&mut w, 0x2000, 0, &[1]);
        self.pass_all(&mut w);
        w
    }

    /// The device's pace as the bounds narrow it (at power-on; resets keep it).
    fn pace(&self, w: &mut World) {
        let pace = self.bounds.pace;
        w.real.wheel.lock(|h| h.feed.set_sequence_pace(pace));
    }

    /// The host's configuration (the component's `Configure`): the device's 0x2002 read
    /// (still the host's session: nothing to do), else no producer heartbeat (fewer frames to
    /// interleave), the bounds' event timer and inhibit time, the master's heartbeat watched
    /// when the bounds have beats, 0x2000 = 0, a fresh session token, NMT start. Its frames
    /// reach the device at once; what the device answers goes the way of every frame. The host
    /// takes the session when the device holds it (the component reads it back).
    fn configure(&self, w: &mut World) {
        let device = w.real.wheel.lock(|h| h.feed.session());
        self.log(w, HostEvent::Configure(device, w.now_ms));
        if w.host.session().is_some_and(|own| own == device) {
            w.host.configured(device, None, w.now_ms);
            return;
        }
        let Some(token) = w.host.next_token(w.now_ms, device) else {
            w.host.configured(device, None, w.now_ms);
            return;
        };
        let timer = self.bounds.event_timer_ms.to_le_bytes();
        let inhibit = self.bounds.inhibit_100us.to_le_bytes();
        let cob_id = |flags: u32| (flags | 0x180 | u32::from(NODE)).to_le_bytes();
        let (invalid, valid) = (cob_id(0xC000_0000), cob_id(0x4000_0000));
        for (index, sub, data) in [
            (0x1017u16, 0u8, &[0u8, 0][..]),
            (0x1800, 5, &timer[..]),
            // The inhibit time may change only while the PDO is invalid (CiA 301).
            (0x1800, 1, &invalid[..]),
            (0x1800, 3, &inhibit[..]),
            (0x1800, 1, &valid[..]),
        ] {
            self.sdo_write(w, index, sub, data);
        }
        if self.bounds.master_beats > 0 {
            let entry = ((1u32 << 16) | u32::from(self.bounds.consumer_ms)).to_le_bytes();
            self.sdo_write(w, 0x1016, 1, &entry);
            self.receive(w, 0x701, &[0x05]);
        }
        self.sdo_write(w, 0x2000, 0, &[0]);
        self.sdo_write(w, 0x2002, 0, &[token]);
        let written = w.real.wheel.lock(|h| h.feed.session()) == token;
        w.host
            .configured(device, written.then_some(token), w.now_ms);
        self.nmt(w, Nmt::Start);
    }

    fn log(&self, w: &mut World, event: HostEvent) {
        if let Some(log) = &mut w.log {
            log.push(event);
        }
    }

    /// One round of the node (`Node::poll`, what the firmware's loop calls) at the model's
    /// time, with `frame` received.
    fn step(&self, w: &mut World, frame: Option<Frame>) -> Outputs {
        let mut port = Port {
            rx: frame,
            queue: &mut w.transmit,
            capacity: self.bounds.transmit_capacity,
            tag: Tag {
                era: w.era,
                made_ms: w.now_ms,
            },
        };
        // The model's time stays far below the tick count's wrap.
        let ticks = w.now_ms as u32;
        w.real
            .node
            .poll(ticks, &mut port, &mut Lines(w.axis), &mut w.real.wheel)
    }

    /// The switch is at the model's axis: rounds a millisecond apart until the node's
    /// debouncer takes it (four samples, 5 ms apart). Nothing else happens meanwhile.
    fn select(&self, w: &mut World) {
        for _ in 0..40 {
            if self.step(w, None).log.selection.is_some() {
                return;
            }
            w.now_ms += 1;
        }
        panic!("the debouncer never took the switch position");
    }

    fn receive(&self, w: &mut World, id: u16, data: &[u8]) {
        let frame = Frame::new(id, data).expect("a valid frame");
        self.step(w, Some(frame));
    }

    fn nmt(&self, w: &mut World, command: Nmt) {
        if command == Nmt::ResetNode {
            w.era += 1;
            w.truth.moves.push(Vec::new());
            w.truth.credited_upto.push(0);
        }
        self.receive(w, 0x000, &[command.byte(), NODE]);
    }

    fn sdo_write(&self, w: &mut World, index: u16, sub: u8, value: &[u8]) {
        let cmd = 0x23 | (((4 - value.len()) as u8) << 2);
        let mut data = [cmd, index as u8, (index >> 8) as u8, sub, 0, 0, 0, 0];
        data[4..4 + value.len()].copy_from_slice(value);
        self.receive(w, SDO_RX, &data);
    }

    fn turn(&self, w: &mut World) {
        let before = w.real.wheel.feed().position();
        for _ in 0..4 {
            w.real.levels = w.real.levels.next_forward();
            let _ = w.real.wheel.edge().on_edge(w.real.levels);
        }
        let after = w.real.wheel.feed().position();
        let era = usize::from(w.era);
        for _ in before..after {
            w.truth.moves[era].push((w.axis, w.now_ms));
        }
        self.step(w, None);
    }

    fn power_cycle(&self, w: &mut World) {
        let storage = w.real.node.device_mut().engine().storage().clone();
        w.era += 1;
        w.truth.moves.push(Vec::new());
        w.truth.credited_upto.push(0);
        w.transmit.clear();
        w.real.node = new_node(storage);
        w.real.wheel = LinkedWheel::local(DecoderConfig::default(), w.real.levels);
        self.pace(w);
        self.step(w, None);
        self.select(w);
    }

    fn pass_all(&self, w: &mut World) {
        while !w.transmit.is_empty() {
            self.pass(w, 1);
        }
    }

    /// The bus takes the next frame (a millisecond passes: generously a frame's time); the
    /// host receives it `copies` times.
    fn pass(&self, w: &mut World, copies: usize) {
        let Some(frame) = w.transmit.pop_front() else {
            return;
        };
        w.now_ms += 1;
        if frame.id == TPDO1 {
            w.delivered.push_back((frame.clone(), w.now_ms));
            while w.delivered.len() > usize::from(self.bounds.copy_depth)
                || w.delivered
                    .front()
                    .is_some_and(|(_, at)| at + self.bounds.copy_age_ms < w.now_ms)
            {
                w.delivered.pop_front();
            }
        }
        for _ in 0..copies {
            self.to_host(w, frame.clone());
        }
        // The transmit interrupt wakes the device: what it could not queue goes now.
        self.step(w, None);
    }

    fn to_host(&self, w: &mut World, frame: Wire) {
        if w.host_stalled {
            w.host_backlog.push_back(frame);
            return;
        }
        self.host_handles(w, &frame);
        self.host_drained(w);
    }

    fn host_drained(&self, w: &mut World) {
        w.host.drained(w.now_ms);
        let now = w.now_ms;
        if let Some(log) = &mut w.log {
            log.push(HostEvent::Drained(now));
        }
    }

    fn host_handles(&self, w: &mut World, frame: &Wire) {
        let now = w.now_ms;
        if let Some(log) = &mut w.log {
            log.push(HostEvent::Frame {
                id: frame.id,
                data: frame.data[..usize::from(frame.len)].to_vec(),
                at_ms: now,
            });
        }
        if frame.id == HEARTBEAT && frame.len == 1 {
            w.host.heartbeat(frame.data[0], w.now_ms);
        } else if frame.id == TPDO1 && frame.len == 8 {
            if let Some(credit) = w.host.record(frame.data, frame.tag, w.now_ms) {
                if w.violation.is_none() {
                    w.violation = self.judge(w, &credit).err();
                }
            }
        }
    }

    /// The property for one credit: motion of the credited axis only, forward, counted by the
    /// device in one era, never credited before, and no older than the bound.
    fn judge(&self, w: &mut World, credit: &Credit<Tag>) -> Result<(), String> {
        let (from, from_tag) = &credit.from;
        let (to, to_tag) = &credit.to;
        let axis = ["X", "Y"][credit.axis];
        if from_tag.era != to_tag.era {
            return Err(format!(
                "{axis} credited {} across a reset (era {} -> {})",
                credit.delta, from_tag.era, to_tag.era
            ));
        }
        if credit.delta < 0 {
            return Err(format!("{axis} credited {}: backwards", credit.delta));
        }
        let era = usize::from(to_tag.era);
        if from.position < w.truth.credited_upto[era] {
            return Err(format!(
                "{axis} credited positions {}..{} again (credited up to {})",
                from.position, to.position, w.truth.credited_upto[era]
            ));
        }
        for p in from.position..to.position {
            let Some(&(turned_axis, at)) = w.truth.moves[era].get(p as usize) else {
                return Err(format!("{axis} credited position {}: never turned", p + 1));
            };
            if turned_axis != credit.axis {
                return Err(format!(
                    "{axis} credited a detent turned on {}",
                    ["X", "Y"][turned_axis]
                ));
            }
            if w.now_ms - at > self.bounds.late_ms {
                return Err(format!(
                    "{axis} credited a detent {} ms after it was turned",
                    w.now_ms - at
                ));
            }
        }
        w.truth.credited_upto[era] = to.position;
        Ok(())
    }

    fn warmed(&self, mut w: World, turns: u8) -> World {
        for _ in 0..turns {
            self.turn(&mut w);
            self.pass_all(&mut w);
            // The inhibit time (2 ms) lets the record of the next detent go, and the pace
            // has a number for it.
            w.now_ms += (u64::from(self.bounds.pace.us_per_number) / 1000 + 1).max(2);
        }
        w
    }

    /// An initial state `like` (one of [`Model::init_states`]) made again with the host's
    /// input recorded from power-on.
    pub fn recorded(&self, like: &World) -> World {
        // The warm-up's detents are the only ones of era 0 in an initial state.
        let start = self.initial_with(Some(Vec::new()));
        let warmup = like.truth.moves[0].len() - start.truth.moves[0].len();
        self.warmed(start, warmup as u8)
    }

    fn spend(&self, w: &mut World, b: Budget) -> bool {
        let slot = &mut w.used[b as usize];
        if *slot >= self.budget(b) {
            return false;
        }
        *slot += 1;
        true
    }

    fn left(&self, w: &World, b: Budget) -> bool {
        w.used[b as usize] < self.budget(b)
    }
}

impl Model for FeedModel {
    type State = World;
    type Action = Action;

    fn init_states(&self) -> Vec<World> {
        let start = self.initial();
        if self.bounds.warmups.is_empty() {
            return vec![start];
        }
        self.bounds
            .warmups
            .iter()
            .map(|&turns| self.warmed(start.clone(), turns))
            .collect()
    }

    fn actions(&self, w: &World, actions: &mut Vec<Action>) {
        if w.violation.is_some() {
            return;
        }
        let b = |kind| self.left(w, kind);
        if b(Budget::Turns) {
            actions.push(Action::Turn);
        }
        if b(Budget::Switches) {
            actions.push(Action::SwitchAxis);
        }
        if b(Budget::FeedWrites) {
            actions.extend([Action::Enable, Action::Disable]);
        }
        if b(Budget::Nmt) {
            actions.extend(Nmt::ALL.map(Action::Nmt));
        }
        if b(Budget::PowerCycles) {
            actions.push(Action::PowerCycle);
        }
        if b(Budget::Ticks) {
            actions.push(Action::Tick);
        }
        if !w.transmit.is_empty() {
            actions.push(Action::Pass);
            if b(Budget::ChannelFaults) {
                actions.extend([Action::Lose, Action::Duplicate]);
            }
        }
        if b(Budget::ChannelFaults) {
            let young = w
                .delivered
                .iter()
                .filter(|(_, at)| at + self.bounds.copy_age_ms >= w.now_ms)
                .count();
            actions.extend((1..=young as u8).map(Action::Copy));
        }
        if w.host.configure_due(w.now_ms) && !w.host_stalled && b(Budget::Configures) {
            actions.push(Action::Configure);
        }
        if b(Budget::HostStalls) && !w.host_stalled {
            actions.push(Action::HostStall);
        }
        if w.host_stalled {
            actions.push(Action::HostResume);
        } else if b(Budget::MasterBeats) {
            actions.push(Action::MasterBeat);
        }
    }

    fn next_state(&self, last: &World, action: Action) -> Option<World> {
        let mut w = last.clone();
        let ok = match action {
            Action::Turn => self.spend(&mut w, Budget::Turns),
            Action::SwitchAxis => self.spend(&mut w, Budget::Switches),
            Action::Enable | Action::Disable => self.spend(&mut w, Budget::FeedWrites),
            Action::Nmt(_) => self.spend(&mut w, Budget::Nmt),
            Action::PowerCycle => self.spend(&mut w, Budget::PowerCycles),
            Action::Tick => self.spend(&mut w, Budget::Ticks),
            Action::Lose | Action::Duplicate | Action::Copy(_) => {
                self.spend(&mut w, Budget::ChannelFaults)
            }
            Action::Configure => self.spend(&mut w, Budget::Configures),
            Action::HostStall => self.spend(&mut w, Budget::HostStalls),
            Action::MasterBeat => self.spend(&mut w, Budget::MasterBeats),
            Action::Pass | Action::HostResume => true,
        };
        if !ok {
            return None;
        }
        match action {
            Action::Turn => self.turn(&mut w),
            Action::SwitchAxis => {
                w.axis = (w.axis + 1) % AXES;
                self.select(&mut w);
            }
            Action::Enable => self.sdo_write(&mut w, 0x2000, 0, &[1]),
            Action::Disable => self.sdo_write(&mut w, 0x2000, 0, &[0]),
            Action::Nmt(command) => self.nmt(&mut w, command),
            Action::PowerCycle => self.power_cycle(&mut w),
            Action::Tick => {
                w.now_ms += self.bounds.tick_ms;
                self.step(&mut w, None);
            }
            Action::Pass => self.pass(&mut w, 1),
            Action::Duplicate => self.pass(&mut w, 2),
            Action::Lose => {
                w.transmit.pop_front();
                w.now_ms += 1;
                self.step(&mut w, None);
            }
            Action::Copy(back) => {
                let index = w.delivered.len() - usize::from(back);
                let frame = w.delivered[index].0.clone();
                self.to_host(&mut w, frame);
            }
            Action::Configure => self.configure(&mut w),
            Action::HostStall => w.host_stalled = true,
            Action::MasterBeat => self.receive(&mut w, 0x701, &[0x05]),
            Action::HostResume => {
                w.host_stalled = false;
                while let Some(frame) = w.host_backlog.pop_front() {
                    self.host_handles(&mut w, &frame);
                }
                self.host_drained(&mut w);
            }
        }
        Some(w)
    }

    fn properties(&self) -> Vec<Property<Self>> {
        vec![Property::always(
            "every credit is motion of that axis, forward, once, in time",
            |_, w: &World| w.violation.is_none(),
        )]
    }
}
