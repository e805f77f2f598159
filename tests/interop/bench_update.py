"""The update over CAN's time (docs/PERFORMANCE.md, part 5; `cargo xtask bench update`, not
part of the suite): today's release image installed by `canopen-handwheel update` through the
loader on the emulated board, segmented and by block download, at 1 Mbit/s and at 125 kbit/s
(the DIP switch's code 4, the emulated bus's host side at the same rate). It prints, per
transfer and rate, the file's size, the frames each way, the bus time those frames take at
least (111 bits per 8-byte data frame, without stuffing and interframe space), the flash
time, the floor (the bus time of the least frames the download needs, plus the flash time),
the device's time (the emulated clock), its ratio to the floor, the wall time of the whole
command on this machine, and the new image's boot time (reset to boot-up).
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


def floor_frames(size: int, transfer: str) -> int:
    """The frames the download of `size` bytes needs at the least: segmented, a request and
    an answer per 7 bytes (and the initiate's pair); by block download, one segment per 7
    bytes, an acknowledgement per sub-block of 127, and the initiate's and the end's
    pairs."""
    segments = -(-size // 7)
    if transfer == "segmented":
        return 2 * segments + 2
    return segments + -(-segments // 127) + 4


def boot_time_ms(board: Board, relay: Relay, node: int) -> float:
    """Device milliseconds from the last reset (the loader's "start") to the application's
    boot-up: the loader's image check and its 100 ms window, then the application's start.
    The boot-up's device time is taken as the board's clock now less the wall time since the
    relay saw it (the board keeps real time while it waits)."""
    status = board.status()
    now = time.monotonic()
    boot_up = [f for f in relay.device.frames(0x700 + node) if f.data == b"\x00"][-1]
    at_ms = float(status["ms"]) - (now - boot_up.t) * 1000
    return at_ms - float(status["reset_ms"])


def download_time(relay: Relay, node: int, host_mark: int, device_mark: int) -> float:
    """Seconds from the download's initiate (0x1F50:1, segmented or block) to the device's
    last answer of it, on the relay's clock. The emulated board keeps real time through a
    download (its device time and the wall time of the command agree to 0.1 s), so this is
    the device's time too."""
    initiate = next(
        f
        for f in relay.host.frames(0x600 + node, since=host_mark)
        if f.data[0] in (0x21, 0xC6) and f.data[1:4] == b"\x50\x1f\x01"
    )
    answers = [f for f in relay.device.frames(0x580 + node, since=device_mark) if f.t >= initiate.t]
    # Up to the answer before the next request of another object (the 0x1F57 poll after it).
    last = initiate
    for f in answers:
        if f.data[0] in (0xA1,) or f.data[0] & 0xE0 == 0x20 or f.data[0] in (0xA4, 0xA2, 0x60):
            last = f
        else:
            break
    return last.t - initiate.t


@pytest.mark.parametrize("transfer", ["segmented", "block"])
@pytest.mark.parametrize("kbit, code", [(1000, 0), (125, 4)])
def test_update_time(tmp_path, release, kbit, code, transfer):
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
        code_, _, err = run_update(relay, path, "--node", str(node), "--sdo-transfer", transfer)
        wall = time.monotonic() - started
        assert code_ == 0, err
        boot_ms = boot_time_ms(board, relay, node)
        device_ms = float(board.status()["ms"]) - ms
        from_device = len(relay.device.frames(since=device_mark))
        from_host = len(relay.host.frames(since=host_mark))
        bus_s = (from_device + from_host) * BITS_PER_FRAME / (kbit * 1000)
        after = flash_ops(board)
        erases, programs = after["erases"] - ops["erases"], after["programs"] - ops["programs"]
        flash_s = erases * ERASE_S + programs * PROGRAM_S
        floor_s = floor_frames(len(new), transfer) * BITS_PER_FRAME / (kbit * 1000) + flash_s
        download_s = download_time(relay, node, host_mark, device_mark)
        print(
            f"\nupdate by {transfer} at {kbit} kbit/s: {len(new)} B file, {from_host} frames "
            f"from the host, {from_device} from the device; bus time of those at least "
            f"{bus_s:.2f} s, flash time {flash_s:.2f} s ({erases} erases, {programs} programs); "
            f"floor (the download's least frames plus flash) {floor_s:.2f} s; the download "
            f"itself (its initiate to its last answer) {download_s:.2f} s, "
            f"{download_s / floor_s:.2f} x the floor; the whole command {device_ms / 1000:.2f} s "
            f"of device time, {wall:.1f} s of wall time; the new image's boot: "
            f'{boot_ms:.0f} ms from the reset ("start") to its boot-up'
        )
    finally:
        if relay is not None:
            relay.close()
        board.stop()
