"""The firmware update over CAN (docs/FIRMWARE-UPDATE.md) on the emulated board as
a flashed board is: the resident loader and the release application, python-canopen as the
master through the host's own command, `canopen-handwheel update`, run as a user runs it.

The master reaches the board through the rig's relay (`rig.relay`), which lets a test drop
the device's frames or put a frame of its own on the bus. A new image is the release one with
bytes appended to it and its header sealed again (`variant`): another length, CRC-32 and
version, the same code, so that 0x1F56 shows which of the two runs.
"""

from __future__ import annotations

import os
import struct
import subprocess
import sys
import threading
import time
import zlib
from contextlib import contextmanager
from pathlib import Path

import canopen
import pytest

from rig import Board, slcan_line
from rig.constants import NODE_ID, NOTIFIER_CYCLE
from rig.relay import Relay

ROOT = Path(__file__).resolve().parents[2]
UPDATE_FILE = Path(
    os.environ.get(
        "HANDWHEEL_UPDATE_FILE",
        ROOT / "target" / "thumbv7m-none-eabi" / "release" / "handwheel-firmware.update",
    )
)
HEADER_SLOT = 512  # docs/FIRMWARE-UPDATE.md: the header slot before the image
SLOT_SIZE = 50 * 1024
BOOT = 0x544F_4F42  # the loader's 0x1000
SAVE = 0x6576_6173
SDO_TIMEOUT = 3.0  # s, the tests' master and `update --sdo-timeout`
COMMAND = "import sys; from canopen_handwheel import cli; sys.exit(cli.main())"


def variant(data: bytes, version: int, pad: int) -> bytes:
    """`data` (an update file) with `pad` bytes of 0xFF appended to its image, its header's
    version set to `version` and its length and CRC-32 sealed again."""
    body = data[HEADER_SLOT:] + b"\xff" * pad
    header = bytearray(data[:HEADER_SLOT])
    struct.pack_into("<III", header, 0x10, version, len(body), zlib.crc32(body))
    return bytes(header) + body


def image_crc(data: bytes) -> int:
    return struct.unpack_from("<I", data, 0x18)[0]


@contextmanager
def master(relay: Relay, node_id: int = NODE_ID):
    """A python-canopen master on the relay's client port for a few SDO requests."""
    network = canopen.Network(slcan_line(relay.channel))
    network.NOTIFIER_CYCLE = NOTIFIER_CYCLE
    network.connect()
    try:
        node = network.add_node(node_id, canopen.ObjectDictionary())
        # Generous: on a loaded machine the emulated board can fall a second behind, and a
        # timed-out request the master repeats derails the transfer the test is about.
        node.sdo.RESPONSE_TIMEOUT = SDO_TIMEOUT
        yield network, node
    finally:
        network.disconnect()


def read(node, index: int, sub: int) -> int:
    return int.from_bytes(node.sdo.upload(index, sub), "little")


def run_update(relay: Relay, path: Path, *options: str, timeout: float = 600):
    """`canopen-handwheel update PATH` on the relay's port: (exit status, stdout, stderr)."""
    env = dict(os.environ, PYTHONPATH=str(ROOT / "host" / "src"))
    started = time.monotonic()
    done = subprocess.run(
        [sys.executable, "-c", COMMAND, "update", str(path)]
        + ["--interface", "slcan", "--channel", relay.channel]
        + ["--sdo-timeout", str(SDO_TIMEOUT)]
        + list(options),
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
    )
    print(f"update of {path.name}: exit {done.returncode} in {time.monotonic() - started:.1f} s")
    print(done.stderr[-2000:])
    return done.returncode, done.stdout, done.stderr


def flash_ops(board: Board) -> dict[str, int]:
    (reply,) = board.control("flash-ops")
    fields = dict(item.split("=") for item in reply.split()[1:])
    return {k: int(v) for k, v in fields.items() if v.lstrip("-").isdigit()}


def flash_file(board: Board) -> bytes:
    return Path(board.flash).read_bytes()


def flash_ops_of(data: bytes) -> list[str]:
    """The flash operations a complete download of update file `data` takes, in order: the
    header page's erase at "clear", then per page the stream reaches its erase and one
    program per half-word that is not 0xFFFF (the erase left those; the first four bytes,
    the mark, held back), the mark's two half-words last."""
    ops = ["erase"]
    for offset in range(4, len(data), 2):
        if offset % 1024 == 0:
            ops.append("erase")
        if data[offset : offset + 2] != b"\xff\xff":
            ops.append("program")
    return ops + ["mark", "mark"]


def test_power_cuts_in_a_download_leave_a_loader_that_takes_the_next_update(
    board, relay, release, tmp_path
):
    """Power fails inside "clear"'s erase, before the first program, inside a page erase of
    the stream, in the middle of the image and inside the mark's last half-word: each time
    the board comes back in the loader, which answers SDO and reports "no valid program";
    the loader's pages and the parameter pages are as they were. Then `canopen-handwheel
    update` installs a new image: it runs, 0x1F56 reads its CRC-32 and the heartbeat stored
    before stays. The cuts hit the download of a small image the loader takes as valid
    (`small_valid_image`), so that a cut in its mark costs no full download; every operation
    of clear, stream and mark is cut on the host (crates/canopen-loader/tests). By block
    download, each sub-block written before its acknowledgement, as the update command
    sends the file: the program sees the same bytes in the same order either way (a cut in a
    segmented download: `tests/node-master/update.test.js`, and every operation on the host),
    and a segmented download after the cuts is `test_a_dropped_answer_...` below."""
    with master(relay) as (_, node):
        assert read(node, 0x1F56, 1) == image_crc(release)
        node.sdo.download(0x1017, 0, (250).to_bytes(2, "little"))
        node.sdo.download(0x1010, 1, SAVE.to_bytes(4, "little"))
        enter_loader(relay, node)
    small = small_valid_image(release, 3000)
    ops = flash_ops_of(small)
    total = len(ops)
    second_erase = ops.index("erase", 1) + 1  # operations count from 1
    kept = flash_file(board)
    cuts = [(1, "inside"), (2, "before"), (second_erase, "inside"), (total // 2, "inside")]
    cuts.append((total, "inside"))
    for n, where in cuts:
        with master(relay) as (_, node):
            mark = relay.device.mark()
            board.control(f"cut {n} {where}")
            with pytest.raises(canopen.SdoCommunicationError):
                node.sdo.download(0x1F51, 1, b"\x03")  # clear
                download(node, small, block=True)
        relay.device.wait_id(0x700 + NODE_ID, b"\x00", since=mark, timeout=5)
        assert board.control("mode") == ["mode loader"], f"cut at operation {n}"
        with master(relay) as (_, node):
            assert read(node, 0x1000, 0) == BOOT
            assert read(node, 0x1F57, 1) == 1 << 1, "no valid program"
            assert read(node, 0x1F56, 1) == 0
        now = flash_file(board)
        assert now[:0x3000] == kept[:0x3000], "the loader's pages are untouched"
        assert now[0xF800:] == kept[0xF800:], "the parameter pages are untouched"
    assert flash_ops(board)["cuts"] == len([w for _, w in cuts if w == "inside"])
    # Without a cut the same download makes the small image valid: the cut points were
    # inside a download the loader completes.
    with master(relay) as (_, node):
        node.sdo.download(0x1F51, 1, b"\x03")
        before = flash_ops(board)["ops"]
        assert download(node, small, block=True) is None
        assert flash_ops(board)["ops"] - before == total - 1, "clear's erase came before"
        assert read(node, 0x1F56, 1) == image_crc(small)
    new = variant(release, version=7, pad=100)
    path = tmp_path / "new.update"
    path.write_bytes(new)
    started_ms = float(board.status()["ms"])
    code, out, err = run_update(relay, path, "--sdo-transfer", "block")
    assert code == 0, err
    assert f"0x{image_crc(new):08X}" in out, out
    print(f"update: {float(board.status()['ms']) - started_ms:.0f} ms emulated")
    with master(relay) as (_, node):
        assert read(node, 0x1000, 0) == 0, "the application runs"
        assert read(node, 0x1F56, 1) == image_crc(new)
        assert read(node, 0x1F57, 1) == 0
        assert read(node, 0x1017, 0) == 250, "the stored heartbeat survived"
    assert board.control("mode") == ["mode application"]
    feed = [f for f in relay.device.frames() if f.id in (0x180 + NODE_ID, 0x280 + NODE_ID)]
    assert not feed, "no feed record without a turn of the wheel"


def enter_loader(relay: Relay, node) -> None:
    mark = relay.device.mark()
    node.sdo.download(0x1F51, 1, b"\x00")
    relay.device.wait_id(0x700 + NODE_ID, b"\x00", since=mark, timeout=5)
    assert read(node, 0x1000, 0) == BOOT


def download(node, data: bytes, size: int | None = None, block: bool = False) -> int | None:
    """0x1F50:1 = `data` (segmented, or block download with its CRC; `size` indicated): the
    abort code, None if none."""
    try:
        stream = node.sdo.open(
            0x1F50,
            1,
            "wb",
            buffering=0,
            size=len(data) if size is None else size,
            block_transfer=block,
        )
        sent = 0
        while sent < len(data):
            sent += stream.write(data[sent : sent + 7])
        stream.close()
    except canopen.SdoAbortedError as e:
        return e.code
    return None


def small_image(release: bytes, body: bytes) -> bytearray:
    header = bytearray(release[:HEADER_SLOT])
    struct.pack_into("<II", header, 0x14, len(body), zlib.crc32(body))
    return header + body


APP_ORIGIN = 0x0800_3200  # memory.x: FLASH


def small_valid_image(release: bytes, size: int) -> bytes:
    """An update file the loader takes as valid (its CRC-32 and vector table check out) of
    `size` bytes of image: a stack pointer in RAM, a reset vector to a branch-to-self, then a
    pattern with no erased half-word. Never started here."""
    body = struct.pack("<II", 0x2000_4000, (APP_ORIGIN + 8) | 1) + b"\xfe\xe7"
    body += bytes((i * 7 + 1) % 255 for i in range(size - len(body)))
    return bytes(small_image(release, body))


def test_the_loader_refuses_another_devices_image_a_bad_crc_and_an_oversized_one(relay, release):
    """Each refusal gives the SDO abort and 0x1F57 code of docs/FIRMWARE-UPDATE.md and leaves
    no valid program; the next download from "clear" completes."""
    with master(relay) as (_, node):
        enter_loader(relay, node)
        cases = []
        other = small_image(release, bytes(range(64)))
        struct.pack_into("<I", other, 0x0C, struct.unpack_from("<I", other, 0x0C)[0] + 1)
        cases.append(("another device", bytes(other), None, 0x0609_0030, 2))
        bad_crc = small_image(release, bytes(range(64)))
        bad_crc[HEADER_SLOT + 5] ^= 0xFF
        cases.append(("a bad CRC", bytes(bad_crc), None, 0x0800_0020, 3))
        cases.append(("too large", release, SLOT_SIZE + 2, 0x0504_0005, 6))
        big = bytearray(release[:HEADER_SLOT] + bytes(16))
        struct.pack_into("<I", big, 0x14, SLOT_SIZE)
        cases.append(("a header too large", bytes(big), None, 0x0504_0005, 6))
        for what, data, size, abort, status in cases:
            node.sdo.download(0x1F51, 1, b"\x03")
            assert read(node, 0x1F57, 1) & 1 == 0
            assert download(node, data, size) == abort, what
            assert read(node, 0x1F57, 1) == status << 1, what
            assert read(node, 0x1F56, 1) == 0, what
        # Data without "clear" first.
        assert download(node, release[:64]) == 0x0800_0022
        assert read(node, 0x1F57, 1) == 4 << 1
        # After all that, the next download from "clear" completes.
        small = small_valid_image(release, 1000)
        node.sdo.download(0x1F51, 1, b"\x03")
        assert download(node, small) is None
        assert read(node, 0x1F57, 1) == 0
        assert read(node, 0x1F56, 1) == image_crc(small)


def test_a_dropped_answer_and_a_repeated_segment_cost_a_retry_each(board, relay, release, tmp_path):
    """The device's answer to the 100th segment of the first download is lost (the host's
    SDO request times out), and the 100th segment of the second reaches the device twice
    (its toggle bit is wrong the second time: the device aborts with 0x05030000); the third
    download from "clear" completes."""
    answers = {"n": 0}

    def hundredth_answer(frame) -> bool:
        if frame.id != 0x580 + NODE_ID or frame.data[0] & 0xE0 != 0x20:
            return False
        answers["n"] += 1
        return answers["n"] == 100

    relay.drop(hundredth_answer)
    new = variant(release, version=11, pad=20)
    path = tmp_path / "new.update"
    path.write_bytes(new)
    done = {}

    def repeat_a_segment() -> None:
        deadline = time.monotonic() + 300
        while time.monotonic() < deadline and "sent" not in done:
            requests = relay.host.frames(0x600 + NODE_ID)
            initiates = [i for i, f in enumerate(requests) if f.data[:3] == b"\x21\x50\x1f"]
            if len(initiates) >= 2:
                segments = [f for f in requests[initiates[1] :] if f.data[0] & 0xE0 == 0]
                if len(segments) >= 100:
                    relay.send(0x600 + NODE_ID, segments[99].data, to_client=False)
                    done["sent"] = segments[99]
                    return
            time.sleep(0.005)

    repeater = threading.Thread(target=repeat_a_segment, daemon=True)
    repeater.start()
    code, _, err = run_update(relay, path, "--retries", "2", "--sdo-transfer", "segmented")
    repeater.join(1)
    assert "sent" in done, "the repeated segment was never sent"
    assert code == 0, err
    assert "attempt 3 of 3" in err, err
    # The device answers the repeated segment with a toggle abort. Whether the host sees it
    # depends on timing: an abort that arrives before the host's next segment is discarded
    # by python-canopen, which then sees the device, idle after its abort, answer that
    # segment with 0x05040001. So the device's side is what is checked.
    toggle_abort = b"\x80\x50\x1f\x01" + (0x0503_0000).to_bytes(4, "little")
    answers_from_device = relay.device.frames(0x580 + NODE_ID)
    assert any(f.data == toggle_abort for f in answers_from_device), err
    assert "0x05030000" in err or "0x05040001" in err, err
    with master(relay) as (_, node):
        assert read(node, 0x1F56, 1) == image_crc(new)
    assert board.control("mode") == ["mode application"]


def test_the_loader_answers_at_the_stored_node_id_and_bit_rate(board, relay, release):
    """Node-ID 7 and 125 kbit/s stored by LSS (DIP switch off): the application's 0x1F51
    stop is refused while the feed is enabled; in Pre-operational with the feed off the node
    resets into its loader, which boots up at node 7 on the 125 kbit/s bus and reads the
    application's CRC-32 in 0x1F56; "start" boots the application, at node 7 again."""
    from canopen.lss import LssMaster

    with master(relay) as (network, node):
        lss = network.lss
        # Generous, as SDO_TIMEOUT: a block download on the other worker's board can hold
        # this board's emulation back (one run without an answer in 1 s).
        lss.RESPONSE_TIMEOUT = 3.0
        lss.send_switch_state_global(LssMaster.CONFIGURATION_STATE)
        lss.configure_node_id(7)
        lss.configure_bit_timing(4)  # CiA 301's table: 125 kbit/s
        lss.store_configuration()
        lss.send_switch_state_global(LssMaster.WAITING_STATE)
    board.control("rate 125")
    powered = relay.device.mark()
    board.control("power")
    relay.device.wait_id(0x707, b"\x00", since=powered, timeout=10)
    with master(relay, node_id=7) as (network, node):
        network.send_message(0x000, bytes([0x01, 7]))  # NMT start
        time.sleep(0.1)
        node.sdo.download(0x2000, 0, b"\x01")  # feed enabled
        with pytest.raises(canopen.SdoAbortedError) as refused:
            node.sdo.download(0x1F51, 1, b"\x00")
        assert refused.value.code == 0x0800_0022
        node.sdo.download(0x2000, 0, b"\x00")
        network.send_message(0x000, bytes([0x80, 7]))  # NMT pre-operational
        time.sleep(0.1)
        mark = relay.device.mark()
        node.sdo.download(0x1F51, 1, b"\x00")
        relay.device.wait_id(0x707, b"\x00", since=mark, timeout=5)
        assert board.control("mode") == ["mode loader"]
        assert read(node, 0x1000, 0) == BOOT
        assert read(node, 0x1018, 2) == 0x8000_0001, "the loader of product 1"
        assert read(node, 0x1F56, 1) == image_crc(release), "the application is still valid"
        assert read(node, 0x1F57, 1) == 0
        assert read(node, 0x1F51, 1) == 0, "stopped"
        mark = relay.device.mark()
        node.sdo.download(0x1F51, 1, b"\x01")  # start
        relay.device.wait_id(0x707, b"\x00", since=mark, timeout=5)
        assert board.control("mode") == ["mode application"]
        assert read(node, 0x1000, 0) == 0
        assert read(node, 0x1F51, 1) == 1, "started"
    assert not relay.device.frames(0x710, since=powered), "nothing at node 16 after the store"


def test_block_download_sends_again_what_was_lost_and_a_lost_acknowledgement_costs_a_retry(
    board, relay, release, tmp_path
):
    """By block download: the 50th segment of the second sub-block never reaches the device
    (the relay drops it): the device acknowledges the 49 before it, and python-canopen sends
    again from there, in the same attempt. Then the device's fifth acknowledgement (of the
    fourth full sub-block) is lost: the host's wait for it times out, it aborts, and the
    second attempt from "clear" completes. The device's answers show each step."""
    blocks = {"segments": None}

    def fiftieth_of_the_second_sub_block(frame) -> bool:
        if frame.id != 0x600 + NODE_ID:
            return False
        if frame.data[0] & 0xE1 == 0xC0:  # the block download's initiate: segments follow
            blocks["segments"] = 0
            return False
        if blocks["segments"] is None:
            return False
        blocks["segments"] += 1
        return blocks["segments"] == 127 + 50

    def fourth_acknowledgement(frame) -> bool:
        if frame.id != 0x580 + NODE_ID or frame.data[0] != 0xA2:
            return False
        blocks["acks"] = blocks.get("acks", 0) + 1
        return blocks["acks"] == 5  # the first four, and the one after the lost segment

    lost = relay.drop_from_host(fiftieth_of_the_second_sub_block)
    relay.drop(fourth_acknowledgement)
    new = variant(release, version=12, pad=40)
    path = tmp_path / "new.update"
    path.write_bytes(new)
    code, _, err = run_update(relay, path, "--retries", "2", "--sdo-transfer", "block")
    assert lost.done.is_set(), "the segment was dropped"
    assert code == 0, err
    assert "attempt 2 of 3" in err and "attempt 3 of 3" not in err, err
    acks = [f.data for f in relay.device.frames(0x580 + NODE_ID) if f.data[0] == 0xA2]
    assert acks[:3] == [bytes([0xA2, 127, 127, 0, 0, 0, 0, 0])] + [
        bytes([0xA2, 49, 127, 0, 0, 0, 0, 0])
    ] + [bytes([0xA2, 127, 127, 0, 0, 0, 0, 0])], acks[:3]
    with master(relay) as (_, node):
        assert read(node, 0x1F56, 1) == image_crc(new)
    assert board.control("mode") == ["mode application"]
