"""The HAL pins: the snapshot the core hands the shell (`Pins`), the pin tables
(`pin_table`), and how `Core` publishes its counts and gates (`Publishing`)."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable, Dict, List, Optional, Tuple

from .dating import BACKLOG_LIMIT
from .metering import IN_FLIGHT, RUN_ON, VELOCITY, AxisMotion, meter_counts
from .outputs import OUT_BOARD_OFFSET, OUT_PINS
from .overrides import OVERRIDES
from .record import STATUS_ENCODER_ERROR, wrap_s32
from .stops import STOP_NONE

# Pin steps (`Core.publish`): consecutive steps are written at least this far apart, so that
# every servo period of LinuxCNC (1 ms by default; up to 5 ms covered) that sees the counts
# of a step also sees its gates.
GATE_HOLD = 0.005


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
    jog_vel_mode: bool = False  # LinuxCNC's velocity mode for every axis
    counts_dropped: int = 0  # counts the run-on budget dropped (wrapping)
    feed_stops: int = 0  # feed stops by the device the component did not ask for (wrapping)
    stop_reason: int = STOP_NONE  # the last one's reason (`STOP_REASONS`)
    in_loader: bool = False  # the device answered as its loader at the last configuration


def _with(pins: Pins, counts: Dict[str, int], gates: Dict[str, bool]) -> Pins:
    """`pins` with these counts and gates."""
    return replace(pins, jog_counts=dict(counts), jog_enable=dict(gates))


# The HAL interface: (name without the prefix, type, direction, meaning). The shell creates
# exactly these pins; host/README.md's pin table lists them.
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
    (
        "axis.{L}.jog-vel-mode",
        "bit",
        "out",
        "true in LinuxCNC's velocity mode (`velocity-mode`, or the run-on mode outside "
        "teleop); false in the run-on and position modes",
    ),
    ("halui.axis.{L}.select", "bit", "out", "the device's switch selects this axis"),
]
# Pins of an override position, `{O}` its name in `OVERRIDES`; they go to halui's
# `halui.feed-override.*`, `halui.spindle.0.override.*`, `halui.rapid-override.*`.
OVERRIDE_PINS = [
    (
        "{O}.counts",
        "s32",
        "out",
        "wrapping sum of the detents turned at this position (any multiplier)",
    ),
    (
        "{O}.count-enable",
        "bit",
        "out",
        "true only while this position is selected, connected, Operational, feed enabled and "
        "`enable` (as `jog-enable`)",
    ),
    ("{O}.scale", "float", "out", "`--override-step` / 100: the override's change per detent"),
]
COMPONENT_PINS = [
    ("enable", "bit", "in", "feed allowed (e.g. machine on); the component writes 0x2000 = 1 / 0"),
    (
        "machine-on",
        "bit",
        "in",
        "the board's machine-on output (output 2): bit 0 of the outputs byte (RPDO1, 0x6A00:1)",
    ),
    *[
        (
            f"out-{n}",
            "bit",
            "in",
            f"the board's output {n + OUT_BOARD_OFFSET}: bit {n} of the outputs byte",
        )
        for n in range(1, OUT_PINS + 1)
    ],
    (
        "outputs-live",
        "bit",
        "out",
        "the device gets the outputs (configured by the component, Operational); false: it "
        "holds its error values (0x6A07)",
    ),
    ("outputs-sent", "s32", "out", "outputs frames (RPDO1) sent (wrapping)"),
    (
        "position-mode",
        "bit",
        "in",
        "true: LinuxCNC's position mode (every count moved, however long it takes); starts "
        "as `--position-mode` sets it",
    ),
    (
        "velocity-mode",
        "bit",
        "in",
        "true (and `position-mode` false): LinuxCNC's velocity mode; starts as "
        "`--velocity-mode` sets it; both false: the run-on mode",
    ),
    (
        "run-on-budget",
        "float",
        "in",
        "s, the run-on mode's budget (0.02..10); starts as `--run-on-budget` sets it",
    ),
    (
        "counts-dropped",
        "s32",
        "out",
        "counts the run-on mode dropped because the axis could not move them within the budget",
    ),
    (
        "connected",
        "bit",
        "out",
        "feed records of the component's session arrive (none for three event-timer periods: "
        "false)",
    ),
    (
        "feed-enabled",
        "bit",
        "out",
        "the newest record is of the component's session and shows feed enabled (status bit 0)",
    ),
    ("encoder-error", "bit", "out", "illegal quadrature transition in this epoch (status bit 1)"),
    ("axis", "s32", "out", "the device's axis switch: 0 none, 1..5 = X, Y, Z, W, V"),
    ("multiplier", "s32", "out", "1, 10 or 100"),
    ("position", "s32", "out", "the last feed record's position (multiplied units)"),
    ("emcy-code", "u32", "out", "the last active EMCY code, 0 once cleared"),
    (
        "records-lost",
        "s32",
        "out",
        "feed records missed or dropped by the device (gaps in the feed sequence)",
    ),
    (
        "frames-bad",
        "s32",
        "out",
        "frames the device cannot send (wrong DLC, impossible record, motion beyond "
        "`--max-detents-per-s`) and copies of earlier records; no motion from them",
    ),
    ("state", "s32", "out", "the device's last heartbeat state (5 Operational), -1 before any"),
    (
        "feed-stops",
        "s32",
        "out",
        "feed stops by the device the component did not ask for (each also logged with its reason)",
    ),
    (
        "stop-reason",
        "s32",
        "out",
        "the last such stop's reason: 0 none yet, 1 master heartbeat lost, 2 transmit path "
        "blocked, 3 disabled by a master write, 4 the device left Operational, 5 session ended",
    ),
    (
        "in-loader",
        "bit",
        "out",
        "the device answered as its resident loader (0x1000 = BOOT), or booted right after "
        "another master stopped its program: no application, no jogging; false once it "
        "answers as its application",
    ),
]


def pin_table(axes: str) -> List[Tuple[str, str, str]]:
    """(name without the prefix, type, direction) of every pin for these switch letters
    (`--axes`: axes and overrides)."""
    table = [
        (n.format(L=L), t, d) for L in axes if L not in OVERRIDES for (n, t, d, _) in AXIS_PINS
    ]
    table += [
        (n.format(O=OVERRIDES[L]), t, d)
        for L in axes
        if L in OVERRIDES
        for (n, t, d, _) in OVERRIDE_PINS
    ]
    table += [(n, t, d) for (n, t, d, _) in COMPONENT_PINS]
    return table


# Replaying events ----------------------------------------------------------------------------


class Publishing:
    """The part of `Core` that writes its state to the pins (see `Core` for the state)."""

    def gate(self, letter: str) -> bool:
        """`jog-enable` of axis `letter` as the core sees it now."""
        selected = self.selected() if self.fresh else None
        return self.enable and self.operational and self.feed_enabled and letter == selected

    def publish(
        self, now: float, motion: Optional[Callable[[str], Optional[AxisMotion]]] = None
    ) -> List[Pins]:
        """What the shell writes to the pins now: a list of snapshots, to be written in
        order, each completely, consecutive ones at least `GATE_HOLD` apart (the last one is
        `pins()`). The steps keep every servo period from seeing counts without their gate:
        first the gates that must be open for the new counts are opened and those of axes
        whose new counts were credited with their gate closed are closed, then the counts
        change, then (a hold later) the gates take their final values. So counts credited
        while the gate was open reach LinuxCNC with the gate open even when the same round
        closes it (a boot-up, staleness, another axis selected), and counts credited while
        it was closed never find it open (an axis's credits of one round go out together,
        with the gate open if any of them was made with it open: `enable` is read between
        rounds, so within one only a heartbeat can close the gate between two credits, and
        those were turned while Operational). Credits older than `BACKLOG_LIMIT` that were not
        yet published (the component stalled between handling a frame and writing the
        pins) are withdrawn: the counts go back to what was published.

        In the run-on mode (`metering`), an axis's new counts pass `meter_counts` first, with
        `motion(letter)`, what LinuxCNC shows of that axis now (asked only for an axis with
        new counts): what the run-on budget does not allow is dropped (`counts_dropped`),
        and all of them when LinuxCNC does not tell (None, or no `motion`)."""
        self.tick(now)
        target = self.pins()
        last = self.published
        if last is None:
            self._published(target)
            return [target]
        if self.credit_time is not None and self.now - self.credit_time > BACKLOG_LIMIT:
            self.withdrawn += 1
            self.counts = dict(last.jog_counts)
            self.credit_open = {}
            target = self.pins()
        if self.metering:
            self._meter(last, motion)
            target = self.pins()
        axes = self.cfg.axes
        changed = {L for L in axes if target.jog_counts[L] != last.jog_counts[L]}
        gates = {
            L: bool(self.credit_open.get(L)) if L in changed else last.jog_enable[L] for L in axes
        }
        steps: List[Pins] = []
        if gates != last.jog_enable:
            steps.append(_with(target, last.jog_counts, gates))
        if changed:
            steps.append(_with(target, target.jog_counts, gates))
        if not steps or gates != target.jog_enable:
            steps.append(target)
        self._published(steps[-1])
        return steps

    def _meter(self, last: Pins, motion) -> None:
        """The run-on budget applied to every axis's counts not yet published. The budget
        runs from when the component read the record of the last detent: the time the counts
        waited here since, and the hold before them when a gate opens first (`publish`), is
        spent."""
        multiplier = self.record.multiplier if self.record else 1
        unpublished = {
            L: wrap_s32(self.counts[L] - last.jog_counts[L]) for L in self.cfg.axis_letters
        }
        waited = self.now - self.credit_last if self.credit_last is not None else 0.0
        gates = {L: bool(self.credit_open.get(L)) for L, n in unpublished.items() if n}
        if any(gate != last.jog_enable[L] for L, gate in gates.items()):
            waited += GATE_HOLD  # `publish` writes the gates first, the counts a hold later
        budget = self.run_on_budget - max(0.0, waited)
        for L, counts in unpublished.items():
            if counts == 0:
                continue
            state = motion(L) if motion is not None else None
            step = multiplier if counts % multiplier == 0 else 1
            released = 0
            if state is not None:
                state = self._with_counts_in_flight(L, state)
                released = meter_counts(counts, step, self.cfg.scale, state, budget)
                if released and state.target is not None:
                    target = state.target + released * self.cfg.scale
                    self.sent_target[L] = (target, self.now)
            if released != counts:
                self.counts[L] = wrap_s32(last.jog_counts[L] + released)
                self.counts_dropped = wrap_s32(self.counts_dropped + abs(counts - released))

    def _with_counts_in_flight(self, letter: str, state: AxisMotion) -> AxisMotion:
        """`state` with the target the component's own last counts give, if it wrote them
        less than `IN_FLIGHT` ago: LinuxCNC may not have taken them yet (if it has, the two
        agree; if it dropped them, the lead is overstated for a moment: fewer counts go)."""
        sent = self.sent_target.get(letter)
        if state.target is None or sent is None or self.now - sent[1] > IN_FLIGHT:
            return state
        position = state.target - state.lead
        return replace(state, lead=sent[0] - position, target=sent[0])

    def _published(self, pins: Pins) -> None:
        self.published = pins
        self.credit_time = None
        self.credit_last = None
        self.credit_open = {}

    def pins(self) -> Pins:
        selected = self.selected() if self.fresh else None
        jog = self.enable and self.operational and self.feed_enabled
        rec = self.record if self.fresh else None
        return Pins(
            jog_counts=dict(self.counts),
            jog_enable={L: jog and L == selected for L in self.cfg.axes},
            select={L: L == selected for L in self.cfg.axis_letters},
            connected=self.fresh,
            feed_enabled=self.feed_enabled,
            encoder_error=bool(rec and rec.flags & STATUS_ENCODER_ERROR),
            axis=0 if rec is None or self.suspect else rec.axis,
            multiplier=self.record.multiplier if self.record else 1,
            position=self.record.position if self.record else 0,
            emcy_code=self.emcy_code,
            records_lost=self.records_lost,
            frames_bad=self.frames_bad,
            state=-1 if self.state is None else self.state,
            jog_vel_mode=self.mode == VELOCITY or (self.mode == RUN_ON and not self.motion_known),
            counts_dropped=self.counts_dropped,
            feed_stops=self.feed_stops,
            stop_reason=self.stop_reason,
            in_loader=self.in_loader,
        )
