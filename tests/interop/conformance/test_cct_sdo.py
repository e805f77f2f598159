"""CCT cases SDO 01-30 against the handwheel (see docs/CONFORMANCE.md)."""

import pytest

from cct import abort_frame, abort_of, dut, req, sdo_raw, shared_rig  # noqa: F401
from rig import BOOTUP, HEARTBEAT, NMT_RESET_COMMUNICATION

DEVICE_NAME = b"CNC handwheel"


def segmented_upload(rig, index, sub=0):
    """Raw segmented upload; checks the toggle and the size and returns the data."""
    init = sdo_raw(rig, req(0x40, index, sub))
    assert init[0] == 0x41, f"segmented initiate with size expected: {init.hex(' ')}"
    assert init[1:4] == bytes([index & 0xFF, index >> 8, sub])
    size = int.from_bytes(init[4:8], "little")
    data = b""
    toggle = 0
    while True:
        seg = sdo_raw(rig, bytes([0x60 | toggle << 4]) + bytes(7))
        assert seg[0] & 0xE0 == 0x00, f"upload segment expected: {seg.hex(' ')}"
        assert (seg[0] >> 4) & 1 == toggle, "toggle bit of the segment"
        n = 7 - ((seg[0] >> 1) & 7)
        data += seg[1 : 1 + n]
        if seg[0] & 1:
            break
        toggle ^= 1
    assert len(data) == size
    return data


def test_sdo_01_read_1000_expedited(dut):
    assert sdo_raw(dut, req(0x40, 0x1000, 0)) == req(0x43, 0x1000, 0, (0).to_bytes(4, "little"))


def test_sdo_02_read_write_rw_communication_entry(dut):
    assert sdo_raw(dut, req(0x40, 0x1017, 0)) == req(0x4B, 0x1017, 0, (1000).to_bytes(2, "little"))
    assert sdo_raw(dut, req(0x2B, 0x1017, 0, (0).to_bytes(2, "little"))) == req(0x60, 0x1017, 0)
    assert dut.read(0x1017) == 0


def test_sdo_03_write_1000_is_refused(dut):
    code = abort_of(sdo_raw(dut, req(0x23, 0x1000, 0, (0x000F0191).to_bytes(4, "little"))))
    assert code in (0x06010000, 0x06010002, 0x08000000)
    assert dut.read(0x1000) == 0


def test_sdo_04_read_write_only_object(dut):
    # The session key (0x2034) is write-only: a read is "attempt to read a write only object".
    assert abort_of(sdo_raw(dut, req(0x40, 0x2034, 0))) == 0x06010001


def test_sdo_05_read_nonexistent_sub_1000_01(dut):
    assert abort_of(sdo_raw(dut, req(0x40, 0x1000, 1))) in (0x06090011, 0x08000000)


def test_sdo_06_read_nonexistent_object_1004(dut):
    assert abort_of(sdo_raw(dut, req(0x40, 0x1004, 0))) in (0x06020000, 0x08000000)


def test_sdo_07_wrong_command_specifier(dut):
    assert abort_of(sdo_raw(dut, req(0xE0, 0x1000, 0))) in (0x05040001, 0x08000000)


def test_sdo_08_write_u32_to_u8_object(dut):
    assert dut.read(0x1003, 0) == 0
    code = abort_of(sdo_raw(dut, req(0x23, 0x1003, 0, bytes(4))))
    assert code in (0x06070010, 0x06070012, 0x08000000)


def test_sdo_09_write_u8_to_u32_object(dut):
    assert dut.read(0x1005) == 0x80
    code = abort_of(sdo_raw(dut, req(0x2F, 0x1005, 0, b"\x80")))
    assert code in (0x06070010, 0x06070013, 0x08000000)
    assert dut.read(0x1005) == 0x80


def test_sdo_10_write_too_high_value(dut):
    # 0x1003:0 accepts only 0 (clear the history).
    code = abort_of(sdo_raw(dut, req(0x2F, 0x1003, 0, b"\xff")))
    assert code in (0x06090030, 0x06090031, 0x08000000)
    # And an object with an EDS high limit: 0x2040:3 is 1..1000.
    code = abort_of(sdo_raw(dut, req(0x2B, 0x2040, 3, (1001).to_bytes(2, "little"))))
    assert code in (0x06090030, 0x06090031, 0x08000000)


def test_sdo_11_write_too_low_value(dut):
    # 0x2040:3 (unit-step backlog bound) has low limit 1.
    code = abort_of(sdo_raw(dut, req(0x2B, 0x2040, 3, (0).to_bytes(2, "little"))))
    assert code in (0x06090030, 0x06090032, 0x08000000)
    assert dut.read(0x2040, 3) == 40


def test_sdo_12_sdo_server_parameter_1200(dut):
    # 0x1200 is optional for the default SDO server; where present it must give
    # 0x600 + node-ID / 0x580 + node-ID.
    reply = sdo_raw(dut, req(0x40, 0x1200, 1))
    if reply[0] == 0x80:
        assert abort_of(reply) == 0x06020000
        pytest.skip("no 0x1200 (optional for the default SDO server); abort 0x06020000 checked")
    assert int.from_bytes(reply[4:8], "little") == 0x600 + dut.node.id
    assert dut.read(0x1200, 2) == 0x580 + dut.node.id


def test_sdo_13_read_1000_by_segmented_request(dut):
    # The tool asks for 0x1000 with an upload request; a 4-byte object is answered
    # expedited, which a client must accept.
    reply = sdo_raw(dut, req(0x40, 0x1000, 0))
    assert reply[0] in (0x43, 0x41)
    if reply[0] == 0x43:
        assert reply[4:8] == bytes(4)


def test_sdo_14_write_100c_segmented(dut):
    pytest.skip("node guarding not implemented (no 0x100C)")


def test_sdo_15_write_1017_segmented(dut):
    assert sdo_raw(dut, req(0x21, 0x1017, 0, (2).to_bytes(4, "little"))) == req(0x60, 0x1017, 0)
    # One last segment with 2 bytes (n = 5), toggle 0.
    assert sdo_raw(dut, bytes([0x0B, 0xF4, 0x01]) + bytes(5)) == bytes([0x20]) + bytes(7)
    assert dut.read(0x1017) == 500


def test_sdo_16_read_segmented_object(dut):
    assert segmented_upload(dut, 0x1008) == DEVICE_NAME


def test_sdo_17_segmented_read_with_wrong_toggle(dut):
    init = sdo_raw(dut, req(0x40, 0x1008, 0))
    assert init[0] == 0x41
    reply = sdo_raw(dut, bytes([0x70]) + bytes(7))  # first segment must have toggle 0
    assert reply == abort_frame(0x1008, 0, 0x05030000)


def test_sdo_18_read_object_segmented(dut):
    for index in (0x1008, 0x1009):
        data = segmented_upload(dut, index)
        assert data == dut.node.sdo.upload(index, 0)


def _block_refused(rig, request):
    reply = sdo_raw(rig, request)
    assert reply[0] == 0x80, f"block transfer is not supported, expected an abort: {reply.hex(' ')}"
    return abort_of(reply)


def test_sdo_19_block_read_1000_without_crc(dut):
    assert _block_refused(dut, req(0xA0, 0x1000, 0, bytes([0x14]))) == 0x05040001


def test_sdo_20_block_write_100c_without_crc(dut):
    pytest.skip("node guarding not implemented (no 0x100C)")


def test_sdo_21_block_write_1017_without_crc(dut):
    assert _block_refused(dut, req(0xC2, 0x1017, 0, (2).to_bytes(4, "little"))) == 0x05040001
    assert dut.read(0x1017) == 1000


def test_sdo_22_block_read_segmented_object(dut):
    assert _block_refused(dut, req(0xA0, 0x1008, 0, bytes([0x14]))) == 0x05040001


def test_sdo_23_block_read_with_crc(dut):
    assert _block_refused(dut, req(0xA4, 0x1008, 0, bytes([0x14]))) == 0x05040001


def test_sdo_24_block_write_100c_with_crc(dut):
    pytest.skip("node guarding not implemented (no 0x100C)")


def test_sdo_25_block_write_1017_with_crc(dut):
    assert _block_refused(dut, req(0xC6, 0x1017, 0, (2).to_bytes(4, "little"))) == 0x05040001
    assert dut.read(0x1017) == 1000


def test_sdo_26_block_read_with_wrong_blocksize(dut):
    code = _block_refused(dut, req(0xA0, 0x1000, 0, bytes([0x80])))
    assert code in (0x05040001, 0x05040002, 0x08000000)


def test_sdo_27_block_read_with_wrong_sequence_number(dut):
    assert _block_refused(dut, req(0xA0, 0x1000, 0, bytes([0x14]))) == 0x05040001
    pytest.skip(
        "block transfer not supported (refused with 0x05040001, as the tool requires);"
        " the tool skips this case then"
    )


def test_sdo_28_additional_sdo_servers(dut):
    # One additional server, 0x1201, not valid until a master configures it; 0x1202..0x127F
    # absent.
    assert sdo_raw(dut, req(0x40, 0x1201, 0)) == req(0x4F, 0x1201, 0, bytes([3]))
    for sub in (1, 2):
        reply = sdo_raw(dut, req(0x40, 0x1201, sub))
        assert reply == req(0x43, 0x1201, sub, (0x80000000).to_bytes(4, "little"))
    assert sdo_raw(dut, req(0x40, 0x1201, 3)) == req(0x4F, 0x1201, 3, bytes([0]))
    for index in range(0x1202, 0x1280):
        reply = sdo_raw(dut, req(0x40, index, 1))
        assert abort_of(reply) in (0x06020000, 0x08000000), f"{index:#06x}"


def test_sdo_29_additional_sdo_servers_after_reset_communication(dut):
    rx, tx = 0x680 + dut.node.id, 0x6A0 + dut.node.id
    dut.write(0x1201, 1, rx, 4)
    dut.write(0x1201, 2, tx, 4)
    dut.write(0x1201, 3, 1, 1)
    mark = dut.frames.mark()
    dut.network.send_message(rx, req(0x40, 0x1000, 0))
    assert dut.frames.wait_id(tx, since=mark).data == req(0x43, 0x1000, 0, bytes(4))
    mark = dut.nmt(NMT_RESET_COMMUNICATION)
    dut.frames.wait_id(HEARTBEAT, bytes([BOOTUP]), since=mark)
    assert [dut.read(0x1201, sub) for sub in (1, 2, 3)] == [0x80000000, 0x80000000, 0]
    mark = dut.frames.mark()
    dut.network.send_message(rx, req(0x40, 0x1000, 0))
    dut.frames.assert_none(lambda f: f.id == tx, 0.4, since=mark, what="second SDO replies")


def test_sdo_30_sdo_clients_saved_and_reset(dut):
    for index in (0x1280, 0x1281, 0x12FF):
        assert abort_of(sdo_raw(dut, req(0x40, index, 1))) in (0x06020000, 0x08000000)
    pytest.skip("no SDO client (0x1280..0x12FF absent, checked)")
