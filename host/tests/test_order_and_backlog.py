"""Records out of order, a backlog, the order of the pin writes and the replay of events (at the
core, and the shell's part of them without a device)."""

import gc
import socket
import threading
import time
import tracemalloc

import can
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import fake_hal
import records
from canopen_handwheel import component, core, slcan
from canopen_handwheel.core import Config, Core, Record
from records import EMCY, EN, HB, ML, SESSION, TPDO1


def rec(position, seq, axis=1, flags=EN, epoch=1, mult=1, session=SESSION) -> bytes:
    return records.rec(position, axis, mult, flags, seq, epoch, session)


class Wheel:
    """A core fed as the shell feeds it: every frame handled at once (the receive path
    found empty just before) and published, the device configured, `enable` true. `send`
    makes the device's next record (consecutive sequence numbers, epoch 1 on X)."""

    def __init__(self, seq=40) -> None:
        self.c = records.configured()
        self.t = 0.0
        self.seq = seq
        self.pos = 0
        self.sent = []
        self.c.set_enable(True)
        self.steps = []
        self.hal = None  # a `Hal` the published steps are written to

    def frame(self, cob_id, data, dt=0.01, drained=True):
        self.t += dt
        if drained:
            self.c.drained(self.t)
        self.c.frame(cob_id, data, self.t)
        steps = self.c.publish(self.t)
        self.steps += steps
        if self.hal is not None:
            self.hal.write(steps)

    def send(self, detents=0, axis=1, flags=EN, epoch=1, dt=0.01) -> bytes:
        self.pos += detents
        self.seq = (self.seq + 1) % core.SEQUENCE_MODULO
        data = rec(self.pos, self.seq, axis, flags, epoch, session=self.c.session or 0)
        self.sent.append(data)
        self.frame(TPDO1, data, dt)
        return data

    @property
    def x(self) -> int:
        return self.c.counts["x"]

    def pins(self):
        return self.c.pins()


# Replayed and duplicated records ------------------------------------------------------------------


def test_a_replayed_record_from_four_numbers_back_moves_nothing():
    """Five single detents on X, then the record from four sequence numbers back once more,
    unchanged, then the device's next record (no turning since): X is +5, never +9; the copy
    is counted in frames-bad and is no loss."""
    w = Wheel()
    w.send()  # baseline
    for _ in range(5):
        w.send(1)
    assert w.x == 5
    w.frame(TPDO1, w.sent[-5])  # sequence numbers: last - 4
    assert w.x == 5
    w.send(0, dt=0.1)  # the event timer's record
    assert w.x == 5
    p = w.pins()
    assert p.frames_bad == 1 and p.records_lost == 0 and p.jog_enable["x"]
    w.send(2)  # and it goes on
    assert w.x == 7


def test_the_record_at_the_peak_replayed_does_not_move_x_backwards():
    """+2, +2, +2, -2, -2, -2 (net 0), then the record at the peak (+6) again, then the next
    genuine record: X ends at 0, not -6."""
    w = Wheel()
    w.send()
    for d in (2, 2, 2, -2, -2, -2):
        w.send(d)
    assert w.x == 0
    peak = w.sent[3]
    assert Record.decode(peak).position == 6
    w.frame(TPDO1, peak)
    w.send(0)
    assert w.x == 0
    assert w.pins().frames_bad == 1


@pytest.mark.parametrize("back", [1, 2, 6, 7, 60, 127, 128, 129, 249, 255, 256, 300])
def test_any_record_behind_is_ignored_while_baselines_are_pending(back):
    """A copy of any earlier record (here up to 300 numbers back: past the 8-bit wrap that
    made copies 249-255 back read as 6 ahead) never becomes the reference, also right after
    an impossible frame made the next record a baseline: the next genuine record continues
    from the last genuine one, not from the copy."""
    w = Wheel()
    w.send()
    for _ in range(310):
        w.send(1, dt=0.002)
    w.frame(TPDO1, b"\x01\x02")  # impossible: the next record is a baseline
    assert w.pins().frames_bad == 1
    w.frame(TPDO1, w.sent[-1 - back])
    assert w.pins().frames_bad == 2
    w.send(0)  # a baseline after the impossible frame
    w.send(3)
    assert w.x == 313
    assert w.pins().records_lost == 0


def test_a_frame_received_twice_is_no_loss():
    """The same frame twice in a row (a known CAN effect): ignored entirely, so records-lost
    stays 0 (it grew by 255 before), frames-bad too, and motion stays right."""
    w = Wheel()
    w.send()
    for _ in range(4):
        data = w.send(1)
        w.frame(TPDO1, data, dt=0.0001)
    w.send(1)
    p = w.pins()
    assert w.x == 5 and p.records_lost == 0 and p.frames_bad == 0


def test_a_duplicate_does_not_keep_the_device_fresh():
    w = Wheel()
    w.send()
    data = w.send(1)
    for _ in range(5):
        w.frame(TPDO1, data, dt=0.1)  # the same frame, 0.5 s long (ignored after staleness too)
    assert not w.pins().connected and w.pins().frames_bad == 0
    w.send(1)  # after staleness: a baseline
    assert w.x == 1


def test_one_number_with_other_bytes_is_impossible():
    w = Wheel()
    w.send()
    w.send(1)
    data = rec(w.pos + 50, w.seq)
    w.frame(TPDO1, data)
    assert w.pins().frames_bad == 1 and w.x == 1
    assert not w.pins().jog_enable["x"]  # no axis selected until a possible record
    w.send(1)  # a baseline
    w.send(1)
    assert w.x == 2


def test_a_copy_after_the_master_was_lost_moves_nothing():
    """The device reported master lost (feed off, the next epoch); a copy of an earlier
    enabled record with motion arrives after that, read in time or from a backlog: no motion,
    no gate, and the device's next record is measured against its own last one."""
    for drained in (True, False):
        w = Wheel()
        w.send()
        w.send(2)
        enabled = w.send(3)
        w.send(0, flags=ML, epoch=2)
        w.frame(TPDO1, w.sent[-3], drained=drained)
        w.frame(TPDO1, enabled, drained=drained)
        assert w.x == 5 and not any(w.pins().jog_enable.values())
        w.send(0, flags=ML, epoch=2)
        assert w.x == 5 and w.pins().frames_bad == 2, drained


def test_a_break_of_eight_numbers_never_continues():
    """Contract v2: after a break (NMT start after a stop, a reset, a blocked transmit path)
    the next record is at least 8 numbers on, whatever its epoch bits say."""
    for epoch_step in range(8):
        w = Wheel()
        w.send()
        w.send(1)
        w.seq += 7  # 7 numbers missing: the next is 8 on
        w.send(5, epoch=1 + epoch_step)
        assert w.x == 1, epoch_step
        assert w.pins().records_lost == 7


# A backlog and a flood at the core ----------------------------------------------------------------


def test_records_from_a_backlog_move_nothing():
    """The component frozen for 3 s while 20 detents are turned in the first 0.3 s: when it
    runs again it reads the records that waited (each handled without the receive path found
    empty since before the freeze): they are baselines only. Once it has read them all, the
    next record continues from the last of them."""
    w = Wheel()
    w.send()
    w.send(1)
    assert w.x == 1
    frozen_at = w.t
    backlog = []
    for _ in range(20):  # turned during the freeze, 15 ms apart
        w.pos += 1
        w.seq += 1
        backlog.append(rec(w.pos, w.seq))
    for _ in range(27):  # the event timer's records for the rest of the 3 s
        w.seq += 1
        backlog.append(rec(w.pos, w.seq))
    w.t = frozen_at + 3.0
    for data in backlog:
        w.frame(TPDO1, data, dt=0.0001, drained=False)
    assert w.x == 1
    assert w.c.drained_at <= frozen_at
    w.send(1, dt=0.001)  # after the receive path was found empty: turning moves again
    assert w.x == 2
    assert w.pins().frames_bad == 0


@pytest.mark.parametrize("late,moves", [(0.099, True), (0.101, False)])
def test_the_backlog_limit(late, moves):
    w = Wheel()
    w.send()
    w.c.drained(w.t)
    w.t += late
    w.pos += 4
    w.seq += 1
    w.c.frame(TPDO1, rec(w.pos, w.seq), w.t)
    assert w.x == (4 if moves else 0)


def test_a_flood_that_keeps_the_loop_from_draining_moves_nothing():
    """EMCYs arrive faster than the loop handles them: it never finds the receive path
    empty, so the records among them are baselines; the EMCY code is kept and nothing
    else."""
    w = Wheel()
    w.send()
    start = w.t
    for i in range(2000):
        w.t += 0.0002
        w.c.frame(EMCY, bytes.fromhex("0050010000000000"), w.t)
        if i % 150 == 149:
            w.pos += 1
            w.seq += 1
            w.c.frame(TPDO1, rec(w.pos, w.seq), w.t)
    assert w.t - start > core.BACKLOG_LIMIT
    assert w.x == 3  # only the records within 0.1 s of the last drained (0.03, 0.06, 0.09)
    assert w.pins().emcy_code == 0x5000


def test_credits_not_published_in_time_are_withdrawn():
    """The component stalls between handling a record and writing the pins: at the next
    publish the credit is older than the limit, and the counts go back."""
    w = Wheel()
    w.send()
    w.send(1)
    assert w.steps[-1].jog_counts["x"] == 1
    w.t += 0.01
    w.c.drained(w.t)
    w.pos += 3
    w.seq += 1
    w.c.frame(TPDO1, rec(w.pos, w.seq), w.t)
    assert w.x == 4
    w.t += 0.2
    steps = w.c.publish(w.t)
    assert steps[-1].jog_counts["x"] == 1 and w.x == 1 and w.c.withdrawn == 1
    w.send(2)  # goes on from the record it withdrew
    assert w.x == 3


def test_emcy_frames_keep_no_memory():
    """100 000 EMCYs through the core: no memory per frame."""
    c = Core(Config())
    frames = [bytes([i & 0xFF, 0x50, 1, 0, 0, 0, 0, 0]) for i in range(256)]
    for i in range(1000):  # warm up
        c.frame(EMCY, frames[i & 0xFF], i * 1e-4)
    gc.collect()
    tracemalloc.start()
    base = tracemalloc.get_traced_memory()[0]
    for i in range(1000, 101_000):
        c.frame(EMCY, frames[i & 0xFF], i * 1e-4)
    grown = tracemalloc.get_traced_memory()[0] - base
    tracemalloc.stop()
    assert grown < 10_000, grown


# The order of the pin writes ----------------------------------------------------------------------


class Servo:
    """LinuxCNC's handling of jog-counts (motion's control.c): every servo period it takes
    the difference of the counts to the last period's, and moves the axis by it only if
    jog-enable is true in that same period. `sample` is one servo period."""

    def __init__(self, comp) -> None:
        self.comp = comp
        self.old = {L: comp.pins[f"axis.{L}.jog-counts"] for L in "xyzwv"}
        self.moved = {L: 0 for L in "xyzwv"}

    def sample(self) -> None:
        for L in self.old:
            new = self.comp.pins[f"axis.{L}.jog-counts"]
            if new != self.old[L] and self.comp.pins[f"axis.{L}.jog-enable"]:
                self.moved[L] += new - self.old[L]
            self.old[L] = new


class Hal:
    """HalPins on fake_hal whose every single pin write may be followed by a servo period
    (the finest interleaving), and one more period for every hold between steps."""

    def __init__(self) -> None:
        self.pins = component.HalPins(fake_hal, "hw", Config())
        self.comp = self.pins.comp
        self.servo = Servo(self.comp)
        self.holds = []
        comp, servo = self.comp, self.servo
        real = type(comp).__setitem__

        def setitem(name, value):
            real(comp, name, value)
            servo.sample()

        self.pins.comp = _Calls(comp, setitem)

    def write(self, steps) -> None:
        component.write_steps(self.pins, steps, sleep=self._hold)

    def _hold(self, seconds: float) -> None:
        self.holds.append(seconds)
        self.servo.sample()


class _Calls:
    """The component's item writes go through `setitem` (a servo period after each)."""

    def __init__(self, comp, setitem) -> None:
        self._comp = comp
        self._setitem = setitem

    def __setitem__(self, name, value) -> None:
        self._setitem(name, value)

    def __getitem__(self, name):
        return self._comp[name]


def test_detents_handled_with_a_boot_up_reach_linuxcnc_with_their_gate():
    """Records that credit X and the device's boot-up in one round: the counts are written
    while jog-enable is still true, a hold before it goes false, so LinuxCNC moves X by
    them (the old writes put jog-enable false in the same write: the detents were lost)."""
    w = Wheel()
    hal = w.hal = Hal()
    w.send()
    w.send(1)
    hal.write(w.c.publish(w.t))
    assert hal.comp.pins["axis.x.jog-enable"] and hal.servo.moved["x"] == 1
    w.t += 0.01
    w.c.drained(w.t)
    for _ in range(3):
        w.pos += 1
        w.seq += 1
        w.c.frame(TPDO1, rec(w.pos, w.seq), w.t)
    w.c.frame(HB, b"\x00", w.t)
    steps = w.c.publish(w.t)
    assert [s.jog_enable["x"] for s in steps] == [True, False]
    assert [s.jog_counts["x"] for s in steps] == [4, 4]
    hal.write(steps)
    assert hal.holds == [core.GATE_HOLD]
    assert hal.servo.moved["x"] == 4 and not hal.comp.pins["axis.x.jog-enable"]


def test_staleness_in_the_same_round_keeps_the_detents():
    w = Wheel()
    hal = w.hal = Hal()
    w.send()
    hal.write(w.c.publish(w.t))
    w.t += 0.01
    w.c.drained(w.t)
    w.pos += 2
    w.seq += 1
    w.c.frame(TPDO1, rec(w.pos, w.seq), w.t)
    # The round ends late (no more than the backlog limit): the record is stale by then.
    w.c.record_time -= 0.4
    hal.write(w.c.publish(w.t + 0.05))
    assert hal.servo.moved["x"] == 2 and not hal.comp.pins["axis.x.jog-enable"]


def test_opening_writes_the_gate_before_the_counts():
    """The feed enabled and turned within one round: jog-enable goes true one step before
    the counts change."""
    w = Wheel()
    hal = w.hal = Hal()
    w.send(flags=0, epoch=1)  # feed off
    hal.write(w.c.publish(w.t))
    assert not hal.comp.pins["axis.x.jog-enable"]
    w.t += 0.01
    w.c.drained(w.t)
    w.seq += 1
    w.c.frame(TPDO1, rec(w.pos, w.seq, epoch=2), w.t)  # enabled: the next epoch
    w.pos += 3
    w.seq += 1
    w.c.frame(TPDO1, rec(w.pos, w.seq, epoch=2), w.t)
    steps = w.c.publish(w.t)
    assert [(s.jog_enable["x"], s.jog_counts["x"]) for s in steps] == [(True, 0), (True, 3)]
    hal.write(steps)
    assert hal.servo.moved["x"] == 3


def test_a_change_of_axis_in_one_round_credits_both_with_their_gates():
    w = Wheel()
    hal = w.hal = Hal()
    w.send()
    w.send(1)
    hal.write(w.c.publish(w.t))
    w.t += 0.01
    w.c.drained(w.t)
    for axis, epoch, d in [(1, 1, 2), (2, 2, 0), (2, 2, 5)]:
        w.pos += d
        w.seq += 1
        w.c.frame(TPDO1, rec(w.pos, w.seq, axis=axis, epoch=epoch), w.t)
    hal.write(w.c.publish(w.t))
    assert hal.servo.moved["x"] == 3 and hal.servo.moved["y"] == 5
    assert not hal.comp.pins["axis.x.jog-enable"] and hal.comp.pins["axis.y.jog-enable"]


def test_counts_credited_with_the_gate_closed_never_find_it_open():
    """`enable` false: the counts still follow the records, but jog-enable stays false
    while they change, also when `enable` comes back in the same round."""
    w = Wheel()
    hal = w.hal = Hal()
    w.send()
    w.c.set_enable(False)
    hal.write(w.c.publish(w.t))
    w.send(4)
    w.c.set_enable(True)
    steps = w.c.publish(w.t)
    hal.write(steps)
    assert hal.servo.moved["x"] == 0 and hal.comp.pins["axis.x.jog-enable"]
    w.send(1)
    hal.write(w.c.publish(w.t))
    assert hal.servo.moved["x"] == 1


def test_one_step_when_no_gate_changes():
    w = Wheel()
    w.send()
    w.c.publish(w.t)
    w.send(1)
    steps = w.c.publish(w.t)
    assert len(steps) == 1 and steps[0] == w.c.pins()
    assert len(w.c.publish(w.t)) == 1


# The replay of events -------------------------------------------------------------------------


def test_replay_gives_the_published_counts():
    events = [("configure", 0, 0.0), ("drained", 0.0), ("frame", TPDO1, rec(0, 1), 0.0)]
    for i in range(2, 7):
        events += [("drained", i * 0.01), ("frame", TPDO1, rec(i - 1, i), i * 0.01)]
    assert core.replay(events)["x"] == 5
    # The same records read from a backlog (no drained since the first): nothing.
    late = events[:3] + [("frame", TPDO1, rec(i - 1, i), 1 + i * 0.01) for i in (2, 3)]
    assert core.replay(late)["x"] == 0
    # A replayed copy: ignored.
    copy = events + [("drained", 0.1), ("frame", TPDO1, rec(1, 2), 0.1), ("tick", 0.11)]
    copy += [("drained", 0.12), ("frame", TPDO1, rec(5, 7), 0.12)]
    c = core.replay_core(copy)
    assert c.published.jog_counts["x"] == 5 and c.frames_bad == 1
    assert core.replay(events, Config(axes="y"))["y"] == 5  # switch position 1 is Y
    # Without the configuration the records are of no session of the core's: nothing.
    assert core.replay(events[1:])["x"] == 0


@pytest.mark.parametrize(
    "event", [("nothing", 1.0), ("frame", TPDO1, b""), (), "frame", ("configure", 0)]
)
def test_replay_refuses_what_is_no_event(event):
    with pytest.raises(ValueError):
        core.replay([event])


def test_replay_refuses_a_configuration_the_core_does_not_ask_for():
    with pytest.raises(ValueError):
        core.replay([("configure", 0, 0.0), ("configure", 0, 0.1)])


# The shell's receiving ------------------------------------------------------------------------


def test_the_shell_hands_python_canopen_nothing_but_sdo_responses():
    """20 000 EMCYs on a virtual bus, read by the shell's receive path: the core sees their
    code, python-canopen's EMCY consumer keeps nothing (it kept every one, in lists nothing
    cleared), memory does not grow with them, and once they are read the receive path
    reports drained."""
    import can

    channel = f"emcy-{time.monotonic_ns()}"
    args = component.parse_args(["--interface", "virtual", "--channel", channel])
    sender = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    link = component.Link(args, args.config)
    c = Core(args.config)
    try:
        msgs = [
            can.Message(
                arbitration_id=EMCY,
                is_extended_id=False,
                data=bytes([i & 0xFF, 0x50, 1, 0, 0, 0, 0, 0]),
            )
            for i in range(256)
        ]

        def flood(n, start):
            for i in range(start, start + n):
                sender.send(msgs[i & 0xFF], timeout=1)
            while c.drained_at is None or c.drained_at < mark:
                link.receive(c, time.monotonic, 0.0, 1.0)

        mark = time.monotonic()
        flood(2000, 0)  # warm up
        gc.collect()
        tracemalloc.start()
        base = tracemalloc.get_traced_memory()[0]
        for k in range(9):
            mark = time.monotonic()
            flood(2000, 2000 * (k + 1))
        gc.collect()
        grown = tracemalloc.get_traced_memory()[0] - base
        tracemalloc.stop()
        assert c.emcy_code == 0x5000 + (19999 & 0xFF)
        assert link.node.emcy.log == [] and link.node.emcy.active == []
        assert grown < 50_000, grown
    finally:
        link.close()
        sender.shutdown()


def test_slcan_lines_are_read_in_bulk():
    """The shell's SLCAN bus: every standard data frame of a burst, in order, at far more
    than the 5 000 frames/s of a flood; lines it cannot parse are skipped; `recv(0)` is None
    only once everything that arrived was read."""
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(1)
    port = server.getsockname()[1]
    good = [(TPDO1, records.rec(i, seq=i)) for i in range(20000)]
    junk = b"t19X8zz\rt1909" + b"00" * 9 + b"\r" + b"x" * 200
    junk += b"\rT0000019081122334455667788\r\a\r"
    lines = SlcanLines.encode(good[:10]) + junk + SlcanLines.encode(good[10:])
    accepted = []

    def serve():
        conn, _ = server.accept()
        accepted.append(conn)
        time.sleep(0.3)  # pyserial empties the socket once connected
        conn.sendall(lines)

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    bus = component.slcan_bus(f"socket://127.0.0.1:{port}", sleep_after_open=0)
    try:
        got = []
        msg = bus.recv(5.0)
        start = time.perf_counter()
        while msg is not None:
            got.append((msg.arbitration_id, bytes(msg.data)))
            msg = bus.recv(0.5) if len(got) < len(good) else bus.recv(0)
        took = time.perf_counter() - start
        assert got == good
        assert len(good) / took > 20_000, len(good) / took
        assert bus.recv(0) is None
    finally:
        bus.shutdown()
        thread.join(5)
        for conn in accepted:
            conn.close()
        server.close()


@pytest.mark.parametrize("peer_gone", [False, True])
def test_the_slcan_bus_closes_its_line_at_once_even_when_the_line_broke(peer_gone):
    """`shutdown` sends `C` while the line takes it and closes the socket in any case, at
    once: no exception, no port left open for the garbage collector (whose pyserial close
    paused 0.3 s in whatever thread ran it: a send of the next line stalled behind it)."""
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(1)
    bus = component.slcan_bus(f"socket://127.0.0.1:{server.getsockname()[1]}", sleep_after_open=0)
    conn, _ = server.accept()
    port = bus.serialPortOrig
    sock = port._socket
    try:
        if peer_gone:
            conn.close()  # a hub that breaks the line: the `C` meets a closed connection
            time.sleep(0.05)
            with pytest.raises(can.CanError):
                for _ in range(20):  # the first write after a peer's close may still pass
                    bus.send(can.Message(arbitration_id=0x710, data=b"\x05", is_extended_id=False))
                    time.sleep(0.01)
        start = time.perf_counter()
        bus.shutdown()
        took = time.perf_counter() - start
        assert took < 0.1, took
        assert sock.fileno() == -1, "the socket is closed"
        assert not port.is_open
        if not peer_gone:
            conn.settimeout(1.0)
            assert conn.recv(64).endswith(b"C\r")
        bus.shutdown()  # a second call changes nothing
    finally:
        conn.close()
        server.close()


class SlcanLines:
    @staticmethod
    def encode(frames) -> bytes:
        return b"".join(slcan.encode(slcan.Frame(c, d)) for c, d in frames)


# The pin steps over random rounds -------------------------------------------------------------

ROUND_EVENT = st.one_of(
    st.tuples(st.just("turn"), st.integers(-20, 20)),
    st.tuples(st.just("turn"), st.integers(-20, 20)),
    st.tuples(st.just("axis"), st.integers(0, 3)),
    st.tuples(st.just("feed"), st.booleans()),
    st.tuples(st.just("bootup"), st.just(0)),
)


@settings(max_examples=200, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.sampled_from([True, True, False]),  # the enable pin
            st.lists(ROUND_EVENT, max_size=6),
            st.sampled_from([0.01, 0.01, 0.05, 0.4]),  # to the next round (0.4: stale)
        ),
        min_size=1,
        max_size=25,
    )
)
def test_every_credit_made_with_its_gate_open_reaches_linuxcnc(rounds):
    """Random rounds of the shell (the `enable` pin, then records of a device turning,
    switching axes, switching its feed, booting up; silences between), each published and
    written through HalPins with a servo period after every single pin write: LinuxCNC
    moves every axis by exactly the counts credited while that axis's gate was open, and
    the pins end as the core's."""
    w = Wheel()
    hal = w.hal = Hal()
    axis, enabled, epoch = 1, True, 1
    expected = {L: 0 for L in "xyzwv"}
    w.send()
    for enable, events, gap in rounds:
        w.c.set_enable(enable)
        hal.write(w.c.publish(w.t))
        w.t += gap
        w.c.drained(w.t)
        for kind, value in events:
            if kind == "bootup":
                w.c.frame(HB, b"\x00", w.t)
                records.configure(w.c, w.t, due=False)  # a new session, if a token is free
                w.c.frame(HB, b"\x05", w.t)
                continue
            if kind == "turn":
                if enabled and axis:
                    w.pos += value
            elif kind == "axis" and value != axis:
                axis, epoch = value, epoch + 1
            elif kind == "feed" and value != enabled:
                enabled, epoch = value, epoch + 1
            w.seq += 1
            before = dict(w.c.counts)
            data = rec(w.pos, w.seq, axis, EN if enabled else 0, epoch, session=w.c.session or 0)
            w.c.frame(TPDO1, data, w.t)
            for L in "xyzwv":
                if w.c.counts[L] != before[L] and w.c.gate(L):
                    expected[L] += w.c.counts[L] - before[L]
        hal.write(w.c.publish(w.t))
    assert hal.servo.moved == expected
    final = w.c.pins()
    for L in "xyzwv":
        assert hal.comp.pins[f"axis.{L}.jog-counts"] == final.jog_counts[L]
        assert hal.comp.pins[f"axis.{L}.jog-enable"] == final.jog_enable[L]
