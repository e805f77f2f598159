"""The component's decisions, case by case (no bus, no HAL)."""

import pytest

from canopen_handwheel import core
from canopen_handwheel.core import Config, Configure, Configured, Core, WriteFeed
from records import EMCY, EN, HB, ML, TPDO1, rec

T = 0.1  # event timer


def result(action: Configure, event_timer_ms=100, first_reply_at=None) -> Configured:
    """What a configuration that wrote the first token `action` offers (and its key)
    reports."""
    token = core.pick_token(action.tokens, 0)
    return Configured(
        event_timer_ms, first_reply_at, found=0, tried=token, session=token, keyed=True
    )


class Run:
    """A core with a clock, configured (its session in every record) unless told not to be;
    records get consecutive sequence numbers unless given, and the epoch steps as a
    device's does (from 1) on a change of axis, multiplier, enable or master lost, unless
    given."""

    def __init__(self, axes="xyzwv", configured=True, **kw):
        self.c = Core(Config(axes=axes, **kw))
        self.t = 0.0
        self.seq = 0
        self.epoch = 1
        self.sel = None
        if configured:
            self.configure()

    def at(self, dt=0.0):
        self.t += dt
        return self.t

    def record(self, position, axis=1, mult=1, flags=EN, seq=None, dt=0.01, epoch=None):
        if seq is None:
            self.seq = (self.seq + 1) % core.SEQUENCE_MODULO
            seq = self.seq
        sel = (axis, mult, flags & (EN | ML))
        if epoch is None:
            if self.sel is not None and sel != self.sel:
                self.epoch += 1
            epoch = self.epoch
        self.sel = sel
        session = self.c.session or 0
        self.frame(TPDO1, rec(position, axis, mult, flags, seq, epoch, session), dt)

    def frame(self, cob_id, data, dt=0.01, drained=True):
        """A frame handled at once (`drained`: the shell found its receive path empty just
        before), or late."""
        t = self.at(dt)
        if drained:
            self.c.drained(t)
        self.c.frame(cob_id, data, t)

    def hb(self, state, dt=0.01):
        self.frame(HB, bytes([state]), dt)

    def counts(self):
        return self.c.pins().jog_counts

    def bad(self):
        return self.c.pins().frames_bad

    def configure(self, event_timer_ms=100):
        a = self.c.next_action(self.at())
        assert isinstance(a, Configure)
        self.c.done(a, True, None, self.at(), result(a, event_timer_ms))


def test_first_record_is_a_baseline_then_deltas_go_to_the_named_axis():
    r = Run()
    r.record(1000)
    assert r.counts()["x"] == 0
    r.record(1003)
    r.record(1001)
    assert r.counts() == {"x": 1, "y": 0, "z": 0, "w": 0, "v": 0}
    r.record(1001, axis=2)  # the next epoch, directly after the last of X's
    r.record(1011, axis=2)
    assert r.counts()["y"] == 10 and r.counts()["x"] == 1
    assert r.bad() == 0


def test_position_wraps_and_counts_wrap():
    r = Run()
    r.record(2**31 - 2)
    r.record(-(2**31) + 3)  # +5 across the wrap
    assert r.counts()["x"] == 5
    r.c.counts["x"] = 2**31 - 1
    r.record(-(2**31) + 4)
    assert r.counts()["x"] == -(2**31)


@pytest.mark.parametrize("change", ["axis", "mult", "enable"])
def test_a_selection_change_within_an_epoch_is_impossible(change):
    """The device steps the epoch on each of these; the same epoch bits with another
    selection are a record it cannot send: counted, no motion, and it is the baseline."""
    r = Run()
    r.record(0)
    r.record(5)
    axis, mult, status = 1, 1, EN
    if change == "axis":
        axis = 3
    elif change == "mult":
        mult = 10
    else:
        status = 0
    r.record(500, axis=axis, mult=mult, flags=status, epoch=1)
    assert r.counts()["x"] == 5 and sum(r.counts().values()) == 5
    assert r.bad() == 1
    r.record(600, axis=axis, mult=mult, flags=status, epoch=1)  # continues the new baseline
    expected = 0 if change == "enable" else 100
    assert r.bad() == (2 if change == "enable" else 1)  # disabled and moved: impossible
    assert sum(r.counts().values()) == 5 + expected


def test_the_next_epoch_directly_after_carries_its_own_motion():
    """prev is the last record of its epoch (nothing between them in sequence): the
    difference is what was turned in the new epoch, on the new axis."""
    r = Run()
    r.record(0)
    r.record(30)
    r.record(37, axis=2)  # Y selected and turned 7 before its first record went out
    r.record(39, axis=1)  # X again, turned 2
    assert r.counts() == {"x": 32, "y": 7, "z": 0, "w": 0, "v": 0}
    r.record(39, mult=10)  # x10: new epoch, no motion yet
    r.record(59, mult=10)
    assert r.counts()["x"] == 52 and r.bad() == 0


@pytest.mark.parametrize(
    "epoch_step,gap,continues",
    [
        (0, 0, True),
        (0, 6, True),  # 6 records lost hide at most 6 epochs: not 8
        (0, 7, False),  # 7 could hide 8 epoch steps: the bits would read the same
        (0, 126, False),  # the largest step still ahead (127..254: behind, 255: the same)
        (1, 0, True),
        (1, 1, False),  # prev may not be the last record of its epoch
        (2, 0, False),
        (2, 1, False),  # the epoch between may have moved another axis
        (7, 0, False),
    ],
)
def test_which_sequence_gaps_and_epoch_steps_continue(epoch_step, gap, continues):
    r = Run()
    r.record(100, seq=10, epoch=3)
    r.record(104, seq=11 + gap, epoch=3 + epoch_step)
    assert r.counts()["x"] == (4 if continues else 0)
    assert r.bad() == 0
    assert r.c.pins().records_lost == gap


def test_disabled_records_move_nothing():
    r = Run()
    r.record(0, flags=0)
    r.record(0, flags=0)
    assert r.counts()["x"] == 0 and r.bad() == 0
    r.record(7, flags=0)  # moved while disabled, same epoch: impossible
    assert r.counts()["x"] == 0 and r.bad() == 1
    r.record(7)  # enable rises: next epoch
    r.record(9)
    assert r.counts()["x"] == 2
    r.record(20, flags=0)  # disabled, next epoch, moved: impossible
    assert r.counts()["x"] == 2 and r.bad() == 2


def test_no_axis_moves_nothing():
    r = Run()
    r.record(0, axis=0)
    r.record(0, axis=0)
    r.record(4, axis=0)
    assert sum(r.counts().values()) == 0 and r.bad() == 1


def test_motion_not_a_multiple_of_the_multiplier_is_impossible():
    r = Run()
    r.record(0, mult=100)
    r.record(300, mult=100)
    r.record(350, mult=100)
    assert r.counts()["x"] == 300 and r.bad() == 1
    r.record(450, mult=100)  # from the baseline at 350
    assert r.counts()["x"] == 400


def test_status_bits_that_are_no_epoch_keep_the_deltas():
    r = Run()
    r.record(0)
    r.record(4, flags=EN | core.STATUS_ENCODER_ERROR | core.STATUS_IGNORED_MOTION)
    r.record(5, flags=EN | core.STATUS_STEPS_DROPPED)
    assert r.counts()["x"] == 5
    assert not r.c.pins().encoder_error
    r.record(5, flags=EN | core.STATUS_ENCODER_ERROR)
    assert r.c.pins().encoder_error


@pytest.mark.parametrize(
    "data",
    [
        rec(5, axis=6, epoch=1),
        rec(5, axis=7, epoch=1),
        rec(5, mult=0, epoch=1),  # multiplier code 3
        rec(5, flags=EN | ML, epoch=1),
        rec(5, epoch=1)[:7],
        rec(5, epoch=1) + b"\x00",
        b"",
    ],
)
def test_an_impossible_record_is_counted_and_breaks_continuity(data):
    """What the device can never send moves nothing, and the record after it is a
    baseline (a wrong-length one too, as the README says)."""
    r = Run()
    r.c.set_enable(True)
    r.record(0)
    r.record(2)
    r.c.frame(TPDO1, data, r.at(0.01))
    p = r.c.pins()
    assert p.frames_bad == 1 and r.counts()["x"] == 2
    assert p.axis == 0 and not any(p.select.values()) and not any(p.jog_enable.values())
    assert p.position == 2  # the last possible record
    r.seq += 1  # as if it had been the device's
    r.record(9)  # baseline
    r.record(10)
    assert r.counts()["x"] == 3 and r.c.pins().frames_bad == 1
    assert r.c.pins().select["x"]


def test_impossible_records_alone_do_not_keep_the_connection():
    r = Run()
    r.record(0)
    for _ in range(10):
        r.c.frame(TPDO1, rec(5, axis=7, epoch=1), r.at(0.1))
    assert not r.c.pins().connected and r.bad() == 10


def test_motion_faster_than_a_wheel_is_refused():
    """One record 1.1e9 units on (the issue's foreign transmitter): counted, no motion,
    and it is the baseline."""
    r = Run()
    r.record(0)
    r.record(10)
    r.record(1_100_000_010)
    assert r.counts()["x"] == 10 and r.bad() == 1
    r.record(1_100_000_011)
    assert r.counts()["x"] == 11
    r.record(10)  # back down the same jump: refused too
    assert r.counts()["x"] == 11 and r.bad() == 2


def test_the_rate_bound_is_a_bucket_of_detents():
    """Default 2000 detents/s, 0.5 s horizon (the consumer timeout): 1000 detents at once
    after a rest, then only what refills; detents, not units (x100 moves 100 units each)."""
    r = Run()
    r.record(0, mult=100)
    r.record(100_000, mult=100, dt=0.0001)  # 1000 detents: the whole bucket
    assert r.counts()["x"] == 100_000 and r.bad() == 0
    r.record(100_100, mult=100, dt=0.0001)  # 0.2 detents refilled: 1 is too many
    assert r.counts()["x"] == 100_000 and r.bad() == 1
    r.record(120_100, mult=100, dt=0.1)  # 200 refilled in 0.1 s
    assert r.counts()["x"] == 120_000 and r.bad() == 1


def test_a_burst_after_an_outage_passes():
    """After an outage the queued records arrive 150 us apart, each covering turning of
    its own time: at 1500 detents/s for 0.3 s, all of it is applied."""
    r = Run()
    r.record(0)
    r.record(0)
    pos = 0
    for _ in range(15):  # 20 ms each at 1500 detents/s
        pos += 30
        r.record(pos, dt=0.00015 if pos > 30 else 0.29)
    assert r.counts()["x"] == 450 and r.bad() == 0


def test_max_detents_per_s_is_the_option():
    r = Run(max_detents_per_s=100, consumer_timeout_ms=500, event_timer=0.1)
    r.record(0)
    r.record(50, dt=0.0001)  # cap: 100 x 0.5
    r.record(51, dt=0.0001)
    assert r.counts()["x"] == 50 and r.bad() == 1


def test_bucket_refill_and_cap():
    a = core.Allowance(rate=10.0, cap=5.0)
    assert a.take(5, 0.0) and not a.take(1, 0.0)
    assert not a.take(2, 0.1) and a.take(1, 0.1)  # 1 refilled; a refusal spends nothing
    assert a.take(5, 100.0) and not a.take(1, 100.0)  # never more than the cap


def test_a_device_that_shows_no_epoch_moves_nothing():
    """Firmware from before the epoch bits: all 0, so every record looks like one epoch and
    a hidden switch to another axis would look like motion of the old one."""
    r = Run()
    r.record(0, flags=0, epoch=0)
    r.record(0, epoch=0)  # enable without an epoch step: impossible
    assert r.bad() == 1
    for pos in (10, 20, 30):
        r.record(pos, epoch=0)
    assert sum(r.counts().values()) == 0
    r.record(31, epoch=1)  # a non-zero epoch shows the device keeps the contract
    r.record(35, epoch=1)
    assert r.counts()["x"] == 5


def test_the_epoch_must_show_again_after_a_boot_up():
    r = Run()
    r.record(0, epoch=1)
    r.record(5, epoch=1)
    assert r.counts()["x"] == 5
    r.hb(core.BOOTUP)
    r.configure()
    # A reset keeps the sequence going, with a break of 8.
    r.record(0, seq=10, epoch=0)
    r.record(3, seq=11, epoch=0)
    assert r.counts()["x"] == 5
    r.record(3, seq=12, epoch=1)
    r.record(4, seq=13, epoch=1)
    assert r.counts()["x"] == 6


def test_bootup_makes_the_next_record_a_baseline_and_asks_for_configuration():
    """After a boot-up the records of the old session are another session's (the device
    has none): nothing moves until the configuration wrote a new token, and the first
    record of that session is a baseline."""
    r = Run()
    r.record(100)
    r.record(110)
    r.hb(core.BOOTUP)
    assert r.c.session is None
    r.record(0, seq=9, epoch=1)  # before the configuration: session 0
    a = r.c.next_action(r.at())
    assert isinstance(a, Configure) and a.keep is None and 1 not in a.tokens
    r.c.done(a, True, None, r.at(), result(a))
    assert r.c.session == 2
    r.record(0, seq=10)  # a reset keeps the sequence going, with a break of 8
    r.record(3, seq=11)
    assert r.counts()["x"] == 13
    assert r.c.pins().records_lost == 0


def test_after_a_power_cycle_the_first_records_of_the_new_session_move_at_once():
    """A power cycle restarts the sequence at 0, below the last record before it: in the
    new session that is no copy, so the second record after the configuration moves (it
    cost 2 s of dead wheel when the reference outlived the boot-up)."""
    r = Run()
    for p in range(6):
        r.record(p, seq=100 + p)
    assert r.counts()["x"] == 5
    r.hb(core.BOOTUP)
    r.configure()
    r.record(0, seq=8)
    r.record(2, seq=9)
    assert r.counts()["x"] == 7 and r.bad() == 0


def test_stale_records_drop_everything_and_the_next_is_a_baseline():
    r = Run()
    r.c.set_enable(True)
    r.record(0)
    r.record(1)
    p = r.c.pins()
    assert p.connected and p.jog_enable["x"] and p.select["x"]
    r.c.tick(r.at(3 * T - 0.02))
    assert r.c.pins().connected
    r.c.tick(r.at(0.03))
    p = r.c.pins()
    assert not p.connected and not any(p.jog_enable.values()) and not any(p.select.values())
    assert not p.feed_enabled
    r.record(50)  # back, moved meanwhile: baseline
    r.record(52)
    assert r.counts()["x"] == 3
    assert r.c.pins().connected


def test_jog_enable_needs_everything():
    r = Run(axes="xyz")
    r.record(0, axis=2)
    assert not any(r.c.pins().jog_enable.values())  # enable pin false
    r.c.set_enable(True)
    assert r.c.pins().jog_enable == {"x": False, "y": True, "z": False}
    r.hb(core.STOPPED)
    assert not any(r.c.pins().jog_enable.values())
    r.hb(core.OPERATIONAL)
    assert r.c.pins().jog_enable["y"]
    r.hb(core.PRE_OPERATIONAL)  # the session is dropped: configured again, then records
    assert not any(r.c.pins().jog_enable.values())
    r.configure()
    r.hb(core.OPERATIONAL)
    assert not any(r.c.pins().jog_enable.values())
    r.record(0, axis=2)
    assert r.c.pins().jog_enable["y"]
    r.record(0, axis=2, flags=0)
    assert not any(r.c.pins().jog_enable.values())
    r.record(0, axis=4)  # W: not configured with --axes xyz
    p = r.c.pins()
    assert not any(p.jog_enable.values()) and not any(p.select.values()) and p.axis == 4
    r.record(0, axis=0)
    assert not any(r.c.pins().jog_enable.values())


def test_unconfigured_axis_counts_nowhere():
    r = Run(axes="xz")
    r.record(0, axis=3)
    r.record(9, axis=3)
    assert r.counts() == {"x": 0, "z": 0}
    r.record(9, axis=2)
    r.record(12, axis=2)
    assert r.counts() == {"x": 0, "z": 3}


@pytest.mark.parametrize(
    "cob,data",
    [
        (TPDO1, b"\x00" * 7),
        (TPDO1, b"\x00" * 9),
        (TPDO1, b""),
        (EMCY, b"\x30\x81"),
        (HB, b""),
        (HB, b"\x05\x00"),
    ],
)
def test_wrong_dlc_is_counted_and_ignored(cob, data):
    r = Run()
    r.record(0)
    before = r.c.pins()
    r.c.frame(cob, data, r.at(0.01))
    after = r.c.pins()
    assert after.frames_bad == 1
    assert (after.position, after.emcy_code, after.state) == (
        before.position,
        before.emcy_code,
        before.state,
    )


def test_other_nodes_frames_are_ignored():
    r = Run()
    r.c.frame(0x180 + 17, b"\x01" * 3, r.at())
    r.c.frame(0x701, b"\x00", r.at())
    assert r.c.pins().frames_bad == 0 and r.c.state is None


def test_emcy_code_and_its_reset():
    r = Run()
    r.c.frame(EMCY, bytes.fromhex("3081110100000000"), r.at())
    assert r.c.pins().emcy_code == 0x8130
    r.c.frame(EMCY, bytes(8), r.at())
    assert r.c.pins().emcy_code == 0


def test_records_lost_from_sequence_gaps():
    r = Run()
    r.record(0, seq=65530)
    r.record(0, seq=65531)
    r.record(0, seq=65535)  # 3 lost
    r.record(0, seq=2)  # 2 lost across the wrap
    assert r.c.pins().records_lost == 5
    r.c.tick(r.at(1.0))  # stale: the gap to the next record is unknown, not counted
    r.record(0, seq=100)
    assert r.c.pins().records_lost == 5


def test_configure_first_retried_while_it_fails():
    r = Run(configured=False)
    a = r.c.next_action(r.at())
    assert a == Configure(
        master=1,
        timeout_ms=500,
        event_timer_ms=None,
        tokens=core.TOKENS,
        settings=((0x2020, 3, 4), (0x2020, 4, 0), (0x2001, 0, 0)),
    )
    assert r.c.next_action(r.at()) is None  # one at a time
    r.c.done(a, False, None, r.at())
    assert r.c.next_action(r.at(0.1)) is None
    assert isinstance(r.c.next_action(r.at(0.5)), Configure)


def test_feed_enable_follows_the_pin():
    r = Run()
    r.record(0, flags=0)
    assert r.c.next_action(r.at()) is None  # enable false, feed off: nothing to do
    r.c.set_enable(True)
    a = r.c.next_action(r.at())
    assert a == WriteFeed(1)
    r.c.done(a, True, None, r.at())
    assert r.c.next_action(r.at(0.1)) is None  # waits for the records to show it
    r.record(0, flags=EN)
    assert r.c.next_action(r.at()) is None
    r.c.set_enable(False)
    assert not r.c.pins().jog_enable["x"]  # at once, before the device knows
    r.record(0, flags=EN, dt=0.1)
    r.record(0, flags=EN, dt=0.1)
    a = r.c.next_action(r.at())
    assert a == WriteFeed(0)
    r.c.done(a, True, None, r.at())
    for _ in range(10):
        r.record(0, flags=0, dt=0.1)
        assert r.c.next_action(r.at()) is None


def test_refused_feed_enable_is_retried():
    r = Run()
    r.c.set_enable(True)
    r.record(0, flags=core.STATUS_MASTER_LOST)
    a = r.c.next_action(r.at())
    r.c.done(a, False, core.ABORT_DEVICE_STATE, r.at())
    r.record(0, flags=core.STATUS_MASTER_LOST, dt=0.1)
    assert r.c.next_action(r.at()) is None
    for _ in range(4):
        r.record(0, flags=core.STATUS_MASTER_LOST, dt=0.1)
    assert r.c.next_action(r.at()) == WriteFeed(1)


def test_no_feed_enable_while_unconfigured_stale_or_not_operational():
    r = Run(configured=False)
    r.c.set_enable(True)
    r.record(0, flags=0)
    a = r.c.next_action(r.at())
    assert isinstance(a, Configure)  # configuration comes first
    r.c.done(a, True, None, r.at(), result(a))
    r.hb(core.STOPPED)
    assert r.c.next_action(r.at()) is None
    r.hb(core.OPERATIONAL)
    r.c.tick(r.at(1.0))
    assert r.c.next_action(r.at()) is None  # no records: stale


def test_preoperational_device_is_configured_and_started_again():
    r = Run()
    r.hb(core.PRE_OPERATIONAL)
    assert isinstance(r.c.next_action(r.at()), Configure)


def test_shutdown_disables_the_feed_whatever_was_seen():
    """Before any record, with the feed on, off, stale, or a write of 1 unconfirmed."""
    r = Run()
    assert r.c.shutdown_action() == WriteFeed(0)
    r.record(0, flags=EN)
    assert r.c.shutdown_action() == WriteFeed(0)
    r.record(0, flags=0)
    assert r.c.shutdown_action() == WriteFeed(0)
    r.c.set_enable(True)
    assert r.c.next_action(r.at()) == WriteFeed(1)  # pending, the record not seen yet
    assert r.c.shutdown_action() == WriteFeed(0)
    r.c.tick(r.at(5.0))
    assert r.c.shutdown_action() == WriteFeed(0)


def test_event_timer_plan():
    """Keep the device's own unless the option says otherwise; never leave it at 0."""
    assert core.event_timer_plan(100, None) is None
    assert core.event_timer_plan(250, None) is None
    assert core.event_timer_plan(0, None) == 100
    assert core.event_timer_plan(100, 100) is None
    assert core.event_timer_plan(100, 40) == 40
    assert core.event_timer_plan(0, 40) == 40
    # At most 1 s: three silent periods stay within the order window (no session renewed
    # for a device at rest); a device with a longer one or too short a one gets 100 ms.
    assert 3 * core.EVENT_TIMER_MS_RANGE[1] / 1000 < core.ORDER_WINDOW
    assert core.event_timer_plan(1000, None) is None
    assert core.event_timer_plan(1001, None) == 100
    assert core.event_timer_plan(9, None) == 100


def test_staleness_follows_the_devices_event_timer():
    """Assumed 100 ms until configured; then what the device reported (here 250 ms):
    connected for up to 750 ms without a record, not longer."""
    r = Run(configured=False)
    assert r.c.stale_after == pytest.approx(0.3)  # the assumed 100 ms
    r.configure(event_timer_ms=250)
    assert r.c.event_timer == pytest.approx(0.25) and r.c.stale_after == pytest.approx(0.75)
    r.record(0)
    r.c.tick(r.at(0.74))
    assert r.c.pins().connected
    r.c.tick(r.at(0.02))
    assert not r.c.pins().connected


def test_the_option_asks_for_the_event_timer_and_the_bucket_follows_it():
    cfg = core.make_config(16, None, "xyz", 0.001, 1000, 100, max_detents_per_s=100)
    assert cfg.event_timer_ms == 1000 and cfg.stale_after == pytest.approx(3.0)
    r = Run(event_timer_ms=1000, max_detents_per_s=100, configured=False)
    assert r.c.next_action(r.at()) == Configure(
        1, 500, 1000, tokens=core.TOKENS, settings=core.motion_settings(r.c.cfg)
    )
    r.c.pending = None
    r.configure(event_timer_ms=20)  # what the device reports back rules
    assert r.c.stale_after == pytest.approx(0.06)
    assert r.c.allowance.cap == pytest.approx(100 * 0.5)  # the consumer timeout is longer


@pytest.mark.parametrize("timer", [None, 0, 9, 1001])
def test_a_configuration_without_a_usable_event_timer_failed(timer):
    r = Run(configured=False)
    a = r.c.next_action(r.at())
    r.c.done(a, True, None, r.at(), result(a, timer))
    assert not r.c.configured
    assert r.c.next_action(r.at(0.1)) is None
    assert isinstance(r.c.next_action(r.at(0.5)), Configure)


def test_velocity_mode_unless_position_mode():
    r = Run(axes="xy")
    assert r.c.pins().jog_vel_mode
    r.c.set_position_mode(True)
    assert not r.c.pins().jog_vel_mode
    assert not Core(Config(position_mode=True)).pins().jog_vel_mode


def test_a_change_of_mode_never_moves_counts():
    """Mode changes between, before and after records: the counts are those without them."""
    plain, switched = Run(), Run()
    for i, pos in enumerate([0, 3, 3, 10, 110, 111]):
        plain.record(pos)
        switched.c.set_position_mode(i % 2 == 0)
        switched.record(pos)
        switched.c.set_position_mode(i % 3 == 0)
        assert switched.counts() == plain.counts()
    assert plain.counts()["x"] == 111


def test_the_heartbeat_pauses_while_the_loop_stalls():
    assert core.beat_allowed(10.0, 10.25, 0.1)
    assert not core.beat_allowed(10.0, 10.26, 0.1)
    assert core.beat_allowed(10.0, 11.9, 1.0)  # two periods of a slow heartbeat
    assert not core.beat_allowed(10.0, 12.1, 1.0)


def test_next_beat_keeps_the_grid_and_skips_what_it_missed():
    assert core.next_beat(1.0, 1.0, 0.1) == pytest.approx(1.1)
    assert core.next_beat(1.0, 1.004, 0.1) == pytest.approx(1.1)  # sending took 4 ms
    assert core.next_beat(1.0, 1.25, 0.1) == pytest.approx(1.3)  # 2 beats missed, no burst
    assert core.next_beat(1.0, 0.9, 0.1) == pytest.approx(1.1)  # sent early: still the grid
    with pytest.raises(ValueError):
        core.next_beat(1.0, 1.0, 0.0)


def test_consumer_plan():
    assert core.consumer_plan({1: 0, 2: 0}, 1, 500) == (1, 0x0001_01F4)
    assert core.consumer_plan({1: 0x0005_0100, 2: 0}, 1, 500) == (2, 0x0001_01F4)
    assert core.consumer_plan({1: 0x0005_0100, 2: 0x0001_0064}, 1, 500) == (2, 0x0001_01F4)
    assert core.consumer_plan({1: 0x0005_0100, 2: 0x0006_0100}, 1, 500) == (1, 0x0001_01F4)
    assert core.consumer_plan({}, 3, 200) == (1, 0x0003_00C8)


def test_options():
    assert core.parse_axes("XYZ") == "xyz"
    for bad in ["", "xx", "xyzwva", "xq"]:
        with pytest.raises(ValueError):
            core.parse_axes(bad)
    assert core.resolve_master(16, None) == 1
    assert core.resolve_master(1, None) == 2
    assert core.resolve_master(16, 100) == 100
    for node, master in [(16, 16), (16, 0), (16, 128), (0, None), (128, None)]:
        with pytest.raises(ValueError):
            core.resolve_master(node, master)


def test_make_config_checks_every_option():
    cfg = core.make_config(16, None, "XZ", -0.01, 100, 200)
    assert (cfg.master, cfg.axes, cfg.scale) == (1, "xz", -0.01)
    assert (cfg.heartbeat_period, cfg.consumer_timeout_ms) == (0.2, 1000)
    assert cfg.stale_after == pytest.approx(0.3)
    assert cfg.max_detents_per_s == 2000 and cfg.rate_horizon == pytest.approx(1.0)
    cfg = core.make_config(16, None, "x", 0.001, 1000, 10, max_detents_per_s=500)
    assert cfg.max_detents_per_s == 500 and cfg.rate_horizon == pytest.approx(3.0)
    assert cfg.event_timer_ms == 1000 and not cfg.position_mode
    cfg = core.make_config(16, None, "x", 0.001, None, 100, position_mode=True)
    assert cfg.event_timer_ms is None and cfg.event_timer == pytest.approx(0.1)
    assert cfg.position_mode
    for kwargs in [
        dict(scale=0.0),
        dict(scale=float("nan")),
        dict(scale=float("-inf")),
        dict(heartbeat_ms=9),
        dict(heartbeat_ms=10001),
        dict(event_timer_ms=9),
        dict(event_timer_ms=60001),
        dict(axes="xx"),
        dict(master=16),
        dict(max_detents_per_s=9),
        dict(max_detents_per_s=100_001),
    ]:
        args = dict(
            node=16, master=None, axes="xyz", scale=0.001, event_timer_ms=100, heartbeat_ms=100
        )
        args.update(kwargs)
        with pytest.raises(ValueError):
            core.make_config(**args)


def test_pin_table():
    names = [n for n, _, _ in core.pin_table("xz")]
    assert "axis.x.jog-counts" in names and "halui.axis.z.select" in names
    assert "axis.y.jog-counts" not in names
    assert len(names) == len(set(names)) == 2 * 5 + 18 + 1 + core.OUT_PINS + 2


def test_a_boot_up_during_a_configuration_it_then_answered_configures_once():
    """The component starts with the device still booting: its boot-up comes while the first
    configuration waits for an answer. If every answer came after the boot-up, that
    configuration stands (no second one); if the first came before, it is done again at
    once."""
    r = Run(configured=False)
    a = r.c.next_action(r.at())
    r.hb(core.BOOTUP)
    booted = r.t
    assert r.c.next_action(r.at()) is None  # one configuration at a time
    r.c.done(a, True, None, r.at(0.02), result(a, first_reply_at=booted + 0.001))
    assert r.c.configured and r.c.next_action(r.at()) is None
    r = Run(configured=False)
    a = r.c.next_action(r.at())
    first = r.at(0.005)
    r.hb(core.BOOTUP)
    r.c.done(a, True, None, r.at(0.02), result(a, first_reply_at=first))
    assert not r.c.configured and isinstance(r.c.next_action(r.at()), Configure)
    r = Run(configured=False)
    a = r.c.next_action(r.at())
    r.hb(core.BOOTUP)
    r.c.done(a, True, None, r.at(0.02), result(a))  # no time: not known to be after
    assert not r.c.configured and isinstance(r.c.next_action(r.at()), Configure)


def test_a_configuration_that_fails_while_the_device_boots_is_asked_again_at_once():
    """A reset cuts a configuration short (an answer lost, a read-back of the reset value):
    with its boot-up seen while it ran, the failure is the reset's, and the next
    configuration is asked for at once, not after the retry time; a failure without a
    boot-up waits for it."""
    r = Run(configured=False)
    a = r.c.next_action(r.at())
    r.hb(core.BOOTUP)
    r.c.done(a, False, None, r.at(0.02), Configured(found=0, first_reply_at=r.t - 0.01))
    assert isinstance(r.c.next_action(r.at()), Configure)
    r = Run(configured=False)
    a = r.c.next_action(r.at())
    r.c.done(a, False, None, r.at(0.02), Configured(found=0))
    assert r.c.next_action(r.at()) is None
    assert isinstance(r.c.next_action(r.at(r.c.cfg.retry)), Configure)
