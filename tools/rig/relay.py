"""An SLCAN relay between one python-can `slcan` client (the host component) and the
emulator's CAN port, as a CAN bus with a hostile stretch of wire in the middle.

The emulator's SLCAN port takes one client. The relay is that client and listens on a port
of its own (`channel`, `socket://127.0.0.1:<port>`) for the component. Frame lines pass both
ways unchanged and in order; the client's channel commands (`O`, `C`, `S8`, ...) are answered
`\\r` here (the device's channel is open from its power-on). The host component's SLCAN
codec (`canopen_handwheel.slcan`) reads and writes the lines; `drop` predicates get its
`Frame`. On command it

- drops the device's frames that match a predicate (`drop`: e.g. the next boot-up), so that
  the component never sees them;
- re-sends, once, an exact copy of the genuine feed record (TPDO1) from k records back, right
  after a genuine record has passed (`replay`): a copy of any age, as a CAN bus can deliver
  one (a duplicate, a delayed frame, a replay);
- puts frames of its own on the bus (`send`): to the device and to the component, as another
  node would (an NMT start from a second master).

It records what passed: `device` (every frame the device sent, dropped or not, in a
`FrameRecorder`), `host` (every frame the component sent), `records` (the genuine TPDO1s
passed to the component, `Frame.seq` their index), `dropped` and `injected`. Tests wait on the
recorders instead of sleeping.

The relay decodes no feed record: which copy to send is the caller's predicate over the raw
frames (`Replay.source`), so the relay serves whatever layout the record has.
"""

from __future__ import annotations

import select
import socket
import threading
import time
from typing import Callable, List, Optional, Sequence

from canopen_handwheel import slcan

from .constants import NODE_ID, START_TIMEOUT
from .frames import Frame, FrameRecorder


class Replay:
    """One copy to re-send: right after the first genuine record (the newest, index n) for
    which the record `back` before it (index n - back) exists, is at least `since`, and
    passes `source(copy, newest)` (if given), an exact copy of that record goes to the
    component. Fires once; `fired` is set then, with `copy`, `newest` and `at` (the
    relay's `time.monotonic()` when it sent the copy)."""

    def __init__(
        self,
        back: int,
        source: Optional[Callable[[Frame, Frame], bool]] = None,
        since: int = 0,
    ) -> None:
        if back < 1:
            raise ValueError("a copy is of a record before the newest: back >= 1")
        self.back = back
        self.source = source
        self.since = since
        self.fired = threading.Event()
        self.copy: Optional[Frame] = None
        self.newest: Optional[Frame] = None
        self.at: Optional[float] = None

    def offer(self, records: Sequence[Frame]) -> Optional[Frame]:
        """`records`: the genuine records passed so far, the newest last. The copy to send
        now (and the replay is spent), or None."""
        if self.copy is not None or not records:
            return None
        index = len(records) - 1 - self.back
        if index < max(0, self.since):
            return None
        copy, newest = records[index], records[-1]
        if self.source is not None and not self.source(copy, newest):
            return None
        self.copy, self.newest = copy, newest
        return copy

    def wait(self, timeout: float) -> bool:
        return self.fired.wait(timeout)

    def __repr__(self) -> str:
        if self.copy is None:
            return f"<Replay {self.back} back, armed>"
        return (
            f"<Replay {self.back} back: record #{self.copy.seq} [{self.copy.data.hex(' ')}] "
            f"after #{self.newest.seq} [{self.newest.data.hex(' ')}]>"
        )


class Drop:
    """The next `count` frames from the device that match `match` reach no client; each
    one dropped is appended to `frames` (as the device recorder has it) and `done` is set
    once `count` have been dropped."""

    def __init__(self, match: Callable[[slcan.Frame], bool], count: int = 1) -> None:
        self.match = match
        self.count = count
        self.frames: List[Frame] = []
        self.done = threading.Event()

    def wants(self, frame: slcan.Frame) -> bool:
        """Whether `frame` is to be dropped: it matches and fewer than `count` were."""
        return len(self.frames) < self.count and self.match(frame)

    def wait(self, timeout: float) -> bool:
        return self.done.wait(timeout)


def is_bootup(node_id: int = NODE_ID) -> Callable[[slcan.Frame], bool]:
    """Matches the boot-up of `node_id` (its heartbeat identifier, one byte 00)."""
    return lambda f: f.id == 0x700 + node_id and f.data == b"\x00" and not f.remote


class Relay:
    """The relay on `emulator`'s CAN port (a `Board`), for one client on `channel`.
    Connecting it starts the emulator's CPU (it waits for its CAN client), so the device's
    boot-up reaches `device` first. `close` ends it."""

    def __init__(self, emulator, node_id: int = NODE_ID) -> None:
        self.node_id = node_id
        self.tpdo1 = 0x180 + node_id
        self.device = FrameRecorder()  # every frame from the device (dropped ones too)
        self.host = FrameRecorder()  # every frame from the client
        self.records: List[Frame] = []  # genuine TPDO1s passed to the client
        self.dropped: List[Frame] = []
        self.injected: List[Frame] = []  # frames the relay made (copies, `send`)
        self.error: Optional[BaseException] = None
        self._lock = threading.Lock()
        self._drops: List[Drop] = []
        self._host_drops: List[Drop] = []  # `drop_from_host`
        self._replays: List[Replay] = []
        self._outgoing: List[tuple] = []  # (slcan.Frame, to_device, to_client)
        self._hold_until = 0.0  # `hold`: the device's frames wait for the client until then
        self._held: List[bytes] = []
        self._stop = threading.Event()
        self._wake_r, self._wake_w = socket.socketpair()
        self.up = _connect(emulator)
        self.server = socket.socket()
        self.server.bind(("127.0.0.1", 0))
        self.server.listen(1)
        self.channel = f"socket://127.0.0.1:{self.server.getsockname()[1]}"
        self.thread = threading.Thread(target=self._run, name="slcan-relay", daemon=True)
        self.thread.start()

    # Commands (from the test's thread) -------------------------------------------------------

    def drop(self, match: Callable[[slcan.Frame], bool], count: int = 1) -> Drop:
        """Drops the next `count` device frames matching `match`."""
        rule = Drop(match, count)
        with self._lock:
            self._drops.append(rule)
        return rule

    def drop_from_host(self, match: Callable[[slcan.Frame], bool], count: int = 1) -> Drop:
        """Drops the next `count` frames from the client that match `match`: `host` records
        them, the device never sees them."""
        rule = Drop(match, count)
        with self._lock:
            self._host_drops.append(rule)
        return rule

    def replay(
        self,
        back: int,
        source: Optional[Callable[[Frame, Frame], bool]] = None,
        since: int = 0,
    ) -> Replay:
        """Arms one copy (`Replay`). Armed copies fire one after another in the order they
        were armed (one is offered each genuine record only once those before it have
        fired), at most one after each genuine record."""
        rule = Replay(back, source, since)
        with self._lock:
            self._replays.append(rule)
        return rule

    def send(
        self, cob_id: int, data: bytes, to_device: bool = True, to_client: bool = True
    ) -> None:
        """Puts a frame of another node on the bus: to the device and to the client."""
        with self._lock:
            self._outgoing.append((slcan.Frame(cob_id, bytes(data)), to_device, to_client))
        self._wake_w.send(b"\0")

    def hold(self, seconds: float) -> None:
        """Holds every frame of the device for `seconds` from now, then delivers them to the
        client at once, in order (a gateway or adapter that buffers and bursts): the device
        and the recorders see them on time, the client late. Frames the client or the test
        send pass at once."""
        with self._lock:
            self._hold_until = time.monotonic() + seconds
        self._wake_w.send(b"\0")

    def record_count(self) -> int:
        with self._lock:
            return len(self.records)

    def newest_record(self) -> Optional[Frame]:
        with self._lock:
            return self.records[-1] if self.records else None

    def records_since(self, index: int) -> List[Frame]:
        with self._lock:
            return self.records[index:]

    def check(self) -> None:
        """Fails if the relay's thread ended with an error."""
        if self.error is not None:
            raise AssertionError(f"the relay failed: {self.error!r}")

    # The relay's thread ----------------------------------------------------------------------

    def _run(self) -> None:
        try:
            self._loop()
        except Exception as e:  # shown by `check` and the tests' waits
            self.error = e

    def _loop(self) -> None:
        client: Optional[socket.socket] = None
        from_up, from_client = slcan.LineSplitter(), slcan.LineSplitter()
        while not self._stop.is_set():
            waiting = [self.up, self._wake_r, client if client is not None else self.server]
            with self._lock:
                held_for = self._hold_until - time.monotonic()
            readable, _, _ = select.select(waiting, [], [], min(0.1, max(0.0, held_for)))
            to_client, to_up = [], []
            for s in readable:
                if s is self._wake_r:
                    self._wake_r.recv(4096)
                elif s is self.server:
                    client, _ = self.server.accept()
                    client.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                    from_client = slcan.LineSplitter()
                elif s is self.up:
                    data = self.up.recv(65536)
                    if not data:
                        return  # the emulator's port closed
                    now = time.monotonic()
                    for line in from_up.feed(data):
                        to_client += self._from_device(line, now)
                else:
                    try:
                        data = client.recv(65536)
                    except OSError:
                        data = b""
                    if not data:
                        client.close()
                        client = None
                        continue
                    now = time.monotonic()
                    for line in from_client.feed(data):
                        frame = slcan.decode(line)
                        if frame is None:
                            to_client.append(slcan.OK)  # a channel command: answered here
                            continue
                        self.host.on_message_received(slcan.to_message(frame, now))
                        if not self._host_dropped(frame, now):
                            to_up.append(line + b"\r")
            with self._lock:
                outgoing, self._outgoing = self._outgoing, []
            for frame, device, other in outgoing:
                line = slcan.encode(frame)
                self.injected.append(_frame(len(self.injected), time.monotonic(), frame))
                if device:
                    to_up.append(line)
                if other:
                    to_client.append(line)
            if to_up:
                self.up.sendall(b"".join(to_up))
            with self._lock:
                holding = time.monotonic() < self._hold_until
            if holding:
                self._held += to_client
                to_client = []
            elif self._held:
                to_client, self._held = self._held + to_client, []
            if to_client and client is not None:
                try:
                    client.sendall(b"".join(to_client))
                except OSError:
                    client.close()
                    client = None
        if client is not None:
            client.close()

    def _host_dropped(self, frame: slcan.Frame, now: float) -> bool:
        """Whether a `drop_from_host` rule takes the client's `frame`."""
        with self._lock:
            for rule in self._host_drops:
                if rule.wants(frame):
                    rule.frames.append(_frame(len(rule.frames), now, frame))
                    if len(rule.frames) >= rule.count:
                        rule.done.set()
                    return True
        return False

    def _from_device(self, line: bytes, now: float) -> List[bytes]:
        """What goes to the client for one line from the device."""
        frame = slcan.decode(line)
        if frame is None:
            return []  # the device's replies to our commands (`z`, `\r`): not the client's
        self.device.on_message_received(slcan.to_message(frame, now))
        with self._lock:
            for rule in self._drops:
                if rule.wants(frame):
                    seen = _frame(len(self.dropped), now, frame)
                    self.dropped.append(seen)
                    rule.frames.append(seen)
                    if len(rule.frames) >= rule.count:
                        rule.done.set()
                    return []
            out = [line + b"\r"]
            if frame.id != self.tpdo1 or frame.extended or frame.remote or len(frame.data) != 8:
                return out
            self.records.append(_frame(len(self.records), now, frame))
            if not self._replays:
                return out
            rule = self._replays[0]  # the next armed copy; those after it wait their turn
            copy = rule.offer(self.records)
            if copy is not None:
                self._replays.pop(0)
                out.append(slcan.encode(slcan.Frame(copy.id, copy.data)))
                rule.at = time.monotonic()
                self.injected.append(Frame(len(self.injected), rule.at, copy.id, copy.data))
                rule.fired.set()
            return out

    def close(self) -> None:
        self._stop.set()
        self._wake_w.send(b"\0")
        self.thread.join(5)
        for s in (self.up, self.server, self._wake_r, self._wake_w):
            s.close()


def _frame(seq: int, now: float, frame: slcan.Frame) -> Frame:
    return Frame(seq, now, frame.id, frame.data, frame.extended, frame.remote)


def _connect(emulator) -> socket.socket:
    """The emulator's CAN port, as `connect_bus` connects: retried only while refused, never
    a throw-away probe (the emulator would take it as its client)."""
    deadline = time.monotonic() + START_TIMEOUT
    while True:
        emulator.check_alive()
        try:
            s = socket.create_connection(("127.0.0.1", emulator.can_port), timeout=5)
            s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            s.settimeout(None)
            return s
        except ConnectionRefusedError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.1)
