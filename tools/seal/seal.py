"""The seal: fills the application's image header with the image's length and CRC-32.

The firmware source defines its image header (src/image_header.rs) with `length` and `crc`
unset (0xFFFF_FFFF); the link step seals the ELF (docs/FIRMWARE-UPDATE.md, "The image
header"). `tools/seal/linker`, the firmware target's linker (.cargo/config.toml), runs
flip-link and then this on the linked output, so every application ELF that cargo links
(`cargo fw`, `cargo embed`, `cargo xtask`) carries a correct header. An ELF without the
header's section (the loader's) is left as it is.

The image is the flash content after the header slot up to the last loadable byte: the
bytes of every loadable segment at its load address (the initial values of `.data` too),
gaps 0xFF as erased flash; `length` is its size and `crc` zlib's CRC-32 of it. The header
slot is the `.image_header` section (it fills memory.x's HEADER region). Sealing a sealed
ELF again writes the same values.

Python's standard library only: it runs at every firmware link, also where no project venv
exists. The header's mark, format, size and field offsets are the loader's contract
(host/src/canopen_handwheel/update_contract.py, which `cargo xtask contract` writes from
crates/canopen-loader; constants only), imported from host/src as tools/board-emu imports the
SLCAN codec. It reads the ELF itself rather than through xtask's reader (xtask/src/elf.rs):
`cargo fw` and `cargo embed` link without xtask, which nothing builds for them (a fresh clone
has no xtask binary), and building it from here would nest a cargo build of xtask and its
dependencies inside the firmware's link. xtask checks what the seal wrote against its own
reading (xtask/src/update.rs).

    python3 tools/seal/seal.py ELF                 # seal ELF in place
    python3 tools/seal/seal.py --link-args ARGS... # seal the output (-o) of a linker command
"""

from __future__ import annotations

import struct
import sys
import zlib
from dataclasses import dataclass
from pathlib import Path

# The contract's module is the host component's (host/src; standard library only).
sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "host" / "src"))

from canopen_handwheel import update_contract as contract  # noqa: E402

SECTION = ".image_header"
MAGIC = contract.MAGIC
FORMAT = contract.FORMAT
HEADER_SIZE = contract.HEADER_LEN
# Offsets of the fields the seal writes.
LENGTH_AT = contract.LENGTH_AT
CRC_AT = contract.CRC_AT
UNSET = contract.UNSET
# Loadable bytes below this address are flash (the ARMv7-M code region, 0x0000_0000 to
# 0x1FFF_FFFF); above it, RAM and peripherals, which no image programs.
CODE_REGION_END = 0x2000_0000
PT_LOAD = 1


class SealError(Exception):
    """The ELF is not one the seal can seal."""


@dataclass(frozen=True)
class Seal:
    """What the seal wrote: the header's address, the slot's size, the image's length and CRC."""

    header: int
    slot: int
    length: int
    crc: int


def _unpack(fmt: str, data: bytes, at: int) -> tuple[int, ...]:
    try:
        return struct.unpack_from("<" + fmt, data, at)
    except struct.error:
        raise SealError(f"truncated ELF (offset {at:#x})") from None


def _header_section(elf: bytes) -> tuple[int, int, int] | None:
    """The `.image_header` section's (address, file offset, size), or None."""
    if elf[:4] != b"\x7fELF" or elf[4:6] != b"\x01\x01":
        raise SealError("not a 32-bit little-endian ELF")
    (shoff,) = _unpack("I", elf, 0x20)
    shentsize, shnum, shstrndx = _unpack("HHH", elf, 0x2E)
    if shnum == 0:
        return None
    if shentsize < 40 or shstrndx >= shnum:
        raise SealError("bad section header table")
    (names_at,) = _unpack("I", elf, shoff + shstrndx * shentsize + 16)
    wanted = SECTION.encode() + b"\0"
    for i in range(shnum):
        name, _, _, addr, offset, size = _unpack("IIIIII", elf, shoff + i * shentsize)
        if elf[names_at + name : names_at + name + len(wanted)] == wanted:
            return addr, offset, size
    return None


def _flash_segments(elf: bytes) -> list[tuple[int, bytes]]:
    """(load address, bytes) of every loadable segment with bytes in flash."""
    (phoff,) = _unpack("I", elf, 0x1C)
    phentsize, phnum = _unpack("HH", elf, 0x2A)
    segments = []
    for i in range(phnum):
        kind, offset, _, paddr, filesz = _unpack("IIIII", elf, phoff + i * phentsize)
        if kind != PT_LOAD or filesz == 0 or paddr >= CODE_REGION_END:
            continue
        data = elf[offset : offset + filesz]
        if len(data) != filesz:
            raise SealError(f"truncated ELF (segment at {paddr:#x})")
        segments.append((paddr, data))
    return segments


def image_bytes(elf: bytes, header: int, slot: int) -> bytes:
    """The image after the header slot at `header`, as flash holds it (gaps 0xFF)."""
    start = header + slot
    segments = _flash_segments(elf)
    for paddr, _ in segments:
        if paddr < header:
            raise SealError(f"a segment loads at {paddr:#x}, below the header at {header:#x}")
    end = max((paddr + len(data) for paddr, data in segments), default=start)
    if end <= start:
        raise SealError("no image after the header slot")
    image = bytearray(b"\xff" * (end - start))
    for paddr, data in segments:
        # A segment that starts in the header slot (the header and the vector table after it
        # in one): its slot part is the header's own.
        skip = max(start - paddr, 0)
        if skip >= len(data):
            continue
        at = paddr + skip - start
        image[at : at + len(data) - skip] = data[skip:]
    return bytes(image)


def seal_bytes(elf: bytearray) -> Seal | None:
    """Seals `elf` in memory; None (and nothing changed) without an image header."""
    found = _header_section(elf)
    if found is None:
        return None
    header, offset, slot = found
    magic, fmt, size = _unpack("IHH", elf, offset)
    if (magic, fmt, size) != (MAGIC, FORMAT, HEADER_SIZE) or slot < HEADER_SIZE:
        raise SealError(
            f"{SECTION} is not an image header of format {FORMAT} (magic {magic:#010x}, "
            f"format {fmt}, size {size}, section {slot} B)"
        )
    image = image_bytes(bytes(elf), header, slot)
    crc = zlib.crc32(image)
    struct.pack_into("<II", elf, offset + LENGTH_AT, len(image), crc)
    return Seal(header, slot, len(image), crc)


def seal_file(path: Path) -> Seal | None:
    """Seals the ELF at `path` in place; None without an image header."""
    elf = bytearray(path.read_bytes())
    sealed = seal_bytes(elf)
    if sealed is not None:
        path.write_bytes(elf)
    return sealed


def _expand(args: list[str]) -> list[str]:
    """Linker arguments with response files (`@FILE`) read in, as the linker reads them."""
    out = []
    for arg in args:
        if arg.startswith("@") and Path(arg[1:]).is_file():
            text = Path(arg[1:]).read_text()
            out.extend(_expand([line for line in text.splitlines() if line]))
        else:
            out.append(arg)
    return out


def output_of(args: list[str]) -> Path:
    """The output file of a linker command (`-o FILE` or `-oFILE`)."""
    args = _expand(args)
    for i, arg in enumerate(args):
        if arg == "-o" and i + 1 < len(args):
            return Path(args[i + 1])
        if arg.startswith("-o") and len(arg) > 2 and not arg.startswith("-o-"):
            return Path(arg[2:])
    raise SealError("the linker command names no output (-o)")


def main(argv: list[str]) -> int:
    try:
        if argv[:1] == ["--link-args"]:
            path = output_of(argv[1:])
        elif len(argv) == 1:
            path = Path(argv[0])
        else:
            print(__doc__, file=sys.stderr)
            return 2
        seal_file(path)
    except (OSError, SealError) as error:
        print(f"seal: {error}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
