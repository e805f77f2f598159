#!/usr/bin/env python3
"""The handwheel without hardware: the release image on the emulated board and a
python-canopen master.

Started by `cargo xtask demo [--script]`, which builds the image and the Python venvs
(target/interop-venv, target/emu-venv) first. This script starts `cargo xtask board` itself
(in its own process group, its decoded defmt log in a file), connects python-can's `slcan`
interface to the board's CAN port, boots the node, puts it in Operational and enables the
feed (0x2000 = 1), then shows what a CNC would receive from TPDO1 (axis, multiplier,
position, frames/s) while the wheel is turned through the board's control line:

- interactive (default, needs a terminal): arrow keys turn the wheel one detent (right/up
  forward, left/down back), PgUp/PgDn ten; x y z w v select the axis, 0 none; 1 2 3 the
  multiplier x1 x10 x100; e toggles the feed enable; q or Ctrl-C quits.
- `--script`: a scripted tour over every axis and multiplier that checks the CNC's result
  at each step (exit status 1 if one is wrong), then quits.
"""

from __future__ import annotations

import argparse
import collections
import curses
import os
import signal
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Dict, List, Optional, Tuple

import can
import canopen

# The host component's record rule (host/src, standard library only), which the rig decodes
# records with too: the demo's CNC applies feed records exactly as the LinuxCNC component
# does.
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "host" / "src"))

from canopen_handwheel.core import Record, continuity  # noqa: E402

# The rig library (tools/rig), beside this script: emulator, stimulus, bus, constants.
from rig import (  # noqa: E402
    BOOTUP,
    EDS,
    EMCY,
    HEARTBEAT,
    NODE_ID,
    OPERATIONAL,
    PRE_OPERATIONAL,
    SDO_TX,
    STOPPED,
    TPDO1,
    TPDO2,
    Board,
    Stimulus,
    connect_bus,
)

AXIS_NAMES = ["none", "X", "Y", "Z", "W", "V"]
STATE_NAMES = {
    BOOTUP: "boot-up",
    STOPPED: "Stopped",
    OPERATIONAL: "Operational",
    PRE_OPERATIONAL: "Pre-operational",
}
STATUS_BITS = ["enabled", "encoder error", "steps dropped", "master lost", "turned unseen"]

STEP_TIMEOUT = 5.0


class Cnc(can.Listener):
    """What a CNC makes of the node's frames: the feed record applied to its axes by the
    host component's rule (`continuity`: the wrapping difference of the position goes to
    the axis the newer record names, when the two records are of one epoch or of
    consecutive epochs with none missing), the NMT state, the last EMCY and the frame
    rates."""

    def __init__(self) -> None:
        self.lock = threading.Condition()
        self.axes: Dict[str, int] = {name: 0 for name in AXIS_NAMES[1:]}
        self.record: Optional[Record] = None
        self.state: Optional[int] = None
        self.booted = False
        self.emcy = "none"
        self._last: Optional[Record] = None
        self._tpdo_times: collections.deque = collections.deque()
        self._all_times: collections.deque = collections.deque()

    def on_message_received(self, msg: can.Message) -> None:
        if msg.is_error_frame or msg.is_extended_id:
            return
        now = time.monotonic()
        data = bytes(msg.data)
        with self.lock:
            if msg.arbitration_id in (TPDO1, EMCY, HEARTBEAT, TPDO2, SDO_TX):
                self._all_times.append(now)
            if msg.arbitration_id == TPDO1 and len(data) == 8:
                self._tpdo_times.append(now)
                self._feed(data)
            elif msg.arbitration_id == HEARTBEAT and len(data) == 1:
                self.state = data[0]
                if data[0] == BOOTUP:
                    self.booted = True
                    self._last = None  # reset node zeroes the position
            elif msg.arbitration_id == EMCY and len(data) == 8:
                code = int.from_bytes(data[0:2], "little")
                self.emcy = "error reset" if code == 0 else f"0x{code:04X}"
            self.lock.notify_all()

    def on_error(self, exc: Exception) -> None:
        pass

    def _feed(self, data: bytes) -> None:
        rec = Record.decode(data)
        delta = continuity(self._last, rec) if self._last is not None else None
        if delta and 1 <= rec.axis <= 5:
            self.axes[AXIS_NAMES[rec.axis]] += delta
        self._last = rec
        self.record = rec

    def rates(self) -> Tuple[float, float]:
        """TPDO1 frames and all frames from the node per second, over the last second."""
        now = time.monotonic()
        with self.lock:
            for times in (self._tpdo_times, self._all_times):
                while times and times[0] < now - 1.0:
                    times.popleft()
            return float(len(self._tpdo_times)), float(len(self._all_times))

    def wait(self, predicate, timeout: float) -> bool:
        with self.lock:
            return self.lock.wait_for(predicate, timeout)


def describe_status(rec: Record) -> str:
    """The record's status flags by name, its epoch and its session (0: no master wrote
    one; the demo never does)."""
    names = [name for bit, name in enumerate(STATUS_BITS) if rec.flags & (1 << bit)]
    return (
        f"0x{rec.flags:02X} [{', '.join(names) or 'feed off'}, epoch {rec.epoch}, "
        f"session {rec.session}]"
    )


class Demo:
    """The booted node, its master and the wheel."""

    def __init__(self, log_path: Path) -> None:
        self.emulator = Board(log_path)
        self.cnc = Cnc()
        self.bus: Optional[can.BusABC] = None
        self.network: Optional[canopen.Network] = None
        self.stim: Optional[Stimulus] = None
        self.feed_enabled = False
        self.machine_on = False
        self.last_action = "-"

    def boot(self) -> None:
        # The board listens once it is up, and starts the CPU when we connect.
        self.bus = connect_bus(self.emulator)
        self.network = canopen.Network(self.bus)
        self.network.listeners.append(self.cnc)
        self.node = self.network.add_node(NODE_ID, str(EDS))
        self.network.connect()
        # The boot-up is the first frame the master reads, whether or not python-can's `O`
        # got through.
        if not self.cnc.wait(lambda: self.cnc.booted, STEP_TIMEOUT):
            self.emulator.check_alive()
            raise RuntimeError("no boot-up frame from the node")
        self.stim = Stimulus(self.emulator.stim_port, self.emulator)

    def select(self, axis: str, multiplier: int) -> None:
        """Sets the switch lines and waits until the firmware's debounced selection (0x2010)
        shows them."""
        self.stimulus(f"axis {axis}")
        self.stimulus(f"mult {multiplier}")
        want = (AXIS_NAMES.index(axis.upper()) if axis != "off" else 0, multiplier)
        deadline = time.monotonic() + STEP_TIMEOUT
        while (self.read(0x2010, 1), self.read(0x2010, 2)) != want:
            if time.monotonic() > deadline:
                raise RuntimeError(f"the selection did not become {want}")
            time.sleep(0.01)

    def stimulus(self, command: str) -> bool:
        """Sends a stimulus command; `True` when the firmware answered `ok`."""
        reply = self.stim.send(command)
        self.last_action = f"{command} -> {reply}"
        return reply == "ok"

    def read(self, index: int, sub: int) -> int:
        return int.from_bytes(self.node.sdo.upload(index, sub), "little")

    def start_feed(self) -> None:
        self.node.nmt.state = "OPERATIONAL"
        if not self.cnc.wait(lambda: self.cnc.state == OPERATIONAL, STEP_TIMEOUT):
            raise RuntimeError("the node did not become Operational")
        self.set_feed(True)

    def set_feed(self, on: bool) -> None:
        self.node.sdo.download(0x2000, 0, bytes([int(on)]))
        self.feed_enabled = on
        self.last_action = f"0x2000 = {int(on)}"

    def set_machine_on(self, on: bool) -> None:
        """Bit 0 of the outputs (the "machine on" LED, board output 2), sent as the CNC's
        component does: one RPDO1 frame (0x200 + node-ID) with the outputs' byte."""
        self.network.send_message(0x200 + NODE_ID, bytes([int(on)]))
        self.machine_on = on
        self.last_action = f"RPDO1 = {int(on):#04x}"

    def outputs(self) -> str:
        """The board's outputs as its control line reports them: output 1 the device's "jog
        live", 2..8 the CNC's (0x6A00:1 bits 0..6)."""
        driven, jog = self.emulator.outputs()
        lit = [str(n + 1) for n in range(8) if driven >> n & 1]
        return f"jog live {'ON ' if jog else 'off'}  lit {' '.join(lit) or '-'}"

    def close(self) -> None:
        try:
            if self.stim is not None:
                self.stim.close()
            if self.network is not None:
                self.network.disconnect()
        except Exception:  # the emulator is about to go anyway
            pass
        self.emulator.stop()

    # The view ---------------------------------------------------------------------------

    def axes(self) -> str:
        with self.cnc.lock:
            return "  ".join(f"{name} {value:+5d}" for name, value in self.cnc.axes.items())

    def view(self) -> List[str]:
        cnc = self.cnc
        tpdo_rate, all_rate = cnc.rates()
        axes = self.axes()
        with cnc.lock:
            state = STATE_NAMES.get(cnc.state, "?") if cnc.state is not None else "?"
            record = cnc.record
            emcy = cnc.emcy
        if record is None:
            feed = "no feed record yet"
            selection = "-"
        else:
            feed = (
                f"position {record.position:+d}  seq {record.sequence:5d}  "
                f"status {describe_status(record)}"
            )
            axis = AXIS_NAMES[record.axis] if record.axis < 6 else record.axis
            selection = f"axis {axis}  x{record.multiplier}"
        return [
            f"node {NODE_ID}: {state}, feed {'enabled' if self.feed_enabled else 'disabled'}",
            f"selection    {selection}",
            f"TPDO1        {feed}",
            f"CNC axes     {axes}",
            f"outputs      {self.outputs()}   machine on {'sent' if self.machine_on else 'off'}",
            f"frames/s     TPDO1 {tpdo_rate:3.0f}, all {all_rate:3.0f}   last EMCY {emcy}",
            f"last         {self.last_action}",
        ]


# Interactive mode ---------------------------------------------------------------------------

KEYS_HELP = (
    "keys   right/up +1 detent, left/down -1, PgUp/PgDn +-10\n"
    "       x y z w v axis, 0 none, 1 2 3 = x1 x10 x100, e feed on/off, q quit\n"
    "       m machine on/off (RPDO1: board output 2)\n"
    "       (CNC axes in detents x multiplier)"
)

# The keys that turn the wheel, as curses decodes them (keypad mode: the arrows and PgUp/PgDn
# whatever escape sequences the terminal sends for them).
TURNS = {
    curses.KEY_UP: 1,
    curses.KEY_RIGHT: 1,
    curses.KEY_DOWN: -1,
    curses.KEY_LEFT: -1,
    curses.KEY_PPAGE: 10,
    curses.KEY_NPAGE: -10,
}


def wheel_command(key: int) -> Optional[str]:
    """The stimulus command of a key the demo and the LinuxCNC console share: a turn, an axis
    (x y z w v, 0 none), a multiplier (1 2 3); None for any other key."""
    if key in TURNS:
        return f"turn {TURNS[key]:+d}"
    char = chr(key).lower() if 0 <= key < 128 else ""
    if char and char in "xyzwv":
        return f"axis {char}"
    if char == "0":
        return "axis off"
    if char and char in "123":
        return f"mult {10 ** (int(char) - 1)}"
    return None


def screen(help_text: str, view, on_key) -> None:
    """The interactive screen of the demo and the LinuxCNC console (curses): `help_text` at
    the top, under it the lines of `view()`, redrawn every 0.1 s and cut to the terminal's
    width; each key goes to `on_key(key)` (a curses key code: a character's code or
    `curses.KEY_*`), which returns False to quit. Ctrl-C raises KeyboardInterrupt as ever;
    the terminal is restored however it ends."""

    def loop(window) -> None:
        try:
            curses.curs_set(0)
        except curses.error:  # a terminal that cannot hide the cursor
            pass
        window.keypad(True)
        window.timeout(100)
        while True:
            window.erase()
            height, width = window.getmaxyx()
            for row, line in enumerate(help_text.splitlines() + view()):
                if row < height:
                    window.addnstr(row, 0, line, max(width - 1, 0))
            window.refresh()
            key = window.getch()
            if key != -1 and not on_key(key):
                return

    curses.wrapper(loop)


def interactive(demo: Demo) -> None:
    def on_key(key: int) -> bool:
        command = wheel_command(key)
        if command is not None:
            demo.stimulus(command)
        elif key in (ord("q"), ord("Q")):
            return False
        elif key in (ord("e"), ord("E")):
            try:
                demo.set_feed(not demo.feed_enabled)
            except canopen.SdoAbortedError as e:
                demo.last_action = f"0x2000 write refused: {e}"
        elif key in (ord("m"), ord("M")):
            demo.set_machine_on(not demo.machine_on)
        return True

    screen(KEYS_HELP, demo.view, on_key)


# Scripted tour ------------------------------------------------------------------------------

# (axis, multiplier, detents): each step's motion, checked on the CNC's axes.
TOUR = [
    ("x", 1, 5),
    ("x", 1, -2),
    ("x", 10, 4),
    ("y", 100, -3),
    ("z", 1, 10),
    ("off", 1, 3),
    ("w", 10, 2),
    ("v", 1, -1),
    ("x", 100, 1),
]


def until(predicate, timeout: float) -> bool:
    """Polls `predicate` (the board's control line, not a frame the CNC waits on) every
    10 ms for at most `timeout` s."""
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.01)
    return True


def tour(demo: Demo, pace: float) -> bool:
    expected = {name: 0 for name in AXIS_NAMES[1:]}
    ok = True
    for axis, multiplier, detents in TOUR:
        demo.select(axis, multiplier)
        if not demo.stimulus(f"turn {detents:+d}"):
            raise RuntimeError(f"stimulus refused: {demo.last_action}")
        if axis != "off":
            expected[axis.upper()] += detents * multiplier
        # The feed record follows the turn within its 2 ms inhibit time; the event timer
        # repeats it every 100 ms.
        matched = demo.cnc.wait(lambda: demo.cnc.axes == expected, STEP_TIMEOUT)
        note = "" if matched else f"   <-- expected {expected}"
        ok &= matched
        print(f"axis {axis:>4} x{multiplier:<3} turn {detents:+3d}:  CNC {demo.axes()}{note}")
        time.sleep(pace)
    # The outputs: "jog live" is on while a detent moves an axis (feed on, X selected), the
    # CNC's "machine on" (RPDO1 bit 0) lights board output 2.
    demo.set_machine_on(True)
    seen = until(lambda: demo.emulator.outputs() == (0b11, True), STEP_TIMEOUT)
    ok &= seen
    print(f"machine on (RPDO1):  outputs {demo.outputs()}{'' if seen else '   <-- expected 1 2'}")
    # Disabled feed: turning moves nothing (and the node says so in status bit 4).
    demo.set_feed(False)
    demo.stimulus("turn +2")
    time.sleep(max(pace, 0.3))
    with demo.cnc.lock:
        matched = demo.cnc.axes == expected
    ok &= matched
    print(f"feed disabled, turn  +2:  CNC {demo.axes()}{'' if matched else '   <-- moved'}")
    dark = until(lambda: not demo.emulator.outputs()[1], STEP_TIMEOUT)
    ok &= dark
    print(f"feed disabled:       outputs {demo.outputs()}{'' if dark else '   <-- jog live on'}")
    for line in demo.view():
        print("  " + line)
    return ok


def interrupt(_signum, _frame) -> None:
    """SIGTERM ends the demo as cleanly as Ctrl-C."""
    raise KeyboardInterrupt


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--script", action="store_true", help="run a scripted tour instead of reading the keyboard"
    )
    parser.add_argument(
        "--pace", type=float, default=0.5, help="seconds between the tour's steps (default 0.5)"
    )
    args = parser.parse_args()
    if not args.script and not sys.stdin.isatty():
        print(
            "demo: the interactive mode reads keys from a terminal; use --script", file=sys.stderr
        )
        return 2

    log_path = Path(
        os.environ.get("HANDWHEEL_DEMO_LOG") or Path(tempfile.gettempdir()) / "handwheel-demo.log"
    )
    log_path.parent.mkdir(parents=True, exist_ok=True)
    signal.signal(signal.SIGTERM, interrupt)
    demo = Demo(log_path)
    status = 0
    try:
        print(f"demo: starting the handwheel firmware on the emulated board (log: {log_path})")
        demo.boot()
        demo.select("x", 1)
        demo.start_feed()
        print("demo: node booted, Operational, feed enabled (0x2000 = 1), axis X x1")
        if args.script:
            status = 0 if tour(demo, args.pace) else 1
            print(
                "demo: tour "
                + (
                    "finished, every step as expected"
                    if status == 0
                    else "FAILED: a step did not move the CNC as expected"
                )
            )
        else:
            interactive(demo)
    except KeyboardInterrupt:
        pass
    except Exception as e:  # show the firmware log's tail with any failure
        print(f"demo: {e}", file=sys.stderr)
        tail = log_path.read_text(errors="replace").splitlines()[-15:] if log_path.exists() else []
        print("\n".join(["--- firmware log (tail) ---", *tail]), file=sys.stderr)
        status = 1
    finally:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        demo.close()
        print("demo: stopped")
    return status


if __name__ == "__main__":
    sys.exit(main())
