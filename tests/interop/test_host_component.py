"""The host component against the firmware, frozen and under an EMCY flood:
`canopen-handwheel` from host/src in a process of its own, with host/tests/fake_hal.py as
LinuxCNC's `hal` (every pin change logged with its time), on an SLCAN line relayed to the
emulator's CAN port. The relay stamps the device's feed records as they pass and can flood the
component with EMCYs.
"""

from __future__ import annotations

import os
import select
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from canopen_handwheel import slcan
from canopen_handwheel.core import Record
from rig import NODE_ID, ROOT, START_TIMEOUT, Board, Stimulus
from rig.component import HalLog, capture_problems, end_component

BOOTUP = slcan.Frame(0x700 + NODE_ID, b"\x00")
# EMCY 0x5000, cleared never
EMCY_LINE = slcan.encode(slcan.Frame(0x080 + NODE_ID, bytes.fromhex("0050010000000000")))

COMPONENT_RUN = """
import sys
sys.path[:0] = [{tests!r}, {src!r}]
import fake_hal
sys.modules["hal"] = fake_hal
from canopen_handwheel import component
sys.exit(component.main(sys.argv[1:]))
"""


class Relay:
    """One SLCAN client (the component) relayed to the emulator's single CAN port. Frame
    lines pass both ways; the client's channel commands (`O`, `C`, ...) are answered here.
    Every TPDO1 from the device is kept with the time it arrived (`records`). `flood(rate)`
    sends the client EMCY lines at `rate` per second (0: stop), in the same thread as the
    relayed lines, so that no line is cut."""

    def __init__(self, board: Board) -> None:
        self.up = self._connect(board)
        self.server = socket.socket()
        self.server.bind(("127.0.0.1", 0))
        self.server.listen(1)
        self.channel = f"socket://127.0.0.1:{self.server.getsockname()[1]}"
        self.records = []  # (time.monotonic(), 8 bytes)
        self.booted = threading.Event()  # the device's boot-up passed
        self.flooded = 0
        self._rate = 0.0
        self._flood_start = 0.0
        self._flood_base = 0
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._run, name="relay", daemon=True)
        self.thread.start()

    @staticmethod
    def _connect(board: Board) -> socket.socket:
        # As `connect_bus`: retry only while refused, never a throw-away probe.
        deadline = time.monotonic() + START_TIMEOUT
        while True:
            board.check_alive()
            try:
                s = socket.create_connection(("127.0.0.1", board.can_port), timeout=5)
                s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                return s
            except ConnectionRefusedError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.1)

    def flood(self, rate: float) -> None:
        with self._lock:
            self._rate = rate
            self._flood_start = time.monotonic()
            self._flood_base = self.flooded

    def _run(self) -> None:
        client = None
        from_up, from_client = slcan.LineSplitter(), slcan.LineSplitter()
        try:
            while not self._stop.is_set():
                waiting = [self.up] + ([client] if client else [self.server])
                readable, _, _ = select.select(waiting, [], [], 0.001)
                out = b""
                now = time.monotonic()
                for s in readable:
                    if s is self.server:
                        client, _ = self.server.accept()
                        client.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                    elif s is self.up:
                        data = self.up.recv(65536)
                        if not data:
                            return
                        for line in from_up.feed(data):
                            frame = slcan.decode(line)
                            if frame is None:
                                continue  # the device's answers (`z`) to the client's frames
                            out += line + b"\r"
                            if frame == BOOTUP:
                                self.booted.set()
                            tpdo1 = frame.id == 0x180 + NODE_ID and not frame.extended
                            if tpdo1 and len(frame.data) == 8:
                                self.records.append((now, frame.data))
                    else:
                        data = client.recv(65536)
                        if not data:
                            client = None
                            continue
                        for line in from_client.feed(data):
                            if slcan.decode(line) is not None:
                                self.up.sendall(line + b"\r")
                            else:
                                out += slcan.OK  # a channel command, answered here
                with self._lock:
                    if self._rate:
                        due = int((now - self._flood_start) * self._rate) + self._flood_base
                        out += EMCY_LINE * max(0, due - self.flooded)
                        self.flooded = max(self.flooded, due)
                if client is not None and out:
                    client.sendall(out)
        except OSError:
            return

    def close(self) -> None:
        self._stop.set()
        self.thread.join(5)
        self.up.close()
        self.server.close()


class Component:
    """The board, the relay, the stimulus and the component process (`enable` true)."""

    def __init__(self, board: Board, tmp: Path) -> None:
        self.relay = Relay(board)
        # As `open_rig`: the stimulus port once the firmware has booted.
        assert self.relay.booted.wait(START_TIMEOUT), "no boot-up"
        self.stim = Stimulus(board.stim_port, board)
        self.hal = HalLog(tmp / "hal.log")
        self.hal.path.write_text("")
        self.err = open(tmp / "component.log", "w")
        script = COMPONENT_RUN.format(
            tests=str(ROOT / "host" / "tests"), src=str(ROOT / "host" / "src")
        )
        env = dict(os.environ, FAKE_HAL_LOG=str(self.hal.path), FAKE_HAL_SET="enable=1")
        self.capture = tmp / "capture.log"
        self.proc = subprocess.Popen(
            [sys.executable, "-c", script, "--interface", "slcan", "--channel"]
            + [self.relay.channel, "--axes", "xyz", "--capture", str(self.capture)],
            env=env,
            stderr=self.err,
        )
        self.log_path = tmp / "component.log"

    def wait(self, pred, timeout: float, what: str) -> None:
        deadline = time.monotonic() + timeout
        while not pred():
            assert self.proc.poll() is None, f"the component ended:\n{self.log_path.read_text()}"
            assert time.monotonic() < deadline, (
                f"no {what} within {timeout} s:\n{self.log_path.read_text()[-3000:]}"
            )
            time.sleep(0.01)

    def enabled(self) -> bool:
        return self.hal.value("axis.x.jog-enable") == "True"

    def rss(self) -> int:
        """The component's resident set, bytes."""
        for line in Path(f"/proc/{self.proc.pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) * 1024
        raise AssertionError("no VmRSS")

    def close(self) -> None:
        end_component(self.proc)
        self.err.close()
        self.stim.close()
        self.relay.close()


@pytest.fixture
def host(board: Board, tmp_path):
    c = Component(board, tmp_path)
    try:
        c.stim.axis("x")
        c.stim.mult(1)
        c.wait(c.enabled, 60, "jog-enable of X (configured, started, feed enabled)")
        yield c
    finally:
        c.close()
    # The session's capture replays to the pins the component wrote.
    assert capture_problems(c.capture, c.hal) == []


def test_a_frozen_component_moves_nothing_from_its_backlog(host):
    """The component stopped (SIGSTOP) for 3 s while 20 detents are turned in the first 0.3 s,
    then continued: `axis.x.jog-counts` does not move from the records that waited (the device
    has meanwhile stopped the feed for master loss); afterwards the feed is enabled again and
    turning moves X exactly."""
    start = host.hal.number("axis.x.jog-counts")
    host.stim.turn(2)
    host.wait(lambda: host.hal.number("axis.x.jog-counts") == start + 2, 5, "X +2")
    before = host.hal.number("axis.x.jog-counts")
    host.proc.send_signal(signal.SIGSTOP)
    frozen = time.monotonic()
    try:
        for i in range(10):
            host.stim.turn(2)
            time.sleep(max(0.0, frozen + 0.03 * (i + 1) - time.monotonic()))
        turned = time.monotonic() - frozen
        time.sleep(max(0.0, frozen + 3.0 - time.monotonic()))
    finally:
        host.proc.send_signal(signal.SIGCONT)
    resumed = time.monotonic()
    assert turned < 0.6, turned
    arrived = [t for t, _ in host.relay.records if frozen < t < resumed]
    assert len(arrived) >= 10, "the device sent its records during the freeze"
    time.sleep(1.5)
    after = host.hal.history("axis.x.jog-counts", since=resumed)
    assert after == [], f"counts moved from the backlog: {after}"
    host.wait(host.enabled, 10, "the feed enabled again")
    host.stim.turn(3)
    host.wait(
        lambda: host.hal.number("axis.x.jog-counts") == before + 3, 5, "X +3 after the freeze"
    )
    time.sleep(0.3)
    assert host.hal.number("axis.x.jog-counts") == before + 3


def test_an_emcy_flood_neither_delays_motion_nor_grows_memory(host):
    """EMCYs at 5 000 frames/s to the component while X is turned a detent every 0.4 s: every
    detent reaches `jog-counts`, each within 0.1 s of its record reaching the host (and 0.25 s
    of the `turn` command: the board's stimulus makes a detent's edges 600 us apart and answers
    25 ms later), and the component's resident memory stays within 2 MB (python-canopen's EMCY
    consumer kept about 500 B per EMCY: over 10 MB here)."""
    rate = 5000
    host.relay.flood(rate)
    time.sleep(1.0)
    rss_start = host.rss()
    flood_start, flooded_start = time.monotonic(), host.relay.flooded
    latencies = []  # record reaching the host -> pin
    turns = []  # `turn` command sent -> pin (the detent is made in between)
    first = host.hal.number("axis.x.jog-counts")
    for i in range(10):
        counts = host.hal.number("axis.x.jog-counts")
        position = int(host.hal.value("position") or 0)
        turned = time.monotonic()
        host.stim.turn(1)
        host.wait(
            lambda c=counts: host.hal.number("axis.x.jog-counts") == c + 1, 5, f"detent {i} on X"
        )
        pin_at = host.hal.history("axis.x.jog-counts")[-1][0]
        turns.append(pin_at - turned)
        sent = [t for t, data in host.relay.records if Record.decode(data).position == position + 1]
        assert sent, f"no record of position {position + 1}"
        latencies.append(pin_at - sent[0])
        time.sleep(0.4)
    flood_rate = (host.relay.flooded - flooded_start) / (time.monotonic() - flood_start)
    rss_grown = host.rss() - rss_start
    host.relay.flood(0)
    print(
        f"EMCY flood {flood_rate:.0f} frames/s: record-to-pin latency max "
        f"{max(latencies) * 1000:.1f} ms, median {sorted(latencies)[5] * 1000:.1f} ms; "
        f"turn command to pin max {max(turns) * 1000:.1f} ms; "
        f"RSS {rss_start / 1e6:.1f} MB, grown {rss_grown / 1e3:.0f} kB"
    )
    assert flood_rate > 0.8 * rate, flood_rate
    assert host.hal.number("axis.x.jog-counts") == first + 10
    assert max(latencies) < 0.1, latencies
    assert max(turns) < 0.25, turns
    assert rss_grown < 2_000_000, rss_grown
    assert host.proc.poll() is None
