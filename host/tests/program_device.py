"""A model of the handwheel's program download as docs/FIRMWARE-UPDATE.md states it: the
application's 0x1F51 "stop" into the loader, the loader's clear, download, checks and start,
0x1F56 and 0x1F57, the boot decision with its trial boot (an image that never becomes healthy
leaves the loader in charge with code 64; one that never talks answers nothing). The update's
tests drive it step by step (test_update.py) and through python-canopen on the virtual bus
(test_update_cli.py)."""

import struct
import zlib

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
