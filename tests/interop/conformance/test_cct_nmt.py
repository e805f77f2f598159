"""CCT cases State 01-04 and Transition 01-04 against the handwheel (see
docs/CONFORMANCE.md): boot-up, the NMT states with the heartbeat (no node guarding), PDO and
SDO per state, and every NMT transition."""

import canopen
import pytest

from cct import dut, shared_rig  # noqa: F401
from rig import (
    BOOTUP,
    FRAME_TIMEOUT,
    HEARTBEAT,
    NMT_PRE_OPERATIONAL,
    NMT_RESET_COMMUNICATION,
    NMT_RESET_NODE,
    NMT_START,
    NMT_STOP,
    OPERATIONAL,
    PRE_OPERATIONAL,
    STOPPED,
    TPDO1,
)


def beats(rig, state, period_ms=500, n=2):
    """`n` heartbeats showing `state` at `period_ms`. The wait is host time, which a busy
    host stretches against the node's: only the states are checked here (test_heartbeat.py
    and test_sdo.py check the periods)."""
    rig.write(0x1017, 0, period_ms, 2)
    mark = rig.frames.mark()
    timeout = n * period_ms / 1000 + FRAME_TIMEOUT
    got = rig.frames.wait_count(HEARTBEAT, n, since=mark, timeout=timeout)
    assert all(f.data == bytes([state]) for f in got), got


def reset_to_bootup(rig, command):
    mark = rig.nmt(command)
    boot = rig.frames.wait_id(HEARTBEAT, since=mark)
    assert boot.data == bytes([BOOTUP]), f"first heartbeat after reset: {boot}"
    return mark


def test_state_01_bootup_and_defaults(dut):
    # Non-default values everywhere a master may write, then reset node: defaults again.
    dut.write(0x1017, 0, 700, 2)
    dut.write(0x1800, 5, 250, 2)
    dut.write(0x1016, 1, 1 << 16 | 900, 4)
    dut.write(0x2040, 3, 9, 2)
    dut.write(0x2020, 3, 2, 1)
    reset_to_bootup(dut, NMT_RESET_NODE)
    assert (dut.read(0x1017), dut.read(0x1800, 5), dut.read(0x1016, 1)) == (1000, 100, 0)
    assert (dut.read(0x2040, 3), dut.read(0x2020, 3)) == (40, 4)
    beats(dut, PRE_OPERATIONAL)


def test_state_02_pre_operational_after_bootup(dut):
    assert dut.read(0x1000) == 0  # SDO served
    mark = dut.frames.mark()
    beats(dut, PRE_OPERATIONAL)
    assert dut.frames.frames(TPDO1, since=mark) == []  # no PDO in Pre-operational


def test_state_03_operational(dut):
    mark = dut.frames.mark()
    dut.start()
    dut.frames.wait_id(TPDO1, since=mark)
    beats(dut, OPERATIONAL)
    assert dut.read(0x1000) == 0
    # The 100 ms event timer repeats it (test_pdo.py checks its period; a count in a window
    # of host time fell short when a busy host held the node back).
    dut.frames.wait_count(TPDO1, 3, since=dut.frames.mark())


def test_state_04_stopped(dut):
    dut.start()
    dut.nmt_and_heartbeat(NMT_STOP, STOPPED)
    mark = dut.frames.mark()
    dut.node.sdo.RESPONSE_TIMEOUT = 0.3
    with pytest.raises(canopen.SdoCommunicationError):
        dut.node.sdo.upload(0x1000, 0)
    dut.frames.assert_none(lambda f: f.id == TPDO1, 0.5, since=mark, what="PDO in Stopped")
    got = dut.frames.wait_count(HEARTBEAT, 1, since=mark)
    assert got[0].data == bytes([STOPPED])


def test_transition_01_reset_node_and_reset_communication(dut):
    for to_state in (None, NMT_START, NMT_STOP):
        for reset in (NMT_RESET_NODE, NMT_RESET_COMMUNICATION):
            if to_state is not None:
                state = OPERATIONAL if to_state == NMT_START else STOPPED
                dut.nmt_and_heartbeat(to_state, state)
            if to_state != NMT_STOP:  # Stopped serves no SDO
                dut.write(0x1017, 0, 0, 2)
            reset_to_bootup(dut, reset)
            assert dut.read(0x1017) == 1000
            beats(dut, PRE_OPERATIONAL, n=1)


def test_transition_02_enter_pre_operational(dut):
    dut.nmt(NMT_PRE_OPERATIONAL)  # already there: no change, no heartbeat needed
    assert dut.read(0x1000) == 0
    for start in (NMT_START, NMT_STOP):
        dut.nmt_and_heartbeat(start, OPERATIONAL if start == NMT_START else STOPPED)
        dut.nmt_and_heartbeat(NMT_PRE_OPERATIONAL, PRE_OPERATIONAL)
        mark = dut.frames.mark()
        dut.frames.assert_none(lambda f: f.id == TPDO1, 0.3, since=mark, what="PDO")
        assert dut.read(0x1000) == 0


def test_transition_03_start_remote_node(dut):
    for before in (None, NMT_STOP):
        if before is not None:
            dut.nmt_and_heartbeat(before, STOPPED)
        mark = dut.frames.mark()
        dut.start()
        dut.frames.wait_id(TPDO1, since=mark)
        assert dut.read(0x1000) == 0


def test_transition_04_stop_remote_node(dut):
    for before in (None, NMT_START):
        if before is not None:
            dut.nmt_and_heartbeat(before, OPERATIONAL)
        dut.nmt_and_heartbeat(NMT_STOP, STOPPED)
        dut.node.sdo.RESPONSE_TIMEOUT = 0.3
        with pytest.raises(canopen.SdoCommunicationError):
            dut.node.sdo.upload(0x1000, 0)
        dut.node.sdo.RESPONSE_TIMEOUT = 2
        mark = dut.frames.mark()
        dut.frames.assert_none(lambda f: f.id == TPDO1, 0.3, since=mark, what="PDO")
