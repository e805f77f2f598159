"""The component's decisions, case by case (no bus, no HAL)."""

import pytest

from canopen_handwheel import core
from canopen_handwheel.core import Config, Configure, Core, WriteFeed

NODE = 16
TPDO1, EMCY, HB = 0x180 + NODE, 0x080 + NODE, 0x700 + NODE
EN = core.STATUS_ENABLED
T = 0.1  # event timer


def rec(position, axis=1, mult=1, status=EN, seq=0) -> bytes:
    return (position & 0xFFFFFFFF).to_bytes(4, "little") + bytes([axis, mult, status, seq & 0xFF])


class Run:
    """A core with a clock; records get consecutive sequence numbers unless given."""

    def __init__(self, axes="xyzwv", **kw):
        self.c = Core(Config(axes=axes, **kw))
        self.t = 0.0
        self.seq = 0

    def at(self, dt=0.0):
        self.t += dt
        return self.t

    def record(self, position, axis=1, mult=1, status=EN, seq=None, dt=0.01):
        if seq is None:
            self.seq = (self.seq + 1) & 0xFF
            seq = self.seq
        self.c.frame(TPDO1, rec(position, axis, mult, status, seq), self.at(dt))

    def hb(self, state, dt=0.01):
        self.c.frame(HB, bytes([state]), self.at(dt))

    def counts(self):
        return self.c.pins().jog_counts

    def configure(self):
        a = self.c.next_action(self.at())
        assert isinstance(a, Configure)
        self.c.done(a, True, None, self.at())


def test_first_record_is_a_baseline_then_deltas_go_to_the_named_axis():
    r = Run()
    r.record(1000)
    assert r.counts()["x"] == 0
    r.record(1003)
    r.record(1001)
    assert r.counts() == {"x": 1, "y": 0, "z": 0, "w": 0, "v": 0}
    r.record(1001, axis=2)  # axis change: baseline
    r.record(1011, axis=2)
    assert r.counts()["y"] == 10 and r.counts()["x"] == 1


def test_position_wraps_and_counts_wrap():
    r = Run()
    r.record(2**31 - 2)
    r.record(-(2**31) + 3)  # +5 across the wrap
    assert r.counts()["x"] == 5
    r.c.counts["x"] = 2**31 - 1
    r.record(-(2**31) + 4)
    assert r.counts()["x"] == -(2**31)


@pytest.mark.parametrize("change", ["axis", "mult", "enable", "master_lost"])
def test_a_new_selection_epoch_is_a_baseline(change):
    r = Run()
    r.record(0)
    r.record(5)
    axis, mult, status = 1, 1, EN
    if change == "axis":
        axis = 3
    elif change == "mult":
        mult = 10
    elif change == "enable":
        status = 0
    else:
        status = EN | core.STATUS_MASTER_LOST
    r.record(500, axis=axis, mult=mult, status=status)
    assert sum(r.counts().values()) == 5


def test_disabled_records_move_nothing():
    r = Run()
    r.record(0, status=0)
    r.record(7, status=0)
    assert r.counts()["x"] == 0
    r.record(7)  # enable rises: baseline
    r.record(9)
    assert r.counts()["x"] == 2


def test_status_bits_that_are_no_epoch_keep_the_deltas():
    r = Run()
    r.record(0)
    r.record(4, status=EN | core.STATUS_ENCODER_ERROR | core.STATUS_TURNED_UNSEEN)
    assert r.counts()["x"] == 4
    assert r.c.pins().encoder_error


def test_bootup_makes_the_next_record_a_baseline_and_asks_for_configuration():
    r = Run()
    r.configure()
    r.record(100)
    r.record(110)
    r.hb(core.BOOTUP)
    assert isinstance(r.c.next_action(r.at()), Configure)
    r.record(0, seq=1)  # the reset device starts at 0
    r.record(3, seq=2)
    assert r.counts()["x"] == 13
    assert r.c.pins().records_lost == 0


def test_stale_records_drop_everything_and_the_next_is_a_baseline():
    r = Run()
    r.configure()
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
    r.hb(core.PRE_OPERATIONAL)
    assert not any(r.c.pins().jog_enable.values())
    r.hb(core.OPERATIONAL)
    assert r.c.pins().jog_enable["y"]
    r.record(0, axis=2, status=0)
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


def test_unknown_axis_byte_is_bad_no_axis_and_a_baseline():
    r = Run()
    r.c.set_enable(True)
    r.record(0)
    r.record(5, axis=9)
    p = r.c.pins()
    assert p.frames_bad == 1 and p.axis == 0 and not any(p.jog_enable.values())
    assert r.counts()["x"] == 0
    r.record(8)  # baseline after the bad one
    r.record(9)
    assert r.counts()["x"] == 1


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
    r.record(0, seq=250)
    r.record(0, seq=251)
    r.record(0, seq=255)  # 3 lost
    r.record(0, seq=2)  # 2 lost across the wrap
    assert r.c.pins().records_lost == 5
    r.c.tick(r.at(1.0))  # stale: the gap to the next record is unknown, not counted
    r.record(0, seq=100)
    assert r.c.pins().records_lost == 5


def test_configure_first_retried_while_it_fails():
    r = Run()
    a = r.c.next_action(r.at())
    assert a == Configure(master=1, timeout_ms=500)
    assert r.c.next_action(r.at()) is None  # one at a time
    r.c.done(a, False, None, r.at())
    assert r.c.next_action(r.at(0.1)) is None
    assert isinstance(r.c.next_action(r.at(0.5)), Configure)


def test_feed_enable_follows_the_pin():
    r = Run()
    r.configure()
    r.record(0, status=0)
    assert r.c.next_action(r.at()) is None  # enable false, feed off: nothing to do
    r.c.set_enable(True)
    a = r.c.next_action(r.at())
    assert a == WriteFeed(1)
    r.c.done(a, True, None, r.at())
    assert r.c.next_action(r.at(0.1)) is None  # waits for the records to show it
    r.record(0, status=EN)
    assert r.c.next_action(r.at()) is None
    r.c.set_enable(False)
    assert not r.c.pins().jog_enable["x"]  # at once, before the device knows
    r.record(0, status=EN, dt=0.1)
    r.record(0, status=EN, dt=0.1)
    a = r.c.next_action(r.at())
    assert a == WriteFeed(0)
    r.c.done(a, True, None, r.at())
    for _ in range(10):
        r.record(0, status=0, dt=0.1)
        assert r.c.next_action(r.at()) is None


def test_refused_feed_enable_is_retried():
    r = Run()
    r.configure()
    r.c.set_enable(True)
    r.record(0, status=core.STATUS_MASTER_LOST)
    a = r.c.next_action(r.at())
    r.c.done(a, False, core.ABORT_DEVICE_STATE, r.at())
    r.record(0, status=core.STATUS_MASTER_LOST, dt=0.1)
    assert r.c.next_action(r.at()) is None
    for _ in range(4):
        r.record(0, status=core.STATUS_MASTER_LOST, dt=0.1)
    assert r.c.next_action(r.at()) == WriteFeed(1)


def test_no_feed_enable_while_unconfigured_stale_or_not_operational():
    r = Run()
    r.c.set_enable(True)
    r.record(0, status=0)
    a = r.c.next_action(r.at())
    assert isinstance(a, Configure)  # configuration comes first
    r.c.done(a, True, None, r.at())
    r.hb(core.STOPPED)
    assert r.c.next_action(r.at()) is None
    r.hb(core.OPERATIONAL)
    r.c.tick(r.at(1.0))
    assert r.c.next_action(r.at()) is None  # no records: stale


def test_preoperational_device_is_configured_and_started_again():
    r = Run()
    r.configure()
    r.hb(core.PRE_OPERATIONAL)
    assert isinstance(r.c.next_action(r.at()), Configure)


def test_shutdown_disables_the_feed_only_when_on():
    r = Run()
    assert r.c.shutdown_action() is None
    r.record(0, status=EN)
    assert r.c.shutdown_action() == WriteFeed(0)
    r.record(0, status=0)
    assert r.c.shutdown_action() is None


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
    assert len(names) == len(set(names)) == 2 * 5 + 11
