"""Fixtures of the interop suite: the firmware's QEMU variant against python-canopen.

Every test gets a fresh emulator (``cargo xtask qemu``), a python-can ``slcan`` bus on its
CAN port, a ``canopen.Network`` with the handwheel node (``eds/handwheel.eds``, node 16), a
recorder of every frame the master receives, and a client of the stimulus port. See
README.md in this folder for what the suite assumes of the firmware; the rig itself (emulator,
recorder, stimulus client, `open_rig`) is the library `tools/rig`.
"""

from __future__ import annotations

import sys
import time
from contextlib import contextmanager
from typing import Iterator

import can
import canopen
import pytest

# The library in tools/rig (on the path through pytest.ini), shared with the demo and the
# host tools.
from rig import ROOT, FrameRecorder, Qemu, Rig, Stimulus, open_rig

# The emulated board (the release image, `cargo xtask board`): its launcher.
sys.path.insert(0, str(ROOT / "tools" / "board-emu"))
from launcher import BoardProcess  # noqa: E402

# Tests that need the QEMU variant's board layer, with the reason; on the emulated board
# they are skipped (the rest of the suite runs on both).
QEMU_ONLY = {
    "test_receive_overrun_raises_emcy_8110_and_the_node_recovers": (
        "needs the QEMU variant's `stall` stimulus (the board image has no such hook); the "
        "board's overrun is tested by test_board.py::test_burst_during_a_flash_erase_overruns"
    ),
    "test_configure_node_id_store_and_reset": (
        "asserts the QEMU variant's log line for stored settings at an NMT reset (its boot); "
        "the board reads them at power-on: "
        "test_board.py::test_stored_settings_survive_a_power_cycle"
    ),
    "test_configure_bit_timing_and_store": (
        "asserts the QEMU variant's log lines (no bit rate there); the board's bit rates are "
        "checked on BTR by test_board.py::test_every_dip_code_gives_the_tables_node_id_and_bit_rate"
    ),
}

# Tests that need the emulated board, with the reason; on the QEMU variant they are skipped.
_HELD_BUS_PASSES_THE_MASTER = (
    "the master's NMT commands and SDO writes must reach the node while its frames are held: "
    "the board's `hold` passes them, QEMU's closed SLCAN channel (`C`) does not"
)
BOARD_ONLY = {
    "test_nmt_stop_and_start_in_an_outage_never_give_y_turn_to_x": _HELD_BUS_PASSES_THE_MASTER,
    "test_reset_node_in_an_outage_never_moves_x_backwards": _HELD_BUS_PASSES_THE_MASTER,
    "test_reset_node_within_the_stall_limit_boots_up_first_and_breaks_the_sequence": (
        _HELD_BUS_PASSES_THE_MASTER
    ),
}

# Which emulator a test runs on: the QEMU variant, and the board image on the emulated board.
EMULATORS = ["qemu", "board"]


def pytest_collection_modifyitems(config, items):
    for item in items:
        callspec = getattr(item, "callspec", None)
        emulator = None if callspec is None else callspec.params.get("qemu")
        name = getattr(item, "originalname", item.name)
        if emulator == "board" and name in QEMU_ONLY:
            item.add_marker(pytest.mark.skip(reason=f"QEMU variant only: {QEMU_ONLY[name]}"))
        if emulator == "qemu" and name in BOARD_ONLY:
            item.add_marker(pytest.mark.skip(reason=f"emulated board only: {BOARD_ONLY[name]}"))


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    outcome = yield
    report = outcome.get_result()
    setattr(item, "rep_" + report.when, report)


@pytest.fixture(params=EMULATORS)
def qemu(request, tmp_path) -> Iterator[Qemu]:
    """The emulated handwheel: the QEMU variant, or (param `board`) the release image on the
    emulated board, which has the same ports, log and stimulus commands."""
    if request.param == "board":
        q = BoardProcess(tmp_path / "board.log", tmp_path / "flash.bin")
    else:
        q = Qemu(tmp_path / "qemu.log")
    with stopped_after(request, q):
        yield q


@contextmanager
def stopped_after(request, emulator: Qemu) -> Iterator[Qemu]:
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
def rig(qemu: Qemu) -> Iterator[Rig]:
    """A booted handwheel in Pre-operational; the boot-up frame is the first recorded."""
    with open_rig(qemu) as r:
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
def raw_bus(board: BoardProcess):
    """python-can on the board's SLCAN port with a recorder, no canopen network (the tests of
    the board that send raw frames)."""
    deadline = time.monotonic() + 600
    while True:
        board.check_alive()
        try:
            bus = can.Bus(
                interface="slcan",
                channel=f"socket://127.0.0.1:{board.can_port}",
                sleep_after_open=0,
            )
            break
        except can.CanError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.1)
    frames = FrameRecorder()
    notifier = can.Notifier(bus, [frames])
    try:
        yield bus, frames
    finally:
        notifier.stop()
        bus.shutdown()
