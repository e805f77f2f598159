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

    def __init__(self, seq: int = 100) -> None:
        self.t = 0.0
        self.c = Core(Config(axes="xy", dating=True, first_nonce=5))
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
