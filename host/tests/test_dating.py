"""Dating records with the sequence probe 0x2033 (core.py's "Dating"): what an answer dates,
what it does not, and that the core credits a record only while a recent probe dates it."""

import pytest

from canopen_handwheel import core
from canopen_handwheel.core import Config, Core, Probe, Probed, WriteFeed
from records import EN, SESSION, TPDO1, configure, rec

MODULO = core.SEQUENCE_MODULO


def answer(number: int, nonce: int, session: int = SESSION) -> int:
    """The probe's value as the device reads it: number, session, nonce."""
    return (number % MODULO) << 16 | session << core.NONCE_BITS | nonce & core.NONCE_MASK


class Dated:
    """A configured core with dating on, fed as the shell feeds it: records with consecutive
    numbers from `seq`, probes carried out when the core asks for them, answered by a device
    whose next record number is `next_number`."""

    def __init__(self, seq: int = 100, own_sdo=None) -> None:
        self.t = 0.0
        self.c = Core(Config(axes="xy", dating=True, first_nonce=5, own_sdo=own_sdo))
        assert configure(self.c, self.t) == SESSION
        self.c.set_enable(True)
        self.seq = seq
        self.pos = 0

    @property
    def next_number(self) -> int:
        return (self.seq + 1) % MODULO

    def record(self, detents: int = 0, dt: float = 0.01, step: int = 1) -> None:
        self.t += dt
        self.pos += detents
        self.seq = (self.seq + step) % MODULO
        self.c.drained(self.t)
        self.c.frame(TPDO1, rec(self.pos, 1, 1, EN, self.seq, 1, SESSION), self.t)
        self.c.publish(self.t)

    def probe(self, dt: float = 0.0, answered=None) -> Probe:
        """The core's next action, which must be a probe, carried out `dt` later: sent then,
        answered with `answered` (default: the device's answer now)."""
        self.t += dt
        action = self.c.next_action(self.t)
        while isinstance(action, WriteFeed):  # the feed enable the core asks for first
            self.c.done(action, True, None, self.t)
            action = self.c.next_action(self.t)
        assert isinstance(action, Probe), action
        value = answer(self.next_number, action.nonce) if answered is None else answered
        self.c.done(action, True, None, self.t, Probed(sent_at=self.t, value=value))
        return action

    @property
    def x(self) -> int:
        return self.c.counts["x"]


def test_an_answer_dates_from_the_send_when_it_carries_the_nonce_and_the_session():
    probe = Probe(nonce=77, floor=10)
    assert core.probe_date(probe, Probed(2.5, answer(11, 77)), SESSION) == (11, 2.5)
    assert core.probe_date(probe, Probed(2.5, answer(11, 78)), SESSION) is None, "nonce"
    assert core.probe_date(probe, Probed(2.5, answer(11, 77, 3)), SESSION) is None, "session"
    assert core.probe_date(probe, Probed(2.5, answer(10, 77)), SESSION) is None, "not beyond"
    assert core.probe_date(probe, Probed(2.5, None), SESSION) is None, "no answer"
    assert core.probe_date(probe, Probed(2.5, answer(11, 77)), None) is None, "no session"
    # Only the nonce's 13 bits travel.
    wide = Probe(nonce=77 | 1 << 13, floor=None)
    assert core.probe_date(wide, Probed(1.0, answer(5, 77)), SESSION) is None
    # Across the sequence's wrap.
    assert core.probe_date(Probe(3, MODULO - 2), Probed(1.0, answer(0, 3)), SESSION) == (0, 1.0)


def test_the_latest_probe_that_found_the_successor_unmade_dates_a_reference():
    dates = [(100, 1.0), (101, 1.05), (103, 1.1), (105, 1.15)]
    ref = core.Record(0, 1, 1, 1, EN, SESSION, 102)
    assert core.dated_at(dates, ref) == 1.1  # 103 <= 103: the device had not made 103 yet
    assert core.dated_at(dates, core.Record(0, 1, 1, 1, EN, SESSION, 99)) == 1.0
    assert core.dated_at(dates, core.Record(0, 1, 1, 1, EN, SESSION, 98)) is None
    wrapped = [(MODULO - 1, 2.0), (1, 2.1)]
    assert core.dated_at(wrapped, core.Record(0, 1, 1, 1, EN, SESSION, 0)) == 2.1


def test_a_record_is_credited_only_while_a_recent_probe_dates_its_reference():
    d = Dated()
    d.record()  # the session's first record: a baseline
    d.probe()
    probed = d.t
    d.record(3)
    assert d.x == 3, "dated: the probe found the record after the reference unmade"
    # Records every 50 ms, no probe answered (a held path): credited while the last probe is
    # at most DATE_LIMIT old, then baselines.
    while d.t + 0.05 - probed < core.DATE_LIMIT - 1e-9:
        d.record(1, dt=0.05)
    credited = d.x
    assert credited == 3 + 6  # at 0.06 .. 0.31 s after the probe
    d.record(2, dt=0.05)
    d.record(2, dt=0.05)
    assert d.x == credited and d.c.undated == 2, "undated: baselines, nothing credited"
    log = d.c.take_log()
    assert sum("not dated" in line for line in log) == 1, log
    d.probe()
    d.record(4)
    assert d.x == credited + 4, "dated again: the next detents count"


def test_a_probe_answered_after_the_reference_was_made_dates_nothing_before_it():
    """A probe whose answer shows a number beyond the reference's successor was read after
    that successor was made: it does not date the successor (its send may be later)."""
    d = Dated()
    d.record()
    d.probe()  # answered with the next number: 102
    d.record(1)  # 101 -> 102: dated (the probe found 102 unmade)
    d.t += 0.2
    stale = d.probe(answered=answer(d.next_number + 5, d.c.nonce))  # the device was ahead
    assert stale.nonce == (d.c.nonce - 1) & core.NONCE_MASK
    d.t += 0.2  # the first probe is now 0.4 s old, beyond DATE_LIMIT
    d.record(1, dt=0.0)
    assert d.x == 1, "the late probe, read after 103 was made, cannot date 103"


def test_an_undated_core_credits_without_probes_as_the_checked_rule():
    c = Core(Config(axes="xy"))
    assert not c.cfg.dating
    assert configure(c, 0.0) == SESSION
    c.set_enable(True)
    for n, pos in enumerate((0, 5, 9)):
        t = 0.01 * (n + 1)
        c.drained(t)
        c.frame(TPDO1, rec(pos, 1, 1, EN, 200 + n, 1, SESSION), t)
    assert c.counts["x"] == 9
    actions = [c.next_action(0.05)]
    assert not any(isinstance(a, Probe) for a in actions), "no probes without dating"


def test_the_component_dates_records():
    assert core.make_config(16, None, "xyz", 0.001, None, 100).dating


def test_a_probe_every_period_while_a_session_is_held():
    d = Dated()
    first = d.probe()
    assert d.c.next_action(d.t + core.PROBE_PERIOD / 2) is None
    second = d.probe(dt=core.PROBE_PERIOD)
    assert second.nonce == (first.nonce + 1) & core.NONCE_MASK
    assert second.floor is None  # no record received yet
    d.record()
    third = d.probe(dt=core.PROBE_PERIOD)
    assert third.floor == d.seq


def test_the_sequence_going_back_in_the_hosts_own_probe_drops_the_session():
    """After a power cycle whose boot-up the host missed and another master wrote the host's
    token again, the device's numbers start afresh: the host's own probe (its nonce, its
    session) shows a number behind what it received, and the session is dropped before a
    record of the new life can link to the old one."""
    d = Dated(seq=500)
    d.record()
    d.probe()
    d.record(2)
    assert d.x == 2
    action = d.c.next_action(d.t + core.PROBE_PERIOD)
    assert isinstance(action, Probe) and action.floor == d.seq
    d.c.done(action, True, None, d.t + 0.06, Probed(d.t + 0.05, answer(3, action.nonce)))
    assert d.c.session is None
    assert any("went back" in line for line in d.c.take_log())
    # A record of the new life with the old token links to nothing now.
    d.c.frame(TPDO1, rec(50, 1, 1, EN, 502, 1, SESSION), d.t + 0.07)
    assert d.x == 2


@pytest.mark.parametrize("device, wanted", [(5, 20), (10, None), (200, None), (201, 20)])
def test_the_inhibit_time_stays_within_what_dating_allows(device, wanted):
    assert core.inhibit_plan(device) == wanted


# The session key (0x2034) --------------------------------------------------------------------

ABORT_REFUSED = 0x08000022


def test_the_probe_carries_the_session_key_of_the_configuration():
    """The configuration's key (`Configure.key`, the run's drawn start) is the session's: its
    probes carry it in bits 16-31 of the value written, the nonce below; the next
    configuration has the next key, 0 never."""
    c = Core(Config(axes="xy", dating=True, first_nonce=0x1ABC, first_key=0x5EC5))
    a = c.next_action(0.0)
    assert isinstance(a, core.Configure) and a.key == 0x5EC5
    ok, result = core.configure_outcome(a, 0, c.event_timer)
    assert result.keyed
    c.done(a, ok, None, 0.0, result)
    assert (c.session, c.session_key) == (SESSION, 0x5EC5)
    probe = c.next_action(0.0)
    assert probe == Probe(nonce=0x1ABC, floor=None, own=False, key=0x5EC5)
    assert probe.value == 0x5EC5_1ABC
    assert core.SESSION_KEY_OBJECT == 0x2034 and core.SESSION_KEY_SHIFT == 16
    # Only the nonce's 13 bits go below the key.
    assert Probe(nonce=0x3FFF, key=1).value == 0x0001_1FFF
    # Keys step per configuration and wrap from 0xFFFF to 1.
    assert core.next_key(0x5EC5) == 0x5EC6 and core.next_key(0xFFFF) == 1
    assert core.next_key(0) == 1 and Core(Config(first_key=0)).key == 0xFFFF
    assert Core(Config(first_key=0xFFFF)).key == 0xFFFF


def test_an_answer_dates_only_by_the_nonce_bits_whatever_the_key():
    """The key goes out in the write; the read-back's bits 16-31 are the number. A probe of
    any key is judged by its nonce alone."""
    keyed = Probe(nonce=77, floor=10, key=0xBEEF)
    assert core.probe_date(keyed, Probed(2.5, answer(11, 77)), SESSION) == (11, 2.5)
    assert core.probe_went_back(keyed, Probed(2.5, answer(9, 77)), SESSION)


def test_a_refused_probe_drops_the_session_and_asks_for_a_configuration():
    """The device refuses the probe's key (abort 0x08000022): the session it is in is not the
    host's although its token is (another master wrote it after a power cycle the host did
    not see). The session is dropped at once, the stop reported as the session's end, the
    log says why, a configuration with another token and the next key follows at once, and
    records of the old token credit nothing."""
    d = Dated()
    d.record()
    d.probe()
    d.record(3)
    assert d.x == 3 and d.c.feed_on
    d.c.take_log()
    probe = d.c.next_action(d.t + core.PROBE_PERIOD)
    assert isinstance(probe, Probe) and probe.key == d.c.session_key == 1
    d.t += core.PROBE_PERIOD + 0.005
    d.c.done(probe, False, ABORT_REFUSED, d.t, Probed(sent_at=d.t - 0.005))
    assert d.c.session is None and d.c.session_key is None
    assert (d.c.feed_stops, d.c.stop_reason) == (1, core.STOP_SESSION_ENDED)
    log = d.c.take_log()
    assert log == [
        "feed stopped by the device: " + core.STOP_REASONS[core.STOP_SESSION_ENDED],
        "session 1 dropped (the device refused the session key: its session is not this "
        "component's (another master opened it, or a new power life)); configuring the device",
    ]
    again = d.c.next_action(d.t)
    assert isinstance(again, core.Configure) and again.keep is None
    assert again.tokens[0] == 2 and SESSION not in again.tokens and again.key == 2
    # Records of the session it dropped (its token, now another master's) move nothing.
    d.record(5)
    d.record(5)
    assert d.x == 3


def test_a_probe_that_timed_out_keeps_the_session():
    """Only the device's refusal tells: a probe without an answer (a timeout, another abort)
    changes nothing but the date it did not give (on the default channel; on the component's
    own, three in a row without an answer do: below)."""
    d = Dated()
    for abort in (None, 0x0504_0000, 0x0800_0020):
        d.probe(dt=core.PROBE_PERIOD)  # answered, then the next one fails
        probe = d.c.next_action(d.t + core.PROBE_PERIOD)
        assert isinstance(probe, Probe)
        d.t += core.PROBE_PERIOD
        d.c.done(probe, False, abort, d.t, Probed(sent_at=d.t))
        assert d.c.session == SESSION and d.c.session_key == 1, abort
    assert not any("refused" in line for line in d.c.take_log())


def test_replay_core_takes_the_vectors_probe_values_and_refusals():
    """The checker's vectors write ("probe", key << 16 | nonce, floor, t) with the model's
    own key: the core's probe matches by its nonce bits and floor; ("probe_refused", t) is
    the device's abort of the write, which drops the session."""
    cfg = Config(axes="xy", dating=True)
    model_key = 0x5EC5 << 16
    events = [
        ("configure", 0, 0.516),
        ("probe", model_key | 0, None, 0.52),
        ("probed", answer(3, 0), 0.521),
        ("probe", model_key | 1, None, 0.62),
        ("probe_refused", 0.621),
    ]
    c = core.replay_core(events, cfg)
    assert c.session is None and c.busy == {SESSION: 0.621}
    assert isinstance(c.next_action(0.621), core.Configure)
    with pytest.raises(ValueError, match="nonce 2"):
        core.replay_core(events[:3] + [("probe", model_key | 2, None, 0.62)], cfg)
    with pytest.raises(ValueError, match="no probe under way"):
        core.replay_core(events[:3] + [("probe_refused", 0.62)], cfg)


# Probes unanswered on the component's own SDO channel ------------------------------------------

OWN_SDO = core.own_sdo_ids(1)
UNANSWERED = (
    "session 1 dropped (3 probes unanswered on the component's own SDO channel (0x1201)); "
    "configuring the device"
)


def unanswered(d: Dated, abort=None) -> Probe:
    """The core's next probe, a period on, carried out without an answer (`abort` None: a
    timeout) or refused with `abort`."""
    d.t += core.PROBE_PERIOD
    probe = d.c.next_action(d.t)
    assert isinstance(probe, Probe), probe
    d.c.done(probe, False, abort, d.t + 0.3, Probed(sent_at=d.t))
    d.t += 0.3
    return probe


def jogging_on_the_own_channel() -> Dated:
    """A `Dated` core whose configuration set up the own channel, the feed on, 3 detents
    credited."""
    d = Dated(own_sdo=OWN_SDO)
    assert d.c.own_channel
    d.record()
    d.probe()
    d.record(3)
    assert d.x == 3 and d.c.feed_on
    d.c.take_log()
    return d


def test_three_probes_unanswered_on_the_own_channel_drop_the_session():
    """After a power cycle (or a reset) the host did not see, or another master's write of
    0x1201, the own channel is gone: every probe on it times out. The third in a row drops
    the session (the feed it had on stopped: the session ended), the log says why, and a
    full configuration follows at once (on the default channel; it sets 0x1201 up again),
    with another token and the next key. Records of the old token credit nothing."""
    assert core.PROBE_TIMEOUTS_BEFORE_CONFIGURING == 3
    d = jogging_on_the_own_channel()
    for n in range(2):
        probe = unanswered(d)
        assert probe.own and probe.key == d.c.session_key == 1
        assert d.c.session == SESSION and d.c.probes_unanswered == n + 1
        assert d.c.take_log() == []
    unanswered(d)
    assert d.c.session is None and d.c.session_key is None and not d.c.own_channel
    assert (d.c.feed_stops, d.c.stop_reason) == (1, core.STOP_SESSION_ENDED)
    assert d.c.take_log() == [
        "feed stopped by the device: " + core.STOP_REASONS[core.STOP_SESSION_ENDED],
        UNANSWERED,
    ]
    again = d.c.next_action(d.t)
    assert isinstance(again, core.Configure) and again.keep is None
    assert again.own_sdo == OWN_SDO and SESSION not in again.tokens and again.key == 2
    d.record(5)
    d.record(5)
    assert d.x == 3
    # The new session counts afresh.
    ok, result = core.configure_outcome(again, 0, d.c.event_timer)
    d.c.done(again, ok, None, d.t, result)
    assert d.c.session == 2 and d.c.probes_unanswered == 0 and d.c.own_channel


def test_a_channel_unanswered_in_two_sessions_in_a_row_gives_way_to_the_default_one():
    """A bus or gateway that does not carry the own channel's identifiers: the session that
    set it up again loses its probes too. After the second drop in a row the core logs why
    and configures on the default channel (no 0x1201), where its probes then count; an
    answer on the own channel in between would have reset the count."""
    assert core.OWN_CHANNEL_DROPS_BEFORE_DEFAULT == 2
    d = jogging_on_the_own_channel()
    for _ in range(3):
        unanswered(d)
    again = d.c.next_action(d.t)
    assert isinstance(again, core.Configure) and again.own_sdo == OWN_SDO
    ok, result = core.configure_outcome(again, 0, d.c.event_timer)
    d.c.done(again, ok, None, d.t, result)
    assert d.c.own_channel and d.c.own_channel_drops == 1
    d.c.take_log()
    for _ in range(3):
        unanswered(d)
    assert d.c.session is None and d.c.own_channel_drops == 2
    assert d.c.take_log()[-1] == (
        "the component's own SDO channel (0x1201) went unanswered in 2 sessions in a row: the "
        "bus or a gateway may not carry its identifiers; configuring on the default channel "
        "from now on"
    )
    third = d.c.next_action(d.t)
    assert isinstance(third, core.Configure) and third.own_sdo is None
    ok, result = core.configure_outcome(third, 0, d.c.event_timer)
    d.c.done(third, ok, None, d.t, result)
    assert d.c.session is not None and not d.c.own_channel
    d.t += core.PROBE_PERIOD
    probe = d.c.next_action(d.t)
    assert isinstance(probe, Probe) and not probe.own
    # An answer on the own channel in between resets the count.
    d = jogging_on_the_own_channel()
    for _ in range(3):
        unanswered(d)
    again = d.c.next_action(d.t)
    ok, result = core.configure_outcome(again, 0, d.c.event_timer)
    d.c.done(again, ok, None, d.t, result)
    assert d.c.own_channel_drops == 1
    d.t += core.PROBE_PERIOD
    probe = d.c.next_action(d.t)
    while isinstance(probe, WriteFeed):
        d.c.done(probe, True, None, d.t)
        probe = d.c.next_action(d.t)
    assert isinstance(probe, Probe) and probe.own
    value = answer(d.next_number, probe.nonce, d.c.session)
    d.c.done(probe, True, None, d.t, Probed(sent_at=d.t, value=value))
    assert d.c.own_channel_drops == 0


def test_two_probes_unanswered_then_an_answer_keep_the_session():
    """A successful probe ends the count: two unanswered ones, an answer, two more keep the
    session; an abort other than 0x08000022 is an answer too (the channel works)."""
    d = jogging_on_the_own_channel()
    for _ in range(2):
        unanswered(d)
    d.record()
    d.probe(dt=core.PROBE_PERIOD)
    assert d.c.probes_unanswered == 0
    for _ in range(2):
        unanswered(d)
    unanswered(d, abort=0x0504_0000)  # the device's abort: an answer
    assert d.c.probes_unanswered == 0
    for _ in range(2):
        unanswered(d)
    assert d.c.session == SESSION and d.c.session_key == 1 and d.c.feed_on
    assert d.c.feed_stops == 0
    assert not any("unanswered" in line for line in d.c.take_log())
    assert isinstance(d.c.next_action(d.t + core.PROBE_PERIOD), Probe)


def test_the_feed_already_off_is_not_reported_again():
    """A feed the device showed off before (reported then, or asked off by the component) is
    not reported stopped a second time when the session is dropped."""
    d = jogging_on_the_own_channel()
    d.c.set_enable(False)
    off = d.c.next_action(d.t)
    assert off == WriteFeed(0, True)
    d.c.done(off, True, None, d.t)
    for _ in range(3):
        unanswered(d)
    assert d.c.session is None and d.c.feed_stops == 0
    assert d.c.take_log() == [UNANSWERED]


def test_unanswered_probes_keep_the_session_on_the_default_channel_or_a_stopped_device():
    """On the default channel an unanswered probe keeps the session, as before (that channel
    does not go away). Nor do probes count while the device shows itself Stopped: it answers
    no SDO then, on any channel, and a configuration would fail too."""
    d = Dated()
    d.record()
    d.probe()
    for _ in range(5):
        assert not unanswered(d).own
    assert d.c.session == SESSION and d.c.probes_unanswered == 0
    d = jogging_on_the_own_channel()
    d.c.frame(0x700 + d.c.cfg.node, bytes([core.STOPPED]), d.t)
    for _ in range(5):
        unanswered(d)
    assert d.c.session == SESSION and d.c.probes_unanswered == 0
    d.c.frame(0x700 + d.c.cfg.node, bytes([core.OPERATIONAL]), d.t)
    for _ in range(3):
        unanswered(d)
    assert d.c.session is None


def test_an_unanswered_probe_of_a_session_already_dropped_counts_for_nothing():
    """A probe under way when the session was dropped (a boot-up) neither drops anything
    nor logs, nor counts against the next session."""
    d = jogging_on_the_own_channel()
    for _ in range(2):
        unanswered(d)
    d.t += core.PROBE_PERIOD
    stale = d.c.next_action(d.t)
    assert isinstance(stale, Probe)
    d.c.frame(0x700 + d.c.cfg.node, bytes([core.BOOTUP]), d.t)  # drops the session
    assert d.c.session is None
    d.c.take_log()
    d.c.done(stale, False, None, d.t + 0.3, Probed(sent_at=d.t))
    assert d.c.probes_unanswered == 0 and d.c.take_log() == []
