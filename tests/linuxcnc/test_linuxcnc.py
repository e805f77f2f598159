"""The handwheel drives LinuxCNC 2.9's axes: the QEMU handwheel, the component loaded by
LinuxCNC (`loadusr -Wn handwheel ...`), positions read from `linuxcnc.stat()`.

The tests share one machine (LinuxCNC takes seconds to start) and run in file order; each
starts from wherever the previous one left the axes and checks relative moves. The last one
kills the component.
"""

import os
import re
import signal
import time

from conftest import SCALE
from rig import BOOTUP, EMCY, HEARTBEAT, NMT_RESET_NODE, TPDO1, feed_record


def moved(pos, axis, distance):
    out = list(pos)
    out["xyz".index(axis)] += distance
    return out


def test_component_is_loaded_and_connected(machine):
    s = machine.status()
    assert s["homed"] == [1, 1, 1] and s["teleop"], s
    p = s["pins"]
    assert p["connected"] and p["state"] == 5 and p["enable"]
    out = machine.halcmd("show", "sig", "hw-x-counts")
    assert "handwheel.axis.x.jog-counts" in out and "axis.x.jog-counts" in out, out
    assert "joint.0.jog-counts" in out, out


def test_turn_x_at_each_multiplier(machine):
    for mult, detents in [(1, 3), (10, -2), (100, 5), (1, -7)]:
        machine.select("x", mult)
        machine.ready_to_jog("x")
        start = machine.pos()
        machine.stim.turn(detents)
        machine.wait_pos(moved(start, "x", detents * mult * SCALE))


def test_axis_change_moves_the_new_axis_only(machine):
    machine.select("x", 10)
    machine.ready_to_jog("x")
    start = machine.pos()
    machine.stim.turn(2)
    after_x = moved(start, "x", 2 * 10 * SCALE)
    machine.wait_pos(after_x)
    for axis, detents in [("y", 4), ("z", -3), ("x", 1)]:
        machine.select(axis, 10)
        machine.ready_to_jog(axis)
        before = machine.pos()
        machine.stim.turn(detents)
        machine.wait_pos(moved(before, axis, detents * 10 * SCALE))


def test_nothing_moves_with_the_machine_off(machine):
    machine.select("x", 100)
    machine.ready_to_jog("x")
    start = machine.pos()
    machine.cnc.must("off")
    machine.wait(
        lambda s: not s["pins"]["enable"] and not s["pins"]["feed-enabled"],
        5,
        "feed off with the machine",
    )
    machine.stim.turn(5)
    machine.assert_still(start, 1.0)
    machine.cnc.must("on")
    machine.ready_to_jog("x")
    machine.assert_still(start, 0.5)  # what was turned meanwhile never arrives
    machine.stim.turn(1)
    machine.wait_pos(moved(start, "x", 100 * SCALE))


def test_nothing_moves_with_enable_false(machine):
    machine.select("y", 10)
    machine.ready_to_jog("y")
    start = machine.pos()
    machine.halcmd("unlinkp", "handwheel.enable")
    machine.halcmd("setp", "handwheel.enable", "0")
    try:
        machine.wait(
            lambda s: not s["pins"]["feed-enabled"] and not s["pins"]["axis.y.jog-enable"],
            5,
            "feed off",
        )
        machine.stim.turn(9)
        machine.assert_still(start, 1.0)
    finally:
        machine.halcmd("net", "machine-is-on", "handwheel.enable")
    machine.ready_to_jog("y")
    machine.assert_still(start, 0.3)
    machine.stim.turn(-1)
    machine.wait_pos(moved(start, "y", -10 * SCALE))


def test_nothing_moves_with_the_axis_switch_off(machine):
    machine.select("off", 1)
    start = machine.pos()
    p = machine.pins()
    assert not any(p[f"axis.{a}.jog-enable"] for a in "xyz")
    machine.stim.turn(6)
    machine.assert_still(start, 1.0)


def test_chatter_moves_nothing(machine):
    machine.select("z", 100)
    machine.ready_to_jog("z")
    start = machine.pos()
    for _ in range(20):  # A bounces while B stays
        machine.stim.ab(1)
        machine.stim.ab(0)
    for _ in range(20):  # then B
        machine.stim.ab(2)
        machine.stim.ab(0)
    machine.assert_still(start, 1.0)
    machine.stim.turn(1)
    machine.wait_pos(moved(start, "z", 100 * SCALE))


def test_device_reset_causes_no_jump(machine):
    machine.select("x", 100)
    machine.ready_to_jog("x")
    start = machine.pos()
    machine.stim.turn(3)
    after = moved(start, "x", 3 * 100 * SCALE)
    machine.wait_pos(after)
    mark = machine.nmt(NMT_RESET_NODE)  # position back to 0 on the device
    machine.frames.wait_id(HEARTBEAT, bytes([BOOTUP]), since=mark)
    # The component starts it again, re-arms the heartbeat watch, enables the feed.
    machine.ready_to_jog("x")
    machine.assert_still(after, 0.5)
    machine.stim.turn(-2)
    machine.wait_pos(moved(after, "x", -2 * 100 * SCALE))


def test_killing_the_component_stops_the_feed(machine):
    machine.select("x", 1)
    machine.ready_to_jog("x")
    start = machine.pos()
    out = machine.halcmd("show", "comp", "handwheel")
    m = re.search(r"User\s+handwheel\s+(\d+)", out) or re.search(r"handwheel\s+User\s+(\d+)", out)
    pid = None
    if m is None:
        for line in out.splitlines():
            if "handwheel" in line and "User" in line:
                nums = [int(t) for t in line.split() if t.isdigit()]
                pid = nums[-1] if nums else None
    else:
        pid = int(m.group(1))
    assert pid, out
    mark = machine.frames.mark()
    os.kill(pid, signal.SIGKILL)
    # The device misses the master's heartbeat: EMCY 0x8130 and a record with bit 3.
    machine.frames.wait_for(
        lambda f: f.id == EMCY and f.data[:2] == b"\x30\x81",
        since=mark,
        timeout=3,
        what="EMCY 0x8130",
    )
    rec = machine.frames.wait_for(
        lambda f: f.id == TPDO1 and f.data[6] & 0x08,
        since=mark,
        timeout=3,
        what="record with master lost",
    )
    assert not feed_record(rec)[3] & 0x01
    mark = machine.frames.mark()
    machine.stim.turn(4)
    time.sleep(0.3)
    recs = machine.frames.frames(TPDO1, since=mark)
    assert recs and all(feed_record(f)[0] == feed_record(rec)[0] for f in recs)
    machine.assert_still(start, 0.5)
