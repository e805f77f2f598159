"""Properties of the component's decisions over generated frame streams (hypothesis)."""

from hypothesis import assume, given, settings
from hypothesis import strategies as st

from canopen_handwheel import core
from canopen_handwheel.core import Config, Record, wrap_s32
from records import EMCY, HB, SESSION, TPDO1, configure, configured, rec

T = 0.1
S32 = st.integers(-(2**31), 2**31 - 1)


def applies(prev: Record, new: Record, axes):
    """The rule of core.continuity restated from the contract: the letter `new` may move,
    or None. `prev`, `new`: two consecutive possible records of the device."""
    if prev is None:
        return None
    gap = (new.sequence - prev.sequence - 1) % 65536
    step = (new.epoch - prev.epoch) % 8
    same = step == 0 and gap <= 6
    if not (same or (step == 1 and gap == 0)):
        return None
    if same and (prev.axis, prev.multiplier, prev.enabled) != (
        new.axis,
        new.multiplier,
        new.enabled,
    ):
        return None
    if not new.enabled or not 1 <= new.axis <= len(axes):
        return None
    return axes[new.axis - 1]


def possible(r: Record) -> bool:
    return r.axis <= 5 and r.multiplier in (1, 10, 100) and not (r.enabled and r.master_lost)


# One step of a hostile stream: (kind, ...).
record_step = st.tuples(
    st.just("record"),
    S32,  # position
    st.one_of(st.integers(0, 5), st.integers(0, 7)),  # axis, sometimes one never sent
    st.sampled_from([1, 10, 100, 0]),  # 0: multiplier code 3
    st.integers(0, 31),  # status flags
    st.one_of(st.integers(0, 40), st.integers(0, 65535)),  # sequence
    st.floats(0, 0.5),  # time since the last step
    st.sampled_from([True, True, True, False]),  # handled at once (else: maybe late)
    st.sampled_from([SESSION, SESSION, SESSION, 0, 2]),  # the core's first session or not
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
    """Whatever arrives: no exception; counts move only on a possible, enabled record of the
    core's session naming their axis, ahead of the order reference (`order_verdict`), that
    continues the previous possible record by the contract's rule (the same epoch within 6
    records, or the next epoch directly after), with nothing in between; at most one
    jog-enable, only for the selected axis, only with `enable` and fresh enabled records of
    the session; every pin in its HAL range; a change of jog mode moves nothing."""
    c = configured(Config(axes=axes))
    session = c.session
    t = 0.0
    prev = None  # previous TPDO1 record processed (decoded), None after an interruption
    ref = None  # the order reference: (record, earliest arrival)
    drained_at = None
    sent = []  # every TPDO1 sent, for "again"

    def tpdo1(data: bytes):
        """The model's view of a TPDO1 handled at `t`: the letter it may move, if any."""
        nonlocal prev, ref
        if len(data) != 8 or not possible(Record.decode(data)):
            prev = None
            return None
        new = Record.decode(data)
        if c.session is None or new.session != c.session:
            return None  # another session's: nothing
        verdict, _ = core.order_verdict(ref, new, t)
        if verdict == core.RENEW:
            prev = ref = None  # the session is dropped
            return None
        if verdict in (core.DUPLICATE, core.COPY):
            return None
        if verdict == core.SAME_NUMBER:
            prev = None  # impossible
            return None
        late = drained_at is None or t - drained_at > core.BACKLOG_LIMIT
        letter = applies(None if not c.fresh or late else prev, new, axes)
        prev, ref = new, (new, t if drained_at is None else min(t, drained_at))
        return letter

    for s in steps:
        before = dict(c.counts)
        kind = s[0]
        moved_ok = set()
        if kind in ("record", "again"):
            if kind == "record":
                _, pos, axis, mult, status, seq, dt, at_once, token = s
                data = rec(pos, axis, mult, status, seq, 0, token)
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
            if isinstance(a, core.Configure):
                ok, result = core.configure_outcome(a, 0, c.event_timer)
                c.done(a, ok and s[1], s[2], t, result)
            elif a is not None:
                c.done(a, s[1], s[2], t)
        if c.session != session:  # a new session, or none: nothing links across
            prev = ref = None
            session = c.session
        for L in axes:
            if c.counts[L] != before[L]:
                assert L in moved_ok, (s, L, before, c.counts)
        p = c.pins()
        assert p.jog_vel_mode == (not c.position_mode)
        assert not p.feed_enabled or (c.record.session == c.session and not c.foreign_newest)
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
    c = configured()
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
    c = configured()
    t = 0.0
    last_record = None
    for s in steps:
        if s[0] == "record":
            _, pos, axis, mult, status, seq, dt, _, token = s
            t += dt
            c.frame(TPDO1, rec(pos, axis, mult, status, seq, 0, token), t)
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
    of 8, the component configuring a new session, the feed enabled again) in the middle of
    a stream: the first record after it is a baseline, so the axis gets the moves before and
    after it only."""
    c = configured()
    session = c.session
    t = 0.0
    pos = 12345
    c.drained(t)
    c.frame(TPDO1, rec(pos, 1, 1, core.STATUS_ENABLED, 0, 1, session), t)
    expected = 0
    cut = where % len(moves)
    seq = 0
    for i, delta in enumerate(moves):
        t += 0.05
        if i == cut:
            c.drained(t)
            c.frame(HB, b"\x00", t)
            session = configure(c, t)
            pos, seq = 0, seq + 8
            c.frame(TPDO1, rec(pos, 1, 1, 0, seq, 0, session), t)
            seq += 1
            c.frame(TPDO1, rec(pos, 1, 1, core.STATUS_ENABLED, seq, 1, session), t)
        pos = wrap_s32(pos + delta)
        expected += delta
        seq += 1
        c.drained(t + 0.01)
        c.frame(TPDO1, rec(pos, 1, 1, core.STATUS_ENABLED, seq, 1, session), t + 0.01)
    assert c.counts["x"] == expected
