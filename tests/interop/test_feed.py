"""Feed scenarios driven through the stimulus port, asserted on what the master receives."""

import time

import pytest

from rig import (
    AXES,
    EMCY,
    NMT_PRE_OPERATIONAL,
    NMT_START,
    OPERATIONAL,
    PRE_OPERATIONAL,
    STATUS_FLAGS,
    TPDO1,
    TPDO2,
    feed_record,
)

ENABLED = 0x01
ENCODER_ERROR = 0x02
STEPS_DROPPED = 0x04
MASTER_LOST = 0x08
IGNORED_MOTION = 0x10

# Quadrature levels, bit 0 = A, bit 1 = B; forward is A leading B: 0 -> 1 -> 3 -> 2 -> 0.
FORWARD = [1, 3, 2, 0]

# The firmware learns where the wheel rests once it has been still this long
# (handwheel_core::STANDSTILL_MS), plus a margin for the 5 ms sampling and the emulator.
STANDSTILL_S = 0.5 + 0.3


def records(rig, since):
    return [feed_record(f) for f in rig.frames.frames(TPDO1, since=since)]


def test_no_pdo_feed_before_enable(rig):
    rig.select("x")
    rig.start()
    mark = rig.frames.mark()
    rig.stim.turn(3)
    # The turning is reported (status bit 4) but the position never moves.
    seen = rig.frames.wait_for(
        lambda f: f.id == TPDO1 and feed_record(f).flags & IGNORED_MOTION,
        since=mark,
        what="feed record with the ignored-motion bit",
    )
    r = feed_record(seen)
    assert (r.position, r.axis, r.multiplier, r.flags) == (0, 1, 1, IGNORED_MOTION)
    assert all(r.position == 0 for r in records(rig, mark)), "position never moves"
    assert rig.read_signed(0x6004) == 0
    assert rig.read(0x2040, 1) == 3, "ignored detents counted"
    assert rig.read(0x2030) & STATUS_FLAGS == IGNORED_MOTION


@pytest.mark.parametrize("factor", [1, 10, 100])
@pytest.mark.parametrize("axis", ["x", "y", "z", "w", "v"])
def test_each_axis_and_multiplier_gives_detents_times_factor(rig, axis, factor):
    mark = rig.feed_on(axis, factor)
    rig.stim.turn(3)
    rig.wait_position(3 * factor, since=mark)
    rig.stim.turn(-1)
    last = rig.wait_position(2 * factor, since=mark)
    r = feed_record(last)
    assert (r.position, r.axis, r.multiplier, r.flags) == (2 * factor, AXES[axis], factor, ENABLED)
    # Every record on the way shows a position the turning actually passed through,
    # forward first, then back by one detent.
    positions = [r.position for r in records(rig, mark)]
    path = [p for i, p in enumerate(positions) if i == 0 or p != positions[i - 1]]
    assert set(path) <= {0, factor, 2 * factor, 3 * factor}, path
    assert path[-2:] == [3 * factor, 2 * factor], path
    assert path == sorted(path[:-1]) + [2 * factor], path
    assert all((r.axis, r.multiplier) == (AXES[axis], factor) for r in records(rig, mark))
    assert rig.read_signed(0x6004) == 2 * factor


def test_axis_change_mid_turn_never_moves_the_other_axis(rig):
    mark = rig.feed_on("x")
    rig.stim.turn(2)
    rig.wait_position(2, since=mark)
    # Half a detent on X ...
    rig.stim.ab(FORWARD[0])
    rig.stim.ab(FORWARD[1])
    epoch = rig.read(0x2010, 3)
    # ... then the operator switches to Z and finishes the detent and one more.
    rig.select("z")
    assert rig.read(0x2010, 3) == (epoch + 1) & 0xFF, "a new selection epoch"
    rig.stim.ab(FORWARD[2])
    rig.stim.ab(FORWARD[3])
    rig.stim.turn(1)
    rig.frames.wait_for(
        lambda f: (
            f.id == TPDO1 and (feed_record(f).position, feed_record(f).axis) == (4, AXES["z"])
        ),
        since=mark,
        what="Z at position 4",
    )
    seen = records(rig, mark)
    on_x = [r.position for r in seen if r.axis == AXES["x"]]
    on_z = [r.position for r in seen if r.axis == AXES["z"]]
    assert on_x and max(on_x) == 2 and on_x[-1] == 2, f"X got its two detents only: {on_x}"
    assert on_z[0] == 2, f"Z starts where X stopped: {on_z}"
    assert on_z[-1] == 4, f"Z moves by its own two detents: {on_z}"
    assert all(r.axis in (AXES["x"], AXES["z"]) for r in seen)


def test_chatter_nets_zero(rig):
    mark = rig.feed_on("x")
    for _ in range(25):
        rig.stim.ab(1)  # A rises ...
        rig.stim.ab(0)  # ... and falls back: one count forward, one back
    for _ in range(25):
        rig.stim.ab(2)  # B chatter, the reverse direction
        rig.stim.ab(0)
    assert rig.read(0x2020, 1) == 0, "raw count back where it was"
    assert rig.read(0x2020, 2) == 0, "no illegal transition"
    assert rig.read_signed(0x6004) == 0
    assert all(r.position == 0 for r in records(rig, mark)), "never any feed"


def test_rest_learnt_at_standstill_keeps_reversals_whole(rig):
    """The wheel is moved half a detent (00 -> 01 -> 11) and stays there; `turn` then counts
    whole detents from 11. Every turn, reversals and single-detent jogs included, must move
    the feed by exactly its detents (a decoder that keeps 00 as the rest would give 5, -4, 2,
    -2, 0, 0)."""
    rig.feed_on("x")
    rig.stim.ab(FORWARD[0])
    rig.stim.ab(FORWARD[1])
    # The wheel is at rest at 11 from here on: longer than the standstill time, so the
    # firmware takes 11 as the rest.
    time.sleep(STANDSTILL_S)
    assert rig.read_signed(0x6004) == 0, "half a detent is no motion"
    for detents, position in zip([5, -5, 3, -3, 1, -1], [5, 0, 3, 0, 1, 0]):
        mark = rig.frames.mark()
        rig.stim.turn(detents)  # replies after its last edge has been decoded
        rig.wait_position(position, since=mark)  # the CAN side has caught up
        assert rig.read_signed(0x6004) == position, f"after turn {detents}"
    assert rig.read_signed(0x2020, 1) == 2, "raw count: the half detent, the turns net zero"
    assert rig.read(0x2020, 2) == 0, "no illegal transition"


def test_illegal_jumps_are_counted_with_emcy(rig):
    mark = rig.feed_on("x")
    rig.stim.ab(3)  # both channels flip: a missed edge
    rig.stim.ab(0)  # and again
    assert rig.read(0x2020, 2) == 2
    emcy = rig.frames.wait_id(EMCY, since=mark)
    assert emcy.data[:2] == bytes([0x00, 0x73]), "EMCY 0x7300 (sensor)"
    assert emcy.data[2] & 0x01, "generic error bit in the error register"
    # Manufacturer bytes: the illegal-transition count when the error was raised (1 if
    # the device serviced the first jump before the second arrived).
    assert int.from_bytes(emcy.data[3:7], "little") in (1, 2)
    assert len(emcy.data) == 8
    rig.frames.wait_for(
        lambda f: f.id == TPDO1 and feed_record(f).flags == ENABLED | ENCODER_ERROR,
        since=mark,
        what="feed record with the encoder-error bit",
    )
    assert rig.read_signed(0x6004) == 0, "illegal jumps never become motion"
    assert [e.code for e in rig.node.emcy.active] == [0x7300]
    # A new selection epoch clears the latched error: error-reset EMCY.
    reset_mark = rig.frames.mark()
    rig.select("y")
    reset = rig.frames.wait_id(EMCY, since=reset_mark)
    assert reset.data == bytes(8)
    assert rig.node.emcy.active == []


def test_paper_format_emits_the_documented_byte_stream(rig):
    mark = rig.feed_on("x", 1, unit_steps=True)
    rig.stim.turn(4)
    rig.frames.wait_count(TPDO2, 4, since=mark)
    rig.stim.turn(-4)
    steps = rig.frames.wait_count(TPDO2, 8, since=mark)
    assert [f.data for f in steps] == [
        bytes([b]) for b in (0x08, 0x18, 0x28, 0x38, 0x40, 0x50, 0x60, 0x70)
    ]
    rig.frames.assert_none(
        lambda f: f.id == TPDO2, 0.3, since=steps[-1].seq + 1, what="more unit steps"
    )


def test_paper_format_backlog_is_bounded_at_x100(rig):
    mark = rig.feed_on("z", 100, unit_steps=True)
    rig.stim.turn(1)  # 100 unit steps, the backlog bound is 40
    steps = rig.frames.wait_count(TPDO2, 40, since=mark)
    rig.frames.assert_none(
        lambda f: f.id == TPDO2, 0.5, since=steps[39].seq + 1, what="steps beyond the bound"
    )
    assert all(f.data[0] & 0x0F == 0x0A for f in steps), "axis Z (2), forward"
    assert rig.read(0x2040, 2) == 60, "dropped steps counted"
    assert rig.read(0x2030) & STEPS_DROPPED


def test_leaving_operational_stops_the_feed(rig):
    mark = rig.feed_on("w", 10)
    rig.stim.turn(2)
    rig.wait_position(20, since=mark)
    hb = rig.nmt_and_heartbeat(NMT_PRE_OPERATIONAL, PRE_OPERATIONAL)
    assert rig.read(0x2000) == 0, "feed disabled on leaving Operational"
    rig.stim.turn(1)
    rig.nmt_and_heartbeat(NMT_START, OPERATIONAL)
    entry = rig.frames.wait_id(TPDO1, since=hb.seq + 1)
    r = feed_record(entry)
    assert (r.position, r.axis, r.multiplier) == (20, AXES["w"], 10), "no motion while stopped"
    assert not r.enabled
    assert rig.read(0x2000) == 0, "it never resumes on its own"
