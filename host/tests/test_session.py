"""Copies and power cycles at the core: the feed record v2, the session token, the order
reference bounded by the device's sequence budget, copies of every age, power cycles with and
without a boot-up, tokens reused only after COPY_AGE, and the report of feed stops (no bus, no
HAL)."""

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from canopen_handwheel import core
from canopen_handwheel.core import Config, Configure, Configured, Core, Record, WriteFeed
from records import EMCY, EN, HB, ML, SESSION, TPDO1, configure, configured, rec, record

MODULO = core.SEQUENCE_MODULO


class Dev:
    """A configured core fed as the shell feeds it (each frame handled at once), and a
    device whose records carry `session` and consecutive sequence numbers (`seq`)."""

    def __init__(self, seq=100, enable=True):
        self.t = 0.0
        self.c = configured(now=self.t)
        self.c.set_enable(enable)
        self.seq = seq
        self.pos = 0
        self.epoch = 1
        self.flags = EN
        self.session = self.c.session
        self.sent = []

    def at(self, dt=0.0):
        self.t += dt
        return self.t

    def frame(self, cob_id, data, dt=0.01):
        t = self.at(dt)
        self.c.drained(t)
        self.c.frame(cob_id, data, t)
        self.c.publish(t)

    def send(self, detents=0, dt=0.01, step=1, **kw) -> bytes:
        """The device's next record: `detents` turned, the sequence `step` on."""
        self.pos += detents
        self.seq = (self.seq + step) % MODULO
        fields = dict(flags=self.flags, epoch=self.epoch, session=self.session)
        fields.update(kw)
        data = rec(self.pos, seq=self.seq, **fields)
        self.sent.append(data)
        self.frame(TPDO1, data, dt)
        return data

    def hb(self, state, dt=0.01):
        self.frame(HB, bytes([state]), dt)

    def emcy(self, code, dt=0.001):
        self.frame(EMCY, code.to_bytes(2, "little") + bytes(6), dt)

    def configure(self, found=0):
        self.session = configure(self.c, self.at(), found)
        return self.session

    @property
    def x(self):
        return self.c.counts["x"]

    def pins(self):
        return self.c.pins()


# The record ------------------------------------------------------------------------------------


def test_the_layout_byte_by_byte():
    """README "Feed record": position I32; byte 4 axis (bits 0-2), multiplier code (3-4),
    epoch (5-7); byte 5 flags (0-4), session (5-7); bytes 6-7 the sequence, little-endian."""
    data = bytes([0xFE, 0xFF, 0xFF, 0xFF, 0b101_10_011, 0b110_01001, 0x34, 0x12])
    r = Record.decode(data)
    assert r == Record(
        position=-2, axis=3, multiplier=100, epoch=5, flags=0x09, session=6, sequence=0x1234
    )
    assert r.enabled and r.master_lost and r.encode() == data
    assert Record.decode(bytes([0, 0, 0, 0, 0b000_11_000, 0, 0, 0])).multiplier == 0  # code 3


@settings(max_examples=500, deadline=None)
@given(st.binary(min_size=8, max_size=8))
def test_every_8_bytes_decode_and_encode_back(data):
    assert Record.decode(data).encode() == data


@pytest.mark.parametrize("size", [0, 7, 9])
def test_a_record_is_8_bytes(size):
    with pytest.raises(ValueError):
        Record.decode(bytes(size))


@pytest.mark.parametrize(
    "fields", [dict(axis=8), dict(mult=7), dict(flags=0x20), dict(session=8), dict(axis=-1)]
)
def test_encode_refuses_what_does_not_fit(fields):
    with pytest.raises(ValueError):
        rec(0, **fields)


def test_the_position_sequence_and_epoch_wrap_in_encode():
    r = Record.decode(record(2**31, seq=MODULO + 3, epoch=9).encode())
    assert (r.position, r.sequence, r.epoch) == (-(2**31), 3, 1)


@pytest.mark.parametrize(
    "r, fault",
    [
        (record(0, axis=5), None),
        (record(0, axis=6), "axis 6"),
        (record(0, axis=7), "axis 7"),
        (record(0, mult=0), "multiplier code 3"),
        (record(0, flags=EN | ML), "feed enabled with master lost"),
        (record(0, flags=ML, session=7), None),
    ],
)
def test_record_fault(r, fault):
    assert core.record_fault(r) == fault


# The bounds --------------------------------------------------------------------------------


def test_the_invariant_copies_never_meet_records_ahead():
    """Spec's invariant, in its own terms and in the core's integers: the most a genuine
    record can be ahead within the order window, plus the most a copy up to COPY_AGE old can
    be behind, stays below the modulo, so the two never alias."""
    spec = (
        core.max_ahead(core.ORDER_WINDOW)
        + core.COPY_AGE * core.SEQUENCE_PER_S * (1 + core.CLOCK_TOLERANCE)
        + core.SEQUENCE_BURST
    )
    assert spec < MODULO
    assert core.max_ahead(core.ORDER_WINDOW) + core.oldest_copy_behind() < MODULO
    assert core.oldest_copy_behind() == 60_664


def test_max_ahead_values():
    """floor((dt + IN_TRANSIT) * 1000 * 1.01) + 64, exactly at the boundaries."""
    assert core.max_ahead(0.0) == 252 + 64
    assert core.max_ahead(0.05) == 303 + 64  # 0.3 s * 1010: an integer, not 302.99..
    assert core.max_ahead(core.ORDER_WINDOW) == 4292 + 64
    for ms in range(0, 4001, 7):
        assert core.max_ahead(ms / 1000) == (ms + 250) * 1010 // 1000 + 64


@given(st.floats(0, 10), st.floats(0, 10))
def test_max_ahead_grows_with_time(a, b):
    if a <= b:
        assert core.max_ahead(a) <= core.max_ahead(b)


REF = (record(0, seq=1000), 10.0)


@pytest.mark.parametrize("dt", [0.0, 0.001, 1.0, 2.5, core.ORDER_WINDOW])
def test_ahead_up_to_max_ahead_and_a_copy_one_beyond(dt):
    bound = core.max_ahead(dt)
    at_bound = record(5, seq=1000 + bound)
    beyond = record(5, seq=1000 + bound + 1)
    assert core.order_verdict(REF, at_bound, 10.0 + dt) == (core.AHEAD, bound)
    assert core.order_verdict(REF, beyond, 10.0 + dt) == (core.COPY, bound + 1)


def test_the_order_window_boundary():
    r = record(5, seq=1001)
    assert core.order_verdict(REF, r, 10.0 + core.ORDER_WINDOW)[0] == core.AHEAD
    assert core.order_verdict(REF, r, 10.0 + core.ORDER_WINDOW + 1e-6)[0] == core.RENEW
    assert core.order_verdict(None, r, 99.0) == (core.FIRST, 0)


def test_the_same_number():
    assert core.order_verdict(REF, record(0, seq=1000), 10.1)[0] == core.DUPLICATE
    assert core.order_verdict(REF, record(1, seq=1000), 10.1)[0] == core.SAME_NUMBER


@settings(max_examples=500, deadline=None)
@given(
    st.integers(0, MODULO - 1),  # the reference's sequence number
    st.floats(0, core.ORDER_WINDOW),  # reference to now
    st.floats(0, core.COPY_AGE),  # the copy's age
    st.floats(0, 1),  # how much of its budget the device used since the copy's original
)
def test_a_copy_within_the_contracts_age_is_always_a_copy(ref_seq, dt, age, used):
    """A device that keeps its budget: the original of a copy `age` old was sent at most
    `age` before the reference (which is older than the copy's delivery), so it lies at most
    what the budget allows in `age` behind it; at any time within the order window that is
    read as a copy, never as a record ahead."""
    behind = math.floor(used * (age * core.SEQUENCE_PER_S * 1.01 + core.SEQUENCE_BURST))
    assert behind <= core.oldest_copy_behind()
    ref = (record(0, seq=ref_seq), 100.0)
    copy = record(7, seq=(ref_seq - behind) % MODULO)
    verdict, _ = core.order_verdict(ref, copy, 100.0 + dt)
    assert verdict in (core.COPY, core.DUPLICATE, core.SAME_NUMBER)
    assert verdict == core.COPY or behind == 0


def test_copies_65529_back_and_more_are_older_than_the_contract_covers():
    """The only numbers behind that read as ahead (65536 - max_ahead(ORDER_WINDOW) and more:
    65529-65535 back are 1-7 ahead) take the device longer than COPY_AGE to send: a copy
    that far back is outside the contract (and indeed reads as a record ahead)."""
    first_alias = MODULO - core.max_ahead(core.ORDER_WINDOW)
    assert first_alias > core.oldest_copy_behind()
    fastest = (first_alias - core.SEQUENCE_BURST) / (core.SEQUENCE_PER_S * 1.01)
    assert fastest > core.COPY_AGE
    for back in range(65529, 65536):
        copy = record(7, seq=(1000 - back) % MODULO)
        assert core.order_verdict(REF, copy, 10.01)[0] == core.AHEAD


# Copies through the core ---------------------------------------------------------------------


@pytest.mark.parametrize("back", [1, 2, 128, 129, 200, 249, 255, 256, 257, 1000, 32768])
def test_copies_of_every_age_move_nothing(back):
    """The device turned X at x100 (a record every 2 ms, 500 per second, as on the board);
    then the genuine record `back` records old is sent again right after a genuine one:
    ignored and counted bad (before feed record v2, 249-255 back read as 6 ahead and moved X
    by everything turned since). The next genuine record goes on from the last genuine one."""
    d = Dev()
    d.send(mult=100)
    for _ in range(back + 1):
        d.send(100, dt=0.002, mult=100)
    assert d.x == 100 * (back + 1)
    d.frame(TPDO1, d.sent[-1 - back], dt=0.001)
    assert d.x == 100 * (back + 1) and d.pins().frames_bad == 1
    d.send(100, dt=0.001, mult=100)
    assert d.x == 100 * (back + 2) and d.pins().records_lost == 0


def test_a_copy_seven_epochs_and_255_records_old_moves_nothing():
    """A Y record 255 records and 7 epochs back, sent again while X is selected: with 8-bit
    numbers it read as the next record of the next epoch; now as a copy."""
    d = Dev()
    d.send(axis=2)
    d.send(30, axis=2)
    y_record = d.sent[-1]
    for i in range(7):  # 7 switch moves: the epoch comes round to Y's bits again
        d.epoch += 1
        d.send(0, axis=1 + (i + 1) % 2)
    d.epoch += 1
    while d.seq != (Record.decode(y_record).sequence + 255) % MODULO:
        d.send(1, axis=1, dt=0.002)
    x, y = d.c.counts["x"], d.c.counts["y"]
    d.frame(TPDO1, y_record, dt=0.001)
    assert (d.c.counts["x"], d.c.counts["y"]) == (x, y) and d.pins().frames_bad == 1


def test_the_16_bit_sequence_wraps():
    d = Dev(seq=MODULO - 5)
    d.send()
    for _ in range(10):
        d.send(1)
    assert d.x == 10 and d.seq == 6 and d.pins().records_lost == 0
    d.send(1, step=7)  # 6 missing across nothing: the same epoch
    assert d.x == 11 and d.pins().records_lost == 6
    d.seq = MODULO - 2
    d.send(0, step=1, dt=0.01)  # from 5 to 65535: far beyond the budget: a copy
    assert d.pins().frames_bad == 1 and d.x == 11


@pytest.mark.parametrize("gap, continues", [(0, True), (6, True), (7, False)])
def test_gaps_across_the_wrap(gap, continues):
    d = Dev(seq=MODULO - 3)
    d.send()
    d.send(4, step=gap + 1)
    assert d.x == (4 if continues else 0) and d.pins().records_lost == gap


@pytest.mark.parametrize("gap, continues", [(0, True), (1, False)])
def test_the_next_epoch_directly_after_across_the_wrap(gap, continues):
    d = Dev(seq=MODULO - 1)
    d.send()
    d.epoch += 1
    d.send(4, step=gap + 1, axis=2)
    assert d.c.counts["y"] == (4 if continues else 0)


def test_a_record_at_max_ahead_is_taken_and_one_beyond_is_a_copy():
    """Through the core, 0.25 s after the reference: max_ahead numbers on is a genuine record
    (a gap: a baseline, the losses counted); one more is a copy, never a reference."""
    for extra, taken in [(0, True), (1, False)]:
        d = Dev()
        d.send()
        d.send(1)
        bound = core.max_ahead(0.25)
        d.send(5, dt=0.25, step=bound + extra)
        p = d.pins()
        assert (p.records_lost, p.frames_bad) == ((bound - 1, 0) if taken else (0, 1))
        d.send(2, dt=0.001)
        assert d.x == (3 if taken else 1)  # the copy: the next is judged from the old one


def test_the_order_window_renews_the_session():
    """No record of the session for ORDER_WINDOW: the next is still judged; a moment more:
    ignored, the session dropped, a configuration with a fresh token (a stale reference
    cannot tell a copy from a record ahead), then motion as after any configuration."""
    d = Dev()
    d.send()
    d.send(1)
    d.send(1, dt=core.ORDER_WINDOW)
    assert d.c.session == SESSION and d.pins().records_lost == 0
    d.send(1, dt=core.ORDER_WINDOW + 0.001)
    assert d.c.session is None and d.x == 1 and d.pins().frames_bad == 0
    assert any("no record of it for more than 4 s" in line for line in d.c.take_log())
    a = d.c.next_action(d.at())
    assert isinstance(a, Configure) and a.keep is None and SESSION not in a.tokens
    ok, result = core.configure_outcome(a, SESSION, d.c.event_timer)
    d.c.done(a, ok, None, d.at(), result)
    assert d.c.session == 2
    d.session = 2
    d.send(0)
    d.send(3)
    assert d.x == 4


# Sessions ----------------------------------------------------------------------------------


def test_a_record_of_another_session_is_foreign():
    """Never credited, never a reference, not bad; it closes the gate, blocks 0x2000 = 1,
    and makes the core check its configuration (0x2002) once per retry time at most."""
    d = Dev()
    d.send(flags=0)
    d.send(0, flags=0)
    for other in (0, 2):
        d.send(50, flags=EN, session=other)
        p = d.pins()
        assert d.x == 0 and p.frames_bad == 0 and not p.feed_enabled
        assert not any(p.jog_enable.values())
    a = d.c.next_action(d.at())
    wanted = core.motion_settings(d.c.cfg)
    # The second configuration: the next session key (the first one's was 1).
    assert a == Configure(
        1, 500, None, keep=SESSION, tokens=(3, 4, 5, 6, 7), settings=wanted, key=2
    )
    ok, result = core.configure_outcome(a, SESSION, d.c.event_timer)
    assert result.intact and result.tried is None
    d.c.done(a, ok, None, d.at(), result)
    assert d.c.session == SESSION and d.c.next_action(d.at()) is None  # the newest: foreign
    d.send(0, flags=0)
    assert d.c.next_action(d.at()) == WriteFeed(1)


def test_an_intact_check_keeps_the_reference_and_the_motion():
    d = Dev()
    d.send()
    d.send(1)
    d.frame(TPDO1, rec(9, seq=7, epoch=1, session=0))  # a copy of another session's record
    a = d.c.next_action(d.at())
    ok, result = core.configure_outcome(a, SESSION, d.c.event_timer)
    d.c.done(a, ok, None, d.at(), result)
    d.send(2)
    assert d.x == 3 and d.c.session == SESSION
    d.frame(TPDO1, rec(9, seq=8, epoch=1, session=0))
    assert d.c.next_action(d.at()) is None  # the next check not before the retry time
    assert isinstance(d.c.next_action(d.at(d.c.cfg.retry)), Configure)


def test_no_feed_enable_while_the_newest_record_is_foreign():
    d = Dev()
    d.send(flags=0)
    d.send(flags=0, session=0)
    assert isinstance(d.c.next_action(d.at()), Configure)  # the check, not 0x2000 = 1


def test_a_missed_boot_up_leads_to_a_configuration_before_any_feed_enable():
    """The device power-cycled, its boot-up lost, started by another node: its records show
    session 0 and the feed off. The component's next action is the check, which finds 0 and
    configures (0x1016 written and read back) before the feed is enabled again; the stop is
    reported as the session's end."""
    d = Dev()
    d.send(flags=0)
    d.c.done(d.c.next_action(d.at()), True, None, d.at())  # 0x2000 = 1
    d.send(0)
    d.send(3)
    assert d.x == 3 and d.pins().feed_enabled
    d.seq = 8  # after the power cycle
    d.send(0, flags=0, session=0, epoch=0)
    assert not d.pins().feed_enabled
    a = d.c.next_action(d.at())
    assert isinstance(a, Configure) and a.keep == SESSION
    ok, result = core.configure_outcome(a, 0, d.c.event_timer)
    d.c.done(a, ok, None, d.at(), result)
    d.session = d.c.session
    assert d.session == 2
    assert (d.pins().feed_stops, d.pins().stop_reason) == (1, core.STOP_SESSION_ENDED)
    assert "feed stopped by the device: the session ended" in " ".join(d.c.take_log())
    assert d.c.next_action(d.at()) is None  # no record of the new session yet
    d.send(0, flags=0, epoch=1)
    assert d.c.next_action(d.at()) == WriteFeed(1)


@pytest.mark.parametrize("bootup_seen", [True, False])
def test_a_quick_power_cycle_costs_only_the_configuration(bootup_seen):
    """The last record before the cut at sequence 130, the device back with its sequence from 8
    (1..128 below it): the second record of the new session moves the axis, at once, with
    nothing counted bad."""
    d = Dev(seq=129)
    d.send()
    d.send(1)
    d.seq = 7
    if bootup_seen:
        d.hb(core.BOOTUP)
        d.configure(found=0)
    else:
        d.send(0, flags=0, session=0, epoch=0)
        d.configure(found=0)
    assert d.session == 2
    d.send(0, flags=EN, epoch=1, dt=0.05)
    d.send(1, dt=0.05)
    assert d.x == 2 and d.pins().frames_bad == 0


@pytest.mark.parametrize("bootup_seen", [True, False])
def test_copies_across_a_power_cycle_move_nothing(bootup_seen):
    """Records from before a power cycle sent again after it (every one of them, in any order)
    are another session's once the new session is written; and before that, they are copies of
    the old session (or foreign after a boot-up)."""
    d = Dev()
    d.send()
    for _ in range(20):
        d.send(1, dt=0.002)
    before = list(d.sent)
    d.seq = 7
    if bootup_seen:
        d.hb(core.BOOTUP)
    else:
        d.send(0, flags=0, session=0, epoch=0)
    for data in reversed(before):  # all copies, before the configuration
        d.frame(TPDO1, data, dt=0.0005)
    assert d.x == 20
    d.configure(found=0)
    d.send(0, epoch=1)
    for data in before + before[::-1]:
        d.frame(TPDO1, data, dt=0.0005)
        d.send(0, dt=0.0005)
    assert d.x == 20 and d.c.session == 2


def seven_boot_ups_in_seven_seconds() -> Dev:
    """Seven boot-ups a second apart (resets of the node, or power cycles: the host cannot
    tell), the first six configured with the next free token: every token used by the
    seventh."""
    d = Dev()
    used = [d.c.session]
    for _ in range(6):
        d.hb(core.BOOTUP, dt=1.0)
        used.append(d.configure())
    assert used == [1, 2, 3, 4, 5, 6, 7]
    assert sorted(d.c.superseded) == [1, 2, 3, 4, 5, 6]
    d.hb(core.BOOTUP, dt=1.0)
    return d


def test_a_token_is_reused_at_once_when_the_uptime_shows_no_power_cycle_since():
    """After seven boot-ups in seven seconds no token is free; the configuration offers the
    host's own tokens, least recently used first, each with its chain's start, and writes the
    first one the device's uptime proves: a device up for 60 s has run since token 1 was first
    written (t = 0), one up for 6.5 s since token 2 (t = 1), not token 1."""
    d = seven_boot_ups_in_seven_seconds()
    t = d.at()
    a = d.c.next_action(t)
    assert isinstance(a, Configure) and a.tokens == ()
    assert [token for token, _ in a.reusable] == [1, 2, 3, 4, 5, 6, 7]
    assert dict(a.reusable)[1] == 0.0 and dict(a.reusable)[2] == pytest.approx(1.0)
    assert core.pick_token((), 0, a.reusable, core.life_began_by(60_000, t)) == 1
    # Up 6.5 s on a clock up to 1 % fast: begun after t = 0.56 at the latest.
    assert core.pick_token((), 0, a.reusable, core.life_began_by(6_500, t)) == 2
    assert core.pick_token((), 1, a.reusable, core.life_began_by(60_000, t)) == 2
    ok, result = core.configure_outcome(a, 0, d.c.event_timer, (60_000, t))
    d.c.done(a, ok, None, t, result)
    assert d.c.session == 1
    # Its chain goes on from t = 0: the next reuse needs a life begun before it, still.
    assert d.c.chains[1] == 0.0


def test_a_token_waits_copy_age_when_the_uptime_shows_a_young_life():
    """The same, the device up for less than the seconds since any token's chain began (a
    power cycle since): nothing is written, the wait is logged, and the first token free
    after COPY_AGE is written then."""
    d = seven_boot_ups_in_seven_seconds()
    t = d.at()
    assert configure(d.c, t, uptime_ms=900) is None
    assert any("does not show it running" in line for line in d.c.take_log())
    free_at = d.c.superseded[1] + core.COPY_AGE
    assert d.c.config_due == pytest.approx(free_at)
    assert d.c.next_action(free_at - 1e-6) is None
    a = d.c.next_action(free_at)
    assert isinstance(a, Configure) and a.tokens == (1,)


def test_a_token_picked_free_starts_a_chain_and_a_reused_one_keeps_its_own():
    """The chain of a token starts when a configuration that writes it free is asked for,
    even if its read-back fails (the device may be in it); a young device's refusal writes
    nothing and starts none."""
    c = Core(Config())
    a = c.next_action(0.0)
    c.done(a, False, None, 0.1, Configured(found=0, tried=1))
    assert c.chains == {1: 0.0}
    a = c.next_action(1.0)
    c.done(a, False, core.ABORT_DEVICE_STATE, 1.1, Configured(found=0, tried=2, young=True))
    assert c.chains == {1: 0.0}


def test_free_tokens_boundaries():
    assert core.free_tokens({}, 0.0) == core.TOKENS
    assert core.free_tokens({}, 0.0, own=1) == (2, 3, 4, 5, 6, 7)
    used = {t: 100.0 + t for t in core.TOKENS}
    assert core.free_tokens(used, 100.0 + 3 + core.COPY_AGE - 1e-9) == (1, 2)
    assert core.free_tokens(used, 100.0 + 3 + core.COPY_AGE) == (1, 2, 3)  # least recent first
    assert core.token_free_at(used, own=1) == 102.0 + core.COPY_AGE
    assert core.pick_token((2, 3), 2) == 3 and core.pick_token((2,), 2) is None
    assert core.pick_token((2, 3), 0) == 2


def test_a_token_written_without_its_read_back_waits_like_a_superseded_one():
    """The configuration wrote token 1 and failed on the read-back: the device may be in
    session 1 and send records of it, so 1 is not offered again for COPY_AGE."""
    c = Core(Config())
    a = c.next_action(0.0)
    c.done(a, False, None, 0.1, Configured(found=0, tried=1))
    assert c.session is None and c.busy == {1: 0.1}
    a = c.next_action(1.0)
    assert a.tokens[0] == 2 and 1 not in a.tokens
    ok, result = core.configure_outcome(a, 1, c.event_timer)  # the device is in 1
    c.done(a, ok, None, 1.1, result)
    assert c.session == 2 and c.superseded == {1: 1.1} and c.busy == {}


def test_a_young_device_is_asked_again_after_a_tenth_of_a_second():
    """The device refuses the token (abort 0x08000022) while it is younger than
    SESSION_DELAY: the configuration failed, but the token was never the device's, so it is
    offered again first, and the next configuration comes YOUNG_RETRY later, not after the
    retry time: the component has its session within about a second of a boot-up."""
    assert core.YOUNG_RETRY == 0.1 and Config().retry == 0.5
    c = Core(Config())
    a = c.next_action(0.0)
    assert a.tokens[0] == SESSION and a.key == 1
    young = Configured(found=0, tried=SESSION, young=True, first_reply_at=0.01)
    c.done(a, False, core.ABORT_DEVICE_STATE, 0.05, young)
    assert c.session is None and c.busy == {} and c.config_due == pytest.approx(0.15)
    assert c.next_action(0.149) is None
    b = c.next_action(c.config_due)
    assert isinstance(b, Configure) and b.tokens[0] == SESSION and b.key == 2
    ok, result = core.configure_outcome(b, 0, c.event_timer)
    c.done(b, ok, None, 0.6, result)
    assert (c.session, c.session_key) == (SESSION, 2)
    # Another failure is retried after the retry time, as before.
    c = Core(Config())
    a = c.next_action(0.0)
    c.done(a, False, None, 0.05, Configured(found=0))
    assert c.config_due == pytest.approx(0.55)


def test_the_session_delay_outlasts_every_date():
    """No probe answered before a power cycle dates a record of the new life: the device
    opens no session within SESSION_DELAY of its start, and a date counts for DATE_LIMIT."""
    assert core.DATE_LIMIT == pytest.approx(0.35) and core.SESSION_DELAY == 0.5
    assert core.DATE_LIMIT < core.SESSION_DELAY


@pytest.mark.parametrize("ok", [False, True])
def test_a_configuration_without_its_key_is_not_taken(ok):
    """The token was written and read back but its key was not written (`keyed` false: the
    write of 0x2034 failed, or a shell that skipped it): the core has no session, its probes
    could not tell its session from another master's; the token counts as possibly the
    device's (busy), and the configuration is retried after the retry time."""
    c = Core(Config())
    a = c.next_action(0.0)
    ok_, result = core.configure_outcome(a, 0, c.event_timer)
    assert ok_ and result.keyed and result.session == SESSION
    unkeyed = Configured(
        event_timer_ms=result.event_timer_ms, found=0, tried=SESSION, session=SESSION
    )
    c.done(a, ok, None, 0.1, unkeyed)
    assert c.session is None and c.session_key is None
    assert c.busy == {SESSION: 0.1} and c.config_due == pytest.approx(0.6)
    b = c.next_action(0.6)
    assert isinstance(b, Configure) and SESSION not in b.tokens and b.key == 2


def test_another_masters_token_is_not_taken():
    """Records of session 3, a token the host never wrote (another master's): not offered
    until COPY_AGE after the configuration that ended it."""
    c = Core(Config())
    c.frame(TPDO1, rec(0, session=3), 0.0)
    a = c.next_action(0.1)
    assert 3 not in a.tokens
    ok, result = core.configure_outcome(a, 3, c.event_timer)
    c.done(a, ok, None, 0.2, result)
    assert c.session == 1 and c.superseded == {3: 0.2}


def test_a_configuration_answered_before_a_boot_up_is_done_again_with_a_new_token():
    c = Core(Config())
    a = c.next_action(0.0)
    c.frame(HB, b"\x00", 0.05)
    ok, result = core.configure_outcome(a, 0, c.event_timer)
    result.first_reply_at = 0.01
    c.done(a, ok, None, 0.1, result)
    assert c.session is None
    a = c.next_action(0.1)
    assert isinstance(a, Configure) and 1 not in a.tokens


def test_replay_of_the_shells_configuration():
    def frame(position, seq, session, t):
        return [
            ("drained", t),
            ("frame", TPDO1, rec(position, seq=seq, epoch=1, session=session), t),
        ]

    events = [("configure", 0, 0.0)] + frame(0, 1, 1, 0.0) + frame(4, 2, 1, 0.01)
    events += [("frame", HB, b"\x00", 0.02), ("configure", 0, 0.03)]
    events += frame(0, 10, 2, 0.04) + frame(1, 11, 2, 0.05)
    c = core.replay_core(events)
    assert c.session == 2 and c.published.jog_counts["x"] == 5


# Feed stops -------------------------------------------------------------------------------


def on_and_turning() -> Dev:
    d = Dev()
    d.send(flags=0)
    d.c.done(d.c.next_action(d.at()), True, None, d.at())
    d.epoch += 1
    d.send(0)
    d.send(1)
    assert d.pins().feed_enabled and d.c.take_log() == [] and d.pins().feed_stops == 0
    return d


def stopped_with(d: Dev, flags: int) -> None:
    d.epoch += 1
    d.send(0, flags=flags)


def test_master_lost_with_its_emcy():
    d = on_and_turning()
    d.emcy(core.EMCY_MASTER_LOST)
    stopped_with(d, ML)
    p = d.pins()
    assert (p.feed_stops, p.stop_reason) == (1, core.STOP_MASTER_LOST)
    assert d.c.take_log() == ["feed stopped by the device: master heartbeat lost (EMCY 0x8130)"]
    stopped_with(d, ML)
    assert d.pins().feed_stops == 1  # one stop, one report


def test_a_blocked_transmit_path_whose_emcy_comes_after_the_record():
    d = on_and_turning()
    stopped_with(d, ML)
    assert d.pins().feed_stops == 0  # waiting for the EMCY that tells why
    d.emcy(core.EMCY_TRANSMIT_BLOCKED, dt=0.01)
    assert (d.pins().feed_stops, d.pins().stop_reason) == (1, core.STOP_TRANSMIT_BLOCKED)
    assert d.c.take_log() == ["feed stopped by the device: transmit path blocked (EMCY 0x8100)"]


def test_the_emcy_counts_also_after_the_feed_is_on_again():
    """The component enables the feed again at once: an enabled record may come before the
    EMCY 0x8100 that tells why the feed stopped."""
    d = on_and_turning()
    stopped_with(d, ML)
    d.c.done(d.c.next_action(d.at()), True, None, d.at())  # 0x2000 = 1 again
    d.epoch += 1
    d.send(0, dt=0.005)
    assert d.pins().feed_stops == 0
    d.emcy(core.EMCY_TRANSMIT_BLOCKED, dt=0.005)
    assert (d.pins().feed_stops, d.pins().stop_reason) == (1, core.STOP_TRANSMIT_BLOCKED)
    d.epoch += 1
    d.send(0, flags=0)  # the next stop: a master's write, the old EMCY forgotten
    assert (d.pins().feed_stops, d.pins().stop_reason) == (2, core.STOP_MASTER_WRITE)


def test_bit_3_without_an_emcy_is_reported_after_the_wait():
    d = on_and_turning()
    stopped_with(d, ML)
    d.c.tick(d.at(core.STOP_REASON_WAIT - 0.002))
    assert d.pins().feed_stops == 0
    d.c.tick(d.at(0.004))
    assert (d.pins().feed_stops, d.pins().stop_reason) == (1, core.STOP_MASTER_LOST)


def test_a_stop_by_another_masters_write():
    d = on_and_turning()
    stopped_with(d, 0)
    assert (d.pins().feed_stops, d.pins().stop_reason) == (1, core.STOP_MASTER_WRITE)


@pytest.mark.parametrize("state", [core.STOPPED, core.PRE_OPERATIONAL])
def test_the_device_leaving_operational(state):
    d = on_and_turning()
    d.hb(state)
    assert (d.pins().feed_stops, d.pins().stop_reason) == (1, core.STOP_NOT_OPERATIONAL)
    assert d.c.take_log()[0] == "feed stopped by the device: the device left Operational"
    if state == core.STOPPED:  # started again by someone: its records show the feed off
        d.hb(core.OPERATIONAL)
        stopped_with(d, 0)
        assert d.pins().feed_stops == 1


def test_a_stop_waiting_for_its_emcy_is_reported_when_the_session_ends():
    d = on_and_turning()
    stopped_with(d, ML)
    d.hb(core.BOOTUP)
    assert (d.pins().feed_stops, d.pins().stop_reason) == (1, core.STOP_MASTER_LOST)


def test_a_boot_up_ends_the_session():
    d = on_and_turning()
    d.hb(core.BOOTUP)
    assert (d.pins().feed_stops, d.pins().stop_reason) == (1, core.STOP_SESSION_ENDED)


def test_no_report_when_the_component_asked():
    d = on_and_turning()
    d.c.set_enable(False)
    assert d.c.next_action(d.at()) == WriteFeed(0)
    d.c.done(WriteFeed(0), True, None, d.at())
    d.send(0)  # still on until the write takes effect
    stopped_with(d, 0)
    d.hb(core.STOPPED)
    d.hb(core.BOOTUP)
    assert d.pins().feed_stops == 0 and d.pins().stop_reason == core.STOP_NONE


def test_the_stop_reason_stays_until_the_next_stop():
    d = on_and_turning()
    stopped_with(d, 0)
    d.c.done(d.c.next_action(d.at(1.0)), True, None, d.at())  # enabled again
    d.epoch += 1
    d.send(0)
    assert d.pins().stop_reason == core.STOP_MASTER_WRITE
    d.emcy(core.EMCY_MASTER_LOST)
    stopped_with(d, ML)
    assert (d.pins().feed_stops, d.pins().stop_reason) == (2, core.STOP_MASTER_LOST)


@pytest.mark.parametrize(
    "master_lost, emcy, left, reason",
    [
        (True, None, False, core.STOP_MASTER_LOST),
        (True, core.EMCY_MASTER_LOST, False, core.STOP_MASTER_LOST),
        (True, core.EMCY_TRANSMIT_BLOCKED, False, core.STOP_TRANSMIT_BLOCKED),
        (True, core.EMCY_TRANSMIT_BLOCKED, True, core.STOP_TRANSMIT_BLOCKED),
        (False, None, True, core.STOP_NOT_OPERATIONAL),
        (False, None, False, core.STOP_MASTER_WRITE),
    ],
)
def test_stop_reason(master_lost, emcy, left, reason):
    assert core.stop_reason(master_lost, emcy, left) == reason


def test_the_log_is_bounded():
    c = configured()
    for i in range(1000):
        c.log.append(str(i))
    assert len(c.take_log()) == core.LOG_LINES and c.take_log() == []


# The gate over random streams ----------------------------------------------------------------

STEP = st.one_of(
    st.tuples(st.just("record"), st.sampled_from([SESSION, SESSION, 0, 2]), st.booleans()),
    st.tuples(st.just("hb"), st.sampled_from([0x00, 0x05, 0x7F, 0x04])),
    st.tuples(st.just("do"), st.booleans(), st.sampled_from([0, SESSION, 2, 3])),
    st.tuples(st.just("enable"), st.booleans()),
    st.tuples(st.just("wait"), st.sampled_from([0.01, 0.3, 1.0, 5.0])),
)


@settings(max_examples=300, deadline=None)
@given(st.lists(STEP, max_size=60))
def test_the_feed_is_enabled_only_on_the_hosts_own_session(steps):
    """Whatever the records, heartbeats, configuration outcomes (the device found in any
    session) and waits: 0x2000 = 1 is asked for only while the newest record was of the
    core's session, read back by a configuration since the last boot-up it saw; and every
    session the core takes is a token it offered and the device did not hold."""
    c = Core(Config())
    t, seq = 0.0, 0
    newest = None  # the session field of the newest possible record
    booted = False
    for s in steps:
        t += 0.001
        if s[0] == "record":
            seq += 1
            newest = s[1]
            c.drained(t)
            c.frame(TPDO1, rec(seq, flags=EN if s[2] else 0, seq=seq, epoch=1, session=s[1]), t)
        elif s[0] == "hb":
            c.frame(HB, bytes([s[1]]), t)
            booted = booted or s[1] == 0
        elif s[0] == "enable":
            c.set_enable(s[1])
        elif s[0] == "wait":
            t += s[1]
            c.tick(t)
        else:
            before = c.session
            a = c.next_action(t)
            if isinstance(a, Configure):
                ok, result = core.configure_outcome(a, s[2], c.event_timer)
                c.done(a, ok and s[1], None, t, result)
                if c.session is not None and c.session != before:
                    assert c.session in a.tokens and c.session != s[2]
                    booted = False
            elif isinstance(a, WriteFeed):
                if a.value == 1:
                    assert c.session is not None and newest == c.session and not booted
                c.done(a, s[1], None, t)


def test_the_mapping_the_configuration_requires_is_the_eds_default():
    """`FEED_RECORD_MAPPING` is TPDO1's default mapping as the object table (and its EDS) give
    it, and the fields `Record` decodes fill its 64 bits exactly."""
    import configparser

    from canopen_handwheel import component

    eds = configparser.ConfigParser()
    eds.read(component.default_eds())
    count = int(eds["1A00sub0"]["DefaultValue"], 0)
    default = tuple(int(eds[f"1A00sub{i}"]["DefaultValue"], 0) for i in range(1, count + 1))
    assert default == core.FEED_RECORD_MAPPING
    assert sum(m & 0xFF for m in core.FEED_RECORD_MAPPING) == 64


def test_tpdo1_must_be_valid_on_the_nodes_identifier():
    assert core.tpdo1_cob_id_fault(0x4000_0190, 16) is None
    assert core.tpdo1_cob_id_fault(0x190, 16) is None
    assert "invalid" in core.tpdo1_cob_id_fault(0xC000_0190, 16)
    assert "0x191" in core.tpdo1_cob_id_fault(0x4000_0191, 16)
    assert "0x280" in core.tpdo1_cob_id_fault(0x4000_0280, 16)
    assert core.tpdo1_cob_id_fault(0x6000_0190, 16) is not None, "29-bit identifiers"
