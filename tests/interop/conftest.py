"""Fixtures of the interop suite: the release image on the emulated board against
python-canopen.

Every test gets a fresh board (``cargo xtask board``), a python-can ``slcan`` bus on its CAN
port, a ``canopen.Network`` with the handwheel node (``eds/handwheel.eds``, node 16), a
recorder of every frame the master receives, and a client of the control line. See
README.md in this folder for what the suite assumes of the firmware; the rig itself (board,
recorder, control client, `open_rig`) is the library `tools/rig`.
"""

from __future__ import annotations

import time
from contextlib import contextmanager
from typing import Iterator

import can
import canopen
import pytest

# The library in tools/rig (on the path through pytest.ini), shared with the demo and the
# host tools.
from rig import NOTIFIER_CYCLE, Board, FrameRecorder, Rig, Stimulus, open_rig, slcan_line

# The suite's longest tests (tens of seconds each: every flash operation of a store cut, the
# update's downloads, the trial boots) go first: on two workers the short ones then fill in
# beside them, instead of one long test running alone at the end.
LONGEST_FIRST = ["test_update.py", "test_power_cut.py", "test_trial_boot.py"]


def pytest_collection_modifyitems(config, items):
    def rank(item) -> int:
        module = item.nodeid.split("::")[0].rsplit("/", 1)[-1]
        return LONGEST_FIRST.index(module) if module in LONGEST_FIRST else len(LONGEST_FIRST)

    items.sort(key=rank)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    outcome = yield
    report = outcome.get_result()
    setattr(item, "rep_" + report.when, report)


@pytest.fixture
def board(request, tmp_path) -> Iterator[Board]:
    """The emulated handwheel: the release image on the emulated board, its parameter page
    in the test's own folder."""
    with stopped_after(request, Board(tmp_path / "board.log", tmp_path / "flash.bin")) as b:
        yield b


@contextmanager
def stopped_after(request, emulator: Board) -> Iterator[Board]:
    """Stops `emulator` when the test is over; if it failed, prints its log's last lines."""
    try:
        yield emulator
    finally:
        emulator.stop()
        failed = any(
            getattr(getattr(request.node, f"rep_{w}", None), "failed", False)
            for w in ("setup", "call")
        )
        if failed:
            tail = "\n".join(emulator.log().splitlines()[-60:])
            print(f"--- last lines of {emulator.log_path} ---\n{tail}")


@pytest.fixture
def rig(board: Board) -> Iterator[Rig]:
    """A booted handwheel in Pre-operational; the boot-up frame is the first recorded."""
    with open_rig(board) as r:
        yield r


@pytest.fixture
def node(rig: Rig) -> canopen.RemoteNode:
    return rig.node


@pytest.fixture
def frames(rig: Rig) -> FrameRecorder:
    return rig.frames


@pytest.fixture
def stim(rig: Rig) -> Stimulus:
    return rig.stim


@contextmanager
def raw_bus(board: Board):
    """python-can on the board's SLCAN port with a recorder, no canopen network (the tests of
    the board that send raw frames)."""
    deadline = time.monotonic() + 600
    while True:
        board.check_alive()
        try:
            bus = slcan_line(f"socket://127.0.0.1:{board.can_port}")
            break
        except can.CanError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.1)
    frames = FrameRecorder()
    notifier = can.Notifier(bus, [frames], timeout=NOTIFIER_CYCLE)
    try:
        yield bus, frames
    finally:
        notifier.stop()
        bus.shutdown()


@pytest.fixture(scope="module")
def release() -> bytes:
    """The update file `cargo xtask fw` writes (`test_update.UPDATE_FILE`), for the update
    and trial-boot tests."""
    from test_update import UPDATE_FILE

    data = UPDATE_FILE.read_bytes()
    assert data[:4] == b"HWIM", f"{UPDATE_FILE} is not an update file (cargo xtask fw)"
    return data


@pytest.fixture
def relay(board: Board):
    """The SLCAN relay of `tools/rig/relay.py` in front of `board`, once its boot-up came."""
    from rig.constants import NODE_ID, START_TIMEOUT
    from rig.relay import Relay

    r = Relay(board)
    try:
        r.device.wait_id(0x700 + NODE_ID, b"\x00", timeout=START_TIMEOUT)
        yield r
    finally:
        r.close()
