"""Heartbeat producer timing and the consumer (0x1016): losing the master stops the feed."""

import time

from emulated_clock import frame_times, gaps
from rig import (
    EMCY,
    HEARTBEAT,
    PRE_OPERATIONAL,
    TPDO1,
    MasterHeartbeat,
    feed_record,
)

MASTER = 1
MASTER_LOST = 0x08
ENABLED = 0x01


def test_default_heartbeat_every_second(rig):
    """1000 ms of the firmware's time must be about 1 s of the board's clock (emulated
    time, emulated_clock.py): a SysTick off by a clock divider, a factor of 2 or more, fails
    it."""
    mark = rig.frames.mark()
    times = frame_times(rig, HEARTBEAT, 3, since=mark, timeout=10)
    hbs = rig.frames.frames(HEARTBEAT, since=mark)[:3]
    assert all(h.data == bytes([PRE_OPERATIONAL]) for h in hbs)
    assert all(0.7 < g < 1.4 for g in gaps(times)), f"heartbeat gaps {gaps(times)}"


def test_duplicate_consumer_entries_are_refused(rig):
    rig.write(0x1016, 1, (MASTER << 16) | 100, 4)
    code = rig.write_abort(0x1016, 2, ((MASTER << 16) | 200).to_bytes(4, "little"))
    assert code == 0x06040043
    assert rig.read(0x1016, 2) == 0
    rig.write(0x1016, 2, (MASTER << 16) | 0, 4)  # time 0 disables the entry: no clash
    assert rig.read_abort(0x1016, 3) == 0x06090011


def test_master_heartbeat_loss_stops_the_feed_with_emcy_8130(rig):
    master = MasterHeartbeat(rig.network, MASTER, period=0.05).start()
    try:
        rig.write(0x1016, 1, (MASTER << 16) | 300, 4)  # monitor node 1, 300 ms
        assert rig.read(0x1016, 1) == 0x0001012C
        mark = rig.feed_on("x")
        rig.stim.turn(1)
        rig.wait_position(1, since=mark)
        # Still alive well past the timeout while the master's heartbeat flows.
        time_mark = rig.frames.mark()
        rig.frames.assert_none(lambda f: f.id == EMCY, 0.8, since=time_mark, what="EMCY")
        assert rig.read(0x2000) == 1
        loss_mark = rig.frames.mark()
        master.stop()
        stopped_at = time.monotonic()
        emcy = rig.frames.wait_id(EMCY, since=loss_mark, timeout=3)
        # 0x8130, error register communication | generic, the lost node-ID first.
        assert emcy.data == bytes([0x30, 0x81, 0x11, MASTER, 0, 0, 0, 0])
        assert 0.15 < emcy.t - stopped_at < 1.5, f"EMCY {emcy.t - stopped_at:.3f} s after"
        assert [e.code for e in rig.node.emcy.active] == [0x8130]
        # The feed record reports the stop: disabled, master lost, position kept.
        rec = rig.frames.wait_for(
            lambda f: f.id == TPDO1 and feed_record(f).flags & MASTER_LOST,
            since=loss_mark,
            what="feed record with the master-lost bit",
        )
        r = feed_record(rec)
        assert (r.position, r.axis, r.multiplier, r.flags) == (1, 1, 1, MASTER_LOST)
        assert rig.read(0x2000) == 0
        assert rig.read(0x1001) == 0x11
        assert rig.read(0x1003, 0) >= 1
        assert rig.read(0x1003, 1) == (MASTER << 16) | 0x8130
        # Turning now is no feed.
        turn_mark = rig.frames.mark()
        rig.stim.turn(2)
        rig.frames.wait_for(
            lambda f: f.id == TPDO1, since=turn_mark, timeout=2, what="a feed record"
        )
        assert all(feed_record(f).position == 1 for f in rig.frames.frames(TPDO1, since=turn_mark))
        assert rig.read_signed(0x6004) == 1
        # The master comes back: error reset, but the feed waits for a new enable.
        back_mark = rig.frames.mark()
        master.start()
        reset = rig.frames.wait_id(EMCY, since=back_mark, timeout=3)
        assert reset.data == bytes(8)
        assert rig.read(0x2000) == 0
        rig.write(0x2000, 0, 1, 1)
        enable_mark = rig.frames.mark()
        rig.stim.turn(1)
        rec = rig.wait_position(2, since=enable_mark)
        assert feed_record(rec).flags == ENABLED, "master-lost bit cleared by the new enable"
    finally:
        master.stop()
