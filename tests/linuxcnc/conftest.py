"""Fixtures of the LinuxCNC suite: the QEMU handwheel, a hub that gives its single SLCAN
port a bus (the component and a test listener on it), and LinuxCNC 2.9 running the sim
machine of host/linuxcnc/sim with the component, driven through its headless display.

Environment (set by `cargo xtask test`):
- HANDWHEEL_COMPONENT: the installed console script (target/linuxcnc-venv/bin/canopen-handwheel);
- HANDWHEEL_LINUXCNC_USER: the unprivileged user LinuxCNC runs as (empty: this user);
- HANDWHEEL_EMULATOR: `qemu` (default) or `board`, the release image on the emulated board
  (`cargo xtask linuxcnc-test --board`).
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import can
import canopen
import pytest

from rig import AXES, NMT, NODE_ID, ROOT, FrameRecorder, Qemu, Stimulus
from sim_machine import SimMachine
from slcan_hub import SlcanHub

SCALE = 0.001
TOL = 1e-6


class Machine:
    """Everything of one run: emulator, stimulus, hub, listener, LinuxCNC."""

    def __init__(self, tmp: Path) -> None:
        component = os.environ.get("HANDWHEEL_COMPONENT") or str(
            Path(sys.executable).parent / "canopen-handwheel"
        )
        user = os.environ.get("HANDWHEEL_LINUXCNC_USER") or None
        if os.environ.get("HANDWHEEL_EMULATOR") == "board":
            sys.path.insert(0, str(ROOT / "tools" / "board-emu"))
            from launcher import BoardProcess

            self.qemu: Qemu = BoardProcess(tmp / "board.log", tmp / "flash.bin")
        else:
            self.qemu = Qemu(tmp / "qemu.log")
        self.hub = SlcanHub(self.qemu.can_port)
        self.bus = can.Bus(interface="slcan", channel=self.hub.channel, sleep_after_open=0)
        self.frames = FrameRecorder()
        self.network = canopen.Network(self.bus)
        self.network.listeners.append(self.frames)
        self.network.connect()
        self.stim = Stimulus(self.qemu.stim_port, self.qemu)
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

    def close(self) -> None:
        for step in (
            self.cnc.stop,
            self.stim.close,
            self.network.disconnect,
            self.hub.close,
            self.qemu.stop,
        ):
            try:
                step()
            except Exception as e:
                print(f"teardown {step}: {e!r}")


@pytest.fixture(scope="module")
def machine(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("linuxcnc")
    m = Machine(tmp)
    try:
        m.cnc.must("on")
        m.wait(
            lambda s: s["pins"]["connected"] and s["pins"]["state"] == 5,
            30,
            "handwheel connected and Operational",
        )
        yield m
    except BaseException:
        print("--- LinuxCNC log ---\n" + m.cnc.tail(80))
        print("--- QEMU log ---\n" + "\n".join(m.qemu.log().splitlines()[-40:]))
        raise
    finally:
        m.close()
