"""`canopen-handwheel decode FILE`: a capture in CANopen terms, and what the host's rule made
of every feed record, by replaying the capture through the component's own core.

Every frame is one line: NMT commands, heartbeats with the state, SDO requests and replies
with index, sub-index, value and the meaning of an abort code, EMCYs with the meaning of their
code, feed records (`core.Record`) with every field, unit steps (TPDO2). Beside each feed
record: the verdict the core answered when it took the record (`core.FeedVerdict`: the
counts it credited and to which axis, or why none: a gap, a duplicate, a copy of an earlier
record, a baseline and why, another session's record), printed as it is; at the end a summary
per axis and the pins as the component last wrote them (`pin_replay`: the component's own
`HalPins` into a stand-in for LinuxCNC's `hal`).

`replay` runs a capture (`capture.read`) through a `core.Core`, as the component's main loop
ran it: the frames of the device at their time stamps, and, with the component's host notes,
its input pins, the actions it carried out and their outcomes, and the moments it last found
its receive path empty, so that the pins come out as the component wrote them (its run-on
metering aside: what LinuxCNC showed of the axes is not in a capture, so a replay never meters
and shows the counts the rule credited). Without notes (a capture taken by candump or any other
tool) the host's side is inferred from the bus: the configuration from the SDO transfers
(0x2002 written and confirmed: the session), the feed as enabled, and every frame read as it
came.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from dataclasses import dataclass, field
from typing import Callable, Dict, List, Optional, Sequence, Tuple

from . import capture as captures
from . import core
from .record import Record

# The verdicts' kinds (`FeedVerdict.kind`), by the names the decoder's users test them with.
from .verdict import (  # noqa: F401
    AT_REST,
    BASELINE,
    COPY,
    CREDITED,
    DROPPED,
    DUPLICATE,
    FOREIGN,
    IMPOSSIBLE,
    NOT_CREDITED,
    FeedVerdict,
)

# NMT command specifiers (CiA 301).
NMT_COMMANDS = {
    0x01: "start",
    0x02: "stop",
    0x80: "enter pre-operational",
    0x81: "reset node",
    0x82: "reset communication",
}
HEARTBEAT_STATES = {
    core.BOOTUP: "boot-up",
    core.STOPPED: "stopped",
    core.OPERATIONAL: "operational",
    core.PRE_OPERATIONAL: "pre-operational",
}
# SDO abort codes (CiA 301, 7.2.4.3.17).
SDO_ABORTS = {
    0x05030000: "toggle bit not alternated",
    0x05040000: "SDO protocol timed out",
    0x05040001: "command specifier not valid or unknown",
    0x05040002: "invalid block size",
    0x05040003: "invalid sequence number",
    0x05040004: "CRC error",
    0x05040005: "out of memory",
    0x06010000: "unsupported access to an object",
    0x06010001: "attempt to read a write-only object",
    0x06010002: "attempt to write a read-only object",
    0x06020000: "object does not exist in the object dictionary",
    0x06040041: "object cannot be mapped to the PDO",
    0x06040042: "mapped objects would exceed the PDO length",
    0x06040043: "general parameter incompatibility",
    0x06040047: "general internal incompatibility in the device",
    0x06060000: "access failed due to a hardware error",
    0x06070010: "data type does not match, length of service parameter does not match",
    0x06070012: "data type does not match, length of service parameter too high",
    0x06070013: "data type does not match, length of service parameter too low",
    0x06090011: "sub-index does not exist",
    0x06090030: "invalid value for parameter",
    0x06090031: "value of parameter written too high",
    0x06090032: "value of parameter written too low",
    0x06090036: "maximum value is less than minimum value",
    0x060A0023: "resource not available: SDO connection",
    0x08000000: "general error",
    0x08000020: "data cannot be transferred or stored to the application",
    0x08000021: "data cannot be transferred or stored because of local control",
    0x08000022: "data cannot be transferred or stored because of the present device state",
    0x08000023: "no object dictionary present",
    0x08000024: "no data available",
}
# This device's EMCY codes (README "Emergency codes"), then the CiA 301 classes of the rest.
EMCY_CODES = {
    0x0000: "error reset (no error left)",
    0x7300: "illegal quadrature transition in this selection epoch",
    0x8130: "monitored heartbeat lost: feed stopped (status bit 3)",
    0x8100: "frames could not reach the bus for 100 ms: feed stopped, queue discarded",
    0x8110: "CAN receive overrun: frames lost",
    0x8120: "CAN controller error passive",
    0x8140: "CAN controller recovered from bus-off",
    0x6300: "a stored parameter was not restored",
}
EMCY_CLASSES = {
    0x10: "generic error",
    0x20: "current",
    0x30: "voltage",
    0x40: "temperature",
    0x50: "device hardware",
    0x60: "device software",
    0x70: "additional modules",
    0x80: "monitoring",
    0x81: "communication",
    0x82: "protocol error",
    0x90: "external error",
    0xF0: "additional functions",
    0xFF: "device specific",
}
FLAG_NAMES = (
    (core.STATUS_ENABLED, "enabled"),
    (core.STATUS_ENCODER_ERROR, "encoder error"),
    (core.STATUS_STEPS_DROPPED, "steps dropped"),
    (core.STATUS_MASTER_LOST, "master lost"),
    (core.STATUS_IGNORED_MOTION, "ignored motion"),
)


def object_names(node: int) -> Dict[Tuple[int, int], str]:
    """(index, sub) -> the object's name in the shipped EDS (python-canopen reads it);
    empty if it cannot be read."""
    try:
        import canopen

        from .bus import default_eds

        od = canopen.import_od(default_eds(), node)
    except Exception:
        return {}
    names: Dict[Tuple[int, int], str] = {}
    for obj in od.values():
        subs = getattr(obj, "subindices", None)
        if subs:
            for sub, var in subs.items():
                own = var.name.startswith(obj.name)
                names[(obj.index, sub)] = var.name if own else f"{obj.name}: {var.name}"
        else:
            names[(obj.index, 0)] = obj.name
    return names


# Frames in CANopen terms --------------------------------------------------------------------


class Describer:
    """One line of CANopen for every frame; SDO requests are kept so that an upload's reply
    names its object (a segmented one's reply carries no index)."""

    def __init__(self, cfg: core.Config, names: Optional[Dict[Tuple[int, int], str]] = None):
        self.cfg = cfg
        self.names = names if names is not None else {}

    def name(self, index: int, sub: int) -> str:
        n = self.names.get((index, sub))
        return f"0x{index:04X}:{sub}" + (f" ({n})" if n else "")

    def describe(self, f: captures.Frame) -> str:
        if f.error:
            return "error frame"
        if f.extended:
            return "extended frame (not CANopen)"
        cob, data = f.id, f.data
        fn, node = cob & 0x780, cob & 0x7F
        if f.remote:
            return f"remote request (RTR) for 0x{cob:03X}"
        if cob == 0x000:
            return self.nmt(data)
        if cob == 0x080:
            return "SYNC" + (f" counter {data[0]}" if data else "")
        if cob == 0x100:
            return "TIME"
        if cob in (0x7E4, 0x7E5):
            return ("LSS reply" if cob == 0x7E4 else "LSS request") + f" cs 0x{data[:1].hex()}"
        if fn == 0x080 and node:
            return self.emcy(node, data)
        if fn == 0x180 and node == self.cfg.node:
            return self.feed_record(data)
        if fn == 0x280 and node == self.cfg.node and len(data) == 1:
            return unit_step(data[0])
        if fn in (0x180, 0x280, 0x380, 0x480):
            return f"TPDO{(fn - 0x100) >> 8} of node {node}"
        if fn == core.RPDO1 and node == self.cfg.node and len(data) == 1:
            return core.describe_outputs(data[0])
        if fn in (0x200, 0x300, 0x400, 0x500):
            return f"RPDO{(fn - 0x180) >> 8} to node {node}"
        if fn == 0x580:
            return f"SDO reply of node {node}: " + self.sdo_reply(data)
        if fn == 0x600:
            return f"SDO request to node {node}: " + self.sdo_request(data)
        if fn == 0x700:
            if len(data) != 1:
                return f"heartbeat of node {node} with {len(data)} bytes (a heartbeat has 1)"
            state = data[0] & 0x7F
            return f"heartbeat of node {node}: " + HEARTBEAT_STATES.get(
                state, f"state 0x{state:02X}"
            )
        return f"0x{cob:03X}"

    @staticmethod
    def nmt(data: bytes) -> str:
        if len(data) != 2:
            return f"NMT command with {len(data)} bytes (it has 2)"
        what = NMT_COMMANDS.get(data[0], f"command 0x{data[0]:02X}")
        return f"NMT {what}, " + ("all nodes" if data[1] == 0 else f"node {data[1]}")

    @staticmethod
    def emcy(node: int, data: bytes) -> str:
        if len(data) != 8:
            return f"EMCY of node {node} with {len(data)} bytes (an EMCY has 8)"
        code = int.from_bytes(data[0:2], "little")
        meaning = (
            EMCY_CODES.get(code)
            or EMCY_CLASSES.get(code >> 8)
            or EMCY_CLASSES.get(code >> 12 << 4, "unknown class")
        )
        return (
            f"EMCY of node {node}: 0x{code:04X} {meaning}; error register 0x{data[2]:02X}, "
            f"manufacturer {data[3:8].hex(' ')}"
        )

    def feed_record(self, data: bytes) -> str:
        if len(data) != 8:
            return f"feed record with {len(data)} bytes (a record has 8)"
        r = Record.decode(data)
        return "feed record: " + record_fields(r)

    def sdo_request(self, data: bytes) -> str:
        if len(data) != 8:
            return f"{len(data)} bytes (SDO frames have 8)"
        cmd, index, sub = data[0], int.from_bytes(data[1:3], "little"), data[3]
        ccs = cmd >> 5
        if ccs == 1:
            return f"download {self.name(index, sub)} " + _initiate_value(cmd, data)
        if ccs == 2:
            return f"upload {self.name(index, sub)}"
        if ccs == 0:
            return _segment(cmd, data, "download segment")
        if ccs == 3:
            return f"upload segment request (toggle {cmd >> 4 & 1})"
        if ccs == 4:
            return f"abort {self.name(index, sub)}: " + _abort(data)
        if ccs in (5, 6):
            return ("block upload" if ccs == 5 else "block download") + f" (command 0x{cmd:02X})"
        return f"command 0x{cmd:02X}"

    def sdo_reply(self, data: bytes) -> str:
        if len(data) != 8:
            return f"{len(data)} bytes (SDO frames have 8)"
        cmd, index, sub = data[0], int.from_bytes(data[1:3], "little"), data[3]
        scs = cmd >> 5
        if scs == 3:
            return f"download {self.name(index, sub)} done"
        if scs == 2:
            return f"upload {self.name(index, sub)} " + _initiate_value(cmd, data)
        if scs == 1:
            return f"download segment done (toggle {cmd >> 4 & 1})"
        if scs == 0:
            return _segment(cmd, data, "upload segment")
        if scs == 4:
            return f"abort {self.name(index, sub)}: " + _abort(data)
        if scs in (5, 6):
            return ("block upload" if scs == 6 else "block download") + f" (command 0x{cmd:02X})"
        return f"command 0x{cmd:02X}"


def _initiate_value(cmd: int, data: bytes) -> str:
    """The value of an SDO initiate frame: expedited (the bytes it gives), or segmented (the
    size, if indicated)."""
    expedited, sized = cmd & 0x02, cmd & 0x01
    if expedited:
        n = 4 - (cmd >> 2 & 3) if sized else 4
        value = int.from_bytes(data[4 : 4 + n], "little")
        return f"= {value} (0x{value:0{2 * n}X})"
    if sized:
        return f"segmented, {int.from_bytes(data[4:8], 'little')} bytes"
    return "segmented"


def _segment(cmd: int, data: bytes, what: str) -> str:
    n = 7 - (cmd >> 1 & 7)
    last = " (last)" if cmd & 1 else ""
    return f"{what} (toggle {cmd >> 4 & 1}): {data[1 : 1 + n]!r}{last}"


def abort_meaning(code: int) -> str:
    return SDO_ABORTS.get(code, "unknown abort code")


def _abort(data: bytes) -> str:
    code = int.from_bytes(data[4:8], "little")
    return f"0x{code:08X} {abort_meaning(code)}"


def unit_step(byte: int) -> str:
    """TPDO2's unit-step byte (README "Paper-compatible unit-step format")."""
    axis = byte & 0x07
    letter = core.DEVICE_AXES[axis].upper() if axis < len(core.DEVICE_AXES) else f"{axis}?"
    direction = "forward" if byte & 0x08 else "backward"
    return f"unit step: axis {letter}, {direction}, counter {byte >> 4}"


def record_fields(r: Record) -> str:
    """Every field of a feed record."""
    axis = (
        "none"
        if r.axis == 0
        else (
            core.DEVICE_AXES[r.axis - 1].upper()
            if r.axis <= len(core.DEVICE_AXES)
            else f"{r.axis} (never sent)"
        )
    )
    flags = [name for bit, name in FLAG_NAMES if r.flags & bit] or ["none"]
    mult = f"x{r.multiplier}" if r.multiplier else "multiplier code 3 (never sent)"
    return (
        f"position {r.position}, axis {axis}, {mult}, epoch {r.epoch}, flags "
        f"{'|'.join(flags)}, session {r.session}, sequence {r.sequence}"
    )


def record_signals(r: Record) -> Dict[str, int]:
    """The raw values the DBC's TPDO1 signals (eds/handwheel.dbc, `cargo xtask dbc`) carry
    for record `r`: what a CAN tool reading a capture with the DBC must show."""
    code = core.MULTIPLIERS.index(r.multiplier) if r.multiplier in core.MULTIPLIERS else 3
    out = {
        "PositionValue": r.position,
        "Axis": r.axis,
        "Multiplier": code,
        "SelectionEpoch": r.epoch,
        "FeedSession": r.session,
        "FeedSequence": r.sequence,
    }
    for (bit, _), name in zip(FLAG_NAMES, DBC_FLAGS):
        out[name] = int(bool(r.flags & bit))
    return out


# The DBC's names of the status flags, bit 0 first.
DBC_FLAGS = ("FeedEnabled", "EncoderError", "StepsDropped", "MasterLost", "IgnoredMotion")


# Replaying -------------------------------------------------------------------------------------


@dataclass
class Line:
    """One frame of the capture and what it was: `text` in CANopen terms, `verdict` for a feed
    record of the device (what the core answered it), `log` the core's log lines it caused."""

    frame: captures.Frame
    text: str
    verdict: Optional[FeedVerdict] = None
    log: List[str] = field(default_factory=list)


@dataclass
class Replay:
    """A capture replayed through the core."""

    cfg: core.Config
    lines: List[Line]
    pins: Dict[str, object]  # the pins as the component wrote them last (at the loop's end)
    changes: List[Tuple[float, str, object]]  # every pin change until then (time, pin, value)
    core: core.Core
    notes: bool  # the component's host notes drove the host's side
    events: List[Tuple[float, str]]  # host notes and inferred host events, in CANopen terms
    mismatches: List[str]  # where the replayed core asked for another action than the notes

    initial: Dict[str, object] = field(default_factory=dict)  # every pin's value when made

    def history(self, pin: str) -> List[object]:
        """The values `pin` changed to, in order."""
        return [v for _, p, v in self.changes if p == pin]

    def differences(self, live: Sequence[Tuple[float, str, str]]) -> List[str]:
        """Where the pins of the live run differ from the replay's: `live` is every change of
        a pin as fake_hal logs it (time, pin, value as text). Every output pin must end on the
        same value, and the values a counting pin (`jog-counts`, an override's `counts`, and
        the counters) took live must appear in the replay in the same order: the replay
        writes the pins after every frame, the component after each round of its loop, which
        may take several frames at once."""
        out = []
        last: Dict[str, str] = {}
        taken: Dict[str, List[str]] = {}
        for _, pin, value in live:
            last[pin] = value
            taken.setdefault(pin, []).append(value)
        for pin, _, direction in core.pin_table(self.cfg.axes):
            if direction != "out":
                continue
            want = last.get(pin, str(self.initial.get(pin)))
            got = str(self.pins.get(pin))
            if pin == "outputs-sent":
                # The outputs' thread may send after the loop last wrote the pins: the
                # capture may hold a few frames more than the pin counted.
                if not 0 <= int(got) - int(want) <= SENT_AFTER_THE_LAST_WRITE:
                    out.append(f"{pin}: {want} live, {got} replayed")
            elif want != got:
                out.append(f"{pin}: {want} live, {got} replayed")
            counting = pin.endswith("counts") or pin in COUNTERS
            replayed = [str(v) for v in [self.initial.get(pin)] + self.history(pin)]
            if counting and not _subsequence(taken.get(pin, []), replayed):
                out.append(
                    f"{pin}: took {taken.get(pin, [])[:40]} live, {self.history(pin)[:40]} replayed"
                )
        return out


# The outputs frames that may go out between the main loop's last pin write and the end of
# the outputs' thread (one round of the loop, far less than `OUTPUT_INHIBIT` apart each).
SENT_AFTER_THE_LAST_WRITE = 2
# The pins that count events: their every value shows in a replay.
COUNTERS = ("records-lost", "frames-bad", "feed-stops", "counts-dropped")


def _subsequence(part: Sequence[str], whole: Sequence[str]) -> bool:
    it = iter(whole)
    return all(any(x == y for y in it) for x in part)


def _records(lines: Sequence[Line]) -> List[Line]:
    return [line for line in lines if line.verdict is not None]


class _Inference:
    """The host's side of a capture without notes, from the bus: a configuration when the
    device confirms a write of 0x2002 (its session), or, if the capture shows none, when the
    first record of a session comes."""

    def __init__(self, c: core.Core, cfg: core.Config, events: List[Tuple[float, str]]) -> None:
        self.c = c
        self.cfg = cfg
        self.events = events
        self.request: Optional[bytes] = None
        self.found: Optional[int] = None
        self.timer_ms: Optional[int] = None
        self.configured = False
        c.set_enable(True)

    def frame(self, f: captures.Frame) -> None:
        node = self.cfg.node
        if f.id == 0x600 + node and len(f.data) == 8:
            self.request = f.data
        elif f.id == 0x580 + node and len(f.data) == 8 and self.request is not None:
            req, rep = self.request, f.data
            self.request = None
            index, sub = int.from_bytes(req[1:3], "little"), req[3]
            if rep[1:4] != req[1:4]:
                return
            if rep[0] >> 5 == 2 and rep[0] & 0x02:  # an expedited upload
                value = int.from_bytes(rep[4:8], "little")
                if (index, sub) == (0x2002, 0):
                    self.found = value
                elif (index, sub) == (0x1800, 5):
                    self.timer_ms = value
            elif rep[0] >> 5 == 3 and req[0] >> 5 == 1 and req[0] & 0x02:  # download done
                value = int.from_bytes(req[4:8], "little") & 0xFF
                if (index, sub) == (0x1800, 5):
                    self.timer_ms = int.from_bytes(req[4:6], "little")
                elif (index, sub) == (0x2002, 0) and value:
                    self.configure(value, f.t, "0x2002 written")
        elif f.id == 0x180 + node and len(f.data) == 8 and not self.configured:
            rec = Record.decode(f.data)
            if rec.session and self.c.session is None:
                self.configure(rec.session, f.t, "no configuration in the capture: assumed")

    def configure(self, token: int, t: float, why: str) -> None:
        c = self.c
        for _ in range(3):
            action = c.next_action(t)
            if isinstance(action, core.WriteFeed):
                c.done(action, True, None, t)
                continue
            break
        else:
            action = None
        if action is None and isinstance(c.pending, core.Configure):
            action = c.pending
        if not isinstance(action, core.Configure):
            self.events.append((t, f"session {token} ({why}): the host's rule had none due"))
            return
        if action.keep is not None and action.keep == token:
            result = core.Configured(found=token, intact=True, session=token, first_reply_at=t)
        else:
            result = core.Configured(
                event_timer_ms=self.timer_ms or core.DEFAULT_EVENT_TIMER_MS,
                first_reply_at=t,
                found=self.found or 0,
                tried=token,
                session=token,
                keyed=True,  # the bus shows no key: a component before it wrote none
            )
        c.done(action, True, None, t, result)
        self.configured = True
        taken = "taken" if c.session == token else f"not taken (the rule's session: {c.session})"
        self.events.append((t, f"configuration: session {token} ({why}), {taken}"))


class _Run:
    """One start of the component: its core, its pins (written by the component's own
    `HalPins` into a recorder) and the host's side (notes, or inferred from the bus)."""

    def __init__(self, cfg: core.Config, with_notes: bool, events) -> None:
        from .pin_replay import HalRecorder, shell_pins

        self.c = core.Core(cfg)
        self.hal = HalRecorder()
        self.pins = shell_pins(self.hal, cfg)
        self.infer = None if with_notes else _Inference(self.c, cfg, events)
        self.stopped: Optional[Tuple[Dict[str, object], int]] = None
        self.drained_noted = False
        self.outputs_sent = 0  # the outputs frames (RPDO1) the component sent so far

    def publish(self, t: float) -> None:
        from .pin_replay import write_steps

        if self.stopped is None:
            self.hal.now = t
            write_steps(self.pins, self.c.publish(t))
            if self.c.cfg.output_period is not None:  # a component that sends outputs
                self.pins.write_outputs(self.c.outputs_live, self.outputs_sent)

    def final(self) -> Tuple[Dict[str, object], int]:
        return self.stopped or (dict(self.hal.values), len(self.hal.changes))


def replay(
    files: Sequence[captures.CaptureFile],
    cfg: Optional[core.Config] = None,
    names: Optional[Dict[Tuple[int, int], str]] = None,
) -> Replay:
    """The capture's files (oldest first) through a `core.Core` of `cfg` (default: the notes'
    settings, else `core.Config()`), publishing the pins after every frame and note as the
    component's main loop does after each round; a note `stop` fixes the pins (the main loop
    ended there; the shutdown's frames are still decoded and judged). A file of another
    start of the component (its notes say) begins a new core; the pins are the last one's."""
    with_notes = any(f.notes is not None for f in files)
    if cfg is None:
        fields = next((f.config for f in files if f.config), None)
        cfg = captures.config_from_fields(fields) if fields else core.Config()
    events: List[Tuple[float, str]] = []
    mismatches: List[str] = []
    lines: List[Line] = []
    describer = Describer(cfg, names)
    device = {0x180 + cfg.node, 0x080 + cfg.node, 0x700 + cfg.node}
    # The default SDO channel's frames the component read (never its own requests): its core
    # sees them too (another master's exchanges hold its requests back).
    sdo_channel = {0x580 + cfg.node, 0x600 + cfg.node}
    run = _Run(cfg, with_notes, events)
    run_id = None
    for f in files:
        if f.run is not None and run_id is not None and f.run != run_id:
            t = f.frames[0].t if f.frames else 0.0
            events.append((t, "the component started again: a new core"))
            run = _Run(cfg, with_notes, events)
        run_id = f.run or run_id
        c = run.c
        for kind, item in captures.merged(f):
            if kind == "note":
                _note(run, item, events, mismatches)
                continue
            frame: captures.Frame = item
            t = frame.t
            line = Line(frame, describer.describe(frame))
            judged = not (frame.error or frame.extended or frame.remote) and frame.id in device
            if not frame.rx and frame.id == core.RPDO1 + cfg.node:
                run.outputs_sent = core.wrap_s32(run.outputs_sent + 1)
            if run.infer is not None:
                run.infer.frame(frame)
            if judged:
                if not run.drained_noted:
                    c.drained(t - (captures.DRAIN_SLACK if with_notes else 0.0))
                run.drained_noted = False
                line.verdict = c.frame(frame.id, frame.data, t)  # TPDO1's: the rule's answer
            elif (
                frame.rx
                and not (frame.error or frame.extended or frame.remote)
                and (frame.id in sdo_channel)
            ):
                c.frame(frame.id, frame.data, t)
            else:
                c.tick(t)
            line.log = c.take_log()
            run.publish(t)
            lines.append(line)
    final, count = run.final()
    return Replay(
        cfg,
        lines,
        final,
        run.hal.changes[:count],
        run.c,
        with_notes,
        events,
        mismatches,
        run.hal.initial,
    )


def _note(run: _Run, note: captures.Note, events, mismatches) -> None:
    """A host note handed to the run's core as the component's main loop did."""
    c, t, n = run.c, note.t, note.fields
    if "drained" in n:
        run.drained_noted = True
        if n["drained"] is not None:
            c.drained(t)
    elif "input" in n:
        _inputs(c, n["input"])
        events.append((t, "inputs: " + _kv(n["input"])))
    elif "action" in n:
        action = c.next_action(t)
        got = captures.action_name(action) if action is not None else "nothing"
        if not isinstance(action, core.Probe):  # one every 0.1 s: not listed
            events.append((t, f"the host asks: {n['action']}"))
        if got != n["action"]:
            mismatches.append(f"{t:.6f}: the component asked {n['action']}, the replay {got}")
    elif "done" in n:
        _done(c, n["done"], t, events, mismatches)
    elif "stop" in n:
        run.publish(t)
        events.append((t, "the component's main loop ended (pins final); shutdown"))
        c.shutdown_action()
        run.stopped = (dict(run.hal.values), len(run.hal.changes))


def _kv(d: dict) -> str:
    return ", ".join(f"{k.replace('_', '-')} {v}" for k, v in d.items())


def _inputs(c: core.Core, values: dict) -> None:
    setters: Dict[str, Callable] = {
        "enable": c.set_enable,
        "position_mode": c.set_position_mode,
        "velocity_mode": c.set_velocity_mode,
        "run_on_budget": c.set_run_on_budget,
    }
    for name, value in values.items():
        if name in setters:
            setters[name](value)
    # What LinuxCNC showed of the axes is not in the capture: the replay never meters.
    c.set_motion_known(False)


def _done(c: core.Core, d: dict, t: float, events, mismatches) -> None:
    action = c.pending
    if action is None or captures.action_name(action) != d.get("action"):
        mismatches.append(f"{t:.6f}: the outcome of {d.get('action')}, the replay has {action}")
        return
    result = None
    if d.get("result"):
        outcome = dict(d["result"])
        for name in [k for k in outcome if k.endswith("_dt")]:
            dt = outcome.pop(name)
            outcome[name[:-3] + "_at"] = None if dt is None else t + dt
        kind = core.Probed if isinstance(action, core.Probe) else core.Configured
        if kind is core.Configured and "keyed" not in outcome:
            outcome["keyed"] = True  # a component before the session key: none to write
        known = {f.name for f in dataclasses.fields(kind)}
        result = kind(**{k: v for k, v in outcome.items() if k in known})
    abort = d.get("abort")
    c.done(action, bool(d.get("ok")), abort, t, result)
    if isinstance(action, core.Probe):
        return  # one every 0.1 s: not listed
    what = f"{d.get('action')}: {'done' if d.get('ok') else 'failed'}"
    if abort:
        what += f", abort 0x{abort:08X} {abort_meaning(abort)}"
    if isinstance(result, core.Configured) and result.session is not None:
        what += f", session {result.session} (0x2002 was {result.found})"
    events.append((t, what))


# The report ------------------------------------------------------------------------------------


@dataclass
class AxisSummary:
    credited: int = 0
    records: int = 0  # records credited
    not_credited: int = 0  # records whose motion was not credited
    motion_not_credited: int = 0


def summary(r: Replay) -> List[str]:
    """The summary lines: per configured position, what was credited and what was not; then
    the records by verdict, and the pins at the end."""
    cfg = r.cfg
    axes: Dict[str, AxisSummary] = {L: AxisSummary() for L in cfg.axes}
    kinds: Dict[str, int] = {}
    lost = 0
    for line in _records(r.lines):
        v = line.verdict
        assert v is not None
        kinds[v.kind] = kinds.get(v.kind, 0) + 1
        lost += v.lost
        if v.axis is None:
            continue
        if v.credited:
            axes[v.axis].credited += v.delta
            axes[v.axis].records += 1
        elif v.kind in (NOT_CREDITED, BASELINE) and v.moved:
            axes[v.axis].not_credited += 1
            axes[v.axis].motion_not_credited += v.moved
    out = ["summary per switch position:"]
    for i, (L, s) in enumerate(axes.items(), start=1):
        name = core.OVERRIDES.get(L, f"axis {L.upper()}")
        pin = f"{core.OVERRIDES[L]}.counts" if L in core.OVERRIDES else f"axis.{L}.jog-counts"
        out.append(
            f"  {i} {name}: credited {s.credited:+d} in {s.records} record(s); "
            f"{s.not_credited} record(s) whose motion was not credited "
            f"({s.motion_not_credited:+d}); "
            f"{pin} = {r.pins.get(pin)}"
        )
    total = sum(kinds.values())
    shown = ", ".join(f"{n} {k}" for k, n in sorted(kinds.items(), key=lambda kv: -kv[1]))
    out.append(f"feed records: {total} ({shown or 'none'}); {lost} lost in gaps")
    keys = ("records-lost", "frames-bad", "feed-stops", "stop-reason", "state", "connected")
    out.append("pins at the end: " + ", ".join(f"{k} {r.pins.get(k)}" for k in keys))
    source = (
        "the component's host notes"
        if r.notes
        else "no host notes: configuration inferred from the bus, feed enable assumed"
    )
    out.append(f"host side: {source}")
    if r.mismatches:
        out.append(f"the replay differs from the notes {len(r.mismatches)} time(s):")
        out.extend(f"  {m}" for m in r.mismatches[:20])
    return out


def report(r: Replay, records_only: bool = False) -> List[str]:
    """The decode's lines: one per frame (time from the capture's first frame), the host's
    events between them, then the summary."""
    out: List[str] = []
    start = r.lines[0].frame.t if r.lines else 0.0
    events = sorted(r.events, key=lambda e: e[0])
    e = 0
    for line in r.lines:
        f = line.frame
        while e < len(events) and events[e][0] <= f.t:
            if not records_only:
                out.append(f"{events[e][0] - start:12.6f}   host   {events[e][1]}")
            e += 1
        if records_only and line.verdict is None:
            continue
        direction = "R" if f.rx else "T"
        text = f"{f.t - start:12.6f} {direction} {f.id:03X} [{len(f.data)}] {f.data.hex(' '):23}  "
        text += line.text
        if line.verdict is not None:
            text += "  ->  " + line.verdict.text
        out.append(text)
        for entry in line.log:
            out.append(f"{f.t - start:12.6f}   host   {entry}")
    if not records_only:
        for t, what in events[e:]:
            out.append(f"{t - start:12.6f}   host   {what}")
    out.extend(summary(r))
    return out


def main(argv: Optional[Sequence[str]] = None) -> int:
    p = argparse.ArgumentParser(
        prog="canopen-handwheel decode",
        description="A capture (candump .log, .asc, .blf or any format python-can reads) in "
        "CANopen terms, with what the component's rule made of every feed record.",
    )
    p.add_argument(
        "files",
        nargs="+",
        metavar="FILE",
        help="capture file(s), oldest first (a rotated capture: NAME.2.log NAME.1.log NAME.log)",
    )
    p.add_argument(
        "--node", type=int, default=None, help="the handwheel's node-ID (the notes', else 16)"
    )
    p.add_argument("--axes", default=None, help="the component's --axes (the notes', else xyzwv)")
    p.add_argument(
        "--notes", default="auto", help="host notes file (default: FILE.host if present)"
    )
    p.add_argument("--no-notes", action="store_true", help="ignore the host notes")
    p.add_argument("--records", action="store_true", help="only the feed records and the summary")
    args = p.parse_args(argv)
    if args.notes != "auto" and len(args.files) > 1:
        p.error("--notes goes with a single FILE")
    try:
        files = [captures.read(path, None if args.no_notes else args.notes) for path in args.files]
    except (OSError, ValueError) as e:
        print(f"canopen-handwheel decode: {e}", file=sys.stderr)
        return 1
    fields = next((f.config for f in files if f.config), None) or {}
    cfg = captures.config_from_fields(fields) if fields else core.Config()
    if args.node is not None or args.axes is not None:
        try:
            cfg = core.make_config(
                args.node if args.node is not None else cfg.node,
                None,
                args.axes if args.axes is not None else cfg.axes,
                cfg.scale,
                cfg.event_timer_ms,
                round(cfg.heartbeat_period * 1000),
                int(cfg.max_detents_per_s),
            )
        except ValueError as e:
            p.error(str(e))
    r = replay(files, cfg, object_names(cfg.node))
    try:
        for text in report(r, args.records):
            print(text)
    except BrokenPipeError:  # `| head`
        sys.stderr.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
