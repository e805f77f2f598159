"""How the component ends, in the real LinuxCNC 2.9: SIGTERM (what `halcmd unload` and
LinuxCNC's shutdown send) and SIGINT at several moments, each time 0x2000 = 0 written when
the bus allows it, exit status 0, no traceback.

The one LinuxCNC loaded is ended first; then the display starts the component again
(`spawn`: the loadusr line's options, linked as handwheel.hal links it) under a shell that
writes its exit status to the component's log. The last test shuts LinuxCNC down. A machine
of its own (this file's `machine` fixture), so that the other file can end with a SIGKILL.
"""

import os
import signal
import time
from pathlib import Path

import pytest

from conftest import SCALE, moved
from rig import SDO_RX


def gone(pid: int) -> bool:
    """The process has ended (a zombie waiting for its reaper counts as ended)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except FileNotFoundError:
        return True
    return stat.rsplit(")", 1)[1].split()[0] == "Z"


def wait_exit_status(log: Path, timeout: float = 5.0) -> tuple:
    """(exit status, the component's output) once the spawning shell wrote the status."""
    deadline = time.monotonic() + timeout
    while True:
        text = log.read_text(errors="replace")
        for line in text.splitlines():
            if line.startswith("exit status "):
                return int(line.split()[2]), text
        assert time.monotonic() < deadline, f"no exit status within {timeout} s:\n{text}"
        time.sleep(0.05)


def assert_quiet(text: str, signum: int) -> None:
    assert "Traceback" not in text and "KeyboardInterrupt" not in text, text
    assert f"canopen-handwheel: {signal.Signals(signum).name}: stopping" in text, text
    assert "canopen-handwheel: stopped" in text, text


def test_sigterm_ends_the_component_linuxcnc_loaded(machine):
    """The loadusr'ed component, connected with the feed on: SIGTERM ends it, 0x2000 = 0
    goes out, its output (LinuxCNC's log) has no traceback, its HAL component is gone."""
    machine.select("x", 10)
    machine.ready_to_jog("x")
    pid = machine.component_pid()
    log_mark = len(machine.cnc.log())
    mark = machine.frames.mark()
    os.kill(pid, signal.SIGTERM)
    deadline = time.monotonic() + 5
    while not gone(pid):
        assert time.monotonic() < deadline, "the component did not end"
        time.sleep(0.02)
    assert 0 in machine.sdo_writes(0x2000, 0, since=mark)
    assert_quiet(machine.cnc.log()[log_mark:], signal.SIGTERM)
    assert "handwheel " not in machine.halcmd("show", "comp", "handwheel")


@pytest.mark.parametrize(
    "when",
    ["running", "at its start", "in an SDO transfer", "while the bus is down"],
)
@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
def test_a_signal_ends_it_quietly_with_status_0(machine, signum, when):
    """- running: connected, feed on, after a turn;
    - at its start: as soon as its HAL component is ready (bus opening, configuring);
    - in an SDO transfer: the device muted, the configuration waits for an answer;
    - while the bus is down: its line broken and refused, the component retrying.
    0x2000 = 0 is written (requested, for the muted device) except while the bus is down."""
    if when == "in an SDO transfer":
        machine.hub.mute(3.0)
    mark = machine.frames.mark()
    pid, log = machine.spawn()
    if when == "running":
        machine.select("x", 10)
        machine.ready_to_jog("x")
        start = machine.pos()
        machine.stim.turn(1)
        machine.wait_pos(moved(start, "x", 10 * SCALE))
    elif when == "in an SDO transfer":
        # A request of the component's is out and its answer (0.3 s timeout) cannot come.
        machine.frames.wait_for(lambda f: f.id == SDO_RX, since=mark, what="SDO request")
    elif when == "while the bus is down":
        machine.wait(lambda s: s["pins"]["connected"], 10, "connected")
        machine.hub.break_clients(refuse_for=1.5)
        back = time.monotonic() + 1.5
        machine.wait(lambda s: not s["pins"]["connected"], 2, "connected dropped")
        time.sleep(0.2)
    signalled = machine.frames.mark()
    os.kill(pid, signum)
    status, text = wait_exit_status(log)
    assert status == 0, text
    assert_quiet(text, signum)
    machine.hub.mute(0)
    if when != "while the bus is down":
        assert 0 in machine.sdo_writes(0x2000, 0, since=signalled), text
    else:
        time.sleep(max(0.0, back - time.monotonic()))  # until the hub takes lines again


def test_linuxcnc_shutdown_ends_the_component_quietly(machine):
    """LinuxCNC shut down as by its user (the display quits; `halcmd unload all` sends
    SIGTERM): the component writes 0x2000 = 0 and exits with status 0 without a
    traceback, within the 2 s LinuxCNC waits for it."""
    pid, log = machine.spawn()
    machine.select("z", 1)
    machine.ready_to_jog("z")
    mark = machine.frames.mark()
    machine.cnc.shutdown()
    status, text = wait_exit_status(log)
    assert status == 0, text
    assert_quiet(text, signal.SIGTERM)
    assert 0 in machine.sdo_writes(0x2000, 0, since=mark)
    assert gone(pid)
