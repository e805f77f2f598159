"""Shared rig of the conformance suite (one emulator per module).

The cases follow the CiA conformance test tool's list as logged in CANopenNode/CANopenDemo
(test/test_report_CCT.md); docs/CONFORMANCE.md has the table. Each test starts from a reset
node (defaults, Pre-operational), so cases are independent while sharing one board.
"""

from __future__ import annotations

import time

import pytest

from rig import (
    BOOTUP,
    HEARTBEAT,
    NMT_RESET_NODE,
    SDO_RX,
    SDO_TIMEOUT,
    SDO_TX,
    Board,
    Rig,
    open_rig,
)


def abort_frame(index: int, sub: int, code: int) -> bytes:
    return bytes([0x80, index & 0xFF, index >> 8, sub]) + code.to_bytes(4, "little")


def req(command: int, index: int, sub: int, data: bytes = b"") -> bytes:
    return bytes([command, index & 0xFF, index >> 8, sub]) + data.ljust(4, b"\0")


def abort_of(reply: bytes) -> int:
    assert reply[0] == 0x80, f"expected an abort, got {reply.hex(' ')}"
    return int.from_bytes(reply[4:8], "little")


@pytest.fixture(scope="module")
def shared_rig(tmp_path_factory):
    board = Board(tmp_path_factory.mktemp("cct") / "board.log")
    try:
        with open_rig(board) as rig:
            yield rig
    finally:
        board.stop()


@pytest.fixture
def dut(shared_rig: Rig) -> Rig:
    """The shared node after a reset node: defaults, Pre-operational, boot-up seen."""
    rig = shared_rig
    rig.board.check_alive()
    rig.node.sdo.RESPONSE_TIMEOUT = SDO_TIMEOUT
    mark = rig.nmt(NMT_RESET_NODE)
    rig.frames.wait_id(HEARTBEAT, bytes([BOOTUP]), since=mark)
    return rig


def sdo_raw(rig: Rig, request: bytes, timeout: float = 2.0) -> bytes:
    mark = rig.frames.mark()
    rig.network.send_message(SDO_RX, request)
    return rig.frames.wait_id(SDO_TX, since=mark, timeout=timeout).data


def no_sdo_reply(rig: Rig, request: bytes, duration: float = 0.4) -> None:
    mark = rig.frames.mark()
    rig.network.send_message(SDO_RX, request)
    rig.frames.assert_none(lambda f: f.id == SDO_TX, duration, since=mark, what="SDO replies")


def count_between(rig: Rig, cob_id: int, seconds: float) -> int:
    mark = rig.frames.mark()
    time.sleep(seconds)
    return len(rig.frames.frames(cob_id, since=mark))
