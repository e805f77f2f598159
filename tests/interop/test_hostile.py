"""The device attacked as a hostile master would: writes that CiA 301 or the node's own use
of identifiers forbids, feed while the master is lost, a moved SYNC, and bounded fuzzing of
SDO requests and of frames on every identifier, after which the node must be healthy."""

import os
import random
import time

from rig import (
    BOOTUP,
    EMCY,
    HEARTBEAT,
    NMT_RESET_NODE,
    NMT_START,
    OPERATIONAL,
    PRE_OPERATIONAL,
    SDO_RX,
    SDO_TX,
    TPDO1,
    MasterHeartbeat,
    feed_record,
)

MASTER = 1
MASTER_LOST = 0x08
INVALID_VALUE = 0x06090030
INCOMPATIBLE = 0x06040043
DEVICE_STATE = 0x08000022
INVALID_BIT = 0x80000000

# Bounded fuzzing (the reviewer's campaign was 40 000 SDO requests and 20 000 frames; the
# suite runs a slice of it on every CI run, with a new seed each time, printed on failure).
SDO_FUZZ = int(os.environ.get("HANDWHEEL_SDO_FUZZ", 1500))
FRAME_FUZZ = int(os.environ.get("HANDWHEEL_FRAME_FUZZ", 3000))


def u32(value: int) -> bytes:
    return value.to_bytes(4, "little")


def test_feed_cannot_be_enabled_while_the_master_is_lost(rig):
    master = MasterHeartbeat(rig.network, MASTER).start()
    try:
        rig.write(0x1016, 1, (MASTER << 16) | 200, 4)  # 0x000100C8
        # Monitoring starts with the first heartbeat after the write (CiA 301): let a few
        # of the master's 50 ms beats arrive before it falls silent.
        time.sleep(0.2)
        mark = rig.feed_on("x")
        rig.stim.turn(1)
        rig.wait_position(1, since=mark)
        loss = rig.frames.mark()
        master.stop()
        rig.frames.wait_id(EMCY, bytes([0x30, 0x81, 0x11, MASTER, 0, 0, 0, 0]), since=loss)
        assert rig.read(0x2000) == 0
        # Still silent: another client's enable is refused, and turning moves nothing.
        assert rig.write_abort(0x2000, 0, bytes([1])) == DEVICE_STATE
        assert rig.read(0x2000) == 0
        turned = rig.frames.mark()
        rig.stim.turn(4)
        rig.frames.wait_for(lambda f: f.id == TPDO1, since=turned, what="a feed record")
        time.sleep(0.3)
        assert rig.read_signed(0x6004) == 1
        records = [feed_record(f) for f in rig.frames.frames(TPDO1, since=turned)]
        assert records and all(r.position == 1 and r.master_lost for r in records), records
        assert rig.read(0x2030) & MASTER_LOST, "the status bit still says why"
        assert rig.read(0x1001) == 0x11
        # The master is back: enabling works again and clears the bit.
        back = rig.frames.mark()
        master.start()
        rig.frames.wait_id(EMCY, bytes(8), since=back)
        rig.write(0x2000, 0, 1, 1)
        enabled = rig.frames.mark()
        rig.stim.turn(1)
        assert feed_record(rig.wait_position(2, since=enabled)).flags == 0x01
    finally:
        master.stop()


def test_moved_sync_is_received_on_its_new_identifier(rig):
    # Restricted identifiers and this node's own are refused, the value kept.
    for value, code in [(0x000, INVALID_VALUE), (0x701, INVALID_VALUE), (0x090, INCOMPATIBLE)]:
        assert rig.write_abort(0x1005, 0, u32(value)) == code, hex(value)
    assert rig.read(0x1005) == 0x080
    rig.write(0x1800, 2, 1, 1)  # TPDO1 on every SYNC
    rig.write(0x1005, 0, 0x081, 4)
    assert rig.read(0x1005) == 0x081
    rig.start()
    time.sleep(0.2)  # TPDO1's entry frame is out
    mark = rig.frames.mark()
    rig.network.send_message(0x080, b"")
    rig.frames.assert_none(lambda f: f.id == TPDO1, 0.5, since=mark, what="TPDO1 on 0x080")
    for _ in range(3):
        rig.network.send_message(0x081, b"")
        time.sleep(0.05)
    assert len(rig.frames.wait_count(TPDO1, 3, since=mark)) == 3
    # Reset communication restores 0x080, and the filter follows again.
    reset = rig.frames.mark()
    rig.nmt(0x82)
    rig.frames.wait_id(HEARTBEAT, bytes([BOOTUP]), since=reset)
    assert rig.read(0x1005) == 0x080
    rig.write(0x1800, 2, 1, 1)
    rig.start()
    time.sleep(0.2)
    synced = rig.frames.mark()
    rig.network.send_message(0x080, b"")
    rig.frames.wait_id(TPDO1, since=synced)


def test_invalid_heartbeat_consumer_entries_are_refused(rig):
    own = 16
    cases = [
        (0x0101_0064, INVALID_VALUE),  # reserved bits 24..31
        (0x0000_0064, INVALID_VALUE),  # node-ID 0 with a time
        (0x0080_0064, INVALID_VALUE),  # node-ID 128
        (0x00FF_00C8, INVALID_VALUE),
        ((own << 16) | 100, INVALID_VALUE),  # this node
    ]
    for entry, code in cases:
        assert rig.write_abort(0x1016, 1, u32(entry)) == code, hex(entry)
        assert rig.read(0x1016, 1) == 0
    rig.write(0x1016, 1, 0x0001_00C8, 4)
    assert rig.write_abort(0x1016, 2, u32(0x0001_0064)) == INCOMPATIBLE
    assert rig.read(0x1016, 2) == 0


NO_RTR = 0x40000000


def test_cob_id_collisions_are_refused(rig):
    emcy = 0x080 + 16
    # TPDO2 onto this node's EMCY.
    rig.write(0x1801, 1, INVALID_BIT | 0x290, 4)
    assert rig.write_abort(0x1801, 1, u32(emcy)) == INCOMPATIBLE
    # TPDO1 and EMCY onto the same free identifier: the second one is refused.
    rig.write(0x1800, 1, INVALID_BIT | 0x190, 4)
    rig.write(0x1800, 1, 0x0A0, 4)
    rig.write(0x1014, 0, INVALID_BIT | emcy, 4)
    assert rig.write_abort(0x1014, 0, u32(0x0A0)) == INCOMPATIBLE
    assert rig.read(0x1014) == INVALID_BIT | emcy
    # Feed records never went out on an EMCY identifier.
    assert rig.read(0x1800, 1) == NO_RTR | 0x0A0  # TPDO COB-IDs read "no RTR" (bit 30)
    assert rig.read(0x1801, 1) == NO_RTR | INVALID_BIT | 0x290


def _healthy(rig) -> None:
    """The node answers NMT, boots up, serves SDO and beats its heart at the defaults."""
    rig.board.check_alive()
    mark = rig.nmt(NMT_RESET_NODE)
    rig.frames.wait_id(HEARTBEAT, bytes([BOOTUP]), since=mark)
    assert rig.read(0x1000) == 0
    assert rig.read(0x1017) == 1000
    beat = rig.frames.mark()
    rig.frames.wait_id(HEARTBEAT, bytes([PRE_OPERATIONAL]), since=beat, timeout=3)
    rig.nmt_and_heartbeat(NMT_START, OPERATIONAL)
    assert "panicked" not in rig.board.log()


def test_fuzzed_sdo_requests_get_one_reply_each(rig):
    seed = random.randrange(1 << 32)
    rng = random.Random(seed)
    rig.nmt_and_heartbeat(NMT_START, OPERATIONAL)
    # Commands weighted towards what a server must parse; indices towards real objects.
    commands = [
        0x20,
        0x21,
        0x22,
        0x23,
        0x27,
        0x2B,
        0x2F,
        0x40,
        0x60,
        0x70,
        0x00,
        0x10,
        0x80,
        0xA0,
        0xC0,
        0xE0,
    ]
    indices = [
        0x1000,
        0x1001,
        0x1003,
        0x1005,
        0x1008,
        0x1010,
        0x1011,
        0x1014,
        0x1016,
        0x1017,
        0x1018,
        0x1800,
        0x1801,
        0x1A00,
        0x1A01,
        0x2000,
        0x2001,
        0x2010,
        0x2020,
        0x2030,
        0x2040,
        0x6004,
    ]
    aborts = 0
    for i in range(SDO_FUZZ):
        cmd = rng.choice(commands) if rng.random() < 0.7 else rng.randrange(256)
        index = rng.choice(indices) if rng.random() < 0.8 else rng.randrange(0x10000)
        sub = rng.randrange(6) if rng.random() < 0.8 else rng.randrange(256)
        # Never "save"/"load" by accident: the suite's node must come back to defaults.
        data = bytes(rng.randrange(256) for _ in range(4))
        if index in (0x1010, 0x1011):
            data = bytes(4)
        request = bytes([cmd]) + index.to_bytes(2, "little") + bytes([sub]) + data
        mark = rig.frames.mark()
        rig.network.send_message(SDO_RX, request)
        if cmd >> 5 == 4:
            # A client's abort (command specifier 4) is never answered (CiA 301 7.2.4.3.17).
            aborts += 1
            continue
        try:
            rig.frames.wait_id(SDO_TX, since=mark, timeout=2)
        except AssertionError as e:
            raise AssertionError(f"seed {seed}, request {i} {request.hex(' ')}: {e}") from e
    # One reply per answered request: nothing more trickles in afterwards.
    time.sleep(0.3)
    replies = len(rig.frames.frames(SDO_TX))
    assert replies == SDO_FUZZ - aborts, f"seed {seed}: {replies} replies, {aborts} aborts"
    _healthy(rig)


def test_random_frames_on_every_identifier_leave_the_node_healthy(rig):
    seed = random.randrange(1 << 32)
    rng = random.Random(seed)
    rig.nmt_and_heartbeat(NMT_START, OPERATIONAL)
    for i in range(FRAME_FUZZ):
        can_id = rng.randrange(0x800)
        data = bytes(rng.randrange(256) for _ in range(rng.randrange(9)))
        # Never a "save"/"load" that would outlive the reset below.
        if can_id == SDO_RX and len(data) == 8 and data[1:3] in (b"\x10\x10", b"\x11\x10"):
            continue
        rig.network.send_message(can_id, data)
        if i % 50 == 0:
            time.sleep(0.01)  # bursts of 50, as a busy bus delivers them
    time.sleep(0.5)
    try:
        _healthy(rig)
    except AssertionError as e:
        raise AssertionError(f"seed {seed}: {e}") from e


def test_receive_overrun_raises_emcy_8110_and_the_node_recovers(rig):
    """A CAN side that falls behind (the board's `stall` keeps it from running while the
    receive interrupts keep queueing) loses frames past the 15-frame receive queue: EMCY
    0x8110, recorded in 0x1003, and nothing else breaks. The stall (200 ms of the board's
    time, the 40 frames on the bus within a few of them) is longer than the device's
    transmit stall limit (100 ms; the transmit interrupt drained the path meanwhile, and the
    port tells the device so: no EMCY 0x8100) and shorter than the watchdog's timeout (no
    reset)."""
    rig.nmt_and_heartbeat(NMT_START, OPERATIONAL)
    mark = rig.frames.mark()
    rig.stim.cmd("stall 200")
    for _ in range(40):
        # Heartbeats of unmonitored nodes: accepted by the filter, ignored by the engine.
        rig.network.send_message(0x77F, bytes([0x05]))
    emcy = rig.frames.wait_id(EMCY, since=mark, timeout=5)
    assert emcy.data == bytes([0x10, 0x81, 0x11, 0, 0, 0, 0, 0]), emcy
    reset = rig.frames.wait_id(EMCY, bytes(8), since=emcy.seq + 1)
    assert reset.seq > emcy.seq
    assert rig.read(0x1001) == 0, "an event: over once reported"
    assert rig.read(0x1003, 1) & 0xFFFF == 0x8110
    others = [f for f in rig.frames.frames(EMCY, since=mark) if f.seq not in (emcy.seq, reset.seq)]
    assert not others, f"EMCYs besides the overrun's: {others}"
    status = rig.board.status()
    assert status["resets"] == "1" and status["locked"] == "0", status
    _healthy(rig)
