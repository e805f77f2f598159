"""Fixtures of the LinuxCNC suite: the handwheel on the emulated board, a hub that gives its
single SLCAN port a bus (the component and a test listener on it), and LinuxCNC 2.9 running
the sim machine of host/linuxcnc/sim with the component, driven through its headless
display.

Environment (set by `cargo xtask test`):
- HANDWHEEL_COMPONENT: the installed console script (target/linuxcnc-venv/bin/canopen-handwheel);
- HANDWHEEL_LINUXCNC_USER: the unprivileged user LinuxCNC runs as (empty: this user).
"""

from __future__ import annotations

import os
import re
import sys
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Callable, Optional

import canopen
import pytest

from rig import (
    AXES,
    NMT,
    NODE_ID,
    NOTIFIER_CYCLE,
    SDO_RX,
    TPDO1,
    Board,
    FrameRecorder,
    Stimulus,
    feed_record,
    slcan_line,
)
from sim_machine import SimMachine
from slcan_hub import SlcanHub

SCALE = 0.001
TOL = 1e-6
# The sim machine's servo period ([EMCMOT]SERVO_PERIOD) and the device's event timer.
SERVO_PERIOD = 0.001
EVENT_TIMER = 0.1


def component_script() -> str:
    """The installed `canopen-handwheel` console script."""
    return os.environ.get("HANDWHEEL_COMPONENT") or str(
        Path(sys.executable).parent / "canopen-handwheel"
    )


def start_emulator(tmp: Path, run: int) -> Board:
    """The board of this run; every run keeps the one flash file."""
    return Board(tmp / f"board-{run}.log", tmp / "flash.bin")


# A slow axis for the run-on tests, as in the field report: 2 mm/s, and 10 mm/s^2, so that
# its stopping distance is 0.2 mm (two detents at x100) and it needs 0.2 s to stop.
SLOW_V, SLOW_A = 2.0, 10.0
# LinuxCNC's commanded position of X and the target its planner moves it to: the lead of the
# one over the other is what velocity mode bounds (read in this order, so that a servo cycle
# between the two reads can only overstate it, by one cycle's motion).
COUNTS_X = "handwheel.axis.x.jog-counts"
POS_X, TARGET_X = "axis.x.pos-cmd", "axis.x.teleop-pos-cmd"


def stopping_distance(velocity: float, acceleration: float) -> float:
    """How far an axis at `velocity` moves while braking at `acceleration`: v^2 / 2a."""
    return velocity * velocity / (2 * acceleration)


def moved(pos, axis, distance):
    """`pos` (X, Y, Z) with `axis` moved by `distance`."""
    out = list(pos)
    out["xyz".index(axis)] += distance
    return out


def spin(machine, detents: int, pause: float, step: int = 1) -> float:
    """Turns `detents` detents (forward; backward if negative) as `turn` commands of `step`
    detents, `pause` apart; returns the time after the last one's reply. The board makes a
    command's edges 600 us apart and replies 25 ms (of its time) after the last, so the last
    edge came at least 25 ms before that time."""
    sign = 1 if detents > 0 else -1
    left = abs(detents)
    while left:
        n = min(step, left)
        machine.stim.turn(sign * n)
        left -= n
        time.sleep(pause)
    return time.monotonic()


def detent_records(machine, since: int):
    """When the test's listener read the first and the last feed record after the mark
    `since` whose position changed: the records of the first and the last detent (the
    component reads them through the same hub)."""
    records = machine.frames.frames(TPDO1)
    changes = [
        b.t
        for a, b in zip(records, records[1:])
        if b.seq >= since and feed_record(a).position != feed_record(b).position
    ]
    assert changes, records[-3:]
    return changes[0], changes[-1]


def last_change(samples, column: int):
    """The sample of a `Machine.watched` list at which column `column` took its final
    value."""
    final = samples[-1][column]
    i = len(samples) - 1
    while i > 0 and samples[i - 1][column] == final:
        i -= 1
    return samples[i]


class Machine:
    """Everything of one run: emulator, stimulus, hub, listener, LinuxCNC."""

    def __init__(self, tmp: Path, prepare: Optional[Callable[["Machine"], None]] = None) -> None:
        """`prepare`, if given, runs with the board, the hub and the listener up and before
        LinuxCNC starts (the component's first look at the device comes after it)."""
        component = component_script()
        user = os.environ.get("HANDWHEEL_LINUXCNC_USER") or None
        self.tmp = tmp
        self.runs = 1
        self.board = start_emulator(tmp, self.runs)
        self.hub = SlcanHub(self.board.can_port)
        self.bus = slcan_line(self.hub.channel)
        self.frames = FrameRecorder()
        self.network = canopen.Network(self.bus)
        self.network.NOTIFIER_CYCLE = NOTIFIER_CYCLE
        self.network.listeners.append(self.frames)
        self.network.connect()
        self.hub.protect_current()  # the listener survives `break_clients`
        self.stim = Stimulus(self.board.stim_port, self.board)
        if prepare is not None:
            try:
                prepare(self)
            except BaseException:
                print("--- board log ---\n" + "\n".join(self.board.log().splitlines()[-40:]))
                self._close_steps(self._rig_steps())
                raise
        self.cnc = SimMachine(component, self.hub.channel, tmp / "linuxcnc.log", user=user)
        self.cnc.connect()

    # LinuxCNC -------------------------------------------------------------------------

    def status(self) -> dict:
        return self.cnc.must("status")

    def pos(self):
        return self.status()["pos"]

    def pins(self) -> dict:
        return self.status()["pins"]

    def wait(self, pred, timeout=20.0, what="condition"):
        deadline = time.monotonic() + timeout
        while True:
            s = self.status()
            if pred(s):
                return s
            if time.monotonic() > deadline:
                raise AssertionError(f"no {what} within {timeout} s; last status {s}")
            time.sleep(0.05)

    def wait_pos(self, expected, timeout=10.0):
        return self.wait(
            lambda s: all(abs(a - b) < TOL for a, b in zip(s["pos"], expected)),
            timeout,
            f"position {expected}",
        )

    def assert_still(self, expected, duration=1.0):
        deadline = time.monotonic() + duration
        while time.monotonic() < deadline:
            pos = self.pos()
            assert all(abs(a - b) < TOL for a, b in zip(pos, expected)), (pos, expected)
            time.sleep(0.05)

    def halcmd(self, *args) -> str:
        return self.cnc.must("halcmd " + " ".join(args))["out"]

    # Handwheel ------------------------------------------------------------------------

    def select(self, axis: str, mult: int = 1) -> None:
        """Sets the switches and waits until the component shows the selection with the
        feed on (and the axis' jog-enable when the machine allows it)."""
        self.stim.axis(axis)
        self.stim.mult(mult)
        code = AXES[axis]
        self.wait(
            lambda s: s["pins"]["axis"] == code and s["pins"]["multiplier"] == mult,
            5,
            f"selection {axis} x{mult}",
        )

    def ready_to_jog(self, axis: str) -> None:
        self.wait(lambda s: s["pins"][f"axis.{axis}.jog-enable"], 10, f"jog-enable {axis}")

    def nmt(self, command: int) -> int:
        mark = self.frames.mark()
        self.network.send_message(NMT, bytes([command, NODE_ID]))
        return mark

    def sdo_writes(self, index: int, sub: int, since: int = 0) -> list:
        """The values of expedited SDO downloads to index:sub seen since `since`."""
        out = []
        where = bytes([index & 0xFF, index >> 8, sub])
        for f in self.frames.frames(SDO_RX, since):
            d = f.data
            if len(d) == 8 and d[0] & 0xE3 == 0x23 and d[1:4] == where:
                size = 4 - ((d[0] >> 2) & 3)
                out.append(int.from_bytes(d[4 : 4 + size], "little"))
        return out

    # The component as a process ----------------------------------------------------------

    def component_pid(self) -> int:
        """The PID of the HAL component `handwheel` (from `halcmd show comp`)."""
        out = self.halcmd("show", "comp", "handwheel")
        m = re.search(r"User\s+handwheel\s+(\d+)", out)
        assert m, out
        return int(m.group(1))

    def spawn(self, *options: str):
        """Starts the component again (the one before must be gone): (pid, log path)."""
        reply = self.cnc.must("spawn " + " ".join(options))
        return reply["pid"], Path(reply["log"])

    def watch(self, seconds: float, *pins: str) -> None:
        """Samples `pins` in LinuxCNC's display for `seconds` (see `watched`)."""
        self.cnc.must(f"watch {seconds} " + " ".join(pins))

    def watched(self, quiet: float = 0.0):
        """The samples of the last `watch`: [(t, value...)], every change of the pins with
        its time.monotonic(), comparable with this process's. With `quiet`, the sampling
        ends once nothing changed for that long (else at the end of its time)."""
        return [tuple(s) for s in self.cnc.must(f"watched {quiet}")["samples"]]

    def setp(self, pin: str, value) -> None:
        self.halcmd("setp", pin, str(value))

    @contextmanager
    def slow_axis(self, axis: str, velocity: float, acceleration: float):
        """The axis' MAX_VELOCITY and MAX_ACCELERATION set (LinuxCNC's `ini.L.*` pins) for
        the block, the sim machine's back after it."""
        before = {
            n: float(self.halcmd("getp", f"ini.{axis}.{n}").strip())
            for n in ("max_velocity", "max_acceleration")
        }
        self.setp(f"ini.{axis}.max_velocity", velocity)
        self.setp(f"ini.{axis}.max_acceleration", acceleration)
        try:
            time.sleep(0.3)  # inihal passes the new limits on
            yield
        finally:
            for n, v in before.items():
                self.setp(f"ini.{axis}.{n}", v)
            time.sleep(0.3)

    # The device's emulator ----------------------------------------------------------------

    def restart_emulator(self) -> None:
        """Stops the board (the device is gone from the bus), starts a new one (the same
        flash file) and puts it on the hub, as a node replaced on a running
        bus."""
        self.stim.close()
        self.board.stop()
        assert self.hub.upstream_lost.wait(10), "the hub did not see the device go"
        self.runs += 1
        self.board = start_emulator(self.tmp, self.runs)
        self.hub.attach(self.board.can_port)
        self.stim = Stimulus(self.board.stim_port, self.board)

    def _rig_steps(self) -> tuple:
        return (self.stim.close, self.network.disconnect, self.hub.close, self.board.stop)

    def close(self) -> None:
        self._close_steps((self.cnc.stop,) + self._rig_steps())

    @staticmethod
    def _close_steps(steps) -> None:
        for step in steps:
            try:
                step()
            except Exception as e:
                print(f"teardown {step}: {e!r}")


@contextmanager
def running_machine(tmp: Path, ready, what: str, prepare=None):
    """A `Machine` (its `prepare` run before LinuxCNC starts) with the machine switched on
    and `ready(status)` true; its logs' last lines printed if anything fails."""
    m = Machine(tmp, prepare)
    try:
        m.cnc.must("on")
        m.wait(ready, 30, what)
        yield m
    except BaseException:
        print("--- LinuxCNC log ---\n" + m.cnc.tail(80))
        print("--- board log ---\n" + "\n".join(m.board.log().splitlines()[-40:]))
        raise
    finally:
        m.close()


@pytest.fixture(scope="module")
def machine(tmp_path_factory):
    with running_machine(
        tmp_path_factory.mktemp("linuxcnc"),
        lambda s: s["pins"]["connected"] and s["pins"]["state"] == 5,
        "handwheel connected and Operational",
    ) as m:
        yield m


@contextmanager
def master(channel: str, timeout: float = 1.0):
    """A python-canopen master of its own on the hub (`channel`) for a few SDO requests to
    the device: (network, node)."""
    network = canopen.Network(slcan_line(channel))
    network.NOTIFIER_CYCLE = NOTIFIER_CYCLE
    network.connect()
    try:
        node = network.add_node(NODE_ID, canopen.ObjectDictionary())
        node.sdo.RESPONSE_TIMEOUT = timeout
        yield network, node
    finally:
        network.disconnect()


def read_u32(node, index: int, sub: int) -> int:
    return int.from_bytes(node.sdo.upload(index, sub), "little")
