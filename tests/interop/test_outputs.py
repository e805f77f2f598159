"""The digital outputs on the board's pins: 0x6A00:1 (the CNC's, CiA 401's layout) on board
outputs 2..8, "jog live" (0x2036, the device's) on output 1, and the error reaction of
0x6A06/0x6A07 on NMT stop and on the master's heartbeat lost."""

import time

from rig import MasterHeartbeat
from rig.constants import NODE_ID

MASTER = 1
# Board outputs 2..8 carry 0x6A00:1 bits 0..6; bit 7 has no pin.
PINNED = 0x7F


def pins_of(written: int) -> int:
    """The board outputs 0x6A00:1 = `written` drives high (without "jog live")."""
    return (written & PINNED) << 1


def wait_outputs(rig, wanted, what: str, timeout: float = 3.0) -> tuple[int, bool]:
    """Polls the control line until `wanted(outputs, jog)` holds."""
    deadline = time.monotonic() + timeout
    while True:
        now = rig.board.outputs()
        if wanted(*now):
            return now
        assert time.monotonic() < deadline, f"{what}: outputs {now[0]:#04x}, jog {now[1]}"
        time.sleep(0.02)


def test_a_write_of_0x6a00_drives_the_pins(rig):
    assert rig.board.outputs() == (0, False), "all off after reset"
    for written in (0x01, 0xA5, 0xFF, 0x80, 0x00):
        rig.write(0x6A00, 1, written, 1)
        assert rig.read(0x6A00, 1) == written
        wait_outputs(
            rig, lambda out, jog, w=written: out == pins_of(w), f"0x6A00:1 = {written:#04x}"
        )


def test_jog_live_follows_feed_enable_axis_and_nmt(rig):
    rig.write(0x6A00, 1, 0xFF, 1)
    wait_outputs(rig, lambda out, jog: out == 0xFE and not jog, "0x6A00 never lights jog live")
    rig.feed_on("x")
    wait_outputs(rig, lambda out, jog: jog and out == 0xFF, "enabled at X")
    assert rig.read(0x2036) == 1
    rig.select("off")
    wait_outputs(rig, lambda out, jog: not jog, "no axis")
    assert rig.read(0x2036) == 0
    rig.select("y")
    wait_outputs(rig, lambda out, jog: jog, "axis Y again, still enabled")
    rig.write(0x2000, 0, 0, 1)
    wait_outputs(rig, lambda out, jog: not jog, "disabled")
    rig.write(0x2000, 0, 1, 1)
    wait_outputs(rig, lambda out, jog: jog, "enabled again")
    rig.nmt(0x80)  # pre-operational: the feed stops
    wait_outputs(rig, lambda out, jog: not jog, "Pre-operational")
    assert rig.read(0x2036) == 0


def test_nmt_stop_applies_the_error_value(rig):
    rig.write(0x6A06, 1, 0x0F, 1)  # outputs 1..4 of the object react
    rig.write(0x6A07, 1, 0x05, 1)
    rig.start()
    rig.write(0x6A00, 1, 0xAA, 1)
    wait_outputs(rig, lambda out, jog: out == pins_of(0xAA), "written")
    rig.nmt(0x02)
    expected = 0xAA & ~0x0F | 0x05
    wait_outputs(rig, lambda out, jog: out == pins_of(expected), "error value on stop")
    rig.start()
    time.sleep(0.2)
    assert rig.board.outputs()[0] == pins_of(expected), "Operational again keeps them"
    assert rig.read(0x6A00, 1) == expected
    rig.write(0x6A00, 1, 0x40, 1)
    wait_outputs(rig, lambda out, jog: out == pins_of(0x40), "a master writes again")


def test_master_heartbeat_loss_applies_the_error_value_within_the_consumer_time(rig):
    master = MasterHeartbeat(rig.network, MASTER, period=0.05).start()
    try:
        rig.write(0x1016, 1, (MASTER << 16) | 300, 4)
        rig.feed_on("x")
        rig.write(0x6A00, 1, 0x7F, 1)
        wait_outputs(rig, lambda out, jog: out == 0xFF and jog, "written, jog live")
        # The consumer watches from the master's first heartbeat after the write of 0x1016.
        time.sleep(0.2)
        master.stop()
        stopped_at = time.monotonic()
        # Default error mode 0xFF, value 0: every output off, and the feed stops.
        wait_outputs(rig, lambda out, jog: out == 0, "error value on master loss")
        assert time.monotonic() - stopped_at < 1.5
        assert rig.read(0x6A00, 1) == 0
        master = MasterHeartbeat(rig.network, MASTER, period=0.05).start()
        time.sleep(0.3)
        assert rig.board.outputs() == (0, False), "the master's return changes nothing"
    finally:
        master.stop()


def test_rpdo1_drives_the_pins_and_its_deadline_applies_the_error_value(rig):
    """RPDO1 (0x200 + node-ID, mapped to 0x6A00:1 by default) writes the outputs as an SDO
    download does; with an event timer (0x1400:05) its absence is an error."""
    rig.write(0x1400, 5, 200, 2)  # deadline 200 ms
    rig.start()
    rpdo1 = 0x200 + NODE_ID
    for written in (0x5A, 0x81):
        rig.network.send_message(rpdo1, bytes([written]))
        wait_outputs(rig, lambda out, jog, w=written: out == pins_of(w), f"RPDO1 {written:#04x}")
        assert rig.read(0x6A00, 1) == written
    # No more RPDOs: the deadline passes, default error mode 0xFF and value 0: all off.
    wait_outputs(rig, lambda out, jog: out == 0, "error value at the RPDO deadline")
    assert rig.read(0x6A00, 1) == 0
    rig.network.send_message(rpdo1, bytes([0x03]))
    wait_outputs(rig, lambda out, jog: out == pins_of(0x03), "the next RPDO drives them again")


def test_a_moved_and_remapped_rpdo1_is_stored_and_listened_to_on_its_new_identifier(rig):
    """The master moves RPDO1 to 0x300 + node-ID and maps a dummy byte before the outputs
    (CiA 301's procedure: invalid, mapping, valid), stores it (0x1010:2, the communication
    parameters) and powers the board off and on: the stored RPDO1 is restored, the
    controller's filter takes the new identifier (the frame's second byte drives the pins),
    and a frame on the old identifier is not taken."""
    moved = 0x300 + NODE_ID
    rig.write(0x1400, 1, 0x8000_0000 | 0x200 + NODE_ID, 4)
    rig.write(0x1600, 0, 0, 1)
    rig.write(0x1600, 1, 0x0005_0008, 4)  # dummy UNSIGNED8: the first byte is another node's
    rig.write(0x1600, 2, 0x6A00_0108, 4)
    rig.write(0x1600, 0, 2, 1)
    rig.write(0x1400, 1, moved, 4)
    rig.node.sdo.download(0x1010, 2, b"save")
    mark = rig.frames.mark()
    rig.board.control("power")
    rig.frames.wait_id(0x700 + NODE_ID, bytes([0]), since=mark)
    assert rig.read(0x1400, 1) == moved
    assert [rig.read(0x1600, sub) for sub in range(3)] == [2, 0x0005_0008, 0x6A00_0108]
    rig.start()
    rig.network.send_message(moved, bytes([0xFF, 0x42]))
    wait_outputs(rig, lambda out, jog: out == pins_of(0x42), "the moved RPDO1's second byte")
    filtered = int(rig.board.status()["filtered"])
    rig.network.send_message(0x200 + NODE_ID, bytes([0x00, 0x11]))
    time.sleep(0.3)
    assert rig.board.outputs()[0] == pins_of(0x42), "the old identifier is not listened to"
    assert int(rig.board.status()["filtered"]) == filtered + 1, "dropped by the filter"
    assert rig.read(0x6A00, 1) == 0x42
