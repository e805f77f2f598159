"""The update over CAN's time (docs/PERFORMANCE.md, part 5; `cargo xtask bench`, not part of
the suite): today's release image installed by `canopen-handwheel update` through the loader
on the emulated board, at 1 Mbit/s and at 125 kbit/s (the DIP switch's code 4, the emulated
bus's host side at the same rate). It prints, per rate, the file's size, the frames each way,
the bus time those frames take at least (111 bits per 8-byte data frame, without stuffing
and interframe space), the device's time (the emulated clock) and the wall time of the whole
command on this machine, where python-canopen's round trip through SLCAN and the relay, not
the bus, sets the pace.
"""

from __future__ import annotations

import time

import pytest

from rig import Board
from rig.constants import START_TIMEOUT
from rig.relay import Relay
from test_update import UPDATE_FILE, flash_ops, run_update, variant

BITS_PER_FRAME = 111  # an 8-byte data frame: 47 + 64 bits, before stuffing
# The flash model's times (tools/stm32emu/periph.py `Fpec`; datasheet t_ERASE 20-40 ms,
# t_prog 40-70 us): the CPU stalls for each.
ERASE_S, PROGRAM_S = 0.020, 52.5e-6


@pytest.fixture(scope="module")
def release() -> bytes:
    return UPDATE_FILE.read_bytes()


@pytest.mark.parametrize("kbit, code", [(1000, 0), (125, 4)])
def test_update_time(tmp_path, release, kbit, code):
    node = 16
    board = Board(tmp_path / "board.log", tmp_path / "flash.bin", dip=node | code << 5)
    relay = None
    try:
        board.control(f"rate {kbit}")
        relay = Relay(board, node_id=node)
        relay.device.wait_id(0x700 + node, b"\x00", timeout=START_TIMEOUT)
        new = variant(release, version=2, pad=0)
        path = tmp_path / "new.update"
        path.write_bytes(new)
        device_mark, host_mark = relay.device.mark(), relay.host.mark()
        ms = float(board.status()["ms"])
        ops = flash_ops(board)
        started = time.monotonic()
        code_, _, err = run_update(relay, path, "--node", str(node))
        wall = time.monotonic() - started
        assert code_ == 0, err
        device_ms = float(board.status()["ms"]) - ms
        from_device = len(relay.device.frames(since=device_mark))
        from_host = len(relay.host.frames(since=host_mark))
        bus_s = (from_device + from_host) * BITS_PER_FRAME / (kbit * 1000)
        after = flash_ops(board)
        erases, programs = after["erases"] - ops["erases"], after["programs"] - ops["programs"]
        flash_s = erases * ERASE_S + programs * PROGRAM_S
        print(
            f"\nupdate at {kbit} kbit/s: {len(new)} B file, {from_host} frames from the host, "
            f"{from_device} from the device; bus time at least {bus_s:.2f} s, flash time "
            f"{flash_s:.2f} s ({erases} erases, {programs} programs), "
            f"together {bus_s + flash_s:.2f} s; "
            f"device time {device_ms / 1000:.2f} s, wall time {wall:.1f} s"
        )
    finally:
        if relay is not None:
            relay.close()
        board.stop()
