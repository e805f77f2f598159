"""The feed record contract (epoch bits, sequence, plausibility) over whole streams: a
selection change while the bus is blocked, a model of the device against the host's rule, and
hostile streams."""

from dataclasses import dataclass, field
from typing import Dict, List, Optional, Tuple

from hypothesis import given, settings
from hypothesis import strategies as st

from canopen_handwheel import core
from canopen_handwheel.core import Config, Core, Record
from records import EN, ML, SESSION, TPDO1, configured, rec

AXES = "xyzwv"


def feed(frames: List[Tuple[float, bytes]], cfg: Optional[Config] = None) -> Core:
    c = configured(cfg)
    for t, data in frames:
        c.drained(t)
        c.frame(TPDO1, data, t)
    return c


def old_rule(frames: List[Tuple[float, bytes]]) -> Dict[str, int]:
    """The host's rule before the epoch bits, restated: a delta counts when two consecutive
    fresh records agree on axis, multiplier and status bits 0 and 3 with the feed enabled."""
    counts = {L: 0 for L in AXES}
    prev = None
    prev_t = None
    for t, data in frames:
        r = Record.decode(data)
        sel = (r.axis, r.multiplier, r.flags & (EN | ML))
        if prev is not None and t - prev_t <= 0.3 and prev[1] == sel and sel[2] & EN:
            counts[AXES[sel[0] - 1]] += core.wrap_s32(r.position - prev[0])
        prev, prev_t = (r.position, sel), t
    return counts


# The blocked-bus scenario: X turned 30, then the bus is blocked (250 ms here, under the
# host's staleness time; the record with X at 30 is already in the device's transmit queue),
# the operator selects Y, turns 7, selects X again and turns 2; then the bus is free.

BEFORE = [
    (0.000, rec(0, 1, 1, 0, 0, epoch=0)),  # after boot-up: disabled, epoch 0
    (0.010, rec(0, 1, 1, EN, 1, epoch=1)),  # the host enabled the feed
    (0.020, rec(10, 1, 1, EN, 2, epoch=1)),
    (0.030, rec(20, 1, 1, EN, 3, epoch=1)),
]
AFTER = 0.280


def test_blocked_bus_stream_of_a_device_with_epochs():
    """The device closes Y's epoch with a record (Y at 37) before any of the next epoch's, so
    the host gives Y its 7 and X its 30 and the 2 turned after selecting it again."""
    frames = BEFORE + [
        (AFTER, rec(30, 1, 1, EN, 4, epoch=1)),  # queued before the outage
        (AFTER + 0.00015, rec(37, 2, 1, EN, 5, epoch=2)),  # Y's epoch, closed during it
        (AFTER + 0.00030, rec(39, 1, 1, EN, 6, epoch=3)),  # X again, the present state
    ]
    c = feed(frames)
    assert c.pins().jog_counts == {"x": 32, "y": 7, "z": 0, "w": 0, "v": 0}
    assert c.pins().frames_bad == 0 and c.pins().records_lost == 0


def test_blocked_bus_stream_with_the_closing_record_dropped():
    """Y's closing record did not fit the device's store: it counts in the sequence as a
    record lost, so the next record is a baseline and Y's motion goes nowhere."""
    frames = BEFORE + [
        (AFTER, rec(30, 1, 1, EN, 4, epoch=1)),
        (AFTER + 0.00015, rec(39, 1, 1, EN, 6, epoch=3)),  # 5 was Y's, dropped
        (AFTER + 0.05, rec(41, 1, 1, EN, 7, epoch=3)),
    ]
    c = feed(frames)
    assert c.pins().jog_counts == {"x": 32, "y": 0, "z": 0, "w": 0, "v": 0}
    assert c.pins().records_lost == 1 and c.pins().frames_bad == 0


def test_blocked_bus_stream_of_a_device_without_epochs():
    """Today's firmware: bits 5-7 are 0, the Y selection never shows, and the record after
    the outage names X with Y's 7 in its position. The old rule gave Y's turn to X; the host
    now credits nothing to a device that never shows an epoch (and its enable, a change
    within what reads as one epoch, counts as bad)."""
    frames = [
        (0.000, rec(0, 1, 1, 0, 0)),
        (0.010, rec(0, 1, 1, EN, 1)),
        (0.020, rec(10, 1, 1, EN, 2)),
        (0.030, rec(20, 1, 1, EN, 3)),
        (AFTER, rec(30, 1, 1, EN, 4)),  # queued before the outage
        (AFTER + 0.00015, rec(39, 1, 1, EN, 5)),  # the present state: X, Y's 7 in it
    ]
    assert old_rule(frames)["x"] == 39 and old_rule(frames)["y"] == 0  # the defect
    c = feed(frames)
    assert c.pins().jog_counts == {"x": 0, "y": 0, "z": 0, "w": 0, "v": 0}
    assert c.pins().frames_bad == 1


def test_a_foreign_transmitter_on_the_devices_cob_id_moves_nothing():
    """A foreign node on the device's COB-ID: random records in between the device's."""
    frames = BEFORE + [
        (0.031, rec(1_100_000_000, 1, 1, EN, 4, epoch=1)),
        (0.040, rec(21, 1, 1, EN, 4, epoch=1)),
        (0.041, rec(-1_000_000_000, 1, 0, EN, 77, epoch=1)),  # multiplier code 3
        (0.050, rec(22, 1, 1, EN, 5, epoch=1)),
        (0.060, rec(25, 1, 1, EN, 6, epoch=1)),
    ]
    c = feed(frames)
    # The jump is refused; the device's record with the same sequence number 4 but other
    # bytes is impossible, so is the code-3 record; the device's next record is a baseline (after
    # the impossible ones), and 25 continues it.
    assert c.pins().jog_counts["x"] == 23
    assert c.pins().frames_bad == 3


# A model of the device's side of the contract ------------------------------------------------


@dataclass
class Device:
    """The device as the contract describes it: one cumulative position, the selection and
    its epoch, a transmit queue of `txq` frames (full while the bus is blocked), a store of
    `store` closed-epoch records (overflow: dropped, counted into the sequence, at most 8 per
    run), the event timer, and the stop after the consumer timeout without the bus."""

    txq_size: int
    store_size: int
    pos: int = 0
    axis: int = 1
    mult: int = 1
    enabled: bool = False
    master_lost: bool = False
    epoch: int = 0
    seq: int = 0
    truth: Dict[int, int] = field(default_factory=lambda: {a: 0 for a in range(1, 6)})
    unsent: bool = True  # the present state has not gone out as a record
    store: list = field(default_factory=list)  # ["rec", record, truth] or ["drop", n]
    txq: list = field(default_factory=list)  # (record bytes, truth)
    bus_up: bool = True
    down_since: float = 0.0
    last_sent: float = 0.0
    dropped: int = 0

    def state(self) -> Tuple[int, int, int, int, int]:
        status = (EN if self.enabled else 0) | (ML if self.master_lost else 0)
        return (self.pos, self.axis, self.mult, status, self.epoch)

    def _emit(self, state, truth, now) -> bool:
        if not self.bus_up and len(self.txq) >= self.txq_size:
            return False
        pos, axis, mult, status, epoch = state
        self.txq.append((rec(pos, axis, mult, status, self.seq, epoch), dict(truth)))
        self.seq = (self.seq + 1) % core.SEQUENCE_MODULO
        self.last_sent = now
        return True

    def _close_epoch(self, now) -> None:
        if self.unsent:
            if not self.store and self._emit(self.state(), self.truth, now):
                pass
            elif sum(1 for item in self.store if item[0] == "rec") < self.store_size:
                self.store.append(["rec", self.state(), dict(self.truth)])
            else:
                self.dropped += 1
                if self.store and self.store[-1][0] == "drop":
                    self.store[-1][1] += 1
                else:
                    self.store.append(["drop", 1])
        self.epoch += 1
        self.unsent = True

    def change(self, what: str, value: int, now: float) -> None:
        if what == "axis" and value != self.axis:
            self._close_epoch(now)
            self.axis = value
        elif what == "mult" and value != self.mult:
            self._close_epoch(now)
            self.mult = value
        elif what == "enable" and bool(value) != self.enabled:
            self._close_epoch(now)
            self.enabled = bool(value)
            self.master_lost = False
        elif what == "stop":
            self._close_epoch(now)
            self.enabled = False
            self.master_lost = True

    def turn(self, detents: int) -> None:
        if detents and self.enabled and self.axis:
            units = detents * self.mult
            self.pos = core.wrap_s32(self.pos + units)
            self.truth[self.axis] += units
            self.unsent = True

    def pump(self, now: float) -> List[Tuple[bytes, Dict[int, int]]]:
        """Sends what it can; returns what reaches the bus now, in order."""
        if not self.bus_up and now - self.down_since > 0.5 and not self.master_lost:
            self.change("stop", 0, now)  # the master's heartbeat timed out
        while self.store:
            item = self.store[0]
            if item[0] == "drop":
                self.seq = (self.seq + min(item[1], 8)) % core.SEQUENCE_MODULO
            elif not self._emit(item[1], item[2], now):
                break
            self.store.pop(0)
        if not self.store and (self.unsent or now - self.last_sent >= 0.1):
            if self._emit(self.state(), self.truth, now):
                self.unsent = False
        if not self.bus_up:
            return []
        out, self.txq = self.txq, []
        return out


MS = st.integers(2, 40)
TURN = st.tuples(st.just("turn"), st.integers(1, 20), MS)  # detents, ms (at least 2 each)
ENABLE = st.tuples(st.just("enable"), st.sampled_from([True, True, True, False]), MS)
BUS = st.tuples(st.just("bus"), st.sampled_from([True, True, False]), MS)
AXIS = st.tuples(st.just("axis"), st.one_of(st.integers(1, 2), st.integers(0, 5)), MS)
# The host's receiving stops (its queue overruns) and resumes: every record meanwhile is lost.
DEAF = st.tuples(st.just("deaf"), st.booleans(), MS)
# The operator selects another axis, turns it a little and comes back, between two records.
VISIT = st.tuples(st.just("visit"), st.tuples(st.integers(0, 5), st.integers(1, 10)), MS)
ACTION = st.one_of(
    *[TURN] * 8,
    AXIS,
    AXIS,
    VISIT,
    st.tuples(st.just("mult"), st.sampled_from([1, 10, 100]), MS),
    ENABLE,
    ENABLE,
    st.tuples(st.just("stop"), st.just(0), MS),
    BUS,
    BUS,
    DEAF,
)
# Records lost on the way to the host, as a bit mask over a step's records.
LOSSES = st.one_of(*[st.just(0)] * 8, st.integers(0, 15))


@settings(max_examples=300, deadline=None)
@given(
    st.integers(0, 3),
    st.integers(0, 3),
    st.booleans(),
    st.lists(st.tuples(ACTION, LOSSES), min_size=20, max_size=150),
)
def test_device_model_never_leaks_motion(txq_size, store_size, lossy, steps):
    """Random turning (forward only, at most 500 detents/s), axis, multiplier and enable
    changes, stops, bus outages, stretches when the host receives nothing and single records
    lost on the way to the host (`lossy`: both of these): every delta the
    host applies is exactly the motion of its axis between the two records, no other axis
    having moved between them; so no axis ever gets more than it was turned, and with no
    record lost or dropped and no staleness it gets exactly that."""
    dev = Device(txq_size=txq_size, store_size=store_size)
    c = configured()
    t = 0.0
    steps = [(("enable", True, 10), 0)] + steps  # the host enables the feed after boot-up
    prev_truth = None
    lost = stale = 0
    deaf = False
    for (kind, value, ms), lose in steps:
        if kind == "turn":
            ms = max(ms, 2 * value)  # at most 500 detents/s
        t += ms / 1000
        if kind == "turn":
            dev.turn(value)
        elif kind == "bus":
            if dev.bus_up and not value:
                dev.down_since = t
            dev.bus_up = value
        elif kind == "deaf":
            deaf = lossy and value
        elif kind == "visit":
            back, (axis, detents) = dev.axis, value
            dev.change("axis", axis, t)
            dev.turn(detents)
            dev.change("axis", back, t)
        else:
            dev.change(kind, value, t)
        for i, (data, truth) in enumerate(dev.pump(t)):
            if deaf or (lossy and lose >> i & 1):
                lost += 1
                continue
            at = t + i * 0.00015
            c.tick(at)
            if c.record is not None and not c.fresh:
                stale += 1
            before = dict(c.counts)
            c.drained(at)
            c.frame(TPDO1, data, at)
            for n, L in enumerate(AXES, 1):
                moved = c.counts[L] - before[L]
                if moved:
                    assert prev_truth is not None
                    axis = Record.decode(data).axis
                    assert axis == n and moved == truth[n] - prev_truth[n], (L, moved)
                    assert all(truth[m] == prev_truth[m] for m in truth if m != n)
            prev_truth = truth
    p = c.pins()
    assert p.frames_bad == 0  # a device that keeps the contract is never doubted
    for n, L in enumerate(AXES, 1):
        assert 0 <= p.jog_counts[L] <= dev.truth[n]
    if lost == 0 and dev.dropped == 0 and stale == 0:
        # Motion after the last record sent is not known to the host yet.
        sent_truth = prev_truth or {n: 0 for n in range(1, 6)}
        assert p.jog_counts == {L: sent_truth[n] for n, L in enumerate(AXES, 1)}


# Hostile streams ---------------------------------------------------------------------------


def impossible(data: bytes) -> bool:
    """What the device never sends, on its own: the oracle for `frames-bad`."""
    if len(data) != 8:
        return True
    r = Record.decode(data)
    return r.axis > 5 or r.multiplier not in (1, 10, 100) or (r.enabled and r.master_lost)


RAW = st.tuples(st.just("raw"), st.binary(min_size=0, max_size=9))
RANDOM_RECORD = st.tuples(
    st.just("raw"),
    st.builds(
        rec,
        st.integers(-(2**31), 2**31 - 1),
        st.integers(0, 7),
        st.sampled_from([1, 10, 100, 0]),
        st.sampled_from([0, EN, ML, EN | ML, EN | core.STATUS_ENCODER_ERROR]),
        st.integers(0, 65535),
        st.integers(0, 7),
        st.sampled_from([SESSION, SESSION, 0, 2]),  # the core's session, none, another's
    ),
)
# A record that follows the last one sent (the same epoch with the next sequence number, or
# the next epoch): a transmitter that imitates the device, by any number of detents.
FOLLOW = st.tuples(
    st.just("follow"),
    st.one_of(st.integers(-50, 50), st.integers(-100_000, 100_000), st.integers(-(2**31), 2**31)),
    st.sampled_from([0, 0, 0, 1]),  # epoch step
    st.sampled_from([1, 1, 2]),  # sequence step
)


@settings(max_examples=300, deadline=None)
@given(
    st.integers(10, 5000),
    st.sampled_from([1, 10, 100]),
    st.lists(
        st.tuples(st.one_of(RAW, RANDOM_RECORD, FOLLOW, FOLLOW, FOLLOW), st.floats(0, 0.2)),
        max_size=80,
    ),
)
def test_hostile_streams_are_counted_and_bounded(rate, mult, frames):
    """Random bytes, random records and records imitating the device's on its TPDO1
    identifier: nothing raises, every frame the device cannot send is counted in frames-bad
    and moves nothing, and the detents applied in any stretch of time never exceed what the
    bucket allows: the rate times the horizon plus the rate times the stretch."""
    cfg = Config(max_detents_per_s=rate)
    c = configured(cfg)
    t = 0.0
    applied: List[Tuple[float, float]] = []  # (time, detents applied by the frame)
    last = (0, 1, mult, EN, 0, 1)  # position, axis, multiplier, status, sequence, epoch
    for step, dt in frames:
        t += dt
        if step[0] == "raw":
            data = step[1]
        else:
            _, detents, epoch_step, seq_step = step
            pos, axis, m, status, seq, epoch = last
            last = (pos + detents * m, axis, m, status, seq + seq_step, epoch + epoch_step)
            data = rec(*last)
        before_counts, before_bad = dict(c.counts), c.frames_bad
        c.drained(t)
        c.frame(TPDO1, data, t)
        moved = sum(abs(c.counts[L] - before_counts[L]) for L in c.counts)
        if impossible(data):
            assert c.frames_bad == before_bad + 1 and moved == 0
        if moved:
            m = Record.decode(data).multiplier
            assert m in (1, 10, 100) and moved % m == 0
            applied.append((t, moved / m))
    cap = rate * cfg.rate_horizon
    for i in range(len(applied)):
        total = 0.0
        for j in range(i, len(applied)):
            total += applied[j][1]
            assert total <= cap + rate * (applied[j][0] - applied[i][0]) + 1e-6
