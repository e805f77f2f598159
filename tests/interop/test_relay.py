"""The SLCAN relay's own logic (tools/rig/relay.py), without an emulator: which record a copy
is of and when it goes out, and the relay itself between a stand-in emulator port (a plain
TCP server) and a python-can `slcan` client. The SLCAN lines it reads and writes are the
codec's (host/tests/test_slcan.py)."""

from __future__ import annotations

import socket
import threading
import time

import can
import pytest

from canopen_handwheel import slcan
from rig import Frame, slcan_line
from rig.relay import Relay, Replay, is_bootup


def records(n: int, tag=lambda i: i) -> list:
    """n records whose data names their index (byte 0) and a tag (byte 1)."""
    return [
        Frame(i, float(i), 0x190, bytes([i % 256, tag(i) % 256, 0, 0, 0, 0, 0, 0]))
        for i in range(n)
    ]


def test_replay_sends_the_record_k_back_from_the_newest():
    log = records(300)
    for k in (1, 2, 129, 255, 256, 299):
        r = Replay(k)
        copy = r.offer(log)
        assert copy is log[-1 - k], k
        assert r.copy is copy and r.newest is log[-1]


def test_replay_waits_until_the_record_k_back_exists():
    r = Replay(5)
    log = records(12)
    for n in range(1, 6):
        assert r.offer(log[:n]) is None
    # Records 0..5: the newest (5) has one 5 back, record 0.
    assert r.offer(log[:6]) is log[0]


def test_replay_fires_once():
    r = Replay(3)
    log = records(10)
    assert r.offer(log[:4]) is log[0]
    assert r.offer(log) is None
    assert r.copy is log[0]


def test_replay_takes_no_record_before_since():
    r = Replay(4, since=10)
    log = records(20)
    for n in range(1, 15):
        assert r.offer(log[:n]) is None, n
    assert r.offer(log[:15]) is log[10]


def test_replay_source_picks_the_copy_and_its_newest():
    # Records 0..9 tagged "y" (tag 2), then "x" (tag 1): a "y" record exactly 7 back.
    log = records(40, tag=lambda i: 2 if i < 10 else 1)
    r = Replay(7, source=lambda copy, newest: copy.data[1] == 2 and newest.data[1] == 1)
    fired = [n for n in range(1, 41) if r.offer(log[:n]) is not None]
    assert fired == [11]  # newest 10 (the first "x"), copy 3 ("y")
    assert r.copy is log[3] and r.newest is log[10]


def test_replay_refuses_a_copy_of_the_newest_itself():
    with pytest.raises(ValueError):
        Replay(0)


def test_bootup_match():
    boot = is_bootup(16)
    assert boot(slcan.Frame(0x710, b"\x00"))
    assert not boot(slcan.Frame(0x710, b"\x05"))
    assert not boot(slcan.Frame(0x711, b"\x00"))
    assert not boot(slcan.Frame(0x710, b"", remote=True, dlc=1))


class FakeEmulator:
    """A TCP server standing in for the emulator's CAN port: `lines` is what the relay
    wrote to it, `send` writes device lines."""

    def __init__(self) -> None:
        self.server = socket.socket()
        self.server.bind(("127.0.0.1", 0))
        self.server.listen(1)
        self.can_port = self.server.getsockname()[1]
        self.conn = None
        self.received = b""
        self._ready = threading.Event()
        threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self) -> None:
        self.conn, _ = self.server.accept()
        self._ready.set()
        while True:
            try:
                data = self.conn.recv(4096)
            except OSError:
                return
            if not data:
                return
            self.received += data

    def check_alive(self) -> None:
        pass

    def send(self, data: bytes) -> None:
        assert self._ready.wait(5)
        self.conn.sendall(data)

    def close(self) -> None:
        if self.conn is not None:
            self.conn.close()
        self.server.close()


@pytest.fixture
def relayed():
    emu = FakeEmulator()
    relay = Relay(emu)
    bus = slcan_line(relay.channel)
    try:
        yield emu, relay, bus
    finally:
        bus.shutdown()
        relay.close()
        emu.close()


def received(bus, count: int, timeout: float = 5.0) -> list:
    out = []
    deadline = time.monotonic() + timeout
    while len(out) < count and time.monotonic() < deadline:
        msg = bus.recv(0.1)
        if msg is not None:
            out.append((msg.arbitration_id, bytes(msg.data)))
    return out


def tpdo(i: int) -> bytes:
    return b"t1908" + bytes([i, 0, 0, 0, 0, 0, 0, i]).hex().upper().encode() + b"\r"


def test_relay_passes_frames_both_ways_and_answers_commands(relayed):
    emu, relay, bus = relayed
    emu.send(b"t7101" + b"00\r" + b"t1908" + b"0102030405060708\r")
    assert received(bus, 2) == [(0x710, b"\x00"), (0x190, bytes(range(1, 9)))]
    bus.send(can.Message(arbitration_id=0x610, data=b"\x40\x00\x10\x00", is_extended_id=False))
    deadline = time.monotonic() + 5
    while b"t6104" not in emu.received:
        assert time.monotonic() < deadline, emu.received
        time.sleep(0.01)
    # python-can's opening `O` (and any command) never reaches the device.
    assert emu.received == b"t610440001000\r"
    assert [f.id for f in relay.device.frames()] == [0x710, 0x190]
    assert [(f.id, f.data) for f in relay.host.frames()] == [(0x610, b"\x40\x00\x10\x00")]
    assert [f.data for f in relay.records] == [bytes(range(1, 9))]


def test_relay_drops_the_matching_frame_once(relayed):
    emu, relay, bus = relayed
    rule = relay.drop(is_bootup())
    emu.send(b"t7101" + b"00\r" + b"t7101" + b"7F\r" + b"t7101" + b"00\r")
    assert received(bus, 2) == [(0x710, b"\x7f"), (0x710, b"\x00")]
    assert rule.done.is_set() and [f.data for f in rule.frames] == [b"\x00"]
    assert len(relay.device.frames()) == 3  # what the device sent, dropped or not


def test_relay_sends_the_copy_right_after_a_genuine_record(relayed):
    emu, relay, bus = relayed
    emu.send(b"".join(tpdo(i) for i in range(5)))
    assert len(received(bus, 5)) == 5
    copy = relay.replay(3)
    emu.send(tpdo(5) + tpdo(6))
    got = received(bus, 3)
    assert got == [(0x190, bytes([i, 0, 0, 0, 0, 0, 0, i])) for i in (5, 2, 6)]
    assert copy.fired.is_set() and copy.copy.seq == 2 and copy.newest.seq == 5
    assert [f.data[0] for f in relay.records] == list(range(7))  # genuine ones only
    assert [f.data[0] for f in relay.injected] == [2]


def test_relay_sends_frames_of_another_node_to_both_sides(relayed):
    emu, relay, bus = relayed
    emu.send(tpdo(0))
    assert len(received(bus, 1)) == 1
    relay.send(0x000, bytes([1, 16]))
    assert received(bus, 1) == [(0x000, bytes([1, 16]))]
    deadline = time.monotonic() + 5
    while b"t0002" + b"0110\r" not in emu.received:
        assert time.monotonic() < deadline, emu.received
        time.sleep(0.01)
    assert relay.host.frames() == []  # not the client's


def test_relay_fires_armed_copies_in_turn_one_per_record(relayed):
    emu, relay, bus = relayed
    emu.send(b"".join(tpdo(i) for i in range(3)))
    assert len(received(bus, 3)) == 3
    # The second could fire at once (2 back from record 3), but waits for the first,
    # which needs record 4 (4 back: record 0).
    first, second = relay.replay(4), relay.replay(2)
    emu.send(tpdo(3))
    assert received(bus, 1) == [(0x190, bytes([3, 0, 0, 0, 0, 0, 0, 3]))]
    assert not first.fired.is_set() and not second.fired.is_set()
    emu.send(tpdo(4) + tpdo(5))
    got = [data[0] for _, data in received(bus, 4)]
    assert got == [4, 0, 5, 3]
    assert (first.copy.seq, first.newest.seq) == (0, 4)
    assert (second.copy.seq, second.newest.seq) == (3, 5)
