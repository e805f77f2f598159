"""Power cuts during parameter stores, and stored values the device must not
trust, on the release image over the emulated chip's flash controller.

The control line arms a cut at the n-th flash operation (a half-word program or a page
erase) from now, before it starts or inside it (`cut <n> <before|inside>`: a partly erased
page, a half-word with only some bits cleared; tools/stm32emu/periph.py), and rolls the
parameter pages back to a snapshot between tries. After each cut the board boots from what
the flash holds and must come up with the old or the new node-ID, bit rate and parameters,
never the factory settings, and answer SDO: every operation of every kind of store, as the
host test `crates/handwheel-device/tests/power_cut.rs` does with its own flash model; and
runs of moves cut in a row inside their first flash operation, after which the store works.
"""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor

import can
import pytest

from conftest import raw_bus, stopped_after
from rig import Board

SAVE = b"save"
LOAD = b"load"
LSS_MASTER, LSS_SLAVE = 0x7E5, 0x7E4


class Node:
    """The booted node as seen from the bus: its node-ID follows each boot-up."""

    def __init__(self, board: Board, bus, frames) -> None:
        self.board, self.bus, self.frames = board, bus, frames
        self.node_id = 16

    def send(self, cob_id: int, data: bytes) -> None:
        self.bus.send(can.Message(arbitration_id=cob_id, data=data, is_extended_id=False))

    def sdo(self, request: bytes, timeout: float = 2.0) -> bytes:
        mark = self.frames.mark()
        self.send(0x600 + self.node_id, request.ljust(8, b"\0"))
        return self.frames.wait_id(0x580 + self.node_id, since=mark, timeout=timeout).data

    def write(self, index: int, sub: int, value: bytes) -> bytes:
        size = {1: 0x2F, 2: 0x2B, 4: 0x23}[len(value)]
        return self.sdo(bytes([size, index & 0xFF, index >> 8, sub]) + value)

    def read(self, index: int, sub: int) -> int:
        reply = self.sdo(bytes([0x40, index & 0xFF, index >> 8, sub]))
        assert reply[0] & 0xE0 == 0x40, f"upload {index:04X}:{sub}: {reply.hex(' ')}"
        return int.from_bytes(reply[4:8], "little")

    def lss_store(self, node_id: int, timing: int, timeout: float = 1.0) -> None:
        """LSS: configuration state, node-ID, bit timing, store; back to waiting. A store
        cut off by the power gets no answer: nothing is asserted about it."""
        self.send(LSS_MASTER, bytes([0x04, 1]).ljust(8, b"\0"))
        for request in ([0x11, node_id], [0x13, 0, timing]):
            mark = self.frames.mark()
            self.send(LSS_MASTER, bytes(request).ljust(8, b"\0"))
            answer = self.frames.wait_id(LSS_SLAVE, since=mark, timeout=timeout)
            assert answer.data[1] == 0, f"LSS {request}: {answer}"
        self.send(LSS_MASTER, bytes([0x17]).ljust(8, b"\0"))
        self.send(LSS_MASTER, bytes([0x04, 0]).ljust(8, b"\0"))

    def booted(self, since: int, timeout: float = 10.0) -> int:
        """Waits for a boot-up after `since`; its node-ID becomes the node's."""
        frame = self.frames.wait_for(
            lambda f: 0x701 <= f.id <= 0x77F and f.data == b"\0",
            since=since,
            timeout=timeout,
            what="boot-up",
        )
        self.node_id = frame.id - 0x700
        return self.node_id

    def state(self) -> tuple[int, int, int]:
        """What the boot found: node-ID, bit rate (from the controller's BTR), 0x1017."""
        status = self.board.status()
        return self.node_id, int(status["bitrate"]), self.read(0x1017, 0)

    def save_heartbeat(self, ms: int) -> None:
        assert self.write(0x1017, 0, ms.to_bytes(2, "little"))[0] == 0x60
        assert self.write(0x1010, 1, SAVE)[0] == 0x60


def flash_ops(board: Board) -> int:
    return int(board.status()["flashops"])


def store(node: Node, kind: str) -> None:
    """The store under test; its answer is not awaited (the power may be gone)."""
    if kind == "lss":
        node.lss_store(42, 3)  # node-ID 42 at 250 kbit/s (CiA 301 table index 3)
    elif kind == "save":
        node.write(0x1017, 0, (777).to_bytes(2, "little"))
        node.send(0x600 + node.node_id, bytes([0x23, 0x10, 0x10, 1]) + SAVE)
    else:
        node.send(0x600 + node.node_id, bytes([0x23, 0x11, 0x10, 1]) + LOAD)


def cut_tries(board: Board, node: Node, kind: str, points, expected_ops: int) -> int:
    """Runs the store of `kind` from the snapshot once uncut (old and new states; it takes
    `expected_ops` flash operations), then cut at each (operation, where) of `points(ops)`;
    returns the cut points tried."""
    board.control("snapshot")
    old = node.state()
    start = flash_ops(board)
    mark = node.frames.mark()
    store(node, kind)
    time.sleep(0.3)
    ops = flash_ops(board) - start
    assert ops == expected_ops, f"{kind}: {ops} flash operations"
    board.control("power")
    node.booted(mark)
    new = node.state()
    assert new != old, f"{kind}: {old} -> {new}"
    tried = 0
    for op, where in points(ops):
        mark = node.frames.mark()
        board.control("rollback")
        node.booted(mark)
        assert node.state() == old
        board.control(f"cut {op} {where}")
        mark = node.frames.mark()
        store(node, kind)
        node.booted(mark)
        found = node.state()
        assert found in (old, new), f"{kind} cut {where} op {op}/{ops}: {found}, {old} / {new}"
        status = board.status()
        assert status["armed"] == "-" and status["locked"] == "0", status
        tried += 1
    return tried


def prepare(node: Node, saves: int) -> None:
    for n in range(saves):
        node.save_heartbeat(200 + n)


def every(ops: int) -> list[tuple[int, str]]:
    return [(n, w) for n in range(1, ops + 1) for w in ("before", "inside")]


@pytest.mark.parametrize(
    "kind,saves,dirty,ops",
    [
        ("lss", 6, False, 78),  # moves: 77 half-words to the other page, the full one erased
        ("lss", 2, False, 77),  # appends
        ("save", 2, False, 77),
        ("save", 6, False, 78),
        ("save", 6, True, 80),  # moves over a spare page a cut move left dirty: tick, erase
        ("load", 3, False, 7),
        ("load", 6, False, 8),
    ],
)
def test_a_store_survives_a_cut_at_every_flash_operation(
    request, board, tmp_path, kind, saves, dirty, ops
):
    """Each kind of store, cut before and inside each of its flash operations. After six
    records (a full page) a store moves: node 16 at 1 Mbit/s with the sixth heartbeat before,
    node 42 at 250 kbit/s (LSS), heartbeat 777 (0x1010) or the defaults (0x1011) after; every
    boot finds one of the two, never the factory settings in place of stored ones.

    Two boards prepared alike share the cut points (one every cut before an operation, the
    other every cut inside one): each try is two power-ons, most of whose time is the loader's
    listening window, in which a board only waits (docs/FIRMWARE-UPDATE.md)."""

    def cut_half(board: Board, where: str) -> int:
        with raw_bus(board) as (bus, frames):
            node = Node(board, bus, frames)
            node.booted(0)
            prepare(node, saves)
            if dirty:
                # A move cut inside its first half-word: the spare page is left not blank.
                board.control("cut 1 inside")
                mark = frames.mark()
                store(node, "save")
                node.booted(mark)

            def half(ops: int) -> list[tuple[int, str]]:
                return [(n, w) for n, w in every(ops) if w == where]

            return cut_tries(board, node, kind, half, ops)

    twin = Board(tmp_path / "twin.log", tmp_path / "twin-flash.bin")
    with stopped_after(request, twin), ThreadPoolExecutor(2) as pool:
        halves = [pool.submit(cut_half, b, w) for b, w in ((board, "before"), (twin, "inside"))]
        tried = sum(h.result() for h in halves)
    print(f"{kind} after {saves} saves{' (dirty spare)' if dirty else ''}: {tried} cut points")
    assert tried == 2 * ops


@pytest.mark.parametrize("run", [7, 9])
def test_moves_cut_in_a_row_inside_their_first_flash_operation_lock_nothing(board, run):
    """The page full, `run` saves in a row each cut inside its first flash operation (the
    record's first half-word on the other page, then each later move's erase tick, which the
    next one finishes in place). No erase began, so nothing of the budget is spent: a changed
    save and then a restore defaults are accepted at once, and each boots. (Before erase ticks,
    seven such cuts refused both with 0x08000020 for good.)"""
    with raw_bus(board) as (bus, frames):
        node = Node(board, bus, frames)
        node.booted(0)
        prepare(node, 6)
        before = node.state()
        status = board.status()
        erases, cuts = int(status["erases"]), int(status["cuts"])
        for _ in range(run):
            board.control("cut 1 inside")
            mark = frames.mark()
            store(node, "save")
            node.booted(mark)
            assert node.state() == before
        status = board.status()
        assert (int(status["erases"]), int(status["cuts"])) == (erases, cuts + run), status
        node.save_heartbeat(333)
        mark = frames.mark()
        board.control("power")
        node.booted(mark)
        assert node.read(0x1017, 0) == 333
        assert int(board.status()["erases"]) == erases + 2, "the other page's, the full one's"
        assert node.write(0x1011, 1, LOAD)[0] == 0x60
        mark = frames.mark()
        board.control("power")
        node.booted(mark)
        assert node.state()[::2] == (16, 1000), "the defaults"


def test_a_stored_tpdo_cob_id_of_0x000_is_not_restored(board):
    """A page whose CRCs are valid with TPDO1's COB-ID 0x000 (crafted here by saving, then
    rewriting that value and both CRCs in the flash file, which the board reloads): the boot
    keeps the default 0x40000190, logs why, and reports EMCY 0x6300 (index 0x1800, sub 1)."""
    with raw_bus(board) as (bus, frames):
        node = Node(board, bus, frames)
        node.booted(0)
        node.save_heartbeat(250)
        # The flash file is the whole flash, written through at once; the parameter pages
        # are its last two (memory.x's STORAGE).
        flash = bytearray(board.flash.read_bytes())
        page = flash[PARAMETER_PAGES:]
        craft_tpdo1_cob_id(page, 0x4000_0000)
        flash[PARAMETER_PAGES:] = page
        board.flash.write_bytes(bytes(flash))
        mark = frames.mark()
        board.control("reload")
        node.booted(mark)
        emcy = frames.wait_id(0x090, since=mark, timeout=5)
        assert emcy.data == bytes([0x00, 0x63, 0x01, 0x00, 0x18, 0x01, 0x01, 0x00]), emcy
        assert node.read(0x1800, 1) == 0x4000_0190
        assert node.read(0x1017, 0) == 250, "the rest of the page is restored"
        board.wait_for_log(r"stored 0x1800:1 not restored \(InvalidValue\)")


# Offset of the parameter pages in the board's flash file (memory.x: STORAGE at 0x0800_F800).
PARAMETER_PAGES = 0xF800


def crc32(data: bytes) -> int:
    import zlib

    return zlib.crc32(data)


def crc16(data: bytes) -> int:
    crc = 0xFFFF
    for b in data:
        crc ^= b << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else crc << 1
            crc &= 0xFFFF
    return crc


def craft_tpdo1_cob_id(page: bytearray, value: int) -> None:
    """Rewrites 0x1800:1 in the first record of the first page (docs/OBJECT-DICTIONARY.md's
    record layout: a 10-byte header, the engine blob, CRC-32; the engine blob: a 4-byte
    header, one U32 per stored parameter, 0x1800:1 the seventh, the application section,
    CRC-16) with both CRCs made valid again."""
    assert page[:4] == b"HWP2"
    blob_len = int.from_bytes(page[6:8], "little")
    blob = bytearray(page[10 : 10 + blob_len])
    blob[4 + 6 * 4 : 4 + 7 * 4] = value.to_bytes(4, "little")
    blob[-2:] = crc16(bytes(blob[:-2])).to_bytes(2, "little")
    page[10 : 10 + blob_len] = blob
    body = 10 + blob_len
    page[body : body + 4] = crc32(bytes(page[:body])).to_bytes(4, "little")
