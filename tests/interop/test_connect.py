"""Connecting the way docs/EMULATED-BOARD.md shows it: one `can.Bus`, a `canopen.Network`,
`network.connect()`, and the boot-up arrives, without the master ever sending `O` again.

python-can writes its `O` (or `C`, `Sn`, `O` with `bitrate=`) right after connecting, while
the board starts its CPU; the boot-up must be the first frame the master reads whether or
not that `O` made it. These tests use a bare board (the `board` fixture), not the `rig`,
because the rig's own connection is what is under test.
"""

import time

import canopen
import pytest
from can.interfaces.slcan import slcanBus

from rig import (
    BOOTUP,
    EDS,
    FRAME_TIMEOUT,
    HEARTBEAT,
    NODE_ID,
    NOTIFIER_CYCLE,
    SDO_TIMEOUT,
    FrameRecorder,
    connect_bus,
)


def _connect_and_check_bootup(board, **bus_kwargs):
    # The snippet of docs/EMULATED-BOARD.md. `connect_bus` retries only the TCP connection
    # while the board is not listening yet (the page has the user start it first); it never
    # re-sends `O`.
    bus = connect_bus(board, **bus_kwargs)
    connected = time.monotonic()
    frames = FrameRecorder()
    network = canopen.Network(bus)
    network.NOTIFIER_CYCLE = NOTIFIER_CYCLE
    network.listeners.append(frames)  # before connect(): the notifier sees every frame
    node = network.add_node(NODE_ID, str(EDS))
    network.connect()
    try:
        first = frames.wait_for(lambda f: True, what="any frame")
        assert (first.id, first.data) == (HEARTBEAT, bytes([BOOTUP])), (
            f"the first frame must be the boot-up, got {first}"
        )
        assert first.t - connected < FRAME_TIMEOUT
        # python-canopen took it as the node's boot-up.
        assert node.nmt.state == "PRE-OPERATIONAL"
        # The link carries the master's frames as well: an SDO upload is answered.
        node.sdo.RESPONSE_TIMEOUT = SDO_TIMEOUT
        assert node.sdo.upload(0x1008, 0) == b"CNC handwheel"
    finally:
        network.disconnect()


@pytest.mark.parametrize(
    "bus_kwargs",
    [
        pytest.param({}, id="plain"),
        # python-can then sends `C`, `S8`, an empty line and `O` instead of `O` alone.
        pytest.param({"bitrate": 1_000_000}, id="bitrate"),
    ],
)
def test_readme_snippet_sees_the_bootup_on_the_first_try(board, bus_kwargs):
    _connect_and_check_bootup(board, **bus_kwargs)


def test_bootup_arrives_even_when_the_opening_o_is_lost(board, monkeypatch):
    # python-can's `open()` (the `O` it writes at the end of its constructor) does nothing,
    # as if the `O` had been lost: the channel is open from the start. `close()` still sends
    # `C` on disconnect.
    monkeypatch.setattr(slcanBus, "open", lambda self: None)
    _connect_and_check_bootup(board)
