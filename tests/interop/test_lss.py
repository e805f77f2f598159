"""LSS (CiA 305) with python-canopen's `LssMaster` against the handwheel on the emulated
board.

A "store configuration" goes to the parameter pages in flash and is what the next power-on
starts with (`power` on the control line); a configured node-ID is taken at the next NMT
reset, a bit timing when it is activated. The host's side of the bus follows the node's
rate (no `rate` set), so the master keeps talking to it after a switch.
"""

import time

import pytest
from canopen.lss import LssError, LssMaster

from rig import (
    BOOTUP,
    FRAME_TIMEOUT,
    HEARTBEAT,
    NMT_RESET_COMMUNICATION,
    NMT_RESET_NODE,
    NODE_ID,
    PRE_OPERATIONAL,
)

LSS_RESPONSE = 0x7E4
# LssMaster waits this long for an answer; fastscan costs one timeout per 1-bit of the
# address, so keep it short (the node answers within a few ms).
LSS_TIMEOUT = 0.3


@pytest.fixture
def lss(rig) -> LssMaster:
    master = rig.network.lss
    master.RESPONSE_TIMEOUT = LSS_TIMEOUT
    return master


def identity(rig):
    return [rig.read(0x1018, sub) for sub in (1, 2, 3, 4)]


def heartbeat_of(node_id):
    return 0x700 + node_id


def sdo_answers(rig, node_id):
    """Whether node `node_id` answers an SDO upload of 0x1000 (raw frames)."""
    mark = rig.frames.mark()
    rig.network.send_message(0x600 + node_id, bytes([0x40, 0x00, 0x10, 0, 0, 0, 0, 0]))
    try:
        rig.frames.wait_id(0x580 + node_id, since=mark, timeout=1)
        return True
    except AssertionError:
        return False


def test_inquire_returns_the_identity(rig, lss):
    vendor, product, revision, serial = identity(rig)
    lss.send_switch_state_global(LssMaster.CONFIGURATION_STATE)
    assert lss.inquire_lss_address(0x5A) == vendor
    assert lss.inquire_lss_address(0x5B) == product
    assert lss.inquire_lss_address(0x5C) == revision
    assert lss.inquire_lss_address(0x5D) == serial
    assert lss.inquire_node_id() == NODE_ID
    lss.send_switch_state_global(LssMaster.WAITING_STATE)
    # Inquiries are for Configuration only: no answer in Waiting.
    with pytest.raises(LssError):
        lss.inquire_node_id()
    # The node itself carried on: SDO still answers, with the same identity.
    assert rig.read(0x1018, 1) == vendor


def test_selective_switch_by_identity(rig, lss):
    vendor, product, revision, serial = identity(rig)
    # python-canopen raises when nobody answers the last part.
    with pytest.raises(LssError):
        lss.send_switch_state_selective(vendor, product, revision, serial ^ 1)
    with pytest.raises(LssError):
        lss.inquire_node_id()
    assert lss.send_switch_state_selective(vendor, product, revision, serial)
    assert lss.inquire_node_id() == NODE_ID
    lss.send_switch_state_global(LssMaster.WAITING_STATE)


def test_identify_remote_slave_by_ranges(rig, lss):
    vendor, product, revision, serial = identity(rig)
    mark = rig.frames.mark()
    lss.send_identify_remote_slave(vendor, product, 0, 0xFFFFFFFF, serial, serial)
    answer = rig.frames.wait_id(LSS_RESPONSE, since=mark)
    assert answer.data == bytes([0x4F, 0, 0, 0, 0, 0, 0, 0])
    mark = rig.frames.mark()
    lss.send_identify_remote_slave(vendor, product, 0, 0xFFFFFFFF, 0, serial - 1)
    rig.frames.assert_none(lambda f: f.id == LSS_RESPONSE, 0.5, since=mark)


def test_configure_node_id_store_and_reset(rig, lss):
    vendor, product, revision, serial = identity(rig)
    assert lss.send_switch_state_selective(vendor, product, revision, serial)
    with pytest.raises(LssError, match="LSS Error: 1"):
        lss.configure_node_id(0)  # out of range
    lss.configure_node_id(5)
    lss.store_configuration()
    # Pending until the reset: still node 16.
    assert lss.inquire_node_id() == NODE_ID
    lss.send_switch_state_global(LssMaster.WAITING_STATE)
    assert sdo_answers(rig, NODE_ID)

    mark = rig.nmt(NMT_RESET_NODE)
    bootup = rig.frames.wait_id(heartbeat_of(5), bytes([BOOTUP]), since=mark)
    assert sdo_answers(rig, 5)
    assert not sdo_answers(rig, NODE_ID)
    hb = rig.frames.wait_id(heartbeat_of(5), since=bootup.seq + 1, timeout=3)
    assert hb.data == bytes([PRE_OPERATIONAL])

    # A further reset (communication, then node) keeps node-ID 5.
    for command in (NMT_RESET_COMMUNICATION, NMT_RESET_NODE):
        mark = rig.nmt(command, 5)
        rig.frames.wait_id(heartbeat_of(5), bytes([BOOTUP]), since=mark)
        assert sdo_answers(rig, 5)
    lss.send_switch_state_global(LssMaster.CONFIGURATION_STATE)
    assert lss.inquire_node_id() == 5
    lss.send_switch_state_global(LssMaster.WAITING_STATE)
    # Stored: the next power-on starts as node 5.
    mark = rig.frames.mark()
    rig.board.control("power")
    rig.frames.wait_id(heartbeat_of(5), bytes([BOOTUP]), since=mark)
    rig.board.wait_for_log(r"node-ID 5, 1000 kbit/s \(Stored")


def test_configure_bit_timing_and_store(rig, lss):
    lss.send_switch_state_global(LssMaster.CONFIGURATION_STATE)
    with pytest.raises(LssError, match="LSS Error: 1"):
        lss.configure_bit_timing(5)  # 100 kbit/s: not in the device's table
    lss.configure_bit_timing(3)  # 250 kbit/s
    lss.store_configuration()
    rig.board.wait_for_log(r"LSS stored node-ID 16 at 250 kbit/s")
    # Stored, not active: an NMT reset keeps the running rate.
    mark = rig.nmt(NMT_RESET_NODE)
    rig.frames.wait_id(HEARTBEAT, bytes([BOOTUP]), since=mark)
    assert rig.board.status()["bitrate"] == "1000000"
    # Activate bit timing: the controller switches, the switch is logged.
    start = len(rig.board.log())
    lss.send_switch_state_global(LssMaster.CONFIGURATION_STATE)
    lss.activate_bit_timing(50)
    rig.board.wait_for_log(r"LSS: bit rate now 250 kbit/s", start=start)
    lss.send_switch_state_global(LssMaster.WAITING_STATE)
    # The board's status follows the controller's switch a moment after the log line.
    deadline = time.monotonic() + FRAME_TIMEOUT
    while rig.board.status()["bitrate"] != "250000" and time.monotonic() < deadline:
        time.sleep(0.01)
    assert rig.board.status()["bitrate"] == "250000"
    assert sdo_answers(rig, NODE_ID)
    # The next power-on starts at the stored rate.
    mark = rig.frames.mark()
    rig.board.control("power")
    rig.frames.wait_id(HEARTBEAT, bytes([BOOTUP]), since=mark)
    rig.board.wait_for_log(r"node-ID 16, 250 kbit/s \(Stored", start=start)
    assert rig.board.status()["bitrate"] == "250000"


def test_unconfigured_node_answers_fastscan_and_is_configured_by_it(rig, lss):
    expected = identity(rig)
    lss.send_switch_state_global(LssMaster.CONFIGURATION_STATE)
    lss.configure_node_id(0xFF)
    lss.send_switch_state_global(LssMaster.WAITING_STATE)
    mark = rig.nmt(NMT_RESET_COMMUNICATION)
    # Unconfigured: no boot-up, no heartbeat, no SDO, only LSS.
    rig.frames.assert_none(lambda f: f.id != LSS_RESPONSE, 1.5, since=mark)
    assert not sdo_answers(rig, NODE_ID)
    mark = rig.frames.mark()
    lss.send_identify_non_configured_remote_slave()
    assert rig.frames.wait_id(LSS_RESPONSE, since=mark).data == bytes([0x50] + [0] * 7)

    found, address = lss.fast_scan()
    assert found and address == expected
    # Fastscan left the node in Configuration.
    assert lss.inquire_node_id() == 0xFF
    lss.configure_node_id(7)
    mark = rig.frames.mark()
    lss.send_switch_state_global(LssMaster.WAITING_STATE)
    rig.frames.wait_id(heartbeat_of(7), bytes([BOOTUP]), since=mark)
    assert sdo_answers(rig, 7)
    node = rig.network.add_node(7, rig.node.object_dictionary)
    assert node.sdo.upload(0x1018, 4) == expected[3].to_bytes(4, "little")


def test_a_configured_node_ignores_fastscan(rig, lss):
    found, _ = lss.fast_scan()
    assert not found
