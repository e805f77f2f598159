#!/usr/bin/env python3
"""`cargo xtask linuxcnc`: LinuxCNC's sim XYZ mill driven by the handwheel on the emulated
board, in the terminal.

Starts the release image on the emulated board (`cargo xtask board`), then LinuxCNC with the
sim machine of `sim/` (as HANDWHEEL_LINUXCNC_USER when set) whose HAL loads the component
(HANDWHEEL_COMPONENT) on the board's SLCAN port, exactly as a machine would on `can0`. Its
headless display switches the machine on and homes it; this console shows LinuxCNC's DRO,
the machine state and the handwheel as the component sees it, and turns the wheel from the
keyboard through the board's control line:

    right/up, left/down   one detent forward / back      PgUp / PgDn   ten
    x y z, w v, 0         axis, feed / spindle override, none    1 2 3  x1 x10 x100
    m                     machine on / off                q, Ctrl-C     quit

`--script` runs a short checked tour instead (exit status 1 if LinuxCNC's position is wrong).
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
# This folder (sim_machine) and tools/ (the rig, the demo's key decoder) are not packages;
# host/src has the component's `Record`, with which the rig and the demo decode records.
sys.path[:0] = [str(HERE), str(ROOT / "tools"), str(ROOT / "host" / "src")]

from demo import screen, wheel_command  # noqa: E402  (the demo's keys and screen)
from rig import Board, Stimulus  # noqa: E402
from sim_machine import SimMachine  # noqa: E402

STATES = {1: "E-stop", 2: "off", 3: "off", 4: "ON"}
# The device's axis switch (the `axis` pin): what its positions drive in the sim machine
# (`--axes xyzfs` in sim/handwheel.hal); the demo's keys `w` and `v` select positions 4 and 5.
AXES = ("none", "X", "Y", "Z", "feed override", "spindle override")
HELP = (
    "keys   right/up +1 detent, left/down -1, PgUp/PgDn +-10, x y z axis, w feed override,\n"
    "       v spindle override, 0 none, 1 2 3 = x1 x10 x100, m machine on/off, q quit"
)


def view(status: dict, last: str) -> list:
    p = status["pins"]
    o = status["overrides"]
    x, y, z = status["pos"]
    axis = p.get("axis") or 0
    homed = "homed" if all(status["homed"]) else "not homed"
    return [
        f"LinuxCNC  machine {STATES.get(status['task_state'], status['task_state'])}, {homed},"
        f" {'teleop' if status['teleop'] else 'joint'} mode",
        f"  DRO     X {x:10.4f}   Y {y:10.4f}   Z {z:10.4f}  mm",
        f"  override feed {100 * o['feed']:.0f} %, spindle {100 * o['spindle']:.0f} %, "
        f"rapid {100 * o['rapid']:.0f} %",
        f"handwheel {'connected' if p.get('connected') else 'NOT connected'}, "
        f"axis {AXES[axis] if 0 <= axis <= 5 else '?'} x{p.get('multiplier')}, "
        f"feed {'on' if p.get('feed-enabled') else 'off'}, enable pin "
        f"{'on' if p.get('enable') else 'off'}, position {p.get('position')}",
        f"          EMCY 0x{(p.get('emcy-code') or 0):04X}, records lost {p.get('records-lost')},"
        f" bad frames {p.get('frames-bad')}",
        f"last      {last}",
    ]


def interactive(cnc: SimMachine, stim) -> None:
    last = ["-"]

    def on_key(key: int) -> bool:
        command = wheel_command(key)
        if command is not None:
            last[0] = f"{command}: {stim.send(command)}"
        elif key in (ord("q"), ord("Q")):
            return False
        elif key in (ord("m"), ord("M")):
            on = cnc.must("status")["task_state"] == 4
            reply = cnc.call("off" if on else "on")
            last[0] = f"machine {'off' if on else 'on'}: {'ok' if reply['ok'] else reply}"
        return True

    screen(HELP, lambda: view(cnc.must("status"), last[0]), on_key)


def wait_status(cnc: SimMachine, pred, timeout: float, what: str) -> dict:
    deadline = time.monotonic() + timeout
    while True:
        s = cnc.must("status")
        if pred(s):
            return s
        if time.monotonic() > deadline:
            raise RuntimeError(f"no {what} in {timeout} s: {s}")
        time.sleep(0.05)


def script(cnc: SimMachine, stim) -> bool:
    """Select, turn, check LinuxCNC's DRO after each step."""
    ok = True
    start = wait_status(cnc, lambda s: s["pins"]["feed-enabled"], 30, "feed on")["pos"]
    expected = list(start)
    for axis, mult, detents in [("x", 1, 5), ("x", 10, -3), ("y", 100, 2), ("z", 10, 7)]:
        stim.send(f"axis {axis}")
        stim.send(f"mult {mult}")
        L = "xyz".index(axis)
        wait_status(
            cnc,
            lambda s, axis=axis, mult=mult: (
                s["pins"][f"axis.{axis}.jog-enable"] and s["pins"]["multiplier"] == mult
            ),
            10,
            f"{axis} x{mult}",
        )
        stim.send(f"turn {detents}")
        expected[L] += detents * mult * 0.001
        try:
            s = wait_status(
                cnc,
                lambda s: all(abs(a - b) < 1e-6 for a, b in zip(s["pos"], expected)),
                10,
                "position",
            )
            result = "ok"
        except RuntimeError:
            s, result, ok = cnc.must("status"), "WRONG", False
        print(
            f"{axis.upper()} x{mult:<3} turn {detents:+d}: "
            + view(s, result)[1].strip()
            + f"  ({result})",
            flush=True,
        )
    # Position 4 is the feed override (sim/handwheel.hal): 1 % a detent, no axis moves.
    stim.send("axis w")
    stim.send("mult 100")
    wait_status(
        cnc, lambda s: s["pins"]["feed-override.count-enable"], 10, "feed override position"
    )
    feed = cnc.must("status")["overrides"]["feed"]
    stim.send("turn -5")
    try:
        s = wait_status(
            cnc,
            lambda s: (
                abs(s["overrides"]["feed"] - (feed - 0.05)) < 1e-6
                and all(abs(a - b) < 1e-6 for a, b in zip(s["pos"], expected))
            ),
            10,
            "feed override",
        )
        result = "ok"
    except RuntimeError:
        s, result, ok = cnc.must("status"), "WRONG", False
    print(f"feed override x100 turn -5: {view(s, result)[2].strip()}  ({result})", flush=True)
    print(
        "linuxcnc console: tour "
        + ("finished, every step as expected" if ok else "FAILED: a step did not move LinuxCNC"),
        flush=True,
    )
    return ok


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--script", action="store_true", help="a checked tour, then exit")
    args = p.parse_args()
    component = os.environ.get("HANDWHEEL_COMPONENT") or str(
        Path(sys.executable).parent / "canopen-handwheel"
    )
    user = os.environ.get("HANDWHEEL_LINUXCNC_USER") or None
    logs = Path(os.environ.get("HANDWHEEL_LOG_DIR") or tempfile.mkdtemp(prefix="handwheel-"))
    logs.mkdir(parents=True, exist_ok=True)
    # The component captures the session (`--capture`) in a folder of its own, which the
    # user LinuxCNC runs as may write; a session's capture replaces the last one's.
    captures = logs / "capture"
    captures.mkdir(exist_ok=True)
    for old in captures.glob("handwheel*.log*"):
        old.unlink()
    if user:
        shutil.chown(captures, user)
    capture = captures / "handwheel.log"
    board = Board(logs / "board.log", logs / "flash.bin")
    cnc = stim = None
    try:
        print(f"starting the emulated board and LinuxCNC (logs in {logs}) ...", flush=True)
        cnc = SimMachine(
            component,
            f"socket://127.0.0.1:{board.can_port}",
            logs / "linuxcnc.log",
            user=user,
            auto_on=True,
            extra_args=f"--capture {capture}",
        )
        cnc.connect()
        stim = Stimulus(board.stim_port, board)
        if args.script:
            return 0 if script(cnc, stim) else 1
        interactive(cnc, stim)
        return 0
    except KeyboardInterrupt:
        return 0
    except Exception as e:
        print(f"linuxcnc console: {e}", file=sys.stderr)
        if cnc is not None:
            print(cnc.tail(30), file=sys.stderr)
        return 1
    finally:
        if stim is not None:
            stim.close()
        if cnc is not None:
            cnc.stop()
        board.stop()
        if capture.exists():
            print(
                f"the session's capture: {capture}; decode it with\n  {component} decode {capture}"
            )


if __name__ == "__main__":
    sys.exit(main())
