"""CCT cases OD 01-09 against the handwheel (see docs/CONFORMANCE.md)."""

import pytest
from canopen.objectdictionary import ODVariable

from cct import abort_of, dut, req, sdo_raw, shared_rig  # noqa: F401

# The serial number (from the MCU), the running image's CRC-32 (sealed at link time) and the
# device's uptime.
RUNTIME_VALUES = {(0x1018, 4), (0x1F56, 1), (0x2035, 0)}


def variables(rig, low, high):
    for obj in rig.node.object_dictionary.values():
        if not low <= obj.index <= high:
            continue
        if isinstance(obj, ODVariable):
            yield obj
        else:
            yield from obj.values()


def readable(var):
    return var.access_type in ("ro", "rw", "rwr", "rww", "const")


SIZES = {0x1: 1, 0x2: 1, 0x3: 2, 0x4: 4, 0x5: 1, 0x6: 2, 0x7: 4}


def test_od_01_communication_objects_by_access_type(dut):
    for var in variables(dut, 0x1000, 0x1FFF):
        reply = sdo_raw(dut, req(0x40, var.index, var.subindex))
        if reply[0] == 0x80:  # only an empty error history may refuse
            assert (var.index, abort_of(reply)) == (0x1003, 0x08000024), var.name
        else:
            assert readable(var)


def test_od_02_communication_objects_against_eds_defaults(dut):
    for var in variables(dut, 0x1000, 0x1FFF):
        if var.default is None or (var.index, var.subindex) in RUNTIME_VALUES:
            continue
        if var.index == 0x1003 and var.subindex > 0:
            continue  # empty history: abort 0x08000024 (OD 01)
        assert var.decode_raw(dut.node.sdo.upload(var.index, var.subindex)) == var.default, (
            f"{var.index:#06x}:{var.subindex}"
        )


def test_od_03_write_to_read_only_objects(dut):
    for var in variables(dut, 0x1000, 0x9FFF):
        if var.access_type not in ("ro", "const"):
            continue
        size = SIZES.get(var.data_type, 4)
        command = {1: 0x2F, 2: 0x2B, 4: 0x23}[size]
        code = abort_of(sdo_raw(dut, req(command, var.index, var.subindex, bytes(size))))
        assert code in (0x06010000, 0x06010002, 0x08000000), f"{var.index:#06x}:{var.subindex}"


def test_od_04_read_write_only_objects(dut):
    write_only = [v for v in variables(dut, 0x1000, 0x9FFF) if v.access_type == "wo"]
    assert [(v.index, v.subindex) for v in write_only] == [(0x2034, 0)], "the session key"
    for var in write_only:
        code = abort_of(sdo_raw(dut, req(0x40, var.index, var.subindex)))
        assert code == 0x06010001, f"{var.index:#06x}:{var.subindex}: {code:#010x}"


def test_od_05_sub_index_255(dut):
    for obj in dut.node.object_dictionary.values():
        if obj.index < 0x1000:
            # The dummy mapping types python-canopen adds from [DummyUsage] (0x0002..0x0007):
            # not in the EDS's object lists, which the tool walks; the device has no object
            # there (0x06020000) and takes them only as RPDO mapping entries (PDO 33).
            continue
        assert abort_of(sdo_raw(dut, req(0x40, obj.index, 0xFF))) in (0x06090011, 0x08000000)
    pytest.skip("no object has sub-index 255 (every read aborts 0x06090011, checked)")


def test_od_06_value_limits_of_rw_objects(dut):
    checked = 0
    for var in variables(dut, 0x1000, 0x9FFF):
        # A mapping's count (sub 0) has no limit in the EDS: a write to a valid PDO's mapping
        # is refused (0x06010000; PDO 24), a count above the entries is PDO 25's.
        if var.access_type not in ("rw", "rwr", "rww") or var.index in (0x1600, 0x1A00, 0x1A01):
            continue
        size = len(dut.node.sdo.upload(var.index, var.subindex))
        for value, codes in (
            (var.min, (0x06090030, 0x06090032)),
            (var.max, (0x06090030, 0x06090031)),
        ):
            if value is None:
                continue
            bad = value - 1 if codes[1] == 0x06090032 else value + 1
            if bad < 0 or bad >= 1 << (8 * size):
                continue
            command = {1: 0x2F, 2: 0x2B, 4: 0x23}[size]
            code = abort_of(
                sdo_raw(dut, req(command, var.index, var.subindex, bad.to_bytes(size, "little")))
            )
            assert code in codes + (0x08000000,), f"{var.index:#06x}:{var.subindex} = {bad}"
            checked += 1
    assert checked >= 5


def test_od_07_application_objects_by_access_type(dut):
    for var in variables(dut, 0x2000, 0x9FFF):
        if var.access_type == "wo":
            continue  # the session key: its read refused, checked in OD 04
        assert readable(var)
        dut.node.sdo.upload(var.index, var.subindex)


# Application objects that count on across a reset node (the feed contract): the record
# sequence and the selection epoch continue, so that no record after a reset can be taken as
# continuing one from before it (a host that missed the boot-up would otherwise link them).
# Their EDS default is the value at power-on only.
RUN_ON_ACROSS_RESETS = {(0x2010, 3), (0x2031, 0), (0x2035, 0)}
# The feed selection byte carries the epoch's low three bits in bits 5-7: those follow
# 0x2010:3, the rest has its default.
FEED_SELECTION = (0x2011, 0)
# The sequence probe reads the number the next record carries (0x2031) in bits 16-31.
SEQUENCE_PROBE = (0x2033, 0)


def test_od_08_application_objects_against_eds_defaults(dut):
    """Every application object with an EDS default has it after a reset node, but the
    counters in `RUN_ON_ACROSS_RESETS`, the epoch's bits of the feed selection byte (which
    the order the cases ran in decides: one step per reset node) and the sequence probe's
    copy of the sequence."""
    wrong = []
    for var in variables(dut, 0x2000, 0x9FFF):
        if var.default is None or (var.index, var.subindex) in RUN_ON_ACROSS_RESETS:
            continue
        if var.access_type == "wo":
            continue  # nothing to read back
        value = var.decode_raw(dut.node.sdo.upload(var.index, var.subindex))
        expected = var.default
        if (var.index, var.subindex) == FEED_SELECTION:
            epoch = dut.node.sdo[0x2010][3].raw
            expected = (var.default & 0x1F) | (epoch & 0b111) << 5
        if (var.index, var.subindex) == SEQUENCE_PROBE:
            expected = var.default & 0xFFFF | dut.node.sdo[0x2031].raw << 16
        if value != expected:
            wrong.append(f"{var.index:#06x}:{var.subindex} = {value}, expected {expected}")
    assert not wrong, wrong


def test_od_09_rw_application_objects_written_back(dut):
    for var in variables(dut, 0x2000, 0x9FFF):
        if var.access_type != "rw":
            continue
        raw = dut.node.sdo.upload(var.index, var.subindex)
        if (var.index, var.subindex) == SEQUENCE_PROBE:
            # A write's bits 16-31 are a session key, a read's the sequence: the nonce and
            # session written back with no key.
            raw = raw[:2] + bytes(2)
            dut.node.sdo.download(var.index, var.subindex, raw)
            assert dut.node.sdo.upload(var.index, var.subindex)[:2] == raw[:2]
            continue
        dut.node.sdo.download(var.index, var.subindex, raw)
        assert dut.node.sdo.upload(var.index, var.subindex) == raw
