"""The component's decisions, free of HAL and CAN: what a frame means, what the pins show,
what to tell the device next.

`Core` is fed events (frames from the device, the `enable` pin, the time, the outcome of the
actions it asked for) and answers with a `Pins` snapshot and at most one `Action` at a time.
The shell (`component.py`) carries out actions over python-canopen and copies the pins to
HAL; it makes no decision of its own. Everything here is plain Python and deterministic in
the times it is given, so it is tested without a bus or LinuxCNC (`host/tests`).

Rules (the README's "Use with LinuxCNC" section states them for machine builders):

- Feed bookkeeping: every accepted feed record (TPDO1) moves the `jog-counts` of the axis it
  names by the wrapping s32 difference of its position to the previous record's, but only
  when both records belong to the same selection (axis, multiplier, status bits 0 and 3)
  with the feed enabled, the previous record is still valid (no boot-up, no staleness, no bad
  record since) and the axis is one of the configured letters. Anything else makes the
  record a new baseline: a device reset, a new selection epoch or a reconnect never turns
  into motion.
- Freshness: records come at least every event-timer period in Operational; none for three
  periods means the device is gone: `connected` and every `jog-enable` drop, and the next
  record is a baseline.
- `jog-enable` of axis L: connected (fresh records), Operational (no heartbeat saying
  otherwise), the device reports feed enabled, `enable` is true, and L is the selected axis.
- Configuration (0x1016 consumer entry for the component's heartbeat, feed format 0, NMT
  start) on start, after every boot-up and when the device shows Pre-operational; retried
  every `retry` seconds while it fails.
- Feed enable: 0x2000 = 1 while `enable` is true, the device is configured, Operational,
  fresh and reports feed disabled; 0x2000 = 0 when `enable` is false and it reports feed
  enabled. Refused writes (0x08000022 while the device still misses the heartbeat) are
  retried.
- Lost records: the gaps in the sequence byte between consecutive fresh records.
- Bad data never raises: a TPDO1 of the wrong length, an unknown axis byte, an EMCY or
  heartbeat of the wrong length are counted in `frames-bad`; an unknown axis acts as "no
  axis" and forces a baseline.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Tuple

# Device heartbeat states.
BOOTUP = 0x00
STOPPED = 0x04
OPERATIONAL = 0x05
PRE_OPERATIONAL = 0x7F

# Feed record status bits.
STATUS_ENABLED = 0x01
STATUS_ENCODER_ERROR = 0x02
STATUS_STEPS_DROPPED = 0x04
STATUS_MASTER_LOST = 0x08
STATUS_TURNED_UNSEEN = 0x10

# The device's axis byte: 0 none, 1..5 these letters.
DEVICE_AXES = "xyzwv"

# SDO abort: "data cannot be transferred because of the present device state".
ABORT_DEVICE_STATE = 0x08000022


def wrap_s32(value: int) -> int:
    """`value` wrapped into the signed 32-bit range."""
    return ((value + 0x8000_0000) & 0xFFFF_FFFF) - 0x8000_0000


def parse_axes(letters: str) -> str:
    """The `--axes` option checked: letters of `xyzwv` in switch order, at least one.

    Position n of the switch (1..5) drives the n-th letter, so `xyz` uses positions 1..3.
    """
    letters = letters.strip().lower()
    if not 1 <= len(letters) <= 5:
        raise ValueError("--axes needs 1 to 5 axis letters")
    if len(set(letters)) != len(letters):
        raise ValueError(f"--axes {letters!r} names an axis twice")
    bad = [c for c in letters if c not in "xyzabcuvw"]
    if bad:
        raise ValueError(f"--axes {letters!r}: {''.join(bad)!r} is not a LinuxCNC axis letter")
    return letters


def resolve_master(node: int, master: Optional[int]) -> int:
    """The master node-ID: `master` if given (1..127, not `node`), else 1, or 2 when the
    device itself is node 1."""
    if not 1 <= node <= 127:
        raise ValueError(f"--node {node}: node-IDs are 1..127")
    if master is None:
        return 2 if node == 1 else 1
    if not 1 <= master <= 127:
        raise ValueError(f"--master-node {master}: node-IDs are 1..127")
    if master == node:
        raise ValueError(f"--master-node {master} is the device's own node-ID")
    return master


def consumer_plan(entries: Dict[int, int], master: int, timeout_ms: int) -> Tuple[int, int]:
    """Which 0x1016 sub-index to write and the value: the sub that already watches
    `master`, else the first unused one (time 0), else sub 1."""
    value = (master << 16) | timeout_ms
    for sub in sorted(entries):
        if (entries[sub] >> 16) & 0xFF == master:
            return sub, value
    for sub in sorted(entries):
        if entries[sub] & 0xFFFF == 0:
            return sub, value
    return 1, value


def make_config(
    node: int,
    master: Optional[int],
    axes: str,
    scale: float,
    event_timer_ms: int,
    heartbeat_ms: int,
) -> "Config":
    """The component's settings from its options, every one checked (`ValueError` says
    which is wrong). The device is told to allow five of the component's heartbeat periods
    (0x1016), so one late beat never stops the wheel."""
    if not (math.isfinite(scale) and scale != 0):
        raise ValueError(f"--scale {scale}: a finite, non-zero number of machine units")
    if not 10 <= heartbeat_ms <= 10000:
        raise ValueError("--heartbeat-ms must be 10..10000")
    if not 10 <= event_timer_ms <= 60000:
        raise ValueError("--event-timer-ms must be 10..60000")
    return Config(
        node=node,
        master=resolve_master(node, master),
        axes=parse_axes(axes),
        scale=scale,
        event_timer=event_timer_ms / 1000,
        heartbeat_period=heartbeat_ms / 1000,
        consumer_timeout_ms=5 * heartbeat_ms,
    )


@dataclass(frozen=True)
class Config:
    node: int = 16
    master: int = 1
    axes: str = DEVICE_AXES
    scale: float = 0.001
    event_timer: float = 0.1  # s, the device's TPDO1 event timer (0x1800:5)
    heartbeat_period: float = 0.1  # s, the component's own heartbeat
    consumer_timeout_ms: int = 500  # what the device is told to allow (0x1016)
    retry: float = 0.5  # s between attempts of a failed or unconfirmed action

    @property
    def stale_after(self) -> float:
        return 3 * self.event_timer


@dataclass(frozen=True)
class Record:
    position: int
    axis: int
    multiplier: int
    status: int
    sequence: int

    @staticmethod
    def decode(data: bytes) -> "Record":
        return Record(
            position=int.from_bytes(data[0:4], "little", signed=True),
            axis=data[4],
            multiplier=data[5],
            status=data[6],
            sequence=data[7],
        )

    @property
    def enabled(self) -> bool:
        return bool(self.status & STATUS_ENABLED)

    @property
    def selection(self) -> Tuple[int, int, int]:
        """What must stay the same for a delta to count: axis, multiplier, enable and
        master-lost bits (a change of any is a new selection epoch on the device)."""
        return (self.axis, self.multiplier, self.status & (STATUS_ENABLED | STATUS_MASTER_LOST))


# Actions the shell carries out, one at a time; it reports back with `Core.done`.
@dataclass(frozen=True)
class Configure:
    """Read 0x1016:1..2, write the `consumer_plan` entry, set 0x2001 = 0 if it is not,
    then NMT start."""

    master: int
    timeout_ms: int


@dataclass(frozen=True)
class WriteFeed:
    """0x2000 = value."""

    value: int


Action = object  # Configure | WriteFeed


@dataclass
class Pins:
    jog_counts: Dict[str, int]
    jog_enable: Dict[str, bool]
    select: Dict[str, bool]
    connected: bool = False
    feed_enabled: bool = False
    encoder_error: bool = False
    axis: int = 0
    multiplier: int = 1
    position: int = 0
    emcy_code: int = 0
    records_lost: int = 0
    frames_bad: int = 0
    state: int = -1  # last heartbeat state byte, -1 before any


@dataclass
class Core:
    cfg: Config
    enable: bool = False
    # What the device showed.
    state: Optional[int] = None  # last heartbeat state byte
    record: Optional[Record] = None  # last accepted record
    record_time: Optional[float] = None
    emcy_code: int = 0
    # Bookkeeping.
    counts: Dict[str, int] = field(default_factory=dict)
    baseline: bool = True  # the next record is a baseline
    records_lost: int = 0
    frames_bad: int = 0
    unknown_axis: bool = False
    # Actions.
    configured: bool = False
    config_due: float = 0.0  # configure at this time (if not configured)
    feed_due: float = 0.0  # earliest time for the next 0x2000 write
    pending: Optional[Action] = None
    now: float = 0.0

    def __post_init__(self) -> None:
        self.counts = {letter: 0 for letter in self.cfg.axes}

    # Events ---------------------------------------------------------------------------

    def frame(self, cob_id: int, data: bytes, now: float) -> None:
        """A frame from the bus (any identifier; others than the device's are ignored)."""
        self.tick(now)
        node = self.cfg.node
        if cob_id == 0x180 + node:
            self._tpdo1(bytes(data), now)
        elif cob_id == 0x080 + node:
            self._emcy(bytes(data))
        elif cob_id == 0x700 + node:
            self._heartbeat(bytes(data), now)

    def set_enable(self, enable: bool) -> None:
        if enable != self.enable:
            self.feed_due = 0.0  # act at once
        self.enable = enable

    def tick(self, now: float) -> None:
        """Time passes: staleness."""
        self.now = max(self.now, now)
        if self.record_time is not None and not self.fresh:
            self.baseline = True

    def done(self, action: Action, ok: bool, abort: Optional[int], now: float) -> None:
        """The outcome of the pending action (`abort`: the SDO abort code, if any)."""
        self.tick(now)
        if action is not self.pending:
            return
        self.pending = None
        if isinstance(action, Configure):
            if ok:
                self.configured = True
                self.feed_due = 0.0
            else:
                self.config_due = self.now + self.cfg.retry
        elif isinstance(action, WriteFeed):
            # Success shows in the next records; give them time before trying again.
            self.feed_due = self.now + self.cfg.retry

    # Decisions ------------------------------------------------------------------------

    @property
    def fresh(self) -> bool:
        return self.record_time is not None and self.now - self.record_time <= self.cfg.stale_after

    @property
    def operational(self) -> bool:
        return self.fresh and self.state in (None, OPERATIONAL)

    @property
    def feed_enabled(self) -> bool:
        return self.fresh and self.record is not None and self.record.enabled

    def selected(self) -> Optional[str]:
        """The configured letter the device's switch selects, if any."""
        if self.record is None or self.unknown_axis:
            return None
        axis = self.record.axis
        if 1 <= axis <= len(self.cfg.axes):
            return self.cfg.axes[axis - 1]
        return None

    def next_action(self, now: float) -> Optional[Action]:
        """The action to carry out now, if any (none while one is pending)."""
        self.tick(now)
        if self.pending is not None:
            return None
        action: Optional[Action] = None
        if not self.configured:
            if self.now >= self.config_due:
                action = Configure(self.cfg.master, self.cfg.consumer_timeout_ms)
        elif self.operational and self.record is not None and self.now >= self.feed_due:
            if self.enable and not self.record.enabled:
                action = WriteFeed(1)
            elif not self.enable and self.record.enabled:
                action = WriteFeed(0)
        self.pending = action
        return action

    def shutdown_action(self) -> Optional[Action]:
        """What to do before the component exits: disable the feed if it may be on."""
        if self.fresh and self.record is not None and self.record.enabled:
            return WriteFeed(0)
        return None

    def pins(self) -> Pins:
        selected = self.selected() if self.fresh else None
        jog = self.enable and self.operational and self.feed_enabled
        rec = self.record if self.fresh else None
        return Pins(
            jog_counts=dict(self.counts),
            jog_enable={L: jog and L == selected for L in self.cfg.axes},
            select={L: L == selected for L in self.cfg.axes},
            connected=self.fresh,
            feed_enabled=self.feed_enabled,
            encoder_error=bool(rec and rec.status & STATUS_ENCODER_ERROR),
            axis=0 if rec is None or self.unknown_axis else rec.axis,
            multiplier=self.record.multiplier if self.record else 1,
            position=self.record.position if self.record else 0,
            emcy_code=self.emcy_code,
            records_lost=self.records_lost,
            frames_bad=self.frames_bad,
            state=-1 if self.state is None else self.state,
        )

    # Frame handlers -------------------------------------------------------------------

    def _bad(self) -> None:
        self.frames_bad = wrap_s32(self.frames_bad + 1)

    def _tpdo1(self, data: bytes, now: float) -> None:
        if len(data) != 8:
            self._bad()
            return
        rec = Record.decode(data)
        prev = self.record
        continuous = prev is not None and self.fresh
        was_fresh = continuous and not self.baseline
        unknown = rec.axis > len(DEVICE_AXES)
        if unknown:
            self._bad()
        if continuous:
            gap = (rec.sequence - prev.sequence - 1) & 0xFF
            self.records_lost = wrap_s32(self.records_lost + gap)
        apply = (
            was_fresh
            and not unknown
            and not self.unknown_axis
            and prev is not None
            and prev.selection == rec.selection
            and rec.enabled
        )
        if apply:
            letter = self._letter(rec.axis)
            if letter is not None:
                delta = wrap_s32(rec.position - prev.position)
                self.counts[letter] = wrap_s32(self.counts[letter] + delta)
        self.record = rec
        self.record_time = now
        self.unknown_axis = unknown
        self.baseline = unknown
        if self.state in (None, BOOTUP):
            # PDOs only flow in Operational; the heartbeat will say so too.
            self.state = OPERATIONAL

    def _letter(self, axis: int) -> Optional[str]:
        if 1 <= axis <= len(self.cfg.axes):
            return self.cfg.axes[axis - 1]
        return None

    def _emcy(self, data: bytes) -> None:
        if len(data) != 8:
            self._bad()
            return
        self.emcy_code = int.from_bytes(data[0:2], "little")

    def _heartbeat(self, data: bytes, now: float) -> None:
        if len(data) != 1:
            self._bad()
            return
        state = data[0] & 0x7F
        if state == BOOTUP:
            # A (re)started device: everything it had is gone.
            self.configured = False
            self.config_due = self.now
            self.baseline = True
            self.record = None
            self.record_time = None
            self.unknown_axis = False
            self.emcy_code = 0
            if isinstance(self.pending, Configure):
                # Its outcome no longer says anything about this boot; do it again.
                self.pending = None
        elif state == PRE_OPERATIONAL and self.configured and self.pending is None:
            # Someone (or a missed boot-up) left it Pre-operational: configure and start.
            self.configured = False
            self.config_due = self.now
        self.state = state


# The HAL interface: (name without the prefix, type, direction, meaning). The shell creates
# exactly these pins; the README's pin table lists them.
AXIS_PINS = [
    (
        "axis.{L}.jog-counts",
        "s32",
        "out",
        "wrapping sum of the position deltas of the feed records that named this axis",
    ),
    (
        "axis.{L}.jog-enable",
        "bit",
        "out",
        "true only for the selected axis while connected, Operational, feed enabled and `enable`",
    ),
    ("axis.{L}.jog-scale", "float", "out", "`--scale`: machine units per multiplied unit"),
    ("axis.{L}.jog-vel-mode", "bit", "out", "false: move the exact distance"),
    ("halui.axis.{L}.select", "bit", "out", "the device's switch selects this axis"),
]
COMPONENT_PINS = [
    ("enable", "bit", "in", "feed allowed (e.g. machine on); the component writes 0x2000 = 1 / 0"),
    ("connected", "bit", "out", "feed records arrive (none for three event-timer periods: false)"),
    ("feed-enabled", "bit", "out", "the device reports feed enabled (status bit 0)"),
    ("encoder-error", "bit", "out", "illegal quadrature transition in this epoch (status bit 1)"),
    ("axis", "s32", "out", "the device's axis switch: 0 none, 1..5 = X, Y, Z, W, V"),
    ("multiplier", "s32", "out", "1, 10 or 100"),
    ("position", "s32", "out", "the last feed record's position (multiplied units)"),
    ("emcy-code", "u32", "out", "the last active EMCY code, 0 once cleared"),
    ("records-lost", "s32", "out", "feed records missed (gaps in the sequence byte)"),
    (
        "frames-bad",
        "s32",
        "out",
        "malformed frames from the device (wrong DLC, unknown axis byte), ignored",
    ),
    ("state", "s32", "out", "the device's last heartbeat state (5 Operational), -1 before any"),
]


def pin_table(axes: str) -> List[Tuple[str, str, str]]:
    """(name without the prefix, type, direction) of every pin for these axis letters."""
    table = [(n.format(L=L), t, d) for L in axes for (n, t, d, _) in AXIS_PINS]
    table += [(n, t, d) for (n, t, d, _) in COMPONENT_PINS]
    return table
