"""Fixtures of the interop suite: the firmware's QEMU variant against python-canopen.

Every test gets a fresh emulator (``cargo xtask qemu``), a python-can ``slcan`` bus on its
CAN port, a ``canopen.Network`` with the handwheel node (``eds/handwheel.eds``, node 16), a
recorder of every frame the master receives, and a client of the stimulus port. See
README.md in this folder for what the suite assumes of the firmware.
"""

from __future__ import annotations

import os
from contextlib import contextmanager
import re
import shlex
import signal
import socket
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterator, List, Optional

import can
import canopen
import pytest

ROOT = Path(__file__).resolve().parents[2]
EDS = ROOT / "eds" / "handwheel.eds"

# The emulated board (the release image, `cargo xtask board`): its launcher.
sys.path.insert(0, str(ROOT / "tools" / "board-emu"))
from launcher import BoardProcess  # noqa: E402

NODE_ID = 16
NMT = 0x000
EMCY = 0x080 + NODE_ID
TPDO1 = 0x180 + NODE_ID
TPDO2 = 0x280 + NODE_ID
SDO_TX = 0x580 + NODE_ID  # server -> client
SDO_RX = 0x600 + NODE_ID  # client -> server
HEARTBEAT = 0x700 + NODE_ID

# Heartbeat / boot-up state bytes.
BOOTUP = 0x00
STOPPED = 0x04
OPERATIONAL = 0x05
PRE_OPERATIONAL = 0x7F

# NMT command specifiers.
NMT_START = 0x01
NMT_STOP = 0x02
NMT_PRE_OPERATIONAL = 0x80
NMT_RESET_NODE = 0x81
NMT_RESET_COMMUNICATION = 0x82


def _env_seconds(name: str, default: float) -> float:
    return float(os.environ.get(name, default))


# The first start also builds the firmware (and may install defmt-print): be patient.
START_TIMEOUT = _env_seconds("HANDWHEEL_QEMU_START_TIMEOUT", 900)
# Waiting for a frame, a reply or a log line. QEMU's time is emulated: generous.
FRAME_TIMEOUT = _env_seconds("HANDWHEEL_FRAME_TIMEOUT", 5)
SDO_TIMEOUT = _env_seconds("HANDWHEEL_SDO_TIMEOUT", 2)
STIM_TIMEOUT = _env_seconds("HANDWHEEL_STIM_TIMEOUT", 30)
# Debounced selector: 4 samples at 5 ms; polled through SDO until it shows.
SELECT_TIMEOUT = _env_seconds("HANDWHEEL_SELECT_TIMEOUT", 3)


# --------------------------------------------------------------------------------------
# Frame recorder
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Frame:
    """One frame the master received."""

    seq: int  # position in the recording
    t: float  # host receive time (time.monotonic())
    id: int
    data: bytes
    extended: bool = False
    remote: bool = False

    def __repr__(self) -> str:
        return f"<#{self.seq} {self.t:.3f} {self.id:03X} [{self.data.hex(' ')}]>"


class FrameRecorder(can.Listener):
    """Keeps every received frame; tests wait on it instead of sleeping."""

    def __init__(self) -> None:
        self._frames: List[Frame] = []
        self._cond = threading.Condition()

    def on_message_received(self, msg: can.Message) -> None:
        if msg.is_error_frame:
            return
        with self._cond:
            self._frames.append(
                Frame(
                    seq=len(self._frames),
                    t=time.monotonic(),
                    id=msg.arbitration_id,
                    data=bytes(msg.data),
                    extended=msg.is_extended_id,
                    remote=msg.is_remote_frame,
                )
            )
            self._cond.notify_all()

    def on_error(self, exc: Exception) -> None:  # keep the notifier alive
        pass

    def mark(self) -> int:
        """A position in the recording; `since=mark` looks only at later frames."""
        with self._cond:
            return len(self._frames)

    def frames(self, cob_id: Optional[int] = None, since: int = 0) -> List[Frame]:
        with self._cond:
            return [f for f in self._frames[since:] if cob_id is None or f.id == cob_id]

    def wait_for(
        self,
        pred: Callable[[Frame], bool],
        timeout: float = FRAME_TIMEOUT,
        since: int = 0,
        what: str = "frame",
    ) -> Frame:
        """The first frame after `since` matching `pred`; fails with the frames seen."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while True:
                for f in self._frames[since:]:
                    if pred(f):
                        return f
                left = deadline - time.monotonic()
                if left <= 0:
                    seen = self._frames[since:][-30:]
                    raise AssertionError(f"no {what} within {timeout} s; last frames: {seen}")
                self._cond.wait(left)

    def wait_id(self, cob_id: int, data: Optional[bytes] = None, **kw) -> Frame:
        what = f"frame {cob_id:03X}" + (f" [{data.hex(' ')}]" if data is not None else "")
        return self.wait_for(
            lambda f: f.id == cob_id and (data is None or f.data == data), what=what, **kw
        )

    def wait_count(
        self, cob_id: int, count: int, timeout: float = FRAME_TIMEOUT, since: int = 0
    ) -> List[Frame]:
        """Waits until `count` frames on `cob_id` arrived after `since`; returns them all."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while True:
                got = [f for f in self._frames[since:] if f.id == cob_id]
                if len(got) >= count:
                    return got
                left = deadline - time.monotonic()
                if left <= 0:
                    raise AssertionError(
                        f"{len(got)} of {count} frames {cob_id:03X} within {timeout} s: {got}"
                    )
                self._cond.wait(left)

    def assert_none(
        self, pred: Callable[[Frame], bool], duration: float, since: int = 0, what: str = ""
    ) -> None:
        """No frame matching `pred` arrives after `since` for `duration` seconds (a
        negative check must wait; it fails as soon as such a frame shows up)."""
        deadline = time.monotonic() + duration
        with self._cond:
            while True:
                bad = [f for f in self._frames[since:] if pred(f)]
                assert not bad, f"unexpected {what or 'frames'}: {bad}"
                left = deadline - time.monotonic()
                if left <= 0:
                    return
                self._cond.wait(left)


# --------------------------------------------------------------------------------------
# Emulator process
# --------------------------------------------------------------------------------------


def free_ports(count: int) -> List[int]:
    """`count` distinct free TCP ports on 127.0.0.1 (bound together, then released)."""
    socks = []
    try:
        for _ in range(count):
            s = socket.socket()
            s.bind(("127.0.0.1", 0))
            socks.append(s)
        return [s.getsockname()[1] for s in socks]
    finally:
        for s in socks:
            s.close()


class Qemu:
    """`cargo xtask qemu --can-port P --stim-port Q`, its stderr (QEMU's messages and the
    decoded defmt log) in `log_path`."""

    def __init__(self, log_path: Path) -> None:
        self.can_port, self.stim_port = free_ports(2)
        self.log_path = log_path
        self._log_file = open(log_path, "wb")
        # HANDWHEEL_QEMU_COMMAND overrides the runner, e.g. to use a prebuilt image:
        # "some-runner --can-port {can_port} --stim-port {stim_port}".
        template = os.environ.get("HANDWHEEL_QEMU_COMMAND")
        if template:
            command = shlex.split(
                template.format(can_port=self.can_port, stim_port=self.stim_port)
            )
        else:
            command = [
                os.environ.get("CARGO", "cargo"),
                "xtask",
                "qemu",
                "--can-port",
                str(self.can_port),
                "--stim-port",
                str(self.stim_port),
            ]
        self.proc = subprocess.Popen(
            command,
            cwd=ROOT,
            stdin=subprocess.DEVNULL,
            stdout=self._log_file,
            stderr=subprocess.STDOUT,
            start_new_session=True,  # its own process group: cargo, xtask, QEMU, defmt-print
        )

    def log(self) -> str:
        return self.log_path.read_text(errors="replace")

    def check_alive(self) -> None:
        code = self.proc.poll()
        if code is not None:
            tail = "\n".join(self.log().splitlines()[-40:])
            raise RuntimeError(f"`cargo xtask qemu` exited with {code}:\n{tail}")

    def wait_for_log(self, pattern: str, timeout: float = FRAME_TIMEOUT, start: int = 0) -> re.Match:
        """The first match of the regex `pattern` in the log after character `start`."""
        deadline = time.monotonic() + timeout
        rx = re.compile(pattern, re.MULTILINE)
        while True:
            m = rx.search(self.log(), start)
            if m:
                return m
            if time.monotonic() > deadline:
                tail = "\n".join(self.log().splitlines()[-30:])
                raise AssertionError(f"log line /{pattern}/ not seen in {timeout} s:\n{tail}")
            time.sleep(0.05)

    def stop(self) -> None:
        if self.proc.poll() is None:
            try:
                os.killpg(self.proc.pid, signal.SIGTERM)
            except ProcessLookupError:
                pass
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait(10)
        self._log_file.close()


# --------------------------------------------------------------------------------------
# Stimulus client
# --------------------------------------------------------------------------------------


class Stimulus:
    """The stimulus port: one command line out, one reply line back."""

    def __init__(self, port: int, qemu: Qemu) -> None:
        deadline = time.monotonic() + FRAME_TIMEOUT
        while True:
            qemu.check_alive()
            try:
                self._sock = socket.create_connection(("127.0.0.1", port), timeout=STIM_TIMEOUT)
                break
            except OSError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.05)
        self._sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._reader = self._sock.makefile("rb")

    def send(self, command: str) -> str:
        """Sends one command; returns the reply line without its newline."""
        self._sock.sendall(command.encode() + b"\n")
        line = self._reader.readline()
        assert line.endswith(b"\n"), f"{command!r}: reply {line!r} cut short"
        return line.decode(errors="replace").rstrip("\r\n")

    def cmd(self, command: str) -> None:
        reply = self.send(command)
        assert reply == "ok", f"stimulus {command!r} answered {reply!r}"

    def turn(self, detents: int) -> None:
        self.cmd(f"turn {detents}")

    def ab(self, levels: int) -> None:
        self.cmd(f"ab {levels}")

    def axis(self, axis: str) -> None:
        self.cmd(f"axis {axis}")

    def mult(self, factor: int) -> None:
        self.cmd(f"mult {factor}")

    def close(self) -> None:
        try:
            self._reader.close()
            self._sock.close()
        except OSError:
            pass


# --------------------------------------------------------------------------------------
# The rig
# --------------------------------------------------------------------------------------

AXES = {"off": 0, "x": 1, "y": 2, "z": 3, "w": 4, "v": 5}


def feed_record(frame: Frame):
    """(position, axis, multiplier, status, sequence) of a TPDO1 feed record."""
    assert frame.id == TPDO1 and len(frame.data) == 8, f"not a feed record: {frame}"
    d = frame.data
    return (int.from_bytes(d[0:4], "little", signed=True), d[4], d[5], d[6], d[7])


class Rig:
    """One emulated handwheel and the master's view of it."""

    def __init__(self, qemu: Qemu, bus: can.BusABC, network: canopen.Network,
                 frames: FrameRecorder, stim: Stimulus) -> None:
        self.qemu = qemu
        self.bus = bus
        self.network = network
        self.frames = frames
        self.stim = stim
        self.node: canopen.RemoteNode = network[NODE_ID]

    # NMT ----------------------------------------------------------------------------

    def nmt(self, command: int, target: int = NODE_ID) -> int:
        """Sends an NMT command; returns the recording mark from before it."""
        mark = self.frames.mark()
        self.network.send_message(NMT, bytes([command, target]))
        return mark

    def nmt_and_heartbeat(self, command: int, state: int, target: int = NODE_ID) -> Frame:
        """Sends an NMT command and waits for the heartbeat (or boot-up) showing `state`,
        which must come right away, not with the next periodic heartbeat."""
        sent = time.monotonic()
        mark = self.nmt(command, target)
        hb = self.frames.wait_id(HEARTBEAT, bytes([state]), since=mark)
        assert hb.t - sent < 0.6, f"state {state:#04x} heartbeat only after {hb.t - sent:.3f} s"
        return hb

    def start(self) -> None:
        self.nmt_and_heartbeat(NMT_START, OPERATIONAL)

    # SDO ----------------------------------------------------------------------------

    def read(self, index: int, sub: int = 0) -> int:
        """Unsigned little-endian value of an SDO upload."""
        return int.from_bytes(self.node.sdo.upload(index, sub), "little")

    def read_signed(self, index: int, sub: int = 0) -> int:
        return int.from_bytes(self.node.sdo.upload(index, sub), "little", signed=True)

    def write(self, index: int, sub: int, value: int, size: int) -> None:
        """Expedited download of `value` in `size` bytes."""
        self.node.sdo.download(index, sub, value.to_bytes(size, "little", signed=value < 0))

    def abort_code(self, action: Callable[[], object]) -> int:
        """The abort code of an SDO transfer that must abort."""
        with pytest.raises(canopen.SdoAbortedError) as err:
            action()
        return err.value.code

    def write_abort(self, index: int, sub: int, data: bytes) -> int:
        return self.abort_code(lambda: self.node.sdo.download(index, sub, data))

    def read_abort(self, index: int, sub: int = 0) -> int:
        return self.abort_code(lambda: self.node.sdo.upload(index, sub))

    def sdo_raw(self, request: bytes, timeout: float = FRAME_TIMEOUT) -> bytes:
        """Sends a raw SDO request frame and returns the server's reply frame."""
        mark = self.frames.mark()
        self.network.send_message(SDO_RX, request)
        return self.frames.wait_id(SDO_TX, since=mark, timeout=timeout).data

    # Inputs -------------------------------------------------------------------------

    def select(self, axis: str, mult: int = 1) -> None:
        """Sets the selector lines and waits until the debounced selection shows in
        0x2010 (the firmware debounces; the stimulus only sets the lines)."""
        self.stim.axis(axis)
        self.stim.mult(mult)
        deadline = time.monotonic() + SELECT_TIMEOUT
        while True:
            now = (self.read(0x2010, 1), self.read(0x2010, 2))
            if now == (AXES[axis], mult):
                return
            assert time.monotonic() < deadline, f"selection {now}, wanted {(AXES[axis], mult)}"
            time.sleep(0.01)

    def feed_on(self, axis: str, mult: int = 1, unit_steps: bool = False) -> int:
        """Selected, (format set,) Operational, feed enabled; returns the mark after."""
        self.select(axis, mult)
        if unit_steps:
            self.write(0x2001, 0, 1, 1)
        self.start()
        self.write(0x2000, 0, 1, 1)
        return self.frames.mark()

    def wait_position(self, position: int, since: int, timeout: float = FRAME_TIMEOUT) -> Frame:
        return self.frames.wait_for(
            lambda f: f.id == TPDO1 and len(f.data) == 8 and feed_record(f)[0] == position,
            since=since, timeout=timeout, what=f"feed record at position {position}",
        )


class MasterHeartbeat:
    """The master's own heartbeat (0x700 + id), sent from a thread through
    `network.send_message`, which serialises it with the SDO client's frames."""

    def __init__(self, network: canopen.Network, node_id: int = 1, period: float = 0.05,
                 state: int = OPERATIONAL) -> None:
        self._network = network
        self._frame = (0x700 + node_id, bytes([state]))
        self._period = period
        self._stop = threading.Event()
        self._thread: Optional[threading.Thread] = None

    def start(self) -> "MasterHeartbeat":
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()
        return self

    def _run(self) -> None:
        while not self._stop.is_set():
            self._network.send_message(*self._frame)
            self._stop.wait(self._period)

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5)
            self._thread = None


def _refused(error: BaseException) -> bool:
    """Whether `error` (python-can's CanInitializationError, from pyserial's
    SerialException) goes back to a refused TCP connection."""
    seen: Optional[BaseException] = error
    while seen is not None:
        if isinstance(seen, ConnectionRefusedError):
            return True
        seen = seen.__cause__ or seen.__context__
    return False


def _connect_bus(qemu: Qemu, **bus_kwargs) -> can.BusABC:
    """python-can's slcan bus on the CAN port, as the top-level README connects (extra
    `bus_kwargs` such as `bitrate` go to `can.Bus`). QEMU listens (and waits for this
    client) only once it is up: retry while the connection is refused, and only then. Never
    probe the port with a throw-away connection: QEMU would take it as its client."""
    deadline = time.monotonic() + START_TIMEOUT
    while True:
        qemu.check_alive()
        try:
            return can.Bus(
                interface="slcan",
                channel=f"socket://127.0.0.1:{qemu.can_port}",
                sleep_after_open=0,
                **bus_kwargs,
            )
        except can.CanError as e:
            if not _refused(e) or time.monotonic() > deadline:
                raise
            time.sleep(0.1)


# Tests that need the QEMU variant's board layer, with the reason; on the emulated board
# they are skipped (the rest of the suite runs on both).
QEMU_ONLY = {
    "test_receive_overrun_raises_emcy_8110_and_the_node_recovers":
        "needs the QEMU variant's `stall` stimulus (the board image has no such hook); the "
        "board's overrun is tested by test_board.py::test_burst_during_a_flash_erase_overruns",
    "test_configure_node_id_store_and_reset":
        "asserts the QEMU variant's log line for stored settings at an NMT reset (its boot); "
        "the board reads them at power-on: test_board.py::test_stored_settings_survive_a_power_cycle",
    "test_configure_bit_timing_and_store":
        "asserts the QEMU variant's log lines (no bit rate there); the board's bit rates are "
        "checked on BTR by test_board.py::test_every_dip_code_gives_the_tables_node_id_and_bit_rate",
}


def pytest_collection_modifyitems(config, items):
    for item in items:
        callspec = getattr(item, "callspec", None)
        if callspec is None or callspec.params.get("qemu") != "board":
            continue
        reason = QEMU_ONLY.get(getattr(item, "originalname", item.name))
        if reason:
            item.add_marker(pytest.mark.skip(reason=f"QEMU variant only: {reason}"))


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    outcome = yield
    report = outcome.get_result()
    setattr(item, "rep_" + report.when, report)


# Which emulator a test runs on: the QEMU variant, and the board image on the emulated board.
EMULATORS = ["qemu", "board"]


@pytest.fixture(params=EMULATORS)
def qemu(request, tmp_path) -> Iterator[Qemu]:
    """The emulated handwheel: the QEMU variant, or (param `board`) the release image on the
    emulated board, which has the same ports, log and stimulus commands."""
    if request.param == "board":
        q = BoardProcess(tmp_path / "board.log", tmp_path / "flash.bin")
    else:
        q = Qemu(tmp_path / "qemu.log")
    try:
        yield q
    finally:
        q.stop()
        failed = any(
            getattr(getattr(request.node, f"rep_{w}", None), "failed", False)
            for w in ("setup", "call")
        )
        if failed:
            tail = "\n".join(q.log().splitlines()[-60:])
            print(f"--- last lines of {q.log_path} ---\n{tail}")


@contextmanager
def open_rig(qemu: Qemu) -> Iterator[Rig]:
    """The master's side of a booted handwheel on `qemu`: bus, network with the node,
    recorder, stimulus client; the boot-up frame is the first recorded. Closed on exit."""
    bus = _connect_bus(qemu)
    frames = FrameRecorder()
    network = canopen.Network(bus)
    network.listeners.append(frames)  # before connect(): the notifier sees every frame
    network.add_node(NODE_ID, str(EDS))
    network.connect()
    stim = None
    try:
        # The firmware sends the boot-up at boot whether or not QEMU passed on python-can's
        # `O`, so one wait, no re-sent `O` (test_connect.py checks exactly that).
        frames.wait_id(HEARTBEAT, bytes([BOOTUP]))
        network[NODE_ID].sdo.RESPONSE_TIMEOUT = SDO_TIMEOUT
        stim = Stimulus(qemu.stim_port, qemu)
        yield Rig(qemu, bus, network, frames, stim)
    finally:
        if stim is not None:
            stim.close()
        try:
            network.disconnect()  # stops the notifier, sends `C`, closes the socket
        except Exception as e:  # a crashed emulator must not hide the test's own failure
            print(f"network.disconnect(): {e!r}")


@pytest.fixture
def rig(qemu: Qemu) -> Iterator[Rig]:
    """A booted handwheel in Pre-operational; the boot-up frame is the first recorded."""
    with open_rig(qemu) as r:
        yield r


@pytest.fixture
def node(rig: Rig) -> canopen.RemoteNode:
    return rig.node


@pytest.fixture
def frames(rig: Rig) -> FrameRecorder:
    return rig.frames


@pytest.fixture
def stim(rig: Rig) -> Stimulus:
    return rig.stim
