"""The update file (docs/FIRMWARE-UPDATE.md, "The image header"): the application slot's
bytes from its start, a 512-byte header slot followed by the image. `UpdateImage.parse`
checks everything the loader would check that the file alone can tell, so that a wrong or
damaged file is refused before the command touches the bus (the loader would refuse it too,
but only after the application was stopped and its slot erased).

Pure: standard library only, no I/O. The header's layout and the slot are the contract's
(update_contract.py, generated from crates/canopen-loader).
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass

from . import update_contract as contract

# The contract's values (crates/canopen-loader, through update_contract.py), by this module's
# names.
MAGIC = contract.MAGIC  # the bytes "HWIM": the validity mark
FORMAT = contract.FORMAT
HEADER_SIZE = contract.HEADER_LEN
SLOT_HEADER = contract.HEADER_SLOT  # the header slot before the image
# The application slot, HEADER + FLASH: 0x0800_3000..0x0800_F800.
SLOT_SIZE = contract.SLOT_SIZE
_HEADER = struct.Struct(contract.HEADER_STRUCT)
_MARK = MAGIC.to_bytes(4, "little")


class ImageError(ValueError):
    """The file is not an update image this command can send."""


@dataclass(frozen=True)
class UpdateImage:
    vendor_id: int
    product_code: int
    version: int
    length: int  # bytes of the image after the header slot
    crc: int  # zlib.crc32 of those bytes: what 0x1F56 reads once it is installed
    data: bytes  # the whole file: what 0x1F50:1 is sent

    @classmethod
    def parse(cls, data: bytes) -> "UpdateImage":
        """The image in `data`, or `ImageError` saying what is wrong with it."""
        data = bytes(data)
        if len(data) < SLOT_HEADER:
            raise ImageError(
                f"{len(data)} bytes: shorter than the {SLOT_HEADER}-byte header slot of an "
                "update file"
            )
        magic, fmt, size, vendor, product, version, length, crc, _reserved = _HEADER.unpack_from(
            data
        )
        if magic != MAGIC:
            raise ImageError(
                f"no update image header: the file begins {data[:4]!r}, not {_MARK!r} (is it the "
                "ELF or the loader's image instead of the update file `cargo xtask fw` prints?)"
            )
        if fmt != FORMAT or size != HEADER_SIZE:
            raise ImageError(
                f"header format {fmt}, size {size}: this command knows format {FORMAT}, "
                f"size {HEADER_SIZE}"
            )
        if length == contract.UNSET:
            raise ImageError("the header is not sealed (length unset): not an update file")
        if SLOT_HEADER + length > SLOT_SIZE:
            raise ImageError(
                f"the image ({length} bytes after its header slot) does not fit the "
                f"{SLOT_SIZE}-byte application slot"
            )
        if len(data) != SLOT_HEADER + length:
            raise ImageError(
                f"the header says {length} bytes after the header slot, the file has "
                f"{len(data) - SLOT_HEADER} (truncated or padded?)"
            )
        actual = zlib.crc32(data[SLOT_HEADER:])
        if actual != crc:
            raise ImageError(
                f"the image's CRC-32 is 0x{actual:08X}, its header says 0x{crc:08X} (damaged?)"
            )
        return cls(vendor, product, version, length, crc, data)

    def describe(self) -> str:
        return (
            f"version {self.version}, CRC 0x{self.crc:08X}, {self.length} bytes, for vendor "
            f"0x{self.vendor_id:08X} product 0x{self.product_code:08X}"
        )


def build(
    image: bytes,
    vendor_id: int,
    product_code: int,
    version: int,
    *,
    magic: int = MAGIC,
    fmt: int = FORMAT,
    header_size: int = HEADER_SIZE,
) -> bytes:
    """An update file around `image` (the tests' and a fake device's; the firmware's own is
    written by `cargo xtask fw`)."""
    header = _HEADER.pack(
        magic,
        fmt,
        header_size,
        vendor_id,
        product_code,
        version,
        len(image),
        zlib.crc32(image),
        0xFFFF_FFFF,
    )
    return header.ljust(SLOT_HEADER, b"\xff") + bytes(image)
