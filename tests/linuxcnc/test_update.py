"""The component and the resident loader (docs/FIRMWARE-UPDATE.md) in the real LinuxCNC 2.9: a
device held in its loader, and reconnecting after an update.

A machine of its own: before LinuxCNC starts, a master of the test's own on the hub sends
the device (in Pre-operational after its boot-up, the feed disabled) 0x1F51:1 = 0, so the
component's first look at it finds the loader (0x1000 = "BOOT"). The tests run in file order:
the loader with the machine on (no jogging); the loader's "start" (0x1F51:1 = 1) and the
component configuring the application on its boot-up; then one update, `canopen-handwheel
update` on the hub beside the running component (the machine off: host/README.md, "Firmware
update over CAN"), and the application it installed jogging again.
"""

from __future__ import annotations

import os
import struct
import subprocess
import time
import zlib
from pathlib import Path

import canopen
import pytest

from conftest import SCALE, component_script, master, moved, read_u32, running_machine
from rig import BOOTUP, HEARTBEAT, NMT, NMT_PRE_OPERATIONAL, NODE_ID, ROOT, SDO_RX, TPDO1
from rig.constants import START_TIMEOUT

BOOT = 0x544F_4F42  # the loader's 0x1000
HEADER_SLOT = 512  # docs/FIRMWARE-UPDATE.md: the header slot before the image
UPDATE_FILE = Path(
    os.environ.get(
        "HANDWHEEL_UPDATE_FILE",
        ROOT / "target" / "thumbv7m-none-eabi" / "release" / "handwheel-firmware.update",
    )
)
LOADER_LINE = f"node {NODE_ID} is in its loader ("
APPLICATION_LINE = "the device runs its application again"


def variant(data: bytes, version: int, pad: int) -> bytes:
    """`data` (an update file) with `pad` bytes of 0xFF appended to its image, its header's
    version set to `version` and its length and CRC-32 sealed again: the same code, another
    CRC, so that the update's report shows which image runs."""
    body = data[HEADER_SLOT:] + b"\xff" * pad
    header = bytearray(data[:HEADER_SLOT])
    struct.pack_into("<III", header, 0x10, version, len(body), zlib.crc32(body))
    return bytes(header) + body


def hold_in_loader(m) -> None:
    """The device, just booted (Pre-operational, feed disabled), told to stop its program
    (0x1F51:1 = 0): it answers, resets into its loader and boots up there."""
    with master(m.hub.channel) as (network, node):
        deadline = time.monotonic() + START_TIMEOUT  # the board's first start may build
        while True:
            try:
                assert read_u32(node, 0x1000, 0) != BOOT, "the application runs first"
                break
            except canopen.SdoCommunicationError:
                assert time.monotonic() < deadline, "the device never answered"
        network.send_message(NMT, bytes([NMT_PRE_OPERATIONAL, NODE_ID]))
        mark = m.frames.mark()
        node.sdo.download(0x1F51, 1, b"\x00")
        m.frames.wait_id(HEARTBEAT, bytes([BOOTUP]), since=mark)
        assert read_u32(node, 0x1000, 0) == BOOT
    assert m.board.control("mode") == ["mode loader"]


@pytest.fixture(scope="module")
def machine(tmp_path_factory):
    with running_machine(
        tmp_path_factory.mktemp("linuxcnc-update"),
        lambda s: s["pins"]["in-loader"],
        "the component showing the loader",
        prepare=hold_in_loader,
    ) as m:
        yield m


def counts(machine) -> dict:
    p = machine.pins()
    return {L: p[f"axis.{L}.jog-counts"] for L in "xyz"}


def test_a_device_in_its_loader_is_reported_and_nothing_jogs(machine):
    """The machine on (`enable` true), the device in its loader: `in-loader` true, the log
    says so once; no session (`connected` and `feed-enabled` false), no jog-enable; the
    wheel turned on a selected axis moves no axis and counts nothing; the loader sends no
    feed record, and the component asks it nothing (no SDO request: one could break a
    download under way)."""
    s = machine.status()
    assert s["homed"] == [1, 1, 1] and s["teleop"], s
    p = s["pins"]
    assert p["in-loader"] and p["enable"], p
    assert not p["connected"] and not p["feed-enabled"], p
    assert not any(p[f"axis.{L}.jog-enable"] for L in "xyz"), p
    assert machine.cnc.log().count(f'{LOADER_LINE}0x1000 = "BOOT")') == 1, machine.cnc.tail(30)
    start, before = s["pos"], counts(machine)
    mark = machine.frames.mark()
    machine.stim.axis("x")
    machine.stim.mult(100)
    machine.stim.turn(5)
    machine.stim.turn(-2)
    machine.assert_still(start, 1.5)
    p = machine.pins()
    assert p["in-loader"] and not p["connected"], p
    assert not any(p[f"axis.{L}.jog-enable"] for L in "xyz"), p
    assert counts(machine) == before
    assert machine.frames.frames(TPDO1, since=mark) == []
    assert machine.frames.frames(SDO_RX, since=mark) == []
    assert machine.board.control("mode") == ["mode loader"]


def test_the_applications_boot_up_ends_the_loader_state(machine):
    """Another master starts the valid program from the loader (0x1F51:1 = 1): on the
    application's boot-up the component configures and starts it, `in-loader` false, its
    log says so; nothing moves until a turn, which moves X by exactly its detents."""
    start = machine.pos()
    mark = machine.frames.mark()
    with master(machine.hub.channel) as (_, node):
        node.sdo.download(0x1F51, 1, b"\x01")
    machine.frames.wait_id(HEARTBEAT, bytes([BOOTUP]), since=mark)
    machine.wait(
        lambda s: s["pins"]["connected"] and s["pins"]["state"] == 5 and not s["pins"]["in-loader"],
        10,
        "the application configured",
    )
    assert APPLICATION_LINE in machine.cnc.log(), machine.cnc.tail(30)
    assert machine.board.control("mode") == ["mode application"]
    machine.select("x", 100)
    machine.ready_to_jog("x")
    machine.assert_still(start, 0.3)
    machine.stim.turn(3)
    machine.wait_pos(moved(start, "x", 3 * 100 * SCALE))


def test_an_update_with_the_component_running_and_the_reconnect(machine, tmp_path):
    """The component connected to the application, the machine off (feed disabled):
    `canopen-handwheel update` on the hub beside it succeeds at the first attempt (exit 0,
    the new image's CRC reported; the component asks nothing while the update's requests
    are on the bus); meanwhile the component shows `in-loader` (known from the update's
    confirmed stop) and moves nothing; after the new application's boot-up it configures it
    (`in-loader` false, connected, Operational), and with the machine on a turn moves the
    selected axis by exactly its detents."""
    machine.select("y", 10)
    machine.ready_to_jog("y")
    start = machine.pos()
    loader_lines = machine.cnc.log().count(LOADER_LINE)
    machine.cnc.must("off")
    machine.wait(lambda s: not s["pins"]["feed-enabled"], 5, "feed off with the machine")
    new = variant(UPDATE_FILE.read_bytes(), version=5, pad=64)
    path = tmp_path / "new.update"
    path.write_bytes(new)
    started = time.monotonic()
    update = subprocess.Popen(
        [component_script(), "update", str(path), "--interface", "slcan"]
        + ["--channel", machine.hub.channel],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    seen = set()
    while update.poll() is None:
        s = machine.status()
        seen.add(s["pins"]["in-loader"])
        assert all(abs(a - b) < 1e-6 for a, b in zip(s["pos"], start)), (s["pos"], start)
        assert time.monotonic() - started < 300, "the update did not end"
        time.sleep(0.1)
    out, err = update.communicate()
    print(f"update: exit {update.returncode} in {time.monotonic() - started:.1f} s\n{err[-3000:]}")
    assert update.returncode == 0, err
    assert "attempt 2" not in err and "trying again" not in err, err
    crc = zlib.crc32(new[HEADER_SLOT:])
    assert f"0x{crc:08X}" in out, out
    assert True in seen, "the component never showed the loader"
    assert machine.board.control("mode") == ["mode application"]
    machine.wait(
        lambda s: s["pins"]["connected"] and s["pins"]["state"] == 5 and not s["pins"]["in-loader"],
        10,
        "the new application configured",
    )
    log = machine.cnc.log()
    assert log.count(LOADER_LINE) == loader_lines + 1, machine.cnc.tail(40)
    # It knew the loader from the update's confirmed stop, and held its requests back.
    assert f"{LOADER_LINE}another master stopped its program" in log, machine.cnc.tail(40)
    assert f"another master is exchanging SDO with node {NODE_ID}" in log, machine.cnc.tail(40)
    assert "Traceback" not in log, machine.cnc.tail(40)
    machine.assert_still(start, 0.3)
    machine.cnc.must("on")
    machine.select("y", 10)
    machine.ready_to_jog("y")
    machine.assert_still(start, 0.3)
    machine.stim.turn(-4)
    machine.wait_pos(moved(start, "y", -4 * 10 * SCALE))
