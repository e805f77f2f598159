"""The seal on hand-made ELF files: the header's length and CRC as docs/FIRMWARE-UPDATE.md
defines them, and ELFs it must leave alone or refuse."""

from __future__ import annotations

import struct
import zlib

import pytest

from seal.seal import CRC_AT, LENGTH_AT, MAGIC, SealError, main, output_of, seal_bytes

HEADER_AT = 0x0800_3000
SLOT = 512


def header(length: int = 0xFFFF_FFFF, crc: int = 0xFFFF_FFFF, magic: int = MAGIC) -> bytes:
    fields = struct.pack("<IHHIIIIII", magic, 1, 32, 0, 1, 1, length, crc, 0xFFFF_FFFF)
    return fields + b"\xff" * (SLOT - len(fields))


def elf(
    segments: list[tuple[int, int, bytes]], sections: list[tuple[str, int, int, int]]
) -> bytearray:
    """An ELF32 LE file: PT_LOAD `segments` (vaddr, paddr, bytes), then the section headers
    `sections` (name, address, offset into the segment data area, size) and their names."""
    phoff = 0x34
    data_at = phoff + 32 * len(segments)
    out = bytearray(data_at)
    out[:6] = b"\x7fELF\x01\x01"
    offsets = []
    for _, _, data in segments:
        offsets.append(len(out))
        out += data
    names = bytearray(b"\0")
    name_at = []
    for name, *_ in sections:
        name_at.append(len(names))
        names += name.encode() + b"\0"
    shstrtab_name = len(names)
    names += b".shstrtab\0"
    names_offset = len(out)
    out += names
    shoff = len(out)
    for i, (vaddr, paddr, data) in enumerate(segments):
        struct.pack_into(
            "<IIIIIIII", out, phoff + 32 * i, 1, offsets[i], vaddr, paddr, len(data),
            len(data), 5, 4,
        )  # fmt: skip
    # (name, type, flags, address, offset, size, link, info, align, entry size)
    shdrs = [bytes(40)]
    for (_, addr, offset, size), name in zip(sections, name_at):
        shdrs.append(struct.pack("<10I", name, 1, 2, addr, data_at + offset, size, 0, 0, 4, 0))
    shdrs.append(struct.pack("<10I", shstrtab_name, 3, 0, 0, names_offset, len(names), 0, 0, 1, 0))
    for shdr in shdrs:
        out += shdr
    struct.pack_into("<I", out, 0x1C, phoff)
    struct.pack_into("<I", out, 0x20, shoff)
    struct.pack_into("<HHHHHH", out, 0x28, 0x34, 32, len(segments), 40, len(shdrs), len(shdrs) - 1)
    return out


CODE = bytes(range(256)) * 3 + b"\x01\x02\x03"  # vector table and code after the header
DATA = b"\x11\x22\x33\x44\x55\x66"  # .data's initial values, loaded in flash, run in RAM
DATA_AT = HEADER_AT + SLOT + len(CODE) + 13  # 13 bytes of gap


def application() -> bytearray:
    return elf(
        [
            (HEADER_AT, HEADER_AT, header() + CODE),
            (0x2000_4F00, DATA_AT, DATA),
            # A RAM segment with file bytes: never flash.
            (0x2000_0000, 0x2000_0000, b"\xaa" * 8),
        ],
        [(".image_header", HEADER_AT, 0, SLOT), (".vector_table", HEADER_AT + SLOT, SLOT, 64)],
    )


# The header is the first segment's first bytes, after the ELF header and 3 program headers.
HEADER_OFFSET = 0x34 + 32 * 3


def field(image: bytes, at: int) -> int:
    return struct.unpack_from("<I", image, HEADER_OFFSET + at)[0]


def test_the_seal_writes_length_and_crc_of_the_image_after_the_slot():
    image = application()
    sealed = seal_bytes(image)
    flash = CODE + b"\xff" * 13 + DATA
    assert sealed is not None
    assert (sealed.header, sealed.slot) == (HEADER_AT, SLOT)
    assert sealed.length == len(CODE) + 13 + len(DATA) == 790
    assert sealed.crc == zlib.crc32(flash)
    assert field(image, LENGTH_AT) == 790
    assert field(image, CRC_AT) == zlib.crc32(flash)
    # Nothing else changed.
    unsealed = application()
    at = HEADER_OFFSET + LENGTH_AT
    assert image[:at] == unsealed[:at]
    assert image[at + 8 :] == unsealed[at + 8 :]


def test_sealing_again_writes_the_same():
    image = application()
    seal_bytes(image)
    once = bytes(image)
    seal_bytes(image)
    assert bytes(image) == once


def test_a_changed_byte_of_the_image_changes_the_crc():
    image = application()
    first = seal_bytes(image)
    changed = application()
    at = changed.index(DATA)
    changed[at] ^= 1
    assert seal_bytes(changed).crc != first.crc


def test_an_elf_without_the_header_is_left_alone():
    loader = elf([(0x0800_0000, 0x0800_0000, CODE)], [(".vector_table", 0x0800_0000, 0, 64)])
    before = bytes(loader)
    assert seal_bytes(loader) is None
    assert bytes(loader) == before


def test_what_is_not_a_header_or_not_an_image_is_refused():
    wrong = elf(
        [(HEADER_AT, HEADER_AT, header(magic=0x1234_5678) + CODE)],
        [(".image_header", HEADER_AT, 0, SLOT)],
    )
    with pytest.raises(SealError, match="not an image header"):
        seal_bytes(wrong)
    below = elf(
        [(0x0800_0000, 0x0800_0000, CODE), (HEADER_AT, HEADER_AT, header() + CODE)],
        [(".image_header", HEADER_AT, len(CODE), SLOT)],
    )
    with pytest.raises(SealError, match="below the header"):
        seal_bytes(below)
    empty = elf([(HEADER_AT, HEADER_AT, header())], [(".image_header", HEADER_AT, 0, SLOT)])
    with pytest.raises(SealError, match="no image"):
        seal_bytes(empty)
    with pytest.raises(SealError, match="ELF"):
        seal_bytes(bytearray(b"not an elf" * 10))


def test_the_output_is_found_in_the_linker_arguments(tmp_path):
    assert str(output_of(["-flavor", "gnu", "a.o", "-o", "/x/fw", "-Tlink.x"])) == "/x/fw"
    assert str(output_of(["a.o", "-o/x/fw"])) == "/x/fw"
    response = tmp_path / "args"
    response.write_text("-flavor\ngnu\n-o\n/y/fw\n")
    assert str(output_of(["a.o", f"@{response}"])) == "/y/fw"
    with pytest.raises(SealError, match="no output"):
        output_of(["a.o"])


def test_the_command_seals_the_linker_output_in_place(tmp_path):
    path = tmp_path / "handwheel-firmware"
    path.write_bytes(application())
    assert main(["--link-args", "-flavor", "gnu", "-o", str(path)]) == 0
    image = path.read_bytes()
    assert field(image, LENGTH_AT) == 790
    assert main([str(tmp_path / "missing")]) == 1
