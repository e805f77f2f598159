"""Fixtures of the interop suite: the firmware's QEMU variant against python-canopen.

Every test gets a fresh emulator (``cargo xtask qemu``), a python-can ``slcan`` bus on its
CAN port, a ``canopen.Network`` with the handwheel node (``eds/handwheel.eds``, node 16), a
recorder of every frame the master receives, and a client of the stimulus port. See
README.md in this folder for what the suite assumes of the firmware; the rig itself (emulator,
recorder, stimulus client, `open_rig`) is the library `tools/rig`.
"""

from __future__ import annotations

from typing import Iterator

import canopen
import pytest

# The library in tools/rig (on the path through pytest.ini), shared with the demo and the
# host tools.
from rig import FrameRecorder, Qemu, Rig, Stimulus, open_rig


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    outcome = yield
    report = outcome.get_result()
    setattr(item, "rep_" + report.when, report)


@pytest.fixture
def qemu(request, tmp_path) -> Iterator[Qemu]:
    q = Qemu(tmp_path / "qemu.log")
    try:
        yield q
    finally:
        q.stop()
        failed = any(
            getattr(getattr(request.node, f"rep_{w}", None), "failed", False)
            for w in ("setup", "call")
        )
        if failed:
            tail = "\n".join(q.log().splitlines()[-60:])
            print(f"--- last lines of {q.log_path} ---\n{tail}")


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
