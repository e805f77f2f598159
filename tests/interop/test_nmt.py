"""NMT: boot-up, state changes addressed and broadcast, resets, Stopped."""

import time

import can
import canopen
import pytest

from rig import (
    BOOTUP,
    HEARTBEAT,
    NMT,
    NMT_PRE_OPERATIONAL,
    NMT_RESET_COMMUNICATION,
    NMT_RESET_NODE,
    NMT_START,
    NMT_STOP,
    NODE_ID,
    OPERATIONAL,
    PRE_OPERATIONAL,
    SDO_RX,
    SDO_TX,
    STOPPED,
)

TARGETS = [pytest.param(NODE_ID, id="addressed"), pytest.param(0, id="broadcast")]


def test_bootup_is_the_first_frame_with_state_0(rig):
    first = rig.frames.frames()[0]
    assert (first.id, first.data) == (HEARTBEAT, bytes([BOOTUP]))
    # The next heartbeat is a periodic Pre-operational one, not one right after the
    # boot-up (a master could miss the boot-up otherwise).
    hb = rig.frames.wait_id(HEARTBEAT, since=first.seq + 1, timeout=3)
    assert hb.data == bytes([PRE_OPERATIONAL])
    assert hb.t - first.t > 0.3, f"heartbeat {hb.t - first.t:.3f} s after the boot-up"
    # The master's view: python-canopen took the boot-up as entry to PRE-OPERATIONAL.
    assert rig.node.nmt.state == "PRE-OPERATIONAL"


@pytest.mark.parametrize("target", TARGETS)
def test_each_command_is_answered_by_a_heartbeat_of_the_new_state(rig, target):
    for command, state, name in [
        (NMT_START, OPERATIONAL, "OPERATIONAL"),
        (NMT_STOP, STOPPED, "STOPPED"),
        (NMT_PRE_OPERATIONAL, PRE_OPERATIONAL, "PRE-OPERATIONAL"),
        (NMT_START, OPERATIONAL, "OPERATIONAL"),
        (NMT_PRE_OPERATIONAL, PRE_OPERATIONAL, "PRE-OPERATIONAL"),
        (NMT_STOP, STOPPED, "STOPPED"),
        (NMT_START, OPERATIONAL, "OPERATIONAL"),
    ]:
        hb = rig.nmt_and_heartbeat(command, state, target)
        assert hb.data == bytes([state])
        assert rig.node.nmt.state == name
    # The periodic heartbeat carries the state too.
    mark = rig.frames.mark()
    periodic = rig.frames.wait_id(HEARTBEAT, since=mark, timeout=3)
    assert periodic.data == bytes([OPERATIONAL])


def test_python_canopen_nmt_api_sees_the_states(rig):
    node = rig.node
    node.nmt.state = "OPERATIONAL"
    assert node.nmt.wait_for_heartbeat(timeout=3) == "OPERATIONAL"
    node.nmt.state = "STOPPED"
    assert node.nmt.wait_for_heartbeat(timeout=3) == "STOPPED"
    node.nmt.state = "PRE-OPERATIONAL"
    assert node.nmt.wait_for_heartbeat(timeout=3) == "PRE-OPERATIONAL"


@pytest.mark.parametrize("target", TARGETS)
def test_reset_node_boots_up_again_with_defaults(rig, target):
    rig.start()
    rig.write(0x2020, 3, 2, 1)  # counts per detent, not stored
    rig.write(0x1017, 0, 300, 2)
    mark = rig.nmt(NMT_RESET_NODE, target)
    bootup = rig.frames.wait_id(HEARTBEAT, since=mark)
    assert bootup.data == bytes([BOOTUP]), "a reset ends in a boot-up frame"
    assert rig.read(0x2020, 3) == 4, "application parameters back to defaults"
    assert rig.read(0x1017) == 1000, "communication parameters back to defaults"
    hb = rig.frames.wait_id(HEARTBEAT, since=bootup.seq + 1, timeout=3)
    assert hb.data == bytes([PRE_OPERATIONAL])


@pytest.mark.parametrize("target", TARGETS)
def test_reset_communication_restores_communication_objects_only(rig, target):
    rig.write(0x1017, 0, 300, 2)
    rig.write(0x2020, 3, 2, 1)
    mark = rig.nmt(NMT_RESET_COMMUNICATION, target)
    bootup = rig.frames.wait_id(HEARTBEAT, since=mark)
    assert bootup.data == bytes([BOOTUP])
    assert rig.read(0x1017) == 1000
    assert rig.read(0x2020, 3) == 2, "the application keeps its parameters"


def test_stopped_answers_no_sdo_but_keeps_its_heartbeat(rig):
    rig.nmt_and_heartbeat(NMT_STOP, STOPPED)
    mark = rig.frames.mark()
    rig.node.sdo.RESPONSE_TIMEOUT = 0.5
    with pytest.raises(canopen.SdoCommunicationError):
        rig.node.sdo.upload(0x1000, 0)
    with pytest.raises(canopen.SdoCommunicationError):
        rig.node.sdo.download(0x2000, 0, b"\x01")
    rig.frames.assert_none(lambda f: f.id == SDO_TX, 0.5, since=mark, what="SDO replies")
    hb = rig.frames.wait_id(HEARTBEAT, since=mark, timeout=3)
    assert hb.data == bytes([STOPPED])
    # Back in Pre-operational the same request is answered.
    rig.node.sdo.RESPONSE_TIMEOUT = 2
    rig.nmt_and_heartbeat(NMT_PRE_OPERATIONAL, PRE_OPERATIONAL)
    assert rig.read(0x1000) == 0
    assert rig.read(0x2000) == 0, "the write sent in Stopped was not carried out"


def test_foreign_and_malformed_nmt_frames_are_ignored(rig):
    mark = rig.frames.mark()
    for data in [
        bytes([NMT_START, NODE_ID + 1]),
        bytes([NMT_START, 127]),
        bytes([NMT_START]),
        bytes([NMT_START, NODE_ID, 0]),
        bytes([0x03, NODE_ID]),
        b"",
    ]:
        rig.network.send_message(NMT, data)
    # No state change: no immediate heartbeat, and the next periodic one is Pre-operational.
    rig.frames.assert_none(lambda f: f.id == HEARTBEAT, 0.3, since=mark, what="heartbeats")
    hb = rig.frames.wait_id(HEARTBEAT, since=mark, timeout=3)
    assert hb.data == bytes([PRE_OPERATIONAL])


def test_29_bit_and_remote_frames_are_ignored(rig):
    """The SLCAN link accepts `T` / `R` / `r` frames; the handwheel ignores them."""
    mark = rig.frames.mark()
    request = bytes([0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0])
    for msg in [
        can.Message(arbitration_id=SDO_RX, data=request, is_extended_id=True),
        can.Message(arbitration_id=NMT, data=[NMT_START, NODE_ID], is_extended_id=True),
        can.Message(arbitration_id=SDO_RX, is_extended_id=False, is_remote_frame=True, dlc=8),
        can.Message(arbitration_id=SDO_RX, is_extended_id=True, is_remote_frame=True, dlc=8),
    ]:
        rig.bus.send(msg)
    rig.frames.assert_none(lambda f: f.id != HEARTBEAT, 0.5, since=mark, what="replies")
    # Still alive and still Pre-operational.
    assert rig.read(0x1000) == 0
    hb = rig.frames.wait_id(HEARTBEAT, since=mark, timeout=3)
    assert hb.data == bytes([PRE_OPERATIONAL])


def test_the_uptime_counts_through_resets_and_starts_again_at_a_power_cycle(rig):
    """0x2035 counts the board's milliseconds (on the emulator's clock: never more than it
    advanced between the two reads), goes on through NMT reset node and reset communication,
    and starts again from 0 at a power cycle: how a master tells a reset from a new power
    life."""

    def uptime() -> int:
        return rig.read(0x2035, 0)

    def emulated_ms() -> float:
        return float(rig.board.status()["ms"])

    started = emulated_ms()  # before the first read's sample, after the second's below
    before = uptime()
    time.sleep(0.5)
    after = uptime()
    elapsed = emulated_ms() - started
    assert 0 < after - before <= elapsed + 1, (before, after, elapsed)
    for command in (NMT_RESET_NODE, NMT_RESET_COMMUNICATION):
        mark = rig.nmt(command)
        rig.frames.wait_id(HEARTBEAT, bytes([BOOTUP]), since=mark)
        now = uptime()
        assert now > after, f"0x{command:02X}: {now} ms after {after} ms"
        after = now
    mark, cycled = rig.frames.mark(), emulated_ms()
    rig.board.control("power")
    rig.frames.wait_id(HEARTBEAT, bytes([BOOTUP]), since=mark)
    young = uptime()
    assert young <= emulated_ms() - cycled + 1 < after, (young, after)
