"""Transmit PDOs: python-canopen's view of the mappings, re-mapping, when TPDOs flow."""

from rig import (
    HEARTBEAT,
    NMT_PRE_OPERATIONAL,
    NMT_START,
    NMT_STOP,
    OPERATIONAL,
    PRE_OPERATIONAL,
    STOPPED,
    TPDO1,
    TPDO2,
    feed_record,
)


def mapping(pdo_map):
    return [(v.index, v.subindex, v.length) for v in pdo_map.map]


def test_tpdo_read_returns_the_default_mapping(rig):
    tpdo = rig.node.tpdo
    tpdo.read()
    feed, steps = tpdo[1], tpdo[2]
    assert (feed.cob_id, feed.enabled, feed.trans_type) == (TPDO1, True, 254)
    assert (feed.inhibit_time, feed.event_timer) == (20, 100)
    assert mapping(feed) == [
        (0x6004, 0, 32),
        (0x2011, 0, 8),
        (0x2030, 0, 8),
        (0x2031, 0, 16),
    ]
    assert feed.length == 64
    assert [v.name for v in feed.map] == [
        "Position value",
        "Feed selection",
        "Feed status",
        "Feed sequence",
    ]
    assert (steps.cob_id, steps.enabled, steps.trans_type) == (TPDO2, True, 254)
    assert (steps.inhibit_time, steps.event_timer) == (20, 0)
    assert mapping(steps) == [(0x2032, 0, 8)]


def test_no_tpdo_outside_operational_and_tpdo1_on_entry(rig):
    mark = rig.frames.mark()
    rig.frames.assert_none(lambda f: f.id in (TPDO1, TPDO2), 0.5, since=mark, what="PDOs")
    rig.start()
    first = rig.frames.wait_id(TPDO1, since=mark)
    # Position 0, no axis, x1 (code 0), epoch 0, no status bit, no session, sequence 0.
    assert first.data == bytes(8)
    # The 100 ms event timer repeats it, the sequence counting the frames sent.
    records = rig.frames.wait_count(TPDO1, 5, timeout=3, since=mark)
    assert [feed_record(f).sequence for f in records[:5]] == [0, 1, 2, 3, 4]
    gaps = [b.t - a.t for a, b in zip(records, records[1:5])]
    assert all(0.03 < g < 0.3 for g in gaps), f"event timer gaps {gaps}"
    assert not rig.frames.frames(TPDO2, since=mark), "TPDO2 carries events only"
    # Stopped and Pre-operational: PDOs stop.
    for command, state in [
        (NMT_STOP, STOPPED),
        (NMT_START, OPERATIONAL),
        (NMT_PRE_OPERATIONAL, PRE_OPERATIONAL),
    ]:
        hb = rig.nmt_and_heartbeat(command, state)
        if state != OPERATIONAL:
            rig.frames.assert_none(
                lambda f: f.id == TPDO1, 0.4, since=hb.seq + 1, what="PDOs outside Operational"
            )


def test_remapping_tpdo1_by_the_cia_procedure(rig):
    rig.select("y")
    tpdo = rig.node.tpdo
    tpdo.read()
    feed = tpdo[1]
    feed.clear()
    feed.add_variable(0x2010, 1)  # axis
    feed.add_variable(0x6004, 0)  # position
    feed.trans_type = 254
    feed.enabled = True
    # python-canopen's save(): COB-ID invalid, parameters, sub0 = 0, entries, sub0 = n,
    # COB-ID valid again: the CiA 301 procedure.
    feed.save()
    assert rig.read(0x1800, 1) == 0x40000000 | TPDO1, "valid again (bit 30: no RTR)"
    assert rig.read(0x1A00, 0) == 2
    assert rig.read(0x1A00, 1) == 0x20100108
    assert rig.read(0x1A00, 2) == 0x60040020
    mark = rig.frames.mark()
    rig.start()
    pdo = rig.frames.wait_id(TPDO1, since=mark)
    assert pdo.data == bytes([2, 0, 0, 0, 0]), "DLC = 8 + 32 bits, axis Y, position 0"
    # Feed goes out in the new layout, and python-canopen decodes it through the EDS.
    rig.write(0x2000, 0, 1, 1)
    mark = rig.frames.mark()
    rig.stim.turn(1)
    pdo = rig.frames.wait_id(TPDO1, bytes([2, 1, 0, 0, 0]), since=mark)
    feed.wait_for_reception(timeout=2)
    assert feed["Position value"].raw == 1
    assert feed["Selection.Axis"].raw == 2
    # Read back by python-canopen from the device.
    tpdo.read()
    assert mapping(tpdo[1]) == [(0x2010, 1, 8), (0x6004, 0, 32)]


def test_mapping_errors_while_remapping(rig):
    rig.write(0x1800, 1, 0x80000000 | TPDO1, 4)
    assert rig.write_abort(0x1A00, 1, (0x60040020).to_bytes(4, "little")) == 0x06010000, (
        "entries locked until sub0 = 0"
    )
    rig.write(0x1A00, 0, 0, 1)
    for entry, code in [
        (0x70000020, 0x06020000),  # no such object
        (0x60040120, 0x06090011),  # no such sub
        (0x60040010, 0x06040041),  # wrong length
        (0x20000008, 0x06040041),  # not mappable
        (0x10080008, 0x06040041),  # not mappable
    ]:
        got = rig.write_abort(0x1A00, 1, entry.to_bytes(4, "little"))
        assert got == code, f"entry {entry:#010x}: {got:#010x}"
    assert rig.write_abort(0x1A00, 0, b"\x09") == 0x06040042, "9 > the 8 entries"
    rig.write(0x1A00, 1, 0x60040020, 4)
    rig.write(0x1A00, 2, 0x20200120, 4)
    rig.write(0x1A00, 3, 0x20100108, 4)
    assert rig.write_abort(0x1A00, 0, b"\x03") == 0x06040042, "72 bits > 64"
    rig.write(0x1A00, 0, 2, 1)
    rig.write(0x1800, 1, TPDO1, 4)
    mark = rig.frames.mark()
    rig.start()
    pdo = rig.frames.wait_id(TPDO1, since=mark)
    assert pdo.data == bytes(8), "position 0 and raw count 0"


def test_moving_tpdo1_to_another_can_id(rig):
    assert rig.write_abort(0x1800, 1, (0x1A0).to_bytes(4, "little")) == 0x06090030
    rig.write(0x1800, 1, 0x80000000 | 0x1A0, 4)
    rig.write(0x1800, 1, 0x1A0, 4)
    mark = rig.frames.mark()
    rig.start()
    pdo = rig.frames.wait_id(0x1A0, since=mark)
    assert len(pdo.data) == 8
    assert not rig.frames.frames(TPDO1, since=mark)
    # Heartbeat unaffected.
    assert rig.frames.frames(HEARTBEAT, since=mark)[0].data == bytes([OPERATIONAL])
