"""Properties of the component's decisions over generated frame streams (hypothesis)."""

from hypothesis import assume, given, settings
from hypothesis import strategies as st

from canopen_handwheel import core
from canopen_handwheel.core import Config, Core, wrap_s32

NODE = 16
TPDO1, EMCY, HB = 0x180 + NODE, 0x080 + NODE, 0x700 + NODE
T = 0.1
S32 = st.integers(-(2**31), 2**31 - 1)


def rec(position, axis, mult, status, seq, epoch=0) -> bytes:
    status |= (epoch % 8) << 5
    return (position & 0xFFFFFFFF).to_bytes(4, "little") + bytes([axis, mult, status, seq & 0xFF])


def applies(prev, new, axes):
    """The rule of core.continuity restated from the contract: the letter `new` may move,
    or None. `prev`, `new`: (position, axis, mult, status, seq) of two consecutive possible
    records of the device."""
    if prev is None:
        return None
    gap = (new[4] - prev[4] - 1) % 256
    step = ((new[3] >> 5) - (prev[3] >> 5)) % 8
    same = step == 0 and gap <= 6
    if not (same or (step == 1 and gap == 0)):
        return None
    if same and (prev[1], prev[2], prev[3] & 1) != (new[1], new[2], new[3] & 1):
        return None
    if not new[3] & 1 or not 1 <= new[1] <= len(axes):
        return None
    return axes[new[1] - 1]


def possible(position, axis, mult, status, seq):
    return axis <= 5 and mult in (1, 10, 100) and not (status & 1 and status & 8)


def fields(data: bytes):
    """(position, axis, mult, status, seq) of 8 record bytes."""
    return (int.from_bytes(data[0:4], "little", signed=True), data[4], data[5], data[6], data[7])


# One step of a hostile stream: (kind, ...).
record_step = st.tuples(
    st.just("record"),
    S32,  # position
    st.one_of(st.integers(0, 5), st.integers(0, 255)),  # axis byte, sometimes unknown
    st.sampled_from([1, 10, 100, 7]),
    st.integers(0, 255),  # status
    st.integers(0, 255),  # sequence
    st.floats(0, 0.5),  # time since the last step
    st.sampled_from([True, True, True, False]),  # handled at once (else: maybe late)
)
step = st.one_of(
    record_step,
    record_step,
    # A TPDO1 sent before, again (a duplicate, a replay): how many records back.
    st.tuples(st.just("again"), st.integers(0, 8), st.floats(0, 0.05)),
    st.tuples(st.just("hb"), st.sampled_from([0x00, 0x04, 0x05, 0x7F, 0x85]), st.floats(0, 0.2)),
    st.tuples(st.just("emcy"), st.binary(min_size=0, max_size=9), st.floats(0, 0.2)),
    st.tuples(
        st.just("raw"),
        st.sampled_from([TPDO1, EMCY, HB, 0x000, 0x181, 0x590]),
        st.binary(min_size=0, max_size=9),
        st.floats(0, 0.2),
    ),
    st.tuples(st.just("enable"), st.booleans()),
    st.tuples(st.just("mode"), st.booleans()),
    st.tuples(st.just("tick"), st.floats(0, 1.0)),
    st.tuples(st.just("done"), st.booleans(), st.sampled_from([None, core.ABORT_DEVICE_STATE])),
)


@settings(max_examples=200, deadline=None)
@given(st.sampled_from(["xyzwv", "xyz", "x", "zx"]), st.lists(step, max_size=60))
def test_any_stream_is_safe(axes, steps):
    """Whatever arrives: no exception; counts move only on a possible, enabled record naming
    their axis that continues the previous possible record by the contract's rule (the same
    epoch within 6 records, or the next epoch directly after), with nothing in between; at
    most one jog-enable, only for the selected axis, only with `enable` and fresh enabled
    records; every pin in its HAL range; a change of jog mode moves nothing."""
    c = Core(Config(axes=axes))
    t = 0.0
    prev = None  # previous TPDO1 record processed (decoded), None after an interruption
    ref = None  # the bytes of the last record accepted (the ordering reference)
    drained_at = None
    sent = []  # every TPDO1 sent, for "again"

    def tpdo1(data: bytes):
        """The model's view of a TPDO1 handled at `t`: the letter it may move, if any."""
        nonlocal prev, ref
        if len(data) != 8 or not possible(*fields(data)):
            prev = None
            return None
        new = fields(data)
        if data == ref:
            return None  # a duplicate: nothing
        if ref is not None and c.fresh:
            ahead = (new[4] - ref[7]) % 256
            if ahead == 0:
                prev = None  # impossible
                return None
            if ahead >= 128:
                return None  # behind: ignored
        late = drained_at is None or t - drained_at > core.BACKLOG_LIMIT
        letter = applies(None if not c.fresh or late else prev, new, axes)
        prev, ref = new, data
        return letter

    for s in steps:
        before = dict(c.counts)
        kind = s[0]
        moved_ok = set()
        if kind in ("record", "again"):
            if kind == "record":
                _, pos, axis, mult, status, seq, dt, at_once = s
                data = rec(pos, axis, mult, status, seq)
            elif sent:
                _, back, dt = s
                data, at_once = sent[max(0, len(sent) - 1 - back)], True
            else:
                continue
            sent.append(data)
            t += dt
            c.tick(t)
            if at_once:
                c.drained(t)
                drained_at = t
            letter = tpdo1(data)
            if letter is not None:
                moved_ok = {letter}
            c.frame(TPDO1, data, t)
        elif kind == "hb":
            t += s[2]
            c.frame(HB, bytes([s[1]]), t)
            if s[1] & 0x7F == 0:
                prev = ref = None
        elif kind == "emcy":
            t += s[2]
            c.frame(EMCY, s[1], t)
        elif kind == "raw":
            t += s[3]
            c.tick(t)
            if s[1] == TPDO1:
                letter = tpdo1(s[2])
                moved_ok = {letter} if letter else set()
            c.frame(s[1], s[2], t)
            if s[1] == HB and len(s[2]) == 1 and s[2][0] & 0x7F == 0:
                prev = ref = None
        elif kind == "enable":
            c.set_enable(s[1])
        elif kind == "mode":  # never motion (moved_ok stays empty)
            c.set_position_mode(s[1])
        elif kind == "tick":
            t += s[1]
            c.tick(t)
        elif kind == "done":
            a = c.next_action(t)
            if a is not None:
                c.done(a, s[1], s[2], t, core.Configured(100))
        for L in axes:
            if c.counts[L] != before[L]:
                assert L in moved_ok, (s, L, before, c.counts)
        p = c.pins()
        assert p.jog_vel_mode == (not c.position_mode)
        on = [L for L in axes if p.jog_enable[L]]
        assert len(on) <= 1
        if on:
            assert c.enable and p.connected and p.feed_enabled and p.select[on[0]]
            assert c.state in (None, core.OPERATIONAL)
        for v in list(p.jog_counts.values()) + [
            p.position,
            p.records_lost,
            p.frames_bad,
            p.axis,
            p.multiplier,
            p.state,
        ]:
            assert -(2**31) <= v < 2**31
        assert 0 <= p.emcy_code <= 0xFFFF


@settings(max_examples=200, deadline=None)
@given(
    st.integers(1, 5),
    S32,
    st.lists(st.tuples(st.integers(-150, 150), st.booleans()), min_size=1, max_size=200),
    st.integers(1, 7),
)
def test_lost_records_cost_nothing(axis, start, moves, epoch):
    """One epoch, a record every event-timer period (turning up to 1500 detents/s at x10),
    any of them lost but never two in a row (three periods of silence are a disconnect):
    the axis gets exactly the wrapping distance between the first and the last record
    received, and the lost ones are counted."""
    assume(max_run_of_losses(moves) < 2)
    c = Core(Config())
    t = 0.0
    seq = 0
    pos = start
    c.drained(t)
    c.frame(TPDO1, rec(pos, axis, 10, core.STATUS_ENABLED, seq, epoch), t)
    last_received, lost, lost_seen = pos, 0, 0
    for detents, received in moves:
        pos = wrap_s32(pos + 10 * detents)
        seq += 1
        t += T
        if received:
            c.drained(t)
            c.frame(TPDO1, rec(pos, axis, 10, core.STATUS_ENABLED, seq, epoch), t)
            last_received, lost_seen = pos, lost
        else:
            lost += 1
            c.tick(t)
    letter = "xyzwv"[axis - 1]
    assert c.counts[letter] == wrap_s32(last_received - start)
    assert c.pins().records_lost == lost_seen  # a gap shows with the next record


def max_run_of_losses(moves):
    run = best = 0
    for _, received in moves:
        run = 0 if received else run + 1
        best = max(best, run)
    return best


@settings(max_examples=200, deadline=None)
@given(st.lists(step, max_size=40), st.floats(0.001, 5))
def test_silence_disconnects(steps, extra):
    """After any stream, three event-timer periods without a record: not connected, no
    jog-enable, no selection."""
    c = Core(Config())
    t = 0.0
    last_record = None
    for s in steps:
        if s[0] == "record":
            _, pos, axis, mult, status, seq, dt, _ = s
            t += dt
            c.frame(TPDO1, rec(pos, axis, mult, status, seq), t)
            last_record = t
        elif s[0] == "enable":
            c.set_enable(s[1])
    if last_record is None:
        assert not c.pins().connected
        return
    c.tick(last_record + 3 * T + extra)
    p = c.pins()
    assert not p.connected and not p.feed_enabled
    assert not any(p.jog_enable.values()) and not any(p.select.values())


@settings(max_examples=200, deadline=None)
@given(st.lists(st.integers(-50, 50), min_size=2, max_size=50), st.integers(1, 5))
def test_bootup_anywhere_never_becomes_motion(moves, where):
    """A device reset (boot-up, position and epoch back to 0, the sequence on with a break
    of 8, the feed enabled again) in the middle of a stream: the first record after it is a
    baseline, so the axis gets the moves before and after it only."""
    c = Core(Config())
    t = 0.0
    pos = 12345
    c.drained(t)
    c.frame(TPDO1, rec(pos, 1, 1, core.STATUS_ENABLED, 0, 1), t)
    expected = 0
    cut = where % len(moves)
    seq = 0
    for i, delta in enumerate(moves):
        t += 0.05
        if i == cut:
            c.drained(t)
            c.frame(HB, b"\x00", t)
            pos, seq = 0, (seq + 8) & 0xFF
            c.frame(TPDO1, rec(pos, 1, 1, 0, seq, 0), t)
            seq = (seq + 1) & 0xFF
            c.frame(TPDO1, rec(pos, 1, 1, core.STATUS_ENABLED, seq, 1), t)
        pos = wrap_s32(pos + delta)
        expected += delta
        seq = (seq + 1) & 0xFF
        c.drained(t + 0.01)
        c.frame(TPDO1, rec(pos, 1, 1, core.STATUS_ENABLED, seq, 1), t + 0.01)
    assert c.counts["x"] == expected
