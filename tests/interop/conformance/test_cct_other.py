"""CCT cases Testing other 01-10 against the handwheel (see docs/CONFORMANCE.md): store
(0x1010) and restore (0x1011) with wrong and right signatures, 0x1020, restricted CAN-IDs."""

import pytest

from cct import abort_of, dut, req, sdo_raw, shared_rig  # noqa: F401
from rig import BOOTUP, HEARTBEAT, NMT_RESET_NODE

SAVE = b"save"
LOAD = b"load"
WRONG = b"wron"


def reset(rig):
    mark = rig.nmt(NMT_RESET_NODE)
    rig.frames.wait_id(HEARTBEAT, bytes([BOOTUP]), since=mark)


def factory(rig):
    rig.node.sdo.download(0x1011, 1, LOAD)
    reset(rig)


def wrong_signature(rig, index, sub):
    assert rig.read(index, sub) & 1, f"{index:#06x}:{sub} says the command is supported"
    code = abort_of(sdo_raw(rig, req(0x23, index, sub, WRONG)))
    assert code in (0x08000020, 0x08000000, 0x06090030)


def test_testing_other_01_store_all_wrong_signature(dut):
    dut.write(0x1017, 0, 1234, 2)
    wrong_signature(dut, 0x1010, 1)
    reset(dut)
    assert dut.read(0x1017) == 1000, "nothing was stored"


def test_testing_other_02_store_all(dut):
    try:
        dut.write(0x1017, 0, 1234, 2)
        dut.write(0x2040, 3, 77, 2)
        dut.node.sdo.download(0x1010, 1, SAVE)
        reset(dut)
        assert dut.read(0x1017) == 1234
        assert dut.read(0x2040, 3) == 77
    finally:
        factory(dut)
    assert dut.read(0x1017) == 1000
    assert dut.read(0x2040, 3) == 40


def test_testing_other_03_restore_all_wrong_signature(dut):
    try:
        dut.write(0x1017, 0, 1234, 2)
        dut.node.sdo.download(0x1010, 1, SAVE)
        wrong_signature(dut, 0x1011, 1)
        reset(dut)
        assert dut.read(0x1017) == 1234, "the stored value was not restored to factory"
    finally:
        factory(dut)


def test_testing_other_04_restore_all(dut):
    dut.write(0x1017, 0, 1234, 2)
    dut.node.sdo.download(0x1010, 1, SAVE)
    dut.node.sdo.download(0x1011, 1, LOAD)
    reset(dut)
    assert dut.read(0x1017) == 1000


def test_testing_other_05_store_communication_wrong_signature(dut):
    dut.write(0x1017, 0, 1234, 2)
    wrong_signature(dut, 0x1010, 2)
    reset(dut)
    assert dut.read(0x1017) == 1000


def test_testing_other_06_store_communication(dut):
    try:
        dut.write(0x1017, 0, 1234, 2)
        dut.write(0x2040, 3, 77, 2)
        dut.node.sdo.download(0x1010, 2, SAVE)
        reset(dut)
        assert dut.read(0x1017) == 1234
        assert dut.read(0x2040, 3) == 40, "application parameters are not in sub 2"
    finally:
        factory(dut)


def test_testing_other_07_restore_communication_wrong_signature(dut):
    try:
        dut.write(0x1017, 0, 1234, 2)
        dut.node.sdo.download(0x1010, 2, SAVE)
        wrong_signature(dut, 0x1011, 2)
        reset(dut)
        assert dut.read(0x1017) == 1234
    finally:
        factory(dut)


def test_testing_other_08_restore_communication(dut):
    try:
        dut.write(0x1017, 0, 1234, 2)
        dut.write(0x2040, 3, 77, 2)
        dut.node.sdo.download(0x1010, 1, SAVE)
        dut.node.sdo.download(0x1011, 2, LOAD)
        reset(dut)
        assert dut.read(0x1017) == 1000
        assert dut.read(0x2040, 3) == 77, "application parameters stay stored"
    finally:
        factory(dut)


def test_testing_other_09_store_with_time_of_day(dut):
    assert abort_of(sdo_raw(dut, req(0x40, 0x1020, 1))) == 0x06020000
    pytest.skip("no 0x1020 (verify configuration) in the dictionary")


RESTRICTED = [
    *range(0x000, 0x080),
    *range(0x101, 0x181),
    *range(0x581, 0x600),
    *range(0x601, 0x680),
    *range(0x6E0, 0x700),
    *range(0x701, 0x800),
]


def test_testing_other_10_restricted_can_ids(dut):
    ids = RESTRICTED[::3] + [0x07F, 0x101, 0x180, 0x5FF, 0x67F, 0x6FF, 0x7FF]
    # SYNC: a plain COB-ID.
    for can_id in ids:
        reply = sdo_raw(dut, req(0x23, 0x1005, 0, can_id.to_bytes(4, "little")))
        assert abort_of(reply) == 0x06090030, f"0x1005 <- {can_id:#x}"
    assert dut.read(0x1005) == 0x80
    # EMCY and TPDOs: made invalid first (a valid one may not change its CAN-ID), then a
    # valid restricted identifier must be refused.
    for index, sub in ((0x1014, 0), (0x1800, 1), (0x1801, 1)):
        before = dut.read(index, sub)
        dut.write(index, sub, before | 0x80000000, 4)
        for can_id in ids:
            reply = sdo_raw(dut, req(0x23, index, sub, can_id.to_bytes(4, "little")))
            assert abort_of(reply) == 0x06090030, f"{index:#06x}:{sub} <- {can_id:#x}"
        dut.write(index, sub, before, 4)
        assert dut.read(index, sub) == before
