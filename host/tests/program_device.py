"""A model of the handwheel's program download as docs/FIRMWARE-UPDATE.md states it: the
application's 0x1F51 "stop" into the loader, the loader's clear, download, checks and start,
0x1F56 and 0x1F57, the boot decision with its trial boot (an image that never becomes healthy
leaves the loader in charge with code 64; one that never talks answers nothing). The update's
tests drive it step by step (test_update.py) and through python-canopen on the virtual bus
(test_update_cli.py), there also behind `BlockDownloadServer`, the server's side of SDO block
download with its CRC-16."""

import binascii
import struct
import zlib
from typing import Optional

from canopen_handwheel import image

VENDOR = 0x0000_0ABC
PRODUCT = 0x0000_4857
APP_DEVICE_TYPE = 0x0000_0000
LOADER_DEVICE_TYPE = 0x544F_4F42
LOADER_REVISION = 7
PRE_OPERATIONAL = 0x7F
OPERATIONAL = 0x05


class Abort(Exception):
    def __init__(self, code: int) -> None:
        super().__init__(f"0x{code:08X}")
        self.code = code


class Silent(Exception):
    """The device runs an image that answers nothing."""


# How an installed image behaves once started (`ProgramDevice.health`, by its CRC).
TRIAL_FAILS = "trial fails"  # hangs or faults: the loader stays after 3 starts, code 64
SILENT = "silent"  # feeds its watchdog and never talks
TRIAL_FAILED = 64


def update_file(version: int, size: int = 1000, vendor=VENDOR, product=PRODUCT) -> bytes:
    body = bytes((version * 7 + i * 13) & 0xFF for i in range(size))
    return image.build(body, vendor, product, version)


def status(code: int, in_progress: bool = False) -> int:
    return code << 1 | int(in_progress)


class ProgramDevice:
    """The device: `slot` is the installed update file (None: no valid application);
    `read`, `write` (expedited), `download` (0x1F50:1, the whole stream) raise `Abort`;
    `nmt`; `take_reset` says whether the last write asked for a reset (the caller resets with
    `boot` after the answer, as the device does). `bootups` counts boot-ups sent."""

    def __init__(self, slot=None, has_loader=True, feed=0, status_polls=0, health=None):
        self.slot = slot
        self.health = health or {}  # image CRC -> TRIAL_FAILS or SILENT; others are healthy
        self.silent = False
        self.has_loader = has_loader
        self.feed = 0
        self.status_polls = status_polls  # 0x1F57 reads "in progress" this often after each change
        self.bootups = 0
        self.handoff = False
        self.reset_due = False
        self.rescue_pending = False
        self.log = []
        self.boot()
        self.feed = 0 if self.loader else feed  # left on by a master before this test

    # The boot decision.
    def valid(self) -> bool:
        if self.slot is None:
            return False
        try:
            img = image.UpdateImage.parse(self.slot)
        except image.ImageError:
            return False
        return (img.vendor_id, img.product_code) == (VENDOR, PRODUCT)

    def boot(self, power_on: bool = False) -> None:
        """A reset (the boot decision), or with `power_on` a power cycle: the loader's
        window then catches a pending rescue request (`rescue_pending`)."""
        stay = self.handoff or not self.valid()
        if power_on and self.rescue_pending:
            stay = True
        self.handoff = False
        self.rescue_pending = False
        health = None if stay else self.health.get(self.crc())
        self.silent = health == SILENT
        self.loader = (stay or health == TRIAL_FAILS) and self.has_loader
        self.state = PRE_OPERATIONAL
        self.control = 0 if self.loader else 1
        self.status = status(0 if self.valid() else 1)
        if health == TRIAL_FAILS:
            self.status = status(TRIAL_FAILED)
        self.busy = 0
        self.feed = 0
        self.bootups += 1

    def take_reset(self) -> bool:
        due, self.reset_due = self.reset_due, False
        return due

    def nmt(self, state: int) -> None:
        self.state = state

    def crc(self) -> int:
        return struct.unpack_from("<I", self.slot, 0x18)[0] if self.valid() else 0

    def version(self) -> int:
        return struct.unpack_from("<I", self.slot, 0x10)[0]

    def read(self, index: int, sub: int) -> int:
        self.log.append(("read", index, sub))
        if self.silent:
            raise Silent
        key = (index, sub)
        if key == (0x1000, 0):
            return LOADER_DEVICE_TYPE if self.loader else APP_DEVICE_TYPE
        if key == (0x1018, 1):
            return VENDOR
        if key == (0x1018, 2):
            return PRODUCT | 0x8000_0000 if self.loader else PRODUCT
        if key == (0x1018, 3):
            return LOADER_REVISION if self.loader else self.version()
        if key == (0x1F50, 1):
            raise Abort(0x0601_0001)
        if key == (0x1F51, 1):
            return self.control
        if key == (0x1F56, 1):
            return self.crc()
        if key == (0x1F57, 1):
            if self.busy:
                self.busy -= 1
                return self.status | 1
            return self.status
        if key == (0x2000, 0) and not self.loader:
            return self.feed
        raise Abort(0x0602_0000)

    def write(self, index: int, sub: int, value: int) -> None:
        self.log.append(("write", index, sub, value))
        if self.silent:
            raise Silent
        if (index, sub) == (0x2000, 0) and not self.loader:
            self.feed = value
            return
        if (index, sub) != (0x1F51, 1):
            raise Abort(0x0602_0000)
        if value not in (0, 1, 3):
            raise Abort(0x0609_0030)
        if self.state != PRE_OPERATIONAL:
            raise Abort(0x0800_0022)
        if not self.loader:
            if value == 0:
                if self.feed:
                    raise Abort(0x0800_0022)
                self.handoff = True
                self.reset_due = True
            elif value == 3:
                raise Abort(0x0800_0022)
            return
        if value == 1:
            if not self.valid():
                raise Abort(0x0800_0022)
            self.reset_due = True
        elif value == 3:
            self.slot = None
            self.control = 3
            self.status = status(0)
            self.busy = self.status_polls

    def download(self, data: bytes) -> None:
        self.log.append(("download", len(data)))
        if not self.loader:
            raise Abort(0x0602_0000)
        if self.control != 3:
            self.status = status(4)
            raise Abort(0x0800_0022)
        self.control = 0
        self.busy = self.status_polls
        magic, fmt, size, vendor, product, _, length, crc = struct.unpack_from("<IHHIIIII", data)
        if (magic, fmt, size, vendor, product) != (image.MAGIC, 1, 32, VENDOR, PRODUCT):
            self.status = status(2)
            raise Abort(0x0609_0030)
        if image.SLOT_HEADER + length > image.SLOT_SIZE:
            self.status = status(6)
            raise Abort(0x0504_0005)
        if len(data) != image.SLOT_HEADER + length or zlib.crc32(data[image.SLOT_HEADER :]) != crc:
            self.status = status(3)
            raise Abort(0x0800_0020)
        self.slot = bytes(data)
        self.status = status(0)


# SDO block download ----------------------------------------------------------------------


def crc16_xmodem(data: bytes, crc: int = 0) -> int:
    """CRC-16/XMODEM (CiA 301's block transfer CRC: polynomial 0x1021, initial 0, no
    reflection, no final XOR): the standard library's `binascii.crc_hqx`, independent of
    python-canopen's."""
    return binascii.crc_hqx(data, crc)


ABORT_COMMAND = 0x0504_0001
ABORT_SEQUENCE = 0x0504_0003
ABORT_CRC = 0x0504_0004
ABORT_LENGTH = 0x0607_0010


class BlockDownloadServer:
    """The server's side of CiA 301 SDO block download into one object (`index`, `sub`), for
    the tests: `request(frame)` takes each frame the client sends to the node's SDO server and
    returns the answer (None: none). The whole stream goes to `deliver` (a `ProgramDevice`'s
    `download`: its `Abort` becomes the end's abort) after the end request, once its length
    and its CRC-16 are right. Segments out of sequence are ignored; a sub-block ends with the
    segment numbered `blksize` or one with c = 1, acknowledged with the last one taken in
    sequence (as the loader does: crates/canopen-slave/src/sdo.rs). Faults: `lose` the
    segment frames (counted from 1 over the server's life) that never arrive; `damage` a byte
    offset flipped on arrival (the end's CRC no longer matches); `abort_block` (n, code):
    the n-th sub-block's acknowledgement is that abort instead. `log` has what happened,
    `frames` every frame received."""

    IDLE, SUBBLOCK, END = "idle", "sub-block", "end"

    def __init__(
        self, index, sub, deliver, blksize=127, lose=(), damage=None, abort_block=None
    ) -> None:
        assert 1 <= blksize <= 127
        self.index, self.sub = index, sub
        self.deliver = deliver
        self.blksize = blksize
        self.lose = set(lose)
        self.damage = damage
        self.abort_block = abort_block
        self.state = self.IDLE
        self.segments = 0  # segment frames sent to the server (lost ones too)
        self.log = []
        self.frames = []

    @property
    def busy(self) -> bool:
        return self.state != self.IDLE

    def _mux(self) -> bytes:
        return struct.pack("<HB", self.index, self.sub)

    def _abort(self, code: int, mux: bytes = b"") -> bytes:
        self.log.append(("abort", code))
        self.state = self.IDLE
        return b"\x80" + (mux or self._mux()) + struct.pack("<I", code)

    def request(self, frame: bytes) -> Optional[bytes]:
        frame = bytes(frame).ljust(8, b"\x00")
        cmd = frame[0]
        if self.state == self.SUBBLOCK:
            self.segments += 1
            if self.segments in self.lose:
                self.log.append(("lost", cmd & 0x7F))
                return None
        self.frames.append(frame)
        if cmd == 0x80 and self.busy:  # the client's abort (no segment has sequence number 0)
            self.log.append(("client abort", struct.unpack_from("<I", frame, 4)[0]))
            self.state = self.IDLE
            return None
        if self.state == self.IDLE:
            return self._initiate(frame)
        if self.state == self.SUBBLOCK:
            return self._segment(frame)
        return self._end(frame)

    def _initiate(self, frame: bytes) -> bytes:
        cmd = frame[0]
        if cmd & 0xE1 != 0xC0:  # not ccs 6 with cs 0
            return self._abort(ABORT_COMMAND, frame[1:4])
        if frame[1:4] != self._mux():
            return self._abort(0x0602_0000, frame[1:4])
        self.crc_asked = bool(cmd & 0x04)
        self.size = struct.unpack_from("<I", frame, 4)[0] if cmd & 0x02 else None
        self.log.append(("initiate", self.crc_asked, self.size))
        self.data = bytearray()  # taken in sub-blocks acknowledged
        self.pending = bytearray()  # taken in sequence in this sub-block
        self.ackseq = 0
        self.last = False
        self.blocks = 0
        self.state = self.SUBBLOCK
        # scs 5, sc 1 (the server checks the CRC), ss 0; byte 4 the sub-block size.
        return bytes([0xA4]) + self._mux() + bytes([self.blksize, 0, 0, 0])

    def _segment(self, frame: bytes) -> Optional[bytes]:
        seqno, c = frame[0] & 0x7F, bool(frame[0] & 0x80)
        if not 1 <= seqno <= self.blksize:
            return self._abort(ABORT_SEQUENCE)
        if seqno == self.ackseq + 1 and not self.last:
            chunk = bytearray(frame[1:8])
            at = -1 if self.damage is None else self.damage - len(self.data) - len(self.pending)
            if 0 <= at < 7:
                chunk[at] ^= 0xFF
            self.pending += chunk
            self.ackseq = seqno
            self.last = c
        if seqno < self.blksize and not c:
            return None
        self.blocks += 1
        if self.abort_block is not None and self.blocks == self.abort_block[0]:
            return self._abort(self.abort_block[1])
        self.data += self.pending
        self.pending = bytearray()
        ackseq, self.ackseq = self.ackseq, 0
        self.log.append(("ack", ackseq, self.blksize))
        if self.last:
            self.state = self.END
        return bytes([0xA2, ackseq, self.blksize, 0, 0, 0, 0, 0])

    def _end(self, frame: bytes) -> bytes:
        cmd = frame[0]
        if cmd & 0xE3 != 0xC1:  # not ccs 6 with cs 1
            return self._abort(ABORT_COMMAND)
        unused = cmd >> 2 & 0x07
        data = bytes(self.data[: len(self.data) - unused])
        crc = struct.unpack_from("<H", frame, 1)[0]
        self.log.append(("end", unused, crc))
        if self.size is not None and len(data) != self.size:
            return self._abort(ABORT_LENGTH)
        if self.crc_asked and crc16_xmodem(data) != crc:
            return self._abort(ABORT_CRC)
        try:
            self.deliver(data)
        except Abort as e:
            return self._abort(e.code)
        self.state = self.IDLE
        self.log.append(("done", len(data)))
        return bytes([0xA1, 0, 0, 0, 0, 0, 0, 0])
