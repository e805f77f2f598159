"""The component's decisions, free of HAL and CAN: what a frame means, what the pins show,
what to tell the device next.

`Core` is fed events and answers with pin snapshots and at most one `Action` at a time. The
shell (`component.py`) carries out actions over python-canopen and writes the pins to HAL;
it makes no decision of its own. Everything here is plain Python (standard library only)
and deterministic in the times it is given, so it is tested without a bus or LinuxCNC
(`host/tests`), and the interop suite checks the device's records with the same functions
(`Record`, `record_fault`, `continuity`, `pair_fault`).

The event API (stable; `replay` runs a list of these events through a `Core`):

- `frame(cob_id, data, now)`: a frame the shell read at `now` (identifiers other than the
  device's TPDO1, EMCY and heartbeat are ignored); for TPDO1 it answers a `FeedVerdict`;
- `drained(now)`: the shell's receive path was found empty at a moment not before `now`,
  so every frame that reached the host before `now` has been handed to `frame`;
- `tick(now)`: time passes (staleness);
- `set_enable(bool)`, `set_position_mode(bool)`, `set_velocity_mode(bool)`,
  `set_run_on_budget(s)`: the input pins; `set_motion_known(bool)`: LinuxCNC shows its axes'
  motion (teleop mode);
- `reconnected(now)`: the shell opened the bus again (what the device did meanwhile is
  unknown);
- `next_action(now)` -> the `Action` to carry out (`Configure`, `WriteFeed`, `Probe`) or
  None, and `done(action, ok, abort, now, result)`: its outcome (a `Configure`'s: a
  `Configured`; a `Probe`'s: a `Probed`, and its write refused with abort 0x08000022 ends
  the core's session, as do `PROBE_TIMEOUTS_BEFORE_CONFIGURING` probes in a row on the
  component's own SDO channel without an answer: `done(probe, False, None, ...)`);
- `take_log()` -> the lines the core wants logged (a feed stop and its reason, a session
  dropped, a configuration waiting for a token), for the shell to print;
- `publish(now, motion)` -> the list of `Pins` snapshots to write now, in order, at least
  `GATE_HOLD` apart (`motion(letter)`: LinuxCNC's `AxisMotion` of an axis, asked in the
  run-on mode for an axis with new counts); `pins()` is the state they end in;
  `shutdown_action()`.

The rules the core keeps, and the argument that motion is never credited to another axis,
twice or backwards: docs/ARCHITECTURE.md, "The host core's rules and why they hold"
(host/README.md's "What it does" states them for machine builders); the docstrings (here
and in the modules below) name the rule where one implements it.

The parts have modules of their own, named by idea, and every name they define is
re-exported here: `record` (the feed record, continuity), `order` (the order rule),
`sessions` (tokens, the session key), `dating` (the sequence probe), `configuration`
(settings, the device's configuration, the actions), `metering` (run-on metering,
plausibility), `overrides`, `outputs` (RPDO1: the outputs' byte, when it goes out), `stops`
(feed stops), `sdo` (other masters, the own SDO channel), `pins` (the pins), `verdict`
(what the rule made of a feed record). `Core` itself is the state and the event API; its
session keeping, frame handlers and publishing are the mixins
`session_keeping.SessionKeeping`, `frames.FrameHandling` and `pins.Publishing`.
"""

from __future__ import annotations

import collections
import math
from dataclasses import dataclass, field
from typing import Deque, Dict, List, Optional, Tuple

from .configuration import Action, Config, Configure, Configured, WriteFeed, configure_outcome
from .dating import NONCE_MASK, PROBE_DATES, PROBE_PERIOD, Probe, Probed
from .frames import FrameHandling
from .metering import POSITION, RUN_ON, RUN_ON_BUDGET_RANGE, VELOCITY, Allowance, rate_horizon
from .outputs import outputs_allowed
from .pins import Pins, Publishing
from .record import OPERATIONAL, Record
from .sdo import ABORT_DEVICE_STATE, FOREIGN_SDO_QUIET
from .session_keeping import SessionKeeping
from .sessions import next_key
from .stops import STOP_NONE, STOP_REASON_WAIT
from .verdict import FeedVerdict

# isort: split
# Every public name of the core's modules, as `canopen_handwheel.core` had them all before
# they were split into modules by idea, for component.py, decode.py, capture.py, the tests
# and tools.
from .configuration import *  # noqa: F403
from .dating import *  # noqa: F403
from .metering import *  # noqa: F403
from .order import *  # noqa: F403
from .outputs import *  # noqa: F403
from .overrides import *  # noqa: F403
from .pins import *  # noqa: F403
from .record import *  # noqa: F403
from .sdo import *  # noqa: F403
from .sessions import *  # noqa: F403
from .stops import *  # noqa: F403
from .verdict import *  # noqa: F403

# The core's log lines not yet taken by the shell (`Core.take_log`): a bounded queue, so that
# nothing on the bus can make it grow.
LOG_LINES = 32


@dataclass
class Core(SessionKeeping, FrameHandling, Publishing):
    cfg: Config
    enable: bool = False
    # What the device showed.
    state: Optional[int] = None  # last heartbeat state byte
    record: Optional[Record] = None  # last accepted record (of the session)
    record_time: Optional[float] = None
    # The order reference: the newest record of the session taken, and the earliest it can
    # have reached the host (`order_verdict`).
    order: Optional[Tuple[Record, float]] = None
    foreign_newest: bool = False  # the newest possible record was of another session
    emcy_code: int = 0
    # Bookkeeping.
    counts: Dict[str, int] = field(default_factory=dict)
    baseline: bool = True  # the next record is a baseline
    records_lost: int = 0
    frames_bad: int = 0
    suspect: bool = False  # the last TPDO1 was impossible: no axis until a possible one
    epochs_shown: bool = False  # a non-zero epoch since the last configuration
    drained_at: Optional[float] = None  # the shell's receive path last found empty
    # Publishing (`publish`): the pins last handed to the shell, and the credits since.
    published: Optional[Pins] = None
    credit_time: Optional[float] = None  # the earliest credit not yet published
    credit_last: Optional[float] = None  # the latest credit not yet published
    credit_open: Dict[str, bool] = field(default_factory=dict)  # credited with the gate open
    withdrawn: int = 0  # credits withdrawn because they were not published in time
    allowance: Allowance = field(init=False)
    event_timer: float = field(init=False)  # s: the device's, once configured
    position_mode: bool = field(init=False)  # the `position-mode` input
    velocity_mode: bool = field(init=False)  # the `velocity-mode` input
    run_on_budget: float = field(init=False)  # the `run-on-budget` input, s
    motion_known: bool = False  # LinuxCNC shows its axes' motion (teleop mode)
    counts_dropped: int = 0  # counts the run-on budget dropped
    # Per axis: the jog target LinuxCNC has after the component's last metered counts, and
    # when they were written (`IN_FLIGHT`).
    sent_target: Dict[str, Tuple[float, float]] = field(default_factory=dict)
    # The session (`Configure`): the token the host wrote and read back, None without one,
    # and the key it wrote after it (`SESSION_KEY_OBJECT`; its probes carry it).
    session: Optional[int] = None
    session_key: Optional[int] = None
    key: int = field(init=False)  # the next configuration's key
    superseded: Dict[int, float] = field(default_factory=dict)  # token -> when replaced
    # Tokens the device may have been in since the last successful configuration, and when
    # that was last known: the host's session once it dropped it, a token written without
    # its read-back, a session the device reported or showed that the host never used. The
    # next successful configuration ends them all: it supersedes them.
    busy: Dict[int, float] = field(default_factory=dict)
    # Per token the host wrote: when the configuration that first wrote it after it was last
    # free (`free_tokens`) was asked for (`UPTIME_OBJECT`); the core's clock.
    chains: Dict[int, float] = field(default_factory=dict)
    configure_asked_at: float = 0.0  # when the configuration under way was asked for
    check_due: bool = False  # a record of another session came: check the configuration
    check_at: float = 0.0  # not before this (one check per `retry` at most)
    check_logged: bool = False  # a check was logged in this session
    waiting_logged: bool = False  # the wait for a free token was logged
    # Feed stops (`feed-stops`, `stop-reason`): the component asked for the feed off (its
    # 0x2000 = 0 since it last asked for it on), a stop waiting for its EMCY (when it was
    # seen, and whether status bit 3 was set), what the device showed since the feed was
    # last on: the last EMCY 0x8100 or 0x8130, a heartbeat other than Operational.
    asked_off: bool = False
    stop_seen: Optional[float] = None
    stop_master_lost: bool = False
    stop_emcy: Optional[int] = None
    left_operational: bool = False
    feed_stops: int = 0
    stop_reason: int = STOP_NONE
    feed_on: bool = False  # the last record of the session showed the feed on
    # The last configuration found the device in its loader (`Configured.loader`): no
    # configuration until something shows that an application may run (its boot-up, a
    # record, the bus opened again); none on a timer, since SDO requests of the component
    # would break a program download under way.
    in_loader: bool = False
    # Another master's SDO requests (`FOREIGN_SDO_QUIET`): when the last one was seen, and
    # its expedited write of 0x1F51:1 waiting for the device's answer; when the device
    # confirmed a "stop": a boot-up soon after it is its loader's.
    foreign_sdo_at: Optional[float] = None
    foreign_read: Optional[bytes] = None  # index and sub of another master's read under way
    foreign_quiet: float = FOREIGN_SDO_QUIET  # the hold after `foreign_sdo_at`
    holding_logged: bool = False
    program_request: Optional[int] = None
    program_stopped_at: Optional[float] = None
    log: Deque[str] = field(default_factory=lambda: collections.deque(maxlen=LOG_LINES))
    # Actions.
    config_due: float = 0.0  # configure at this time (without a session)
    feed_due: float = 0.0  # earliest time for the next 0x2000 write
    pending: Optional[Action] = None
    booted_during: Optional[float] = None  # a boot-up while a `Configure` was pending
    # Dating (`DATE_LIMIT`): the probes' dates (n, sent_at), oldest first, for the session;
    # the next probe's nonce and time; records not credited for want of a date.
    dates: Deque[Tuple[int, float]] = field(
        default_factory=lambda: collections.deque(maxlen=PROBE_DATES)
    )
    nonce: int = field(init=False)
    probe_due: float = 0.0
    # The session's configuration set up the component's own SDO channel (`Config.own_sdo`):
    # probes and feed writes go there, never held back by another master's exchanges.
    own_channel: bool = False
    # Probes of the session on the own channel in a row that got no answer at all
    # (`PROBE_TIMEOUTS_BEFORE_CONFIGURING`).
    probes_unanswered: int = 0
    # Sessions dropped in a row for unanswered probes on the own channel
    # (`OWN_CHANNEL_DROPS_BEFORE_DEFAULT`); at the limit the core stays on the default channel
    # for the rest of the run.
    own_channel_drops: int = 0
    undated: int = 0
    undated_logged: bool = False
    now: float = 0.0

    def __post_init__(self) -> None:
        self.nonce = self.cfg.first_nonce & NONCE_MASK
        self.key = next_key(self.cfg.first_key - 1)
        self.counts = {letter: 0 for letter in self.cfg.axes}
        self.event_timer = self.cfg.event_timer
        self.position_mode = self.cfg.position_mode
        self.velocity_mode = self.cfg.velocity_mode
        self.run_on_budget = self.cfg.run_on_budget
        rate = self.cfg.max_detents_per_s
        self.allowance = Allowance(rate=rate, cap=rate * self.rate_horizon)

    # Events ---------------------------------------------------------------------------

    def frame(self, cob_id: int, data: bytes, now: float) -> Optional[FeedVerdict]:
        """A frame from the bus (any identifier; others than the device's are ignored). The
        device's feed record (TPDO1) is answered with what the rule made of it."""
        self.tick(now)
        node = self.cfg.node
        if cob_id == 0x180 + node:
            return self._tpdo1(bytes(data), now)
        if cob_id == 0x080 + node:
            self._emcy(bytes(data))
        elif cob_id == 0x700 + node:
            self._heartbeat(bytes(data), now)
        elif cob_id == 0x600 + node:
            self._foreign_sdo_request(bytes(data))
        elif cob_id == 0x580 + node:
            self._sdo_response(bytes(data))
        return None

    def drained(self, now: float) -> None:
        """The shell found its receive path empty at a moment not before `now`: every frame
        that reached the host before `now` has been handed to `frame`. The shell calls it
        whenever a read (waiting or not) finds nothing, `now` being the time taken before that
        read. A feed record handled more than `BACKLOG_LIMIT` after the last such report
        may have waited that long in a buffer: it is only a baseline."""
        if self.drained_at is None or now > self.drained_at:
            self.drained_at = now
        self.tick(now)

    def reconnected(self, now: float) -> None:
        """The shell opened the bus again: a boot-up may have come while it was closed, so
        a device held in its loader is asked again."""
        self.tick(now)
        if self.in_loader and self.session is None and self.config_due == math.inf:
            self.config_due = self.now

    def set_enable(self, enable: bool) -> None:
        if enable != self.enable:
            self.feed_due = 0.0  # act at once
        self.enable = enable

    def set_position_mode(self, position_mode: bool) -> None:
        """The `position-mode` input. It changes the mode and nothing else."""
        self.position_mode = position_mode

    def set_velocity_mode(self, velocity_mode: bool) -> None:
        """The `velocity-mode` input. It changes the mode and nothing else."""
        self.velocity_mode = velocity_mode

    def set_run_on_budget(self, budget: float) -> None:
        """The `run-on-budget` input (s), held to `RUN_ON_BUDGET_RANGE` (a value outside it:
        the nearest end; not a number: the option's value)."""
        low, high = RUN_ON_BUDGET_RANGE
        self.run_on_budget = (
            min(high, max(low, budget)) if math.isfinite(budget) else self.cfg.run_on_budget
        )

    def set_motion_known(self, known: bool) -> None:
        """Whether LinuxCNC shows its axes' motion (`AxisMotion`; it does in teleop mode).
        Without it the run-on mode cannot meter: the axes are left in LinuxCNC's velocity
        mode, which bounds their run-on by their stopping distance."""
        self.motion_known = known

    @property
    def mode(self) -> str:
        """`POSITION` while the `position-mode` input is true, else `VELOCITY` while
        `velocity-mode` is, else `RUN_ON`."""
        if self.position_mode:
            return POSITION
        return VELOCITY if self.velocity_mode else RUN_ON

    @property
    def metering(self) -> bool:
        """Counts go to the axes through `meter_counts` (the run-on mode, LinuxCNC showing
        the axes' motion)."""
        return self.mode == RUN_ON and self.motion_known

    def tick(self, now: float) -> None:
        """Time passes: staleness; a feed stop whose EMCY did not come is reported."""
        self.now = max(self.now, now)
        if self.record_time is not None and not self.fresh:
            self.baseline = True
        if self.stop_seen is not None and self.now - self.stop_seen >= STOP_REASON_WAIT:
            self._stopped()

    def take_log(self) -> List[str]:
        """The log lines the core made since the last call, for the shell to print."""
        lines = list(self.log)
        self.log.clear()
        return lines

    # Decisions ------------------------------------------------------------------------

    def _set_event_timer(self, period: float) -> None:
        self.event_timer = period
        self.allowance.cap = self.cfg.max_detents_per_s * self.rate_horizon
        if self.allowance.level is not None:
            self.allowance.level = min(self.allowance.level, self.allowance.cap)

    @property
    def configured(self) -> bool:
        """The host holds a session: a configuration wrote its token and read it back, and
        nothing since showed the device lost it."""
        return self.session is not None

    @property
    def stale_after(self) -> float:
        """Three periods of the device's event timer (the assumed one until configured)."""
        return 3 * self.event_timer

    @property
    def rate_horizon(self) -> float:
        return rate_horizon(self.stale_after, self.cfg.consumer_timeout_ms)

    @property
    def fresh(self) -> bool:
        return self.record_time is not None and self.now - self.record_time <= self.stale_after

    @property
    def operational(self) -> bool:
        return self.fresh and self.state in (None, OPERATIONAL)

    @property
    def feed_enabled(self) -> bool:
        """The newest record is of the host's session, fresh, and shows the feed on."""
        return (
            self.fresh
            and self.record is not None
            and self.record.enabled
            and not self.foreign_newest
        )

    @property
    def outputs_live(self) -> bool:
        """The device gets RPDO1, its outputs (`outputs_allowed`)."""
        return outputs_allowed(self.session, self.fresh, self.state, self.foreign_newest)

    def selected(self) -> Optional[str]:
        """The configured letter the device's switch selects, if any."""
        if self.record is None or self.suspect:
            return None
        axis = self.record.axis
        if 1 <= axis <= len(self.cfg.axes):
            return self.cfg.axes[axis - 1]
        return None

    def next_action(self, now: float) -> Optional[Action]:
        """The action to carry out now, if any (none while one is pending). Without a
        session: a configuration; after a record of another session: a check (a
        configuration that keeps the session if the device still has it); else the feed
        enable. 0x2000 = 1 only while the newest record is of the host's session and shows
        the feed off. Another master's SDO exchange holds everything back
        (`_holding_back`), but the feed writes and probes of a session whose configuration set
        up the component's own SDO channel (`own_channel`): those go there."""
        self.tick(now)
        if self.pending is not None:
            return None
        own = self.own_channel
        if not own and self._holding_back():
            return None
        # On the default channel, configurations wait for another master's exchange still.
        held = (
            own
            and self.foreign_sdo_at is not None
            and self.now - self.foreign_sdo_at < self.foreign_quiet
        )
        action: Optional[Action] = None
        if self.session is None:
            if self.now >= self.config_due and not held:
                action = self._configure(keep=None)
        elif self.check_due:
            if self.now >= self.check_at and not held:
                action = self._configure(keep=self.session)
        elif self.operational and self.record is not None and self.now >= self.feed_due:
            if self.enable and not self.record.enabled and not self.foreign_newest:
                action = WriteFeed(1, own)
                self.asked_off = False
            elif not self.enable and self.record.enabled:
                action = WriteFeed(0, own)
                self.asked_off = True
        probing = self.cfg.dating and self.session is not None
        if action is None and probing and self.now >= self.probe_due:
            floor = self.order[0].sequence if self.order is not None else None
            action = Probe(self.nonce, floor, own, self.session_key or 0)
            self.nonce = (self.nonce + 1) & NONCE_MASK
            self.probe_due = self.now + PROBE_PERIOD
        self.pending = action
        return action

    def shutdown_action(self) -> Optional[Action]:
        """What to do before the component exits: disable the feed, whatever the last
        record showed. A write of 0x2000 = 1 may have been accepted without a record
        showing it yet, and a device that has been silent for a while may be back; one SDO
        exchange too many costs nothing. Except to a device held in its loader (None): it
        has no feed, and a request could break a program download under way."""
        self.asked_off = True
        return None if self.in_loader else WriteFeed(0)


Event = tuple  # ("frame", cob_id, data, t) | ("drained", t) | ("tick", t) | ("enable", bool)


def replay_core(events, cfg: Optional[Config] = None) -> Core:
    """A `Core` (of `cfg`, default `Config()`) after `events`, each handled as the shell
    does in a round of its own: the event, then `publish` at its time. Events:
    ("frame", cob_id, data, t), ("drained", t), ("tick", t), ("enable", bool),
    ("position-mode", bool), ("velocity-mode", bool), and ("configure", found, t),
    ("configure", found, t, uptime_ms) or ("configure", found, t, uptime_ms, "refused"): the
    configuration the core asks for at `t` carried out at once on a device whose 0x2002 reads
    `found` and whose uptime 0x2035 reads `uptime_ms` (None: not read) (`configure_outcome`:
    the session kept if it is the core's, else the token `pick_token` gives written), so
    that the records after it can carry the core's session; "refused": the device refused
    the token as too young (`Configured.young`).
    With `Config.dating`, a sequence probe in two events, as the shell carries it out:
    ("probe", value, floor, t): the `Probe` the core asks for at `t` (`next_action`; its
    nonce must be `value`'s bits 0-12 and its floor `floor`, None for no floor; `value`'s
    key bits are the writer's own, not the core's draw), its write sent at `t`; then
    ("probed", value, t): its answer (0x2033 as read, None: not read) reached the core at
    `t` (`done` with a `Probed` of the send time), or ("probe_refused", t): the device
    refused the write (abort 0x08000022: `done` with that abort). A `WriteFeed` the core asks
    for first is reported not carried out (the vectors' host writes no 0x2000: their masters
    do). Nothing else is asked of the core between the two. Times never go backwards in a
    real run; the core takes the latest time it was given. A malformed event, a "configure"
    or "probe" when the core asks for another action, or a "probed" or "probe_refused" with
    no probe under way raises `ValueError` (a vector's mistake, not the bus's)."""
    c = Core(cfg or Config())
    probe_sent: Optional[float] = None  # the probe under way: when its write was sent
    for event in events:
        kind = event[0] if isinstance(event, (tuple, list)) and event else None
        if kind == "configure" and len(event) in (3, 4, 5):
            _, found, t, *more = event
            action = c.next_action(float(t))
            if not isinstance(action, Configure):
                raise ValueError(f"no configuration due at {t}: {action!r}")
            uptime = (int(more[0]), float(t)) if more and more[0] is not None else None
            ok, result = configure_outcome(action, int(found), c.event_timer, uptime)
            abort = None
            if more[1:] == ["refused"] and result.tried is not None:
                # The device refused the token: too young for a session.
                ok, abort = False, ABORT_DEVICE_STATE
                result = Configured(found=int(found), tried=result.tried, young=True)
            elif more[1:]:
                raise ValueError(f"not a configure event: {event!r}")
            c.done(action, ok, abort, float(t), result)
            c.publish(float(t))
        elif kind == "probe" and len(event) == 4:
            _, value, floor, t = event
            action = c.next_action(float(t))
            while isinstance(action, WriteFeed):
                c.done(action, False, None, float(t))
                action = c.next_action(float(t))
            nonce, floor = int(value) & NONCE_MASK, None if floor is None else int(floor)
            if not (isinstance(action, Probe) and (action.nonce, action.floor) == (nonce, floor)):
                raise ValueError(f"no probe of nonce {nonce}, floor {floor} due at {t}: {action!r}")
            probe_sent = float(t)
            c.publish(float(t))
        elif kind == "probe_refused" and len(event) == 2:
            t = event[1]
            action = c.pending
            if not isinstance(action, Probe) or probe_sent is None:
                raise ValueError(f"no probe under way at {t}: {action!r}")
            c.done(action, False, ABORT_DEVICE_STATE, float(t))
            probe_sent = None
            c.publish(float(t))
        elif kind == "probed" and len(event) == 3:
            _, value, t = event
            action = c.pending
            if not isinstance(action, Probe) or probe_sent is None:
                raise ValueError(f"no probe under way at {t}: {action!r}")
            read = None if value is None else int(value)
            c.done(action, read is not None, None, float(t), Probed(probe_sent, read))
            probe_sent = None
            c.publish(float(t))
        elif kind == "frame" and len(event) == 4:
            _, cob_id, data, t = event
            c.frame(int(cob_id), bytes(data), float(t))
            c.publish(float(t))
        elif kind == "drained" and len(event) == 2:
            c.drained(float(event[1]))
            c.publish(float(event[1]))
        elif kind == "tick" and len(event) == 2:
            c.tick(float(event[1]))
            c.publish(float(event[1]))
        elif kind == "enable" and len(event) == 2:
            c.set_enable(bool(event[1]))
        elif kind == "position-mode" and len(event) == 2:
            c.set_position_mode(bool(event[1]))
        elif kind == "velocity-mode" and len(event) == 2:
            c.set_velocity_mode(bool(event[1]))
        else:
            raise ValueError(f"not an event: {event!r}")
    return c


def replay(events, cfg: Optional[Config] = None) -> Dict[str, int]:
    """The per-axis counts (`jog-counts` as published) after `events` (see `replay_core`):
    the entry point for test vectors, e.g. every delivered record stream of a model checker
    with the truth per axis to compare against."""
    c = replay_core(events, cfg)
    assert c.published is not None
    return dict(c.published.jog_counts)
