//! The model: the real device as the firmware runs it (`Node::poll`, the step function, over
//! `HandwheelDevice` with its engine, accumulator and outbox), the transmit path in front of
//! the bus (a FIFO software queue feeding mailboxes that bxCAN empties by identifier), a
//! channel that passes, loses and duplicates frames and delivers copies of any earlier feed
//! record up to the contract's age, the host's rule ([`HostRule`], with the sessions it opens)
//! and the truth ([`crate::truth`]): what the stimulus turned on each axis while the device had
//! the feed enabled.
//!
//! Every action is one thing the outside world can do: the operator turns (forward or back,
//! between two rounds of the device or landing inside one, at a chosen access of the CAN side
//! to the wheel, a lock or an intake of motion), moves the axis or the multiplier switch; a master sends NMT or writes
//! 0x2000; the device loses power; time passes; the bus takes a frame (or the channel loses
//! or doubles it, or delivers a copy of an earlier record); the host configures (when its rule
//! asks), stalls or resumes; the master's heartbeat comes; or time settles (half a second without faults, so that motion
//! owed to the host must have come); a path between the bus and the host holds what the bus
//! takes, or releases it. Where the host's rule dates records, it probes the device's
//! sequence (0x2033) whenever its rule asks, after every action. Not taking a frame is the bus being held. The property
//! is checked in every state the actions reach, within the budgets of a [`Bounds`].
//!
//! What the device must do besides (README "What the device promises") is judged against the
//! model's own view of it, [`Spec`]: the feed enabled only by a 0x2000 write accepted in
//! Operational with the master present and the transmit path drained since it was last
//! blocked, and off once the device left Operational, lost the master's heartbeat for its
//! consumer time, changed or ended its session, or had frames wait 100 ms without the path
//! running empty; the session the token written last (0 after a reset, a write of anything it
//! stands for, or the pace); nothing made before a reset reaching the bus after it; and every
//! detent taken in under what it counted for when it came (the feed off, or the axis and
//! multiplier: motion before a change belongs to the old state).

use std::collections::VecDeque;
use std::fmt::{self, Write as _};
use std::hash::{Hash, Hasher};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use canopen_slave::{BusState, Frame, FrameSink, MemoryStorage, NodeId, SinkFull};
use handwheel_core::outbox::PaceMutant;
use handwheel_core::{
    AbLevels, Axis, BitRate, DecoderConfig, EdgeState, FeedAccumulator, Handwheel, Intake,
    LinkedWheel, Multiplier, Mutex, SelectorInput, SequencePace, Wheel,
};
use handwheel_device::mutant::Mutant;
use handwheel_device::od::SESSION_DELAY_MS;
use handwheel_device::{CanIo, HandwheelDevice, Node, Outputs, TransmitState, TRANSMIT_STALL_MS};
use stateright::{Model, Property};

use crate::host::{Credit, HostRule, RuleConfig, AXES, SESSION_KEY};
use crate::truth::{AxisTruth, Detent, Miss};

/// The device's node-ID in the model.
pub const NODE: u8 = 16;
const TPDO1: u16 = 0x180 + NODE as u16;
const HEARTBEAT: u16 = 0x700 + NODE as u16;
const SDO_RX: u16 = 0x600 + NODE as u16;
const SDO_TX: u16 = 0x580 + NODE as u16;
/// An expedited upload's answer with four bytes (the probe's answer).
const PROBE_ANSWER: u8 = 0x43;
/// The master's node-ID, whose heartbeat the device watches in settings with master beats.
const MASTER: u16 = 1;
/// Axis letters for messages.
const LETTERS: [&str; AXES] = ["X", "Y"];
/// The multiplier switch's positions.
const FACTORS: [i32; 3] = [1, 10, 100];
/// Time steps of [`Action::Settle`], ms: the master's heartbeat comes at least this often.
const SETTLE_STEP_MS: u64 = 50;
/// Rounds the model runs back to back while the node asks for no sleep at all (a feed
/// record made due at the end of a round goes out in the next one, at once) or a detent
/// waits to be taken in.
const BACK_TO_BACK: usize = 4;

/// Explore on past breaches (`feed-check --through`): for measuring how large a setting that
/// breaches on today's code will be once it passes.
pub static THROUGH_BREACHES: AtomicBool = AtomicBool::new(false);

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

/// An object another master writes while the host holds a session ([`Action::ForeignWrite`]):
/// each one the session stands for, so the write ends it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Foreign {
    /// 0x1016:2, a heartbeat consumer entry for another node (2, the consumer time of the
    /// bounds): which heartbeats the device watches.
    Consumer,
    /// 0x1800:5, TPDO1's event timer, with the value the host wrote.
    EventTimer,
    /// 0x2020:4 = 1, the encoder's direction inverted: a session that survived it would
    /// credit every detent with the wrong sign.
    Invert,
    /// 0x2020:3 = 2, counts per detent: a session that survived it would credit the wrong
    /// amount.
    CountsPerDetent,
}

impl Foreign {
    /// Every object.
    pub const ALL: [Self; 4] = [
        Self::Consumer,
        Self::EventTimer,
        Self::Invert,
        Self::CountsPerDetent,
    ];
}

/// One thing the world does.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Action {
    /// The operator turns one detent forward; the edge wakes the device for a round.
    Turn,
    /// One detent backward.
    TurnBack,
    /// One detent forward that lands while the device runs the next action's round(s): at
    /// the CAN side's `n`-th access to the wheel (1 = before the first).
    TurnAt(u8),
    /// One detent backward, landing like [`Action::TurnAt`].
    TurnBackAt(u8),
    /// The operator moves the axis switch to the other axis (X <-> Y).
    SwitchAxis,
    /// The operator moves the multiplier switch on (x1 -> x10 -> x100 -> x1).
    SwitchMultiplier,
    /// A master writes 0x2000 = 1 (without waiting for the answer).
    Enable,
    /// A master writes 0x2000 = 0.
    Disable,
    /// Another master writes 0x2002 with the host's session token (the 3-bit token is not
    /// unique to a master): through the device's SDO server, as [`Action::Enable`] writes
    /// 0x2000. Only while the host holds a session.
    WriteToken,
    /// Another master writes an object the host's session stands for, through the device's
    /// SDO server. Only while the host holds a session.
    ForeignWrite(Foreign),
    /// A master (any node) sends an NMT command.
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
    /// (1 = the newest; any record it received within the contract's copy age,
    /// [`Bounds::copy_age_ms`]).
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
    /// A path between the bus and the host (a gateway) starts holding what the bus takes:
    /// from now on the device's frames, and the answers to the host's probes, wait there in
    /// order; the host's receive path stays empty (its backlog rule sees nothing).
    Hold,
    /// The holding path delivers what it holds to the host at once, in order, now.
    Release,
    /// Time passes until every detent owed to the host is older than the bound, the bus
    /// taking every frame, no fault, the master alive: what is owed must have come.
    Settle,
}

/// A warm-up step: what happens, with every frame taken by the bus and received, before the
/// exploration starts.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Warm {
    /// Detents forward, each with its record (2 ms apart: the inhibit time).
    Turns(u8),
    /// Detents backward.
    Backs(u8),
    /// The axis switch moved.
    Switch,
    /// The multiplier switch moved.
    Multiplier,
    /// Detents forward whose records wait in the transmit path: the bus takes nothing.
    Held(u8),
}

/// What one exploration may do: how often each kind of action, and the settings.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Bounds {
    /// A name for the report.
    pub name: &'static str,
    /// The host's rule and its widths.
    pub rule: RuleConfig,
    /// Frames the transmit path holds: the software queue and the mailboxes (16 + 3 on the
    /// board).
    pub transmit_capacity: usize,
    /// How many of them are mailboxes (3 on bxCAN), which the bus empties lowest identifier
    /// first; 0: one FIFO whose head is on the bus (a controller that sends in queue order).
    pub mailboxes: usize,
    /// Detents turned between rounds at most.
    pub turns: u8,
    /// Detents may be turned backward too.
    pub backward: bool,
    /// Detents landing inside a round at most.
    pub inner_turns: u8,
    /// The last access to the wheel such a detent may land at.
    pub inner_locks: u8,
    /// Axis switch moves at most.
    pub switches: u8,
    /// Multiplier switch moves at most.
    pub multipliers: u8,
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
    /// Frames lost or duplicated and copies of earlier feed records delivered, at most.
    pub channel_faults: u8,
    /// How far back a copy may reach, in feed records delivered (bounds the state; the age
    /// limit below is the contract's).
    pub copy_depth: u8,
    /// The contract's age of copies (model ms): a record delivered longer ago is never copied.
    pub copy_age_ms: u64,
    /// The device's pace (narrowed with the sequence the host sees).
    pub pace: SequencePace,
    /// Configurations by the host (after the first) at most.
    pub configures: u8,
    /// Host stalls at most.
    pub host_stalls: u8,
    /// Master heartbeats at most; with any, the device watches the master (0x1016:1, node 1,
    /// [`Bounds::consumer_ms`]).
    pub master_beats: u8,
    /// The device's heartbeat consumer time for the master, ms.
    pub consumer_ms: u16,
    /// The bound the property sets on lateness: nothing is credited later than this after
    /// it was turned, and what is owed is credited by then.
    pub late_ms: u64,
    /// [`Action::Settle`] at most.
    pub settles: u8,
    /// [`Action::Hold`]s of the path between the bus and the host at most.
    pub holds: u8,
    /// [`Action::WriteToken`]s (another master writing the host's token) at most.
    pub token_writes: u8,
    /// [`Action::ForeignWrite`]s at most, and which objects they may write (none: every one
    /// of [`Foreign::ALL`]).
    pub foreign_writes: u8,
    /// The objects of [`Action::ForeignWrite`]; empty: all.
    pub foreign: &'static [Foreign],
    /// What happens before the exploration starts, one initial state for each: where the
    /// sequence, the epoch and the history of copies stand when the trouble begins.
    pub warmups: &'static [&'static [Warm]],
    /// The device bug to run ([`Mutant`]), for the mutation tests; `None`: the real code.
    pub mutant: Option<Mutant>,
}

/// Where a frame came from, which the host cannot see.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Tag {
    /// When the device made the frame.
    pub made_ms: u64,
    /// Resets and power cycles before it was made.
    pub boot: u8,
    /// Made before something after which records may be missing (and so not what tells
    /// that the host is back in step).
    pub stale: bool,
    /// A copy delivered by the channel, not the device's frame.
    pub copy: bool,
}

#[derive(Clone, Debug, PartialEq, Eq, Hash)]
struct Wire {
    id: u16,
    data: [u8; 8],
    len: u8,
    tag: Tag,
}

/// The transmit path: a FIFO software queue in front of the mailboxes. A frame moves from the
/// queue's head into a mailbox only while it outranks (has a lower identifier than) every
/// frame pending there (so each identifier's frames stay in order); with every mailbox full
/// it displaces the lowest-ranked one back to the queue's head. The bus takes the
/// highest-ranked mailbox. (`src/can/port.rs` over `bxcan::Can::transmit`.)
#[derive(Clone, Debug, Default, PartialEq, Eq, Hash)]
struct Path {
    queue: VecDeque<Wire>,
    boxes: Vec<Wire>,
    /// Times the path moved (a frame into a mailbox or onto the bus), wrapping: what the
    /// stall watch counted before its fix (the stall-completions mutant still does).
    completed: u32,
    /// The bus took the last waiting frame since the device last looked.
    ran_empty: bool,
}

impl Path {
    fn waiting(&self) -> bool {
        !self.queue.is_empty() || !self.boxes.is_empty()
    }

    fn pump(&mut self, mailboxes: usize) {
        while let Some(front) = self.queue.front() {
            if mailboxes == 0 || self.boxes.iter().any(|b| b.id <= front.id) {
                return;
            }
            let Some(next) = self.queue.pop_front() else {
                return;
            };
            if self.boxes.len() == mailboxes {
                let lowest = (0..self.boxes.len())
                    .max_by_key(|&i| self.boxes[i].id)
                    .expect("mailboxes are full");
                let displaced = self.boxes.swap_remove(lowest);
                self.queue.push_front(displaced);
            }
            self.boxes.push(next);
            self.completed = self.completed.wrapping_add(1);
        }
    }

    /// The frame the bus takes next.
    fn next(&self) -> Option<&Wire> {
        if self.boxes.is_empty() {
            self.queue.front()
        } else {
            self.boxes.iter().min_by_key(|w| w.id)
        }
    }

    /// The bus takes the next frame.
    fn take(&mut self, mailboxes: usize) -> Option<Wire> {
        let taken = if mailboxes == 0 {
            self.queue.pop_front()
        } else {
            let i = (0..self.boxes.len()).min_by_key(|&i| self.boxes[i].id)?;
            Some(self.boxes.remove(i))
        };
        self.completed = self.completed.wrapping_add(1);
        self.pump(mailboxes);
        self.ran_empty |= !self.waiting();
        taken
    }

    fn clear(&mut self) {
        self.queue.clear();
        self.boxes.clear();
        self.ran_empty = true;
    }
}

/// The node and its wheel: real code, hashed as their types derive `Hash` (the firmware's
/// types derive it for the checker: a state's hash is most of the checker's time) and
/// compared through their `Debug` form.
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

/// Hashed as the firmware's types derive it (every field), which tells apart whatever their
/// `Debug` does.
impl Hash for Real {
    fn hash<H: Hasher>(&self, state: &mut H) {
        self.node.hash(state);
        self.wheel.hash(state);
        self.levels.hash(state);
    }
}

impl fmt::Debug for Real {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("device")
    }
}

/// The model's own view of what the device must be doing, from what the world did to it
/// (never from its state): the checks of README "What the device promises", and which
/// records went missing.
#[derive(Clone, Debug, Default, PartialEq, Eq, Hash)]
pub struct Spec {
    /// The device is Operational (NMT commands, resets and power cycles it was given).
    operational: bool,
    /// The feed may be enabled: a 0x2000 = 1 was accepted and nothing stopped it since.
    enabled: bool,
    /// Resets of the node or communication and power cycles so far.
    boot: u8,
    /// When the device last powered up (ms): no session opens for `SESSION_DELAY_MS`.
    powered_ms: u64,
    /// The master's session (0x2002) the device must be in: the token last written, 0 after
    /// a reset or a write of anything the session stands for.
    session: u8,
    /// The device watches the master's heartbeat (0x1016 written since its last reset).
    watching: bool,
    /// The master's last heartbeat the device took, ms.
    last_beat: Option<u64>,
    /// The master counts as lost (its heartbeat missed the consumer time).
    master_lost: bool,
    /// Since when frames wait for the bus, the path not empty once (the device's stall watch
    /// counts from there).
    stall_since: Option<u64>,
    /// The path was found blocked and has not run empty since: 0x2000 = 1 is refused.
    transmit_blocked: bool,
    /// The host received a record the device made since the last of those: detents turned
    /// now are owed.
    synced: bool,
    /// The device's pace as the model keeps it from the numbers the device took and the
    /// times it refilled at ([`Bounds::pace`]): a number beyond it must end the session
    /// within the round.
    pace: PaceSpec,
    /// Another master put the device in the host's session ([`Action::WriteToken`]) since
    /// the host last wrote it: the records of that session are not the host's to be in step
    /// with (nothing is owed until the host configures again).
    foreign: bool,
}

/// The pace's bucket (README "Feed record"): `burst` numbers at once, one more per period,
/// a number taken from the empty bucket overdraws it.
#[derive(Clone, Debug, Default, PartialEq, Eq, Hash)]
struct PaceSpec {
    allowance: u16,
    refilled_us: u64,
    overdrawn: bool,
}

impl PaceSpec {
    fn full(pace: SequencePace) -> Self {
        Self {
            allowance: pace.burst,
            refilled_us: 0,
            overdrawn: false,
        }
    }

    /// The device took `numbers` from the bucket: beyond what it holds overdraws it.
    fn take(&mut self, numbers: u16) {
        self.overdrawn |= numbers > self.allowance;
        self.allowance = self.allowance.saturating_sub(numbers);
    }

    /// The device refilled at `now_us`: one number per whole period since the bucket was
    /// last refilled up to, up to the burst; a full bucket is refilled up to now. (Again at
    /// the same time, with numbers taken in between, it adds nothing.)
    fn refill(&mut self, pace: SequencePace, now_us: u64) {
        let period = u64::from(pace.us_per_number);
        let due = now_us.saturating_sub(self.refilled_us) / period;
        let room = pace.burst.saturating_sub(self.allowance);
        let credit = due.min(u64::from(room)) as u16;
        self.allowance += credit;
        self.refilled_us += u64::from(credit) * period;
        if self.allowance >= pace.burst {
            self.refilled_us = self.refilled_us.max(now_us);
        }
    }

    /// A round that took `before` numbers, refilled at `refilled_us` (if it did), then took
    /// `after`. The device refills at every service of the round (`tick`), all at the
    /// round's time: only the first refill of a round adds numbers, and the numbers taken
    /// before it (a received frame's, ahead of its service) come from the bucket as the
    /// last round left it.
    fn round(&mut self, pace: SequencePace, before: u16, refilled_us: Option<u64>, after: u16) {
        self.take(before);
        if let Some(now_us) = refilled_us {
            self.refill(pace, now_us);
        }
        self.take(after);
    }
}

/// One state of the world.
#[derive(Clone, Debug, PartialEq, Hash)]
pub struct World {
    real: Real,
    now_ms: u64,
    axis: usize,
    multiplier: usize,
    /// Frames the device handed out that the bus has not taken.
    transmit: Path,
    /// Feed records the host received from the bus and when (ms), oldest first, for copies
    /// (as far back as the bounds' copy age and depth, while copies are left in the budget).
    delivered: VecDeque<(Wire, u64)>,
    host: HostRule<Tag>,
    host_stalled: bool,
    host_backlog: VecDeque<Wire>,
    /// What the path between the bus and the host holds, in order, while it holds
    /// ([`Action::Hold`]); `None`: it passes everything at once.
    gateway: Option<VecDeque<Wire>>,
    truth: [AxisTruth; AXES],
    spec: Spec,
    /// A detent that lands at this access to the wheel during the next action's rounds
    /// (backward?, access).
    pending: Option<(bool, u8)>,
    /// Detents in the edge state that no intake of the device took in yet (backward?, what
    /// they counted for when they came), in turning order; none once an action is over.
    untaken: Vec<(bool, CountsFor)>,
    /// Accesses to the wheel so far in this action.
    locks: u8,
    /// The object (index, value) of the SDO write this action makes, until the device
    /// answers it.
    writing: Option<(u16, u32)>,
    /// The host's probe write is under way: the device's answer to it is kept here instead
    /// of going to the bus (`Some(None)` until it answers).
    probe_answer: Option<Option<[u8; 8]>>,
    used: [u8; 16],
    /// Which warm-up this state started from.
    warmup: u8,
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
    /// The host configured the device, whose 0x2002 read this, at a time (ms), and read its
    /// uptime (0x2035, ms) if its rule needed it to pick a token; `true`: the device refused
    /// the token it wrote (too young for a session).
    Configure(u8, u64, Option<u32>, bool),
    /// The host sent a sequence probe (0x2033 = key and nonce, then read back) at a time
    /// (ms): the value written and the floor its rule gave.
    Probe {
        /// Written to 0x2033: the session key in bits 16-31, the nonce in bits 0-12.
        nonce: u32,
        /// The newest record number of the session the host had received.
        floor: Option<u64>,
        /// When, ms.
        at_ms: u64,
    },
    /// The answer to the host's probe (0x2033 as read) reached it at a time (ms).
    Probed {
        /// 0x2033.
        value: u32,
        /// When, ms.
        at_ms: u64,
    },
    /// The device refused the probe's write (abort 0x08000022), the abort reaching the host
    /// at a time (ms).
    ProbeRefused {
        /// When, ms.
        at_ms: u64,
    },
    /// The device did not answer the probe (no SDO in its state): the host's request timed
    /// out, at a time (ms).
    Unanswered {
        /// When, ms.
        at_ms: u64,
    },
}

impl World {
    /// The host's counts per axis (X, Y).
    pub fn host_counts(&self) -> [i32; AXES] {
        self.host.counts
    }

    /// Which of the bounds' warm-ups this state started from.
    pub fn warmup(&self) -> usize {
        usize::from(self.warmup)
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
    InnerTurns,
    Switches,
    Multipliers,
    FeedWrites,
    Nmt,
    PowerCycles,
    Ticks,
    ChannelFaults,
    HostStalls,
    MasterBeats,
    Settles,
    Configures,
    Holds,
    TokenWrites,
    ForeignWrites,
}

/// The CAN port of one round: at most one received frame, the transmit path, a controller
/// that is always on the bus and error-active.
struct Port<'a> {
    rx: Option<Frame>,
    path: &'a mut Path,
    capacity: usize,
    mailboxes: usize,
    tag: Tag,
    spec: &'a mut Spec,
    now_ms: u64,
    writing: &'a mut Option<(u16, u32)>,
    probe_answer: &'a mut Option<Option<[u8; 8]>>,
    /// The path counts as blocked now (the device stops the feed and discards what waits).
    stalled: bool,
    /// The device took 0x2000 = 1 although it must not have: why.
    wrongly_enabled: Option<&'static str>,
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

    /// The device looks once per round; the model's own stall watch looks at the same time
    /// (before the device may discard what waits).
    fn transmit_state(&mut self) -> TransmitState {
        let state = TransmitState {
            waiting: self.path.waiting(),
            ran_empty: std::mem::take(&mut self.path.ran_empty),
        };
        let spec = &mut *self.spec;
        if !state.waiting || state.ran_empty {
            spec.stall_since = None;
            spec.transmit_blocked = false;
        }
        if state.waiting {
            let since = *spec.stall_since.get_or_insert(self.now_ms);
            if !spec.transmit_blocked && self.now_ms >= since + TRANSMIT_STALL_MS {
                spec.transmit_blocked = true;
                spec.enabled = false;
                self.stalled = true;
            }
        }
        state
    }

    fn switch_bit_rate(&mut self, _: BitRate) -> bool {
        true
    }
    fn frame_acknowledged(&mut self) -> bool {
        true
    }
}

impl Port<'_> {
    /// What a write the device took does to the feed (README "What the device promises"):
    /// 0x2000 enables (only in Operational with the master present) or disables it; a new
    /// token in 0x2002 opens that session with the feed off; a write of anything else the
    /// session stands for ends it, and the feed with it.
    fn written(&mut self, index: u16, value: u32) {
        let spec = &mut *self.spec;
        match index {
            0x2000 => {
                let enable = value == 1;
                if enable && !spec.operational {
                    self.wrongly_enabled = Some("not Operational");
                } else if enable && spec.master_lost {
                    self.wrongly_enabled = Some("the master is lost");
                } else if enable && spec.transmit_blocked {
                    self.wrongly_enabled =
                        Some("its transmit path has not drained since it was blocked");
                }
                spec.enabled = enable;
            }
            0x2002 => {
                let token = (value & 0b111) as u8;
                if token != spec.session {
                    spec.session = token;
                    spec.enabled = false;
                }
            }
            0x1003 | 0x1010 | 0x1011 | 0x2033 | 0x2034 => {}
            _ => {
                // 0x1016 naming the master: its heartbeat is watched from now on.
                spec.watching |= index == 0x1016 && (value >> 16) & 0xFF == u32::from(MASTER);
                if spec.session != 0 {
                    spec.session = 0;
                    spec.enabled = false;
                }
            }
        }
    }
}

impl FrameSink for Port<'_> {
    fn send(&mut self, frame: Frame) -> Result<(), SinkFull> {
        // The device's answer to the write: it took it, now (later in this round a stop may
        // end its effect again).
        if frame.id() == SDO_TX && frame.data().first() == Some(&0x60) {
            let index = u16::from_le_bytes([frame.data()[1], frame.data()[2]]);
            if let Some((_, value)) = self.writing.take_if(|(i, _)| *i == index) {
                self.written(index, value);
            }
        }
        if frame.id() == SDO_TX {
            if let Some(answer @ None) = self.probe_answer {
                let mut data = [0; 8];
                data[..frame.data().len()].copy_from_slice(frame.data());
                *answer = Some(data);
                return Ok(());
            }
        }
        if self.path.queue.len() >= self.capacity - self.mailboxes {
            return Err(SinkFull);
        }
        let mut data = [0; 8];
        data[..frame.data().len()].copy_from_slice(frame.data());
        self.path.queue.push_back(Wire {
            id: frame.id(),
            data,
            len: frame.data().len() as u8,
            tag: self.tag,
        });
        self.path.pump(self.mailboxes);
        Ok(())
    }

    fn discard_pending(&mut self) {
        self.path.clear();
    }
}

/// The switch lines: the model's axis (X or Y) and multiplier.
struct Lines(usize, usize);

impl SelectorInput for Lines {
    fn read_lines(&mut self) -> (u8, u8) {
        (1 << self.0, 1 << self.1)
    }
}

/// What a detent counts for in the device's accumulator: the axis and multiplier while the
/// feed is enabled, nothing otherwise.
type CountsFor = Option<(Option<Axis>, Multiplier)>;

fn counts_for(feed: &FeedAccumulator) -> CountsFor {
    feed.enabled().then(|| {
        let s = feed.selection();
        (s.axis, s.multiplier)
    })
}

/// The CAN side's wheel for one action's rounds: a detent may land at a chosen access (a lock
/// or an intake of motion), and counts as taken in by the next intake.
///
/// The device must take a detent in under what it counted for when it came: motion before a
/// change of enable or selection belongs to the old state (`handwheel_core::wheel`). An intake
/// before a change and the change's lock count as one access: an edge between the two (a
/// few instructions on the MCU) is the one order the model leaves out.
struct ModelWheel<'a> {
    inner: &'a mut LinkedWheel<EdgeState>,
    levels: &'a mut AbLevels,
    pending: &'a mut Option<(bool, u8)>,
    locks: &'a mut u8,
    untaken: &'a mut Vec<(bool, CountsFor)>,
    /// The last access was an intake before a change: the change's lock is the same access.
    changing: bool,
    /// The detents the device took in, backward?, and whether its feed was enabled then.
    taken: Vec<(bool, bool)>,
    /// A detent taken in under something else than it counted for when it came.
    misplaced: Option<(CountsFor, CountsFor)>,
}

/// One detent's four edges.
fn detent(wheel: &mut LinkedWheel<EdgeState>, levels: &mut AbLevels, back: bool) {
    for _ in 0..4 {
        *levels = if back {
            levels.next_reverse()
        } else {
            levels.next_forward()
        };
        let _ = wheel.edge().on_edge(*levels);
    }
}

impl ModelWheel<'_> {
    /// An access of the CAN side to the wheel: the pending detent lands right before it if
    /// this is its access.
    fn access(&mut self) {
        *self.locks = self.locks.saturating_add(1);
        if let Some((back, at)) = *self.pending {
            if at == *self.locks {
                *self.pending = None;
                detent(self.inner, self.levels, back);
                self.untaken.push((back, counts_for(self.inner.feed())));
            }
        }
    }
}

impl Mutex for ModelWheel<'_> {
    type T = Handwheel;

    fn lock<R>(&mut self, f: impl FnOnce(&mut Handwheel) -> R) -> R {
        if !std::mem::take(&mut self.changing) {
            self.access();
        }
        self.inner.lock(f)
    }
}

impl Wheel for ModelWheel<'_> {
    fn take_motion(&mut self, at: Intake) {
        self.access();
        self.changing = at == Intake::BeforeChange;
        self.inner.take_motion(at);
        // The detents waiting are taken in now: feed if the device has the feed enabled.
        let now = counts_for(self.inner.feed());
        for (back, then) in self.untaken.drain(..) {
            if then != now {
                self.misplaced.get_or_insert((then, now));
            }
            self.taken.push((back, now.is_some()));
        }
    }
}

/// A node as the firmware makes it at power-on, with `storage` as its parameter page.
fn new_node(storage: MemoryStorage, mutant: Option<Mutant>) -> Node<MemoryStorage> {
    let node_id = NodeId::new(NODE).expect("a valid node-ID");
    let mut node = Node::new(
        HandwheelDevice::new(node_id, 0x5EED, storage),
        BitRate::Kbit1000,
    );
    node.device_mut().set_mutant(mutant);
    node
}

/// The model of one [`Bounds`].
#[derive(Clone, Debug)]
pub struct FeedModel {
    /// Its bounds.
    pub bounds: Bounds,
    /// No state is explored further after this (the run's time cap, [`crate::run::Caps`]):
    /// what is pending drains at once.
    pub deadline: Option<Instant>,
}

impl FeedModel {
    /// The model of `bounds`, explored without a time cap.
    pub const fn new(bounds: Bounds) -> Self {
        Self {
            bounds,
            deadline: None,
        }
    }

    fn budget(&self, b: Budget) -> u8 {
        let bounds = &self.bounds;
        match b {
            Budget::Turns => bounds.turns,
            Budget::InnerTurns => bounds.inner_turns,
            Budget::Switches => bounds.switches,
            Budget::Multipliers => bounds.multipliers,
            Budget::FeedWrites => bounds.feed_writes,
            Budget::Nmt => bounds.nmt,
            Budget::PowerCycles => bounds.power_cycles,
            Budget::Ticks => bounds.ticks,
            Budget::ChannelFaults => bounds.channel_faults,
            Budget::HostStalls => bounds.host_stalls,
            Budget::MasterBeats => bounds.master_beats,
            Budget::Settles => bounds.settles,
            Budget::Configures => bounds.configures,
            Budget::Holds => bounds.holds,
            Budget::TokenWrites => bounds.token_writes,
            Budget::ForeignWrites => bounds.foreign_writes,
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
            node: new_node(MemoryStorage::new(), self.bounds.mutant),
            wheel: LinkedWheel::local(DecoderConfig::default(), levels),
            levels,
        };
        let mut w = World {
            real,
            now_ms: 0,
            axis: 0,
            multiplier: 0,
            transmit: Path::default(),
            delivered: VecDeque::new(),
            host: HostRule::new(self.bounds.rule),
            host_stalled: false,
            host_backlog: VecDeque::new(),
            gateway: None,
            truth: Default::default(),
            spec: Spec::default(),
            pending: None,
            untaken: Vec::new(),
            locks: 0,
            writing: None,
            probe_answer: None,
            used: [0; 16],
            warmup: 0,
            violation: None,
            log,
        };
        // The first round joins the bus and starts the device.
        self.pace(&mut w);
        self.step(&mut w, None);
        self.select(&mut w);
        self.pass_all(&mut w);
        // A session opens only once the device is old enough.
        w.now_ms += SESSION_DELAY_MS;
        self.step(&mut w, None);
        self.pass_all(&mut w);
        self.configure(&mut w);
        self.pass_all(&mut w);
        // The pace's bucket full again before the exploration starts.
        w.now_ms +=
            u64::from(self.bounds.pace.us_per_number) * u64::from(self.bounds.pace.burst) / 1000;
        self.step(&mut w, None);
        self.pass_all(&mut w);
        self.feed_write(&mut w, true);
        self.pass_all(&mut w);
        self.probe_if_due(&mut w);
        assert!(w.spec.enabled, "the initial enable was refused");
        w.locks = 0;
        w
    }

    /// The device's pace as the bounds narrow it (at power-on; resets keep it).
    fn pace(&self, w: &mut World) {
        let pace = self.bounds.pace;
        w.real.wheel.lock(|h| h.feed.set_sequence_pace(pace));
        w.spec.pace = PaceSpec::full(pace);
        let mutant = match self.bounds.mutant {
            Some(Mutant::PaceBurstPlusOne) => Some(PaceMutant::BurstPlusOne),
            Some(Mutant::PaceRefillEarly) => Some(PaceMutant::RefillEarly),
            Some(Mutant::PaceNotEnforced) => Some(PaceMutant::NotEnforced),
            _ => None,
        };
        w.real.wheel.lock(|h| h.feed.mutant_set_pace(mutant));
    }

    /// The host's configuration (the component's `Configure`): the device's 0x2002 read
    /// (still the host's session: nothing to do), else no producer heartbeat (fewer frames to
    /// interleave; the boot-up still goes out), the bounds' event timer and inhibit time, the
    /// master's heartbeat watched when the bounds have beats, 0x2000 = 0, a fresh session
    /// token, NMT start. Its frames reach the device at once; what the device answers goes the
    /// way of every frame. The host takes the session when the device holds it (the component
    /// reads it back).
    fn configure(&self, w: &mut World) {
        let device = w.real.wheel.lock(|h| h.feed.session());
        let own = w.host.session().is_some_and(|own| own == device);
        // The device's uptime through its SDO server, when only a token the host used less
        // than the copy age ago is left (the reads before and after the session is written
        // see the same: no time passes within the configuration).
        let uptime = (!own && w.host.needs_uptime(w.now_ms, device))
            .then(|| self.sdo_read_u32(w, 0x2035, 0))
            .flatten();
        let logged = w.log.as_ref().map_or(0, Vec::len);
        self.log(w, HostEvent::Configure(device, w.now_ms, uptime, false));
        if own {
            w.host.configured(device, None, w.now_ms);
            return;
        }
        let Some(token) = w.host.next_token(w.now_ms, device, uptime) else {
            w.host.configured(device, None, w.now_ms);
            if uptime.is_some() {
                // Not proven: the host waits for a free token.
                w.host.unproven(w.now_ms);
            }
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
            let entry =
                ((u32::from(MASTER) << 16) | u32::from(self.bounds.consumer_ms)).to_le_bytes();
            self.sdo_write(w, 0x1016, 1, &entry);
            self.master_beat(w);
        }
        self.sdo_write(w, 0x2000, 0, &[0]);
        self.sdo_write(w, 0x2002, 0, &[token]);
        self.sdo_write(w, 0x2034, 0, &SESSION_KEY.to_le_bytes());
        w.spec.foreign = false;
        let written = w
            .real
            .wheel
            .lock(|h| (h.feed.session(), h.feed.session_key()))
            == (token, SESSION_KEY);
        let young = w.now_ms < w.spec.powered_ms + SESSION_DELAY_MS;
        if let Some(HostEvent::Configure(.., refused)) =
            w.log.as_mut().and_then(|log| log.get_mut(logged))
        {
            *refused = !written && young;
        }
        w.host
            .configured(device, written.then_some(token), w.now_ms);
        if !written && young {
            // The device refused the token: asked again a little later.
            w.host.young(w.now_ms);
        }
        self.nmt(w, Nmt::Start);
    }

    fn log(&self, w: &mut World, event: HostEvent) {
        if let Some(log) = &mut w.log {
            log.push(event);
        }
    }

    /// One round of the node (`Node::poll`, what the firmware's loop calls) at the model's
    /// time, with `frame` received, and the rounds that follow at once while the node asks
    /// for no sleep.
    ///
    /// The firmware also runs the next round at once when one ends with a feed record due
    /// (a stall's stop, a detent taken in by the round's last intake), and when a detent
    /// came after the round's last intake (the edge's wake-up). The model does so after a
    /// round a detent landed in; otherwise the next action's round, which every action that
    /// reaches the device begins with, sends it (fewer states, and only orders the firmware
    /// could also take, a little later).
    fn step(&self, w: &mut World, frame: Option<Frame>) {
        let mut frame = frame;
        for _ in 0..BACK_TO_BACK {
            let landing = w.pending.is_some();
            let out = self.round(w, frame.take());
            if w.untaken.is_empty() && (out.sleep_ms > 0 || !landing || w.pending.is_some()) {
                break;
            }
        }
        assert!(w.untaken.is_empty(), "a detent the device never took in");
    }

    fn round(&self, w: &mut World, frame: Option<Frame>) -> Outputs {
        let now = w.now_ms;
        let tag = Tag {
            made_ms: now,
            boot: w.spec.boot,
            stale: false,
            copy: false,
        };
        let mut port = Port {
            rx: frame,
            path: &mut w.transmit,
            capacity: self.bounds.transmit_capacity,
            mailboxes: self.bounds.mailboxes,
            tag,
            spec: &mut w.spec,
            now_ms: now,
            writing: &mut w.writing,
            probe_answer: &mut w.probe_answer,
            stalled: false,
            wrongly_enabled: None,
        };
        let mut wheel = ModelWheel {
            inner: &mut w.real.wheel,
            levels: &mut w.real.levels,
            pending: &mut w.pending,
            locks: &mut w.locks,
            untaken: &mut w.untaken,
            changing: false,
            taken: Vec::new(),
            misplaced: None,
        };
        // What only the stall-completions mutant reads: frames that left the path so far.
        w.real
            .node
            .device_mut()
            .mutant_transmit_completed(port.path.completed);
        let sequence = wheel.inner.feed().outbox().sequence();
        let mark = wheel.inner.feed().outbox().mutant_refill_mark();
        // The model's time stays far below the tick count's wrap.
        let out = w.real.node.poll(
            now as u32,
            &mut port,
            &mut Lines(w.axis, w.multiplier),
            &mut wheel,
        );
        // Where the round refilled the pace: the device's first refill at a new time, with
        // the sequence then (a refill at a time the bucket was refilled at already adds
        // nothing).
        let outbox = wheel.inner.feed().outbox();
        let (end, refill) = (outbox.sequence(), outbox.mutant_refill_mark());
        let (before, refilled_us, after) = match refill {
            Some((at_us, at)) if refill != mark => {
                (at.wrapping_sub(sequence), Some(at_us), end.wrapping_sub(at))
            }
            _ => (end.wrapping_sub(sequence), None, 0),
        };
        let (taken, misplaced) = (wheel.taken, wheel.misplaced);
        let (stalled, wrongly) = (port.stalled, port.wrongly_enabled);
        if let Some(why) = wrongly {
            self.breach(w, format!("device: 0x2000 = 1 accepted while {why}"));
        }
        if let Some((then, now)) = misplaced {
            let message = format!(
                "device: a detent that came while it counted for {then:?} was taken in \
                 after a change, for {now:?}"
            );
            self.breach(w, message);
        }
        for (back, enabled) in taken {
            self.turned(w, back, enabled);
        }
        // The pace: a number beyond it ends the session in the round that took it.
        w.spec
            .pace
            .round(self.bounds.pace, before, refilled_us, after);
        if std::mem::take(&mut w.spec.pace.overdrawn) {
            let session = w.real.wheel.feed().session();
            if session != 0 {
                self.breach(
                    w,
                    format!("device: a number beyond its pace kept session {session}"),
                );
            }
        }
        if stalled {
            self.records_missing(w);
        }
        self.watch_master(w);
        out
    }

    /// The master's heartbeat: lost once the consumer time passed without one (the device's
    /// engine looks in every round, as the model does after it).
    fn watch_master(&self, w: &mut World) {
        let spec = &mut w.spec;
        let consumer = u64::from(self.bounds.consumer_ms);
        if spec.watching
            && !spec.master_lost
            && spec
                .last_beat
                .is_some_and(|beat| w.now_ms >= beat + consumer)
        {
            spec.master_lost = true;
            spec.enabled = false;
            self.records_missing(w);
        }
    }

    /// A detent was turned (now, at the model's switch positions): truth if the device had
    /// the feed enabled when it took it in.
    fn turned(&self, w: &mut World, back: bool, enabled: bool) {
        if !enabled {
            return;
        }
        let units = FACTORS[w.multiplier] * if back { -1 } else { 1 };
        w.truth[w.axis].turned(Detent {
            units,
            at: w.now_ms,
            owed: w.spec.synced,
        });
    }

    /// Something happened after which records may be missing: nothing turned so far is
    /// owed, nor is anything until the host has a record made after it.
    fn records_missing(&self, w: &mut World) {
        for frame in w.transmit.queue.iter_mut().chain(&mut w.transmit.boxes) {
            frame.tag.stale = true;
        }
        for frame in w
            .host_backlog
            .iter_mut()
            .chain(w.gateway.iter_mut().flatten())
        {
            frame.tag.stale = true;
        }
        w.spec.synced = false;
        for t in &mut w.truth {
            t.excuse();
        }
    }

    /// The switch is at the model's axis and multiplier: rounds a millisecond apart until
    /// the node's debouncer takes it (four samples, 5 ms apart). Nothing else happens
    /// meanwhile.
    fn select(&self, w: &mut World) {
        for _ in 0..40 {
            let out = self.round(w, None);
            if out.log.selection.is_some() {
                if out.sleep_ms == 0 {
                    self.step(w, None);
                }
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
        self.records_missing(w);
        match command {
            Nmt::Start => w.spec.operational = true,
            Nmt::Stop | Nmt::PreOperational => {
                w.spec.operational = false;
                w.spec.enabled = false;
            }
            Nmt::ResetNode | Nmt::ResetCommunication => self.reset(w),
        }
        self.receive(w, 0x000, &[command.byte(), NODE]);
    }

    /// A reset or power-up: Pre-operational, feed off, the master's heartbeat no longer
    /// watched (0x1016 is back at its default, nothing).
    fn reset(&self, w: &mut World) {
        let spec = &mut w.spec;
        spec.boot = spec.boot.wrapping_add(1);
        spec.session = 0;
        spec.operational = false;
        spec.enabled = false;
        spec.watching = false;
        spec.master_lost = false;
        spec.last_beat = None;
    }

    /// An SDO read (expedited upload) of a U32 through the device's server, its answer kept
    /// off the bus (as a probe's); `None`: refused or unanswered.
    fn sdo_read_u32(&self, w: &mut World, index: u16, sub: u8) -> Option<u32> {
        w.probe_answer = Some(None);
        self.receive(
            w,
            SDO_RX,
            &[0x40, index as u8, (index >> 8) as u8, sub, 0, 0, 0, 0],
        );
        let answer = w.probe_answer.take().flatten()?;
        (answer[0] == 0x43)
            .then(|| u32::from_le_bytes([answer[4], answer[5], answer[6], answer[7]]))
    }

    /// An SDO write (expedited download); the device's answer says whether it took it (see
    /// [`Port::written`]).
    fn sdo_write(&self, w: &mut World, index: u16, sub: u8, value: &[u8]) {
        let cmd = 0x23 | (((4 - value.len()) as u8) << 2);
        let mut data = [cmd, index as u8, (index >> 8) as u8, sub, 0, 0, 0, 0];
        data[4..4 + value.len()].copy_from_slice(value);
        let mut bytes = [0; 4];
        bytes[..value.len()].copy_from_slice(value);
        w.writing = Some((index, u32::from_le_bytes(bytes)));
        self.receive(w, SDO_RX, &data);
        w.writing = None;
    }

    /// Another master's write of `object` ([`Action::ForeignWrite`]).
    fn foreign_write(&self, w: &mut World, object: Foreign) {
        match object {
            Foreign::Consumer => {
                let entry = ((2u32 << 16) | u32::from(self.bounds.consumer_ms)).to_le_bytes();
                self.sdo_write(w, 0x1016, 2, &entry);
            }
            Foreign::EventTimer => {
                let timer = self.bounds.event_timer_ms.to_le_bytes();
                self.sdo_write(w, 0x1800, 5, &timer);
            }
            Foreign::Invert => self.sdo_write(w, 0x2020, 4, &[1]),
            Foreign::CountsPerDetent => self.sdo_write(w, 0x2020, 3, &[2]),
        }
    }

    /// A write of 0x2000.
    fn feed_write(&self, w: &mut World, enable: bool) {
        self.sdo_write(w, 0x2000, 0, &[u8::from(enable)]);
    }

    /// The master's heartbeat, taken at the start of the round, before the device looks at
    /// its consumer time.
    fn master_beat(&self, w: &mut World) {
        if w.spec.watching {
            w.spec.last_beat = Some(w.now_ms);
            w.spec.master_lost = false;
        }
        self.receive(w, 0x700 + MASTER, &[0x05]);
    }

    /// A detent between two rounds: the next round takes it in first.
    fn turn(&self, w: &mut World, back: bool) {
        detent(&mut w.real.wheel, &mut w.real.levels, back);
        w.untaken.push((back, counts_for(w.real.wheel.feed())));
        self.step(w, None);
    }

    fn power_cycle(&self, w: &mut World) {
        let storage = w.real.node.device_mut().engine().storage().clone();
        self.records_missing(w);
        self.reset(w);
        w.spec.powered_ms = w.now_ms;
        w.transmit.clear();
        w.spec.stall_since = None;
        w.spec.transmit_blocked = false;
        w.real.node = new_node(storage, self.bounds.mutant);
        w.real.wheel = LinkedWheel::local(DecoderConfig::default(), w.real.levels);
        self.pace(w);
        self.step(w, None);
        self.select(w);
    }

    fn pass_all(&self, w: &mut World) {
        while w.transmit.waiting() && w.violation.is_none() {
            self.pass(w, 1);
        }
    }

    /// The bus takes the next frame (a millisecond passes: generously a frame's time); the
    /// host receives it `copies` times (0: lost on its way).
    fn pass(&self, w: &mut World, copies: usize) {
        let Some(frame) = w.transmit.take(self.bounds.mailboxes) else {
            return;
        };
        w.now_ms += 1;
        if frame.tag.boot != w.spec.boot {
            self.breach(
                w,
                format!(
                    "device: a frame ({:#05x}) made before a reset went out after it",
                    frame.id
                ),
            );
        }
        if copies == 0 {
            self.records_missing(w);
        }
        if frame.id == TPDO1 && copies > 0 && self.left(w, Budget::ChannelFaults) {
            w.delivered.push_back((frame.clone(), w.now_ms));
        }
        for _ in 0..copies {
            self.to_link(w, frame.clone());
        }
        // The transmit interrupt wakes the device: what it could not queue goes now.
        self.step(w, None);
    }

    /// A frame on its way from the bus to the host: held in the path between them while it
    /// holds ([`Action::Hold`]), else at the host now.
    fn to_link(&self, w: &mut World, frame: Wire) {
        if let Some(held) = &mut w.gateway {
            held.push_back(frame);
        } else {
            self.to_host(w, frame);
        }
    }

    /// The host probes when its rule asks (the component's `Probe`: while it holds a
    /// session, one per probe period, none while a configuration is due or a probe is under
    /// way; a stalled host none): it writes its nonce to 0x2033 and reads the object back,
    /// its send time now. The write reaches the device at once (the host-to-device direction
    /// is not held); the value is the accumulator's real `sequence_probe()` right after the
    /// write, the earliest a read can see (a real read follows the write's answer, so its
    /// number is this or later: this answer dates the most records). The answer goes the way
    /// of the device's frames from the bus on: at the host now, or held with them (then it
    /// arrives late with its old send time). Not through the device's transmit path and SDO
    /// server (fewer states; the mailboxes would send it after every record waiting).
    fn probe_if_due(&self, w: &mut World) {
        if w.host_stalled || !w.host.probe_due(w.now_ms) {
            return;
        }
        let now = w.now_ms;
        let (nonce, floor) = w.host.probe(now);
        self.log(
            w,
            HostEvent::Probe {
                nonce,
                floor,
                at_ms: now,
            },
        );
        // The write goes through the device's SDO server, in a round of its own; its answer
        // is kept off the bus: the read's answer (or the write's abort) stands for both.
        w.probe_answer = Some(None);
        self.sdo_write(w, 0x2033, 0, &nonce.to_le_bytes());
        let data = match w.probe_answer.take().flatten() {
            Some(answer) if answer[0] == 0x60 => {
                let v = w.real.wheel.lock(|h| h.feed.sequence_probe()).to_le_bytes();
                [PROBE_ANSWER, 0x33, 0x20, 0, v[0], v[1], v[2], v[3]]
            }
            // Refused (the key is not the session's): the abort, as the device sent it.
            Some(abort) => abort,
            // No SDO in its state (Stopped): the host's request times out.
            None => {
                self.log(w, HostEvent::Unanswered { at_ms: now });
                w.host.probed(None, now);
                return;
            }
        };
        let tag = Tag {
            made_ms: now,
            boot: w.spec.boot,
            stale: false,
            copy: false,
        };
        let answer = Wire {
            id: SDO_TX,
            data,
            len: 8,
            tag,
        };
        self.to_link(w, answer);
    }

    /// A frame reaches the host. A host that reads finds its receive path empty right before
    /// and after it (it reads all the time); a stalled one leaves it in its backlog.
    fn to_host(&self, w: &mut World, frame: Wire) {
        if w.host_stalled {
            w.host_backlog.push_back(frame);
            return;
        }
        self.host_drained(w);
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
        if frame.id == SDO_TX && frame.data[..4] == [PROBE_ANSWER, 0x33, 0x20, 0] {
            // The answer to the host's probe (the model's device answers no other upload).
            let value =
                u32::from_le_bytes([frame.data[4], frame.data[5], frame.data[6], frame.data[7]]);
            self.log(w, HostEvent::Probed { value, at_ms: now });
            w.host.probed(Some(value), now);
            return;
        }
        if frame.id == SDO_TX && frame.data[..4] == [0x80, 0x33, 0x20, 0] {
            // The device refused the probe's write.
            self.log(w, HostEvent::ProbeRefused { at_ms: now });
            w.host.probe_refused(now);
            return;
        }
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
                self.judge(w, &credit);
            }
            // A record of the host's session: what is turned from now on must reach it.
            let session = frame.data[5] >> 5;
            if !frame.tag.copy
                && !frame.tag.stale
                && !w.spec.foreign
                && w.host.session() == Some(session)
            {
                w.spec.synced = true;
            }
        }
    }

    fn breach(&self, w: &mut World, message: String) {
        if w.violation.is_none() {
            w.violation = Some(message);
        }
    }

    /// The property for one credit: a run of the detents turned on that axis while enabled,
    /// in order, none credited before, none older than the bound, skipping none owed.
    fn judge(&self, w: &mut World, credit: &Credit<Tag>) {
        let (axis, delta, now, late) = (credit.axis, credit.delta, w.now_ms, self.bounds.late_ms);
        let letter = LETTERS[axis];
        let truth = &mut w.truth[axis];
        let why = match truth.credit(delta, now, late) {
            Ok(()) => return,
            Err(Miss::Skipped(d)) => format!(
                "an owed detent ({:+} at {} ms) skipped: no record was missing",
                d.units, d.at
            ),
            Err(Miss::Unsound) => {
                let other = &w.truth[1 - axis];
                let truth = &w.truth[axis];
                if truth.explains_from_start(delta, now, late, true) {
                    "motion credited again".to_string()
                } else if let Some(age) = truth.explains_late(delta, now) {
                    format!("a detent {age} ms after it was turned")
                } else if other.explains_from_start(delta, now, u64::MAX, false) {
                    format!("a detent turned on {}", LETTERS[1 - axis])
                } else {
                    let units = truth.detents().iter().map(|d| d.units);
                    let back: i32 = units.clone().filter(|&u| u < 0).sum();
                    let forward: i32 = units.filter(|&u| u > 0).sum();
                    if delta < back {
                        format!("backwards, more than the {back} turned back")
                    } else if delta > forward {
                        format!("more than the {forward} turned forward")
                    } else {
                        "no run of what was turned on it while enabled".to_string()
                    }
                }
            }
        };
        let turned: Vec<String> = w.truth[axis]
            .detents()
            .iter()
            .map(|d| format!("{:+}@{}", d.units, d.at))
            .collect();
        let message = format!(
            "{letter} credited {delta} at {now} ms: {why} (turned on {letter} while enabled, \
             last {late} ms: [{}]; from {:?} to {:?})",
            turned.join(" "),
            credit.from.0,
            credit.to.0
        );
        self.breach(w, message);
    }

    /// After every action: what the device promises about its feed, and what is owed.
    fn after(&self, w: &mut World) {
        let session = w.real.wheel.feed().session();
        if session != w.spec.session {
            if session == 0 {
                // The device ended the session itself: a loss took numbers beyond its pace
                // (records are missing, and the host must configure again).
                w.spec.session = 0;
                w.spec.enabled = false;
                self.records_missing(w);
            } else {
                let message = format!(
                    "device: in session {session}, not the {} written last",
                    w.spec.session
                );
                self.breach(w, message);
            }
        }
        let enabled = w.real.wheel.feed().enabled();
        if enabled && !w.spec.enabled {
            let spec = &w.spec;
            let why = if !spec.operational {
                "out of Operational"
            } else if spec.master_lost {
                "after the master was lost"
            } else if spec.transmit_blocked {
                "after its frames waited 100 ms"
            } else {
                "not enabled by an accepted write"
            };
            self.breach(w, format!("device: feed enabled {why}"));
        } else if !enabled && w.spec.enabled {
            self.breach(w, "device: feed disabled by itself".to_string());
        }
        let (now, late) = (w.now_ms, self.bounds.late_ms);
        for (letter, truth) in LETTERS.iter().zip(&mut w.truth) {
            if let Some(d) = truth.owed().filter(|d| now - d.at > late) {
                let message = format!(
                    "{letter} not credited {:+} turned at {} ms, by {now} ms: no record was \
                     missing",
                    d.units, d.at
                );
                if w.violation.is_none() {
                    w.violation = Some(message);
                }
            }
            truth.age(now, late);
        }
        // Only what a copy may still be of: delivered within the contract's age, as far
        // back as the bounds' depth, and nothing once the channel's faults are spent.
        let (age, depth) = (self.bounds.copy_age_ms, usize::from(self.bounds.copy_depth));
        if self.left(w, Budget::ChannelFaults) {
            while w.delivered.len() > depth
                || w.delivered.front().is_some_and(|(_, at)| at + age < now)
            {
                w.delivered.pop_front();
            }
        } else {
            w.delivered.clear();
        }
        w.locks = 0;
    }

    /// Time passes, fault-free, until every owed detent is older than the bound.
    fn settle(&self, w: &mut World) {
        let Some(oldest) = w
            .truth
            .iter()
            .filter_map(AxisTruth::owed)
            .map(|d| d.at)
            .min()
        else {
            return;
        };
        let until = oldest + self.bounds.late_ms + 1;
        loop {
            self.pass_all(w);
            if w.now_ms >= until || w.violation.is_some() {
                return;
            }
            w.now_ms = (w.now_ms + SETTLE_STEP_MS).min(until);
            if w.spec.watching && !w.spec.master_lost {
                self.master_beat(w);
            } else {
                self.step(w, None);
            }
            self.probe_if_due(w);
        }
    }

    fn warmed(&self, mut w: World, index: usize) -> World {
        let script = self.bounds.warmups[index];
        for &step in script {
            match step {
                Warm::Turns(n) | Warm::Backs(n) => {
                    for _ in 0..n {
                        self.turn(&mut w, matches!(step, Warm::Backs(_)));
                        self.pass_all(&mut w);
                        // The inhibit time (2 ms) lets the record of the next detent go, and
                        // the pace has a number for it.
                        w.now_ms += (u64::from(self.bounds.pace.us_per_number) / 1000 + 1).max(2);
                        self.probe_if_due(&mut w);
                        // Credited: the truth keeps only what may still be.
                        for truth in &mut w.truth {
                            truth.forget_credited();
                        }
                    }
                }
                Warm::Switch => {
                    w.axis = (w.axis + 1) % AXES;
                    self.select(&mut w);
                    self.pass_all(&mut w);
                }
                Warm::Multiplier => {
                    w.multiplier = (w.multiplier + 1) % FACTORS.len();
                    self.select(&mut w);
                    self.pass_all(&mut w);
                }
                Warm::Held(n) => {
                    for _ in 0..n {
                        self.turn(&mut w, false);
                    }
                }
            }
        }
        if let Some(v) = &w.violation {
            panic!("warm-up {index} of {:?} breaches: {v}", self.bounds.name);
        }
        for truth in &mut w.truth {
            truth.forget_credited();
        }
        w.warmup = index as u8;
        w.locks = 0;
        w
    }

    /// An initial state `like` (one of [`Model::init_states`]) made again with the host's
    /// input recorded from power-on.
    pub fn recorded(&self, like: &World) -> World {
        let start = self.initial_with(Some(Vec::new()));
        if self.bounds.warmups.is_empty() {
            return start;
        }
        self.warmed(start, usize::from(like.warmup))
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
        (0..self.bounds.warmups.len())
            .map(|i| self.warmed(start.clone(), i))
            .collect()
    }

    fn actions(&self, w: &World, actions: &mut Vec<Action>) {
        if w.violation.is_some() && !THROUGH_BREACHES.load(Ordering::Relaxed) {
            return;
        }
        let b = |kind| self.left(w, kind);
        let free = w.pending.is_none();
        let backward = self.bounds.backward;
        if b(Budget::Turns) {
            actions.push(Action::Turn);
            if backward {
                actions.push(Action::TurnBack);
            }
        }
        if b(Budget::InnerTurns) && free {
            for lock in 1..=self.bounds.inner_locks {
                actions.push(Action::TurnAt(lock));
                if backward {
                    actions.push(Action::TurnBackAt(lock));
                }
            }
        }
        if b(Budget::Switches) && free {
            actions.push(Action::SwitchAxis);
        }
        if b(Budget::Multipliers) && free {
            actions.push(Action::SwitchMultiplier);
        }
        if b(Budget::FeedWrites) {
            actions.extend([Action::Enable, Action::Disable]);
        }
        if b(Budget::TokenWrites) && w.host.session().is_some() {
            actions.push(Action::WriteToken);
        }
        if b(Budget::ForeignWrites) && w.host.session().is_some() {
            let objects = if self.bounds.foreign.is_empty() {
                &Foreign::ALL[..]
            } else {
                self.bounds.foreign
            };
            actions.extend(objects.iter().map(|&o| Action::ForeignWrite(o)));
        }
        if b(Budget::Nmt) {
            actions.extend(Nmt::ALL.map(Action::Nmt));
        }
        if b(Budget::PowerCycles) && free {
            actions.push(Action::PowerCycle);
        }
        if b(Budget::Ticks) {
            actions.push(Action::Tick);
        }
        if w.transmit.next().is_some() {
            actions.push(Action::Pass);
            if b(Budget::ChannelFaults) {
                actions.extend([Action::Lose, Action::Duplicate]);
            }
        }
        if b(Budget::ChannelFaults) && free {
            let young = w
                .delivered
                .iter()
                .filter(|(_, at)| at + self.bounds.copy_age_ms >= w.now_ms)
                .count();
            actions.extend((1..=young as u8).map(Action::Copy));
        }
        // Not while the path holds: the configuration's answers would be held, and the
        // component's SDO client gives up.
        if b(Budget::Configures)
            && free
            && !w.host_stalled
            && w.gateway.is_none()
            && w.host.configure_due(w.now_ms)
        {
            actions.push(Action::Configure);
        }
        if b(Budget::HostStalls) && !w.host_stalled && free {
            actions.push(Action::HostStall);
        }
        if w.host_stalled {
            if free {
                actions.push(Action::HostResume);
            }
        } else if b(Budget::MasterBeats) {
            actions.push(Action::MasterBeat);
        }
        if w.gateway.is_some() {
            actions.push(Action::Release);
        } else if b(Budget::Holds) {
            actions.push(Action::Hold);
        }
        if b(Budget::Settles)
            && free
            && !w.host_stalled
            && w.truth.iter().any(|t| t.owed().is_some())
        {
            actions.push(Action::Settle);
        }
    }

    fn next_state(&self, last: &World, action: Action) -> Option<World> {
        let mut w = last.clone();
        let ok = match action {
            Action::Turn | Action::TurnBack => self.spend(&mut w, Budget::Turns),
            Action::TurnAt(_) | Action::TurnBackAt(_) => self.spend(&mut w, Budget::InnerTurns),
            Action::SwitchAxis => self.spend(&mut w, Budget::Switches),
            Action::SwitchMultiplier => self.spend(&mut w, Budget::Multipliers),
            Action::Enable | Action::Disable => self.spend(&mut w, Budget::FeedWrites),
            Action::Nmt(_) => self.spend(&mut w, Budget::Nmt),
            Action::WriteToken => self.spend(&mut w, Budget::TokenWrites),
            Action::ForeignWrite(_) => self.spend(&mut w, Budget::ForeignWrites),
            Action::PowerCycle => self.spend(&mut w, Budget::PowerCycles),
            Action::Tick => self.spend(&mut w, Budget::Ticks),
            Action::Lose | Action::Duplicate | Action::Copy(_) => {
                self.spend(&mut w, Budget::ChannelFaults)
            }
            Action::Configure => self.spend(&mut w, Budget::Configures),
            Action::HostStall => self.spend(&mut w, Budget::HostStalls),
            Action::MasterBeat => self.spend(&mut w, Budget::MasterBeats),
            Action::Settle => self.spend(&mut w, Budget::Settles),
            Action::Hold => self.spend(&mut w, Budget::Holds),
            Action::Pass | Action::HostResume | Action::Release => true,
        };
        if !ok {
            return None;
        }
        let was_pending = w.pending.is_some();
        match action {
            Action::Turn => self.turn(&mut w, false),
            Action::TurnBack => self.turn(&mut w, true),
            Action::TurnAt(lock) => w.pending = Some((false, lock)),
            Action::TurnBackAt(lock) => w.pending = Some((true, lock)),
            Action::SwitchAxis => {
                w.axis = (w.axis + 1) % AXES;
                self.select(&mut w);
            }
            Action::SwitchMultiplier => {
                w.multiplier = (w.multiplier + 1) % FACTORS.len();
                self.select(&mut w);
            }
            Action::Enable => self.feed_write(&mut w, true),
            Action::Disable => self.feed_write(&mut w, false),
            Action::WriteToken => {
                let token = w
                    .host
                    .session()
                    .expect("only while the host holds a session");
                if w.spec.session != token {
                    // A session the host did not open: what it is owed ends here.
                    self.records_missing(&mut w);
                    w.spec.foreign = true;
                }
                self.sdo_write(&mut w, 0x2002, 0, &[token]);
            }
            Action::ForeignWrite(object) => self.foreign_write(&mut w, object),
            Action::Nmt(command) => self.nmt(&mut w, command),
            Action::PowerCycle => self.power_cycle(&mut w),
            Action::Tick => {
                w.now_ms += self.bounds.tick_ms;
                self.step(&mut w, None);
            }
            Action::Pass => self.pass(&mut w, 1),
            Action::Duplicate => self.pass(&mut w, 2),
            Action::Lose => self.pass(&mut w, 0),
            Action::Copy(back) => {
                let index = w.delivered.len() - usize::from(back);
                let mut frame = w.delivered[index].0.clone();
                frame.tag.copy = true;
                self.to_link(&mut w, frame);
            }
            Action::Configure => self.configure(&mut w),
            Action::HostStall => {
                w.host_stalled = true;
                self.records_missing(&mut w);
            }
            Action::MasterBeat => self.master_beat(&mut w),
            Action::HostResume => {
                w.host_stalled = false;
                self.records_missing(&mut w);
                while let Some(frame) = w.host_backlog.pop_front() {
                    self.host_handles(&mut w, &frame);
                }
                self.host_drained(&mut w);
            }
            Action::Settle => self.settle(&mut w),
            Action::Hold => {
                w.gateway = Some(VecDeque::new());
                // What waits there may come later than the bound: nothing is owed until the
                // host has a record made after it.
                self.records_missing(&mut w);
            }
            Action::Release => {
                for frame in w.gateway.take().into_iter().flatten() {
                    self.to_host(&mut w, frame);
                }
            }
        }
        self.probe_if_due(&mut w);
        // A detent meant to land inside this action's rounds that found no such access:
        // that interleaving does not exist.
        if was_pending && w.pending.is_some() {
            return None;
        }
        self.after(&mut w);
        Some(w)
    }

    /// Past the deadline nothing is explored further.
    fn within_boundary(&self, _: &World) -> bool {
        self.deadline.is_none_or(|at| Instant::now() < at)
    }

    fn properties(&self) -> Vec<Property<Self>> {
        vec![Property::always(
            "every credit is motion turned on that axis while enabled, with its sign, once, \
             in time, all of it when no record is missing; the device keeps its promises",
            |_, w: &World| w.violation.is_none(),
        )]
    }
}
