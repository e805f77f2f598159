"""The master's side of a booted handwheel: bus, network with the node, recorder and
stimulus client in one `Rig`, opened by `open_rig`; the master's own heartbeat."""

from __future__ import annotations

import threading
import time
from contextlib import contextmanager
from typing import Callable, Iterator, Optional

import can
import canopen

from .constants import (
    AXES,
    BOOTUP,
    EDS,
    FRAME_TIMEOUT,
    HEARTBEAT,
    NMT,
    NMT_START,
    NODE_ID,
    NOTIFIER_CYCLE,
    OPERATIONAL,
    SDO_RX,
    SDO_TIMEOUT,
    SDO_TX,
    SELECT_TIMEOUT,
    TPDO1,
)
from .emulator import Board, Stimulus, connect_bus
from .frames import Frame, FrameRecorder, feed_record


class Rig:
    """One emulated handwheel and the master's view of it."""

    def __init__(
        self,
        board: Board,
        bus: can.BusABC,
        network: canopen.Network,
        frames: FrameRecorder,
        stim: Stimulus,
    ) -> None:
        self.board = board
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
        """The abort code of an SDO transfer that must abort (a test's check: pytest's
        `raises`, imported here so that the rest of the rig runs without pytest)."""
        import pytest

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
            lambda f: f.id == TPDO1 and len(f.data) == 8 and feed_record(f).position == position,
            since=since,
            timeout=timeout,
            what=f"feed record at position {position}",
        )


class MasterHeartbeat:
    """The master's own heartbeat (0x700 + id), sent from a thread through
    `network.send_message`, which serialises it with the SDO client's frames."""

    def __init__(
        self,
        network: canopen.Network,
        node_id: int = 1,
        period: float = 0.05,
        state: int = OPERATIONAL,
    ) -> None:
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


@contextmanager
def open_rig(board: Board) -> Iterator[Rig]:
    """The master's side of a booted handwheel on `board`: bus, network with the node,
    recorder, stimulus client; the boot-up frame is the first recorded. Closed on exit."""
    bus = connect_bus(board)
    frames = FrameRecorder()
    network = canopen.Network(bus)
    network.NOTIFIER_CYCLE = NOTIFIER_CYCLE
    network.listeners.append(frames)  # before connect(): the notifier sees every frame
    network.add_node(NODE_ID, str(EDS))
    network.connect()
    stim = None
    try:
        # The CPU starts with this client, so the boot-up is the first frame the master reads:
        # one wait, no re-sent `O` (tests/interop/test_connect.py checks exactly that).
        frames.wait_id(HEARTBEAT, bytes([BOOTUP]))
        network[NODE_ID].sdo.RESPONSE_TIMEOUT = SDO_TIMEOUT
        stim = Stimulus(board.stim_port, board)
        yield Rig(board, bus, network, frames, stim)
    finally:
        if stim is not None:
            stim.close()
        try:
            network.disconnect()  # stops the notifier, sends `C`, closes the socket
        except Exception as e:  # a crashed emulator must not hide the test's own failure
            print(f"network.disconnect(): {e!r}")
