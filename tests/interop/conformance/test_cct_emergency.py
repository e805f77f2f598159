"""CCT cases Emergency 01-06 against the handwheel (see docs/CONFORMANCE.md)."""

from cct import abort_of, dut, req, sdo_raw, shared_rig  # noqa: F401
from rig import EMCY


def raise_emcy(rig):
    """An illegal quadrature jump with feed on: EMCY 0x7300 (README, Emergency codes)."""
    # The wheel's lines persist across the reset node of other cases: after a case that
    # ended on 3, this is itself an illegal jump, whose error the enable below clears.
    rig.stim.ab(0)
    rig.feed_on("x")
    # The device notices the cleared error only after it has answered the enable, so a jump
    # made as soon as that answer arrives could fall before it looks (the error then never
    # counts as cleared, and no new EMCY is due). Any later answer comes after it looked.
    assert rig.read(0x1001) == 0, "the encoder error of an earlier jump is still active"
    mark = rig.frames.mark()
    rig.stim.ab(3)
    return rig.frames.wait_for(
        lambda f: f.id == EMCY and f.data[:2] == b"\x00\x73", since=mark, what="EMCY 0x7300"
    )


def test_emergency_01_emcy_cob_id(dut):
    assert dut.read(0x1014) == 0x80 + dut.node.id


def test_emergency_02_error_register(dut):
    assert dut.read(0x1001) == 0


def test_emergency_03_empty_error_history(dut):
    assert dut.read(0x1003, 0) == 0
    assert abort_of(sdo_raw(dut, req(0x40, 0x1003, 1))) in (0x08000024, 0x06090011, 0x08000000)


def test_emergency_04_emcy_is_sent(dut):
    frame = raise_emcy(dut)
    assert len(frame.data) == 8
    assert frame.data[2] != 0  # error register bits set


def test_emergency_05_error_register_follows_emcy(dut):
    frame = raise_emcy(dut)
    assert dut.read(0x1001) == frame.data[2] != 0


def test_emergency_06_error_history_matches_emcy(dut):
    frame = raise_emcy(dut)
    assert dut.read(0x1003, 0) >= 1
    entry = dut.read(0x1003, 1)
    assert entry & 0xFFFF == int.from_bytes(frame.data[:2], "little")
