"""SDO server: every EDS object, writes, the conformance table's aborts, segmented
transfers. Abort codes are those of the CiA 301 table in shared/docs/canopen-reference.md
and of crates/canopen-slave's tests."""

import canopen
from canopen.objectdictionary import ODVariable

from emulated_clock import frame_times, gaps
from rig import HEARTBEAT, NMT_START, OPERATIONAL, SDO_TX

# Objects whose value the firmware supplies at run time, not the EDS default.
RUNTIME_VALUES = {
    (0x1018, 4),  # serial number: derived from the MCU's unique ID by the firmware
    (0x1F56, 1),  # the running image's CRC-32, sealed into its header at link time
    (0x2035, 0),  # the device's uptime
}


def eds_variables(node):
    for obj in node.object_dictionary.values():
        if isinstance(obj, ODVariable):
            yield obj
        else:
            yield from obj.values()


def abort_frame(index, sub, code):
    return bytes([0x80, index & 0xFF, index >> 8, sub]) + code.to_bytes(4, "little")


def test_every_eds_object_reads_its_default(rig):
    node = rig.node
    mismatches = []
    checked = 0
    for var in eds_variables(node):
        key = (var.index, var.subindex)
        name = f"{var.index:04X}sub{var.subindex} {var.name}"
        if var.access_type == "wo":
            continue
        if var.index < 0x1000:
            # The dummy types python-canopen adds from the EDS's [DummyUsage] (0x0002..0x0007,
            # which RPDO1 may map): data type definitions, not objects; the device answers
            # 0x06020000 (CiA 301 makes reading their size optional).
            code = rig.read_abort(var.index, var.subindex)
            if code != 0x06020000:
                mismatches.append(f"{name}: abort {code:#010x}, wanted 0x06020000")
            continue
        if var.index == 0x1003 and var.subindex > 0:
            # CiA 301: entries above the error count hold no data yet.
            code = rig.read_abort(0x1003, var.subindex)
            if code != 0x08000024:
                mismatches.append(f"{name}: abort {code:#010x}, wanted 0x08000024")
            continue
        try:
            raw = node.sdo.upload(var.index, var.subindex)
        except canopen.SdoAbortedError as e:
            mismatches.append(f"{name}: abort {e.code:#010x}")
            continue
        checked += 1
        if var.fixed_size:
            if len(raw) != len(var) // 8:
                mismatches.append(f"{name}: {len(raw)} bytes, wanted {len(var) // 8}")
                continue
        value = var.decode_raw(raw)
        if key in RUNTIME_VALUES:
            continue
        if value != var.default:
            mismatches.append(f"{name}: {value!r}, EDS default {var.default!r}")
    assert not mismatches, "\n".join(mismatches)
    assert checked > 60, f"only {checked} objects read"


def test_identity_strings_by_segmented_upload(rig):
    node = rig.node
    mark = rig.frames.mark()
    assert node.sdo.upload(0x1008, 0) == b"CNC handwheel"
    replies = [f.data for f in rig.frames.frames(SDO_TX, since=mark)]
    # Initiate with the size indicated, then two segments: 7 bytes, then 6 (n = 1, c = 1).
    assert replies == [
        bytes([0x41, 0x08, 0x10, 0x00, 13, 0, 0, 0]),
        bytes([0x00]) + b"CNC han",
        bytes([0x13]) + b"dwheel" + b"\x00",
    ]
    assert node.sdo["Manufacturer device name"].raw == "CNC handwheel"
    assert node.sdo["Manufacturer hardware version"].raw == "STM32F103C8"
    assert node.sdo["Manufacturer software version"].raw == "0.1.0"


def test_expedited_uploads_exact_frames(rig):
    assert rig.sdo_raw(bytes([0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0])) == bytes(
        [0x43, 0x00, 0x10, 0x00, 0x00, 0x00, 0x00, 0x00]
    )
    assert rig.sdo_raw(bytes([0x40, 0x17, 0x10, 0x00, 0, 0, 0, 0])) == bytes(
        [0x4B, 0x17, 0x10, 0x00, 0xE8, 0x03, 0x00, 0x00]
    )
    assert rig.sdo_raw(bytes([0x40, 0x00, 0x20, 0x00, 0, 0, 0, 0])) == bytes(
        [0x4F, 0x00, 0x20, 0x00, 0x00, 0x00, 0x00, 0x00]
    )


def test_writes_are_read_back(rig):
    rig.write(0x2020, 3, 2, 1)
    assert rig.read(0x2020, 3) == 2
    rig.write(0x2020, 4, 1, 1)
    assert rig.read(0x2020, 4) == 1
    rig.write(0x2001, 0, 1, 1)
    assert rig.read(0x2001) == 1
    rig.write(0x2040, 3, 100, 2)
    assert rig.read(0x2040, 3) == 100
    rig.write(0x1015, 0, 10, 2)
    assert rig.read(0x1015) == 10
    rig.write(0x1003, 0, 0, 1)  # clearing the (empty) history is allowed
    assert rig.read(0x1003) == 0
    # python-canopen's typed access through the EDS.
    rig.node.sdo["Producer heartbeat time"].raw = 700
    assert rig.node.sdo["Producer heartbeat time"].raw == 700


def test_heartbeat_time_write_restarts_the_timer(rig):
    rig.write(0x1017, 0, 200, 2)
    mark = rig.frames.mark()
    beats = gaps(frame_times(rig, HEARTBEAT, 4, since=mark, timeout=3))
    # Timed on the board's clock: their mean stays well short of the old 1000 ms period.
    assert all(0.1 < g < 0.4 for g in beats), f"heartbeat gaps {beats}"
    assert sum(beats) / len(beats) < 0.6, f"heartbeat gaps {beats}"
    rig.write(0x1017, 0, 0, 2)
    mark = rig.frames.mark()
    rig.frames.assert_none(lambda f: f.id == HEARTBEAT, 1.5, since=mark, what="heartbeats")


def test_conformance_table_aborts(rig):
    """The stimuli of the CiA conformance table and the abort each must give."""
    cases = [
        (
            "write 0x1000:00 (read-only)",
            lambda: rig.write_abort(0x1000, 0, b"\x01\x02\x03\x04"),
            0x06010002,
        ),
        ("read 0x1000:01 (no such sub)", lambda: rig.read_abort(0x1000, 1), 0x06090011),
        ("read 0x1004:00 (no such object)", lambda: rig.read_abort(0x1004, 0), 0x06020000),
        (
            "4-byte write to a U8",
            lambda: rig.write_abort(0x2000, 0, b"\x01\x00\x00\x00"),
            0x06070012,
        ),
        ("1-byte write to a U32", lambda: rig.write_abort(0x1016, 1, b"\x01"), 0x06070013),
        ("1-byte write to a U16", lambda: rig.write_abort(0x1017, 0, b"\x01"), 0x06070013),
        ("U8 above its range", lambda: rig.write_abort(0x2000, 0, b"\x02"), 0x06090031),
        ("U8 below its range", lambda: rig.write_abort(0x2020, 3, b"\x00"), 0x06090032),
        ("U8 invalid in range", lambda: rig.write_abort(0x2020, 3, b"\x03"), 0x06090030),
        (
            "U16 above its range",
            lambda: rig.write_abort(0x2040, 3, (1001).to_bytes(2, "little")),
            0x06090031,
        ),
        ("U16 below its range", lambda: rig.write_abort(0x2040, 3, b"\x00\x00"), 0x06090032),
        ("write a ro object", lambda: rig.write_abort(0x6004, 0, b"\x00\x00\x00\x00"), 0x06010002),
        ("write a ro U8", lambda: rig.write_abort(0x2030, 0, b"\x00"), 0x06010002),
        ("write a const sub0", lambda: rig.write_abort(0x1018, 0, b"\x04"), 0x06010002),
        ("write a missing sub", lambda: rig.write_abort(0x1018, 5, b"\x01"), 0x06090011),
        ("write a missing object", lambda: rig.write_abort(0x1004, 0, b"\x01"), 0x06020000),
        ("read the reserved 0x1800:04", lambda: rig.read_abort(0x1800, 4), 0x06090011),
        ("read 0x1003:1 with no errors", lambda: rig.read_abort(0x1003, 1), 0x08000024),
        ("write 0x1003:0 = 1", lambda: rig.write_abort(0x1003, 0, b"\x01"), 0x06090030),
        ("feed enable in Pre-operational", lambda: rig.write_abort(0x2000, 0, b"\x01"), 0x08000022),
        (
            "TPDO1 CAN-ID change while valid",
            lambda: rig.write_abort(0x1800, 1, (0x191).to_bytes(4, "little")),
            0x06090030,
        ),
        (
            "TPDO1 inhibit time while valid",
            lambda: rig.write_abort(0x1800, 3, (50).to_bytes(2, "little")),
            0x06090030,
        ),
        ("transmission type 241", lambda: rig.write_abort(0x1800, 2, b"\xf1"), 0x06090030),
        (
            "mapping entry while the PDO is valid",
            lambda: rig.write_abort(0x1A00, 1, (0x60040020).to_bytes(4, "little")),
            0x06010000,
        ),
        (
            "mapping count while the PDO is valid",
            lambda: rig.write_abort(0x1A00, 0, b"\x00"),
            0x06010000,
        ),
        (
            "EMCY COB-ID change while valid",
            lambda: rig.write_abort(0x1014, 0, (0x91).to_bytes(4, "little")),
            0x06090030,
        ),
    ]
    wrong = []
    for what, action, want in cases:
        got = action()
        if got != want:
            wrong.append(f"{what}: {got:#010x}, wanted {want:#010x}")
    assert not wrong, "\n".join(wrong)
    # Nothing rejected changed anything.
    assert rig.read(0x2000) == 0
    assert rig.read(0x2020, 3) == 4
    assert rig.read(0x2040, 3) == 40
    assert rig.read(0x1017) == 1000
    assert rig.read(0x1800, 1) == 0x40000190  # unchanged (bit 30: no RTR)
    assert rig.read(0x1A00, 0) == 4


def test_unknown_and_block_commands_abort_with_exact_frames(rig):
    for command in [0xE0, 0xA0, 0xA4, 0xC0, 0xC6, 0xFF]:
        reply = rig.sdo_raw(bytes([command, 0x00, 0x10, 0x00, 0, 0, 0, 0]))
        assert reply == abort_frame(0x1000, 0, 0x05040001), f"command {command:#04x}"


def test_segmented_upload_with_a_wrong_toggle_aborts(rig):
    initiate = rig.sdo_raw(bytes([0x40, 0x08, 0x10, 0x00, 0, 0, 0, 0]))
    assert initiate == bytes([0x41, 0x08, 0x10, 0x00, 13, 0, 0, 0])
    # The first segment request must have toggle 0.
    assert rig.sdo_raw(bytes([0x70, 0, 0, 0, 0, 0, 0, 0])) == abort_frame(0x1008, 0, 0x05030000)
    # The transfer is over: a segment request is now an unknown command.
    assert rig.sdo_raw(bytes([0x60, 0, 0, 0, 0, 0, 0, 0])) == abort_frame(0, 0, 0x05040001)


def test_segmented_download_of_two_bytes_to_1017_succeeds(rig):
    mark = rig.frames.mark()
    rig.node.sdo.download(0x1017, 0, (500).to_bytes(2, "little"), force_segment=True)
    replies = [f.data for f in rig.frames.frames(SDO_TX, since=mark)]
    assert replies == [
        bytes([0x60, 0x17, 0x10, 0x00, 0, 0, 0, 0]),  # initiate (segmented) accepted
        bytes([0x20, 0, 0, 0, 0, 0, 0, 0]),  # last segment, toggle 0
    ]
    assert rig.read(0x1017) == 500


def test_expedited_download_without_size_takes_the_object_size(rig):
    reply = rig.sdo_raw(bytes([0x22, 0x17, 0x10, 0x00, 0xF4, 0x01, 0xAA, 0xBB]))
    assert reply == bytes([0x60, 0x17, 0x10, 0x00, 0, 0, 0, 0])
    assert rig.read(0x1017) == 500


def test_requests_with_a_wrong_dlc_are_ignored(rig):
    mark = rig.frames.mark()
    for length in range(8):
        rig.network.send_message(0x610, bytes([0x2F, 0x00, 0x20, 0x00, 1, 0, 0, 0])[:length])
    rig.frames.assert_none(lambda f: f.id == SDO_TX, 0.5, since=mark, what="SDO replies")
    assert rig.read(0x2000) == 0


def test_feed_enable_is_refused_until_operational(rig):
    assert rig.write_abort(0x2000, 0, b"\x01") == 0x08000022
    assert rig.read(0x2000) == 0
    mark = rig.nmt(NMT_START)
    rig.frames.wait_id(HEARTBEAT, bytes([OPERATIONAL]), since=mark)
    rig.write(0x2000, 0, 1, 1)
    assert rig.read(0x2000) == 1
    assert rig.write_abort(0x2000, 0, b"\x02") == 0x06090031
