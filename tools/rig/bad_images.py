"""Update files of broken applications for the trial boot's tests (docs/FIRMWARE-UPDATE.md,
"Trial boot"): the release update file with its code changed and its header sealed again, so
that the header, the vector table and the CRC-32 are all genuine and the loader takes the
image. What each does once started:

- `hang`: the reset handler is a branch to itself: it never gets to the CAN stack;
- `fault`: the reset handler starts with an undefined instruction: HardFault, whose handler
  spins (on the emulated board a fault locks the core up until the watchdog resets it);
- `lockup`: the same fault, with the HardFault vector pointing at an ARM-state address, so
  that the fault's own entry faults: the core locks up (docs/EMULATED-BOARD.md);
- `silent`: the reset handler feeds the watchdog for ever and does nothing else: no reset,
  no frame (it waits with YIELD between feeds, which the emulated board takes as idle);
- `wrong-bit-rate`: the release application with its bit timing table turned by one
  (every DIP code or stored rate gets the next rate's timing): it runs, feeds the watchdog,
  and its frames never reach a bus at the right rate.

The first three are reset by the watchdog the loader starts them under; the last two need
the loader's listening window at power-on (`canopen-handwheel update --rescue`).

    python tools/rig/bad_images.py KIND UPDATE_FILE OUT    # writes OUT
    python tools/rig/bad_images.py KIND UPDATE_FILE --install FLASH_FILE

`--install` writes it into the application's slot of an emulated board's flash file (the
whole 64 KiB flash, `tools/board-emu/server.py --flash`; made if missing, erased elsewhere),
as a completed update leaves it: `cargo xtask board --image KIND` boots it behind the loader.
"""

from __future__ import annotations

import struct
import sys
import zlib
from pathlib import Path

# The update contract is the host component's module (host/src, standard library only;
# generated from crates/canopen-loader), on the path also when this runs as a script.
sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "host" / "src"))

from canopen_handwheel import update_contract as contract  # noqa: E402

HEADER_SLOT = contract.HEADER_SLOT  # the header slot before the image
SLOT_ORIGIN = contract.SLOT_ORIGIN  # memory.x: HEADER
FLASH_ORIGIN = contract.LOADER_ORIGIN  # the chip's flash, the loader's pages first
FLASH_SIZE = contract.CHIP_FLASH_SIZE
SLOT_SIZE = contract.SLOT_SIZE  # memory.x: HEADER + FLASH
HARD_FAULT = 3  # the vector table's entry
IWDG_KR = 0x4000_3000  # RM0008 19.4.1: the key register
KR_RELOAD = 0xAAAA

B_SELF = 0xE7FE  # b .
YIELD = 0xBF10
UDF = 0xDE00  # udf #0: permanently undefined (ARMv7-M ARM A7.7.191)

# CAN_BTR values the release image programs, by bit-rate code (BitRate::ALL at the 36 MHz
# APB1 clock): the table `wrong-bit-rate` looks for. 1 Mbit/s first, 10 kbit/s last.
BIT_RATES = [1_000_000, 800_000, 500_000, 250_000, 125_000, 50_000, 20_000, 10_000]
APB1_HZ = 36_000_000

KINDS = ("hang", "fault", "lockup", "silent", "wrong-bit-rate")


def btr_bit_rate(btr: int) -> float:
    """The bit rate a CAN_BTR value gives at APB1_HZ (RM0008 24.7.7)."""
    prescaler = (btr & 0x3FF) + 1
    quanta = 1 + ((btr >> 16) & 0xF) + 1 + ((btr >> 20) & 0x7) + 1
    return APB1_HZ / (prescaler * quanta)


def seal(data: bytearray) -> bytes:
    """The header's `length` and `crc` written for the image after the header slot."""
    body = bytes(data[HEADER_SLOT:])
    struct.pack_into("<II", data, contract.LENGTH_AT, len(body), zlib.crc32(body))
    return bytes(data)


def _offset(data: bytes, address: int) -> int:
    """The update file's offset of flash `address` (a Thumb bit ignored)."""
    offset = (address & ~1) - SLOT_ORIGIN
    if not HEADER_SLOT <= offset < len(data):
        raise ValueError(f"0x{address:08X} is outside the image")
    return offset


def _halfwords(data: bytearray, offset: int, words: list[int]) -> None:
    for i, word in enumerate(words):
        struct.pack_into("<H", data, offset + 2 * i, word)


def feed_loop(at: int) -> bytes:
    """Thumb code at flash address `at` that feeds the watchdog for ever:

    ldr r0, =IWDG_KR ; ldr r1, =KR_RELOAD ; 1: str r1, [r0] ; yield ; b 1b ; (literals)
    """
    pool = (at + 10 + 3) & ~3  # the literals after the five instructions, word-aligned

    def ldr(rt: int, literal: int, pc: int) -> int:  # LDR Rt, [PC, #imm] (T1)
        return 0x4800 | rt << 8 | (literal - ((pc + 4) & ~3)) // 4

    # str r1, [r0]; yield; b back to the str (8 bytes back from the branch's PC).
    code = [ldr(0, pool, at), ldr(1, pool + 4, at + 2), 0x6001, YIELD, 0xE7FC]
    out = b"".join(struct.pack("<H", h) for h in code)
    out += b"\x00" * (pool - at - len(out))
    return out + struct.pack("<II", IWDG_KR, KR_RELOAD)


def make(kind: str, update: bytes) -> bytes:
    """The update file `update` (the release one) turned into the broken image `kind`."""
    data = bytearray(update)
    reset = struct.unpack_from("<I", data, HEADER_SLOT + 4)[0]
    at = _offset(data, reset)
    if kind == "hang":
        _halfwords(data, at, [B_SELF])
    elif kind == "fault":
        _halfwords(data, at, [UDF])
    elif kind == "lockup":
        _halfwords(data, at, [UDF])
        handler = struct.unpack_from("<I", data, HEADER_SLOT + 4 * HARD_FAULT)[0]
        struct.pack_into("<I", data, HEADER_SLOT + 4 * HARD_FAULT, handler & ~1)
    elif kind == "silent":
        code = feed_loop(reset & ~1)
        data[at : at + len(code)] = code
    elif kind == "wrong-bit-rate":
        at = _bit_timing_table(data)
        table = list(struct.unpack_from("<8I", data, at))
        struct.pack_into("<8I", data, at, *(table[1:] + table[:1]))
    else:
        raise ValueError(f"unknown kind {kind!r} (one of {', '.join(KINDS)})")
    return seal(data)


def _bit_timing_table(data: bytes) -> int:
    """The offset of the one word-aligned run of 8 BTR values giving `BIT_RATES`."""
    found = [
        at
        for at in range(HEADER_SLOT, len(data) - 32, 4)
        if [round(btr_bit_rate(w)) for w in struct.unpack_from("<8I", data, at)] == BIT_RATES
    ]
    if len(found) != 1:
        raise ValueError(f"{len(found)} bit timing tables in the image, not one")
    return found[0]


def install(update: bytes, flash_file: Path) -> None:
    """`update` into the slot of the flash file `flash_file`, the rest of the slot erased."""
    flash = bytearray(flash_file.read_bytes()) if flash_file.exists() else bytearray()
    if len(flash) != FLASH_SIZE:
        flash = bytearray(b"\xff" * FLASH_SIZE)
    start = SLOT_ORIGIN - FLASH_ORIGIN
    if len(update) > SLOT_SIZE:
        raise ValueError("the image does not fit the slot")
    flash[start : start + SLOT_SIZE] = update + b"\xff" * (SLOT_SIZE - len(update))
    flash_file.parent.mkdir(parents=True, exist_ok=True)
    flash_file.write_bytes(flash)


def main(argv: list[str]) -> int:
    if len(argv) == 4 and argv[2] == "--install":
        argv = [argv[0], argv[1], argv[3], "--install"]
    if len(argv) not in (3, 4) or argv[0] not in KINDS or argv[3:] not in ([], ["--install"]):
        print(__doc__.split("\n\n")[-2].strip(), file=sys.stderr)
        print(f"KIND: {', '.join(KINDS)}", file=sys.stderr)
        return 2
    kind, source, out = argv[:3]
    data = make(kind, Path(source).read_bytes())
    if argv[3:]:
        install(data, Path(out))
    else:
        Path(out).write_bytes(data)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
