# written by `cargo xtask contract` from crates/canopen-loader: change the Rust, not this file
"""The update contract of docs/FIRMWARE-UPDATE.md as the loader's crate states it
(crates/canopen-loader): the memory map (`layout`, which a test holds to memory.x), the image
header (`header`), the hand-off words between loader and application (`layout`, `boot`), the
loader's identity (`node`) and its 0x1F57 flash status codes with their meanings (`program`).
`cargo xtask contract --check`, part of `cargo xtask test`, fails when this file is not the
crate's.

Constants only, no imports: the host command (image.py, update.py), the seal (tools/seal, run
at every firmware link by any python3) and the rig's broken images (tools/rig/bad_images.py)
import it.
"""

# The memory map (layout.rs; memory.x at the root, for the linker).
PAGE_SIZE = 1024  # bytes in a flash page
CHIP_FLASH_SIZE = 65536  # bytes of the chip's flash, from LOADER_ORIGIN
LOADER_ORIGIN = 0x0800_0000  # LOADER: the resident loader
LOADER_LENGTH = 12288
SLOT_ORIGIN = 0x0800_3000  # the application slot, HEADER then FLASH
SLOT_SIZE = 51200
SLOT_PAGES = 50
HEADER_SLOT = 512  # HEADER: the image header, padded with 0xFF
APP_ORIGIN = 0x0800_3200  # FLASH: the application's vector table
MAX_IMAGE = 50688  # the most image bytes after the header slot
STORAGE_ORIGIN = 0x0800_F800  # STORAGE: the parameter pages, never written by the loader
STORAGE_LENGTH = 2048
RAM_ORIGIN = 0x2000_0000  # RAM: both images' RAM
RAM_LENGTH = 20472

# The image header (header.rs): HEADER_LEN bytes, little-endian, at SLOT_ORIGIN.
MAGIC = 0x4D49_5748  # the bytes "HWIM": the validity mark, written last
FORMAT = 1
HEADER_LEN = 32
UNSET = 0xFFFF_FFFF  # `length` and `crc` before the seal
MIN_IMAGE = 8  # the smallest image: a stack pointer and a reset vector
MAGIC_AT = 0x00
FORMAT_AT = 0x04
HEADER_SIZE_AT = 0x06
VENDOR_ID_AT = 0x08
PRODUCT_CODE_AT = 0x0C
VERSION_AT = 0x10
LENGTH_AT = 0x14
CRC_AT = 0x18
RESERVED_AT = 0x1C
# The fields in order: (name, offset, bytes).
HEADER_FIELDS = (
    ("magic", 0x00, 4),
    ("format", 0x04, 2),
    ("header_size", 0x06, 2),
    ("vendor_id", 0x08, 4),
    ("product_code", 0x0C, 4),
    ("version", 0x10, 4),
    ("length", 0x14, 4),
    ("crc", 0x18, 4),
    ("reserved", 0x1C, 4),
)
HEADER_STRUCT = "<IHHIIIIII"  # the fields for `struct`

# The hand-off words (layout.rs, boot.rs): the last two words of SRAM, a record and its complement.
HANDOFF_ORIGIN = 0x2000_4FF8  # HANDOFF
HANDOFF_LENGTH = 8
HANDOFF_REQUEST = 0x4C4F_4144  # "LOAD": the application's request to stay in the loader
TRIAL_TAG = 0x5452_4C00  # "TRL" and the count of unconfirmed starts in the low byte
MAX_TRIAL_STARTS = 3  # unconfirmed starts that keep the loader
LISTEN_MS = 100  # the listening window before every start

# The loader's identity (node.rs).
LOADER_DEVICE_TYPE = 0x544F_4F42  # its 0x1000, the bytes "BOOT"
LOADER_PRODUCT_BIT = 0x8000_0000  # its 0x1018:2 is the application's with this bit set

# 0x1F57:1, the flash status (program.rs): bit 0 in progress, bits 1-7 the code.
FLASH_IN_PROGRESS = 0x01
FLASH_CODE_SHIFT = 1
FLASH_CODE_MASK = 0x7F
FLASH_STATUS_OK = 0
FLASH_STATUS_NO_VALID_PROGRAM = 1
FLASH_STATUS_FORMAT_UNKNOWN = 2
FLASH_STATUS_FORMAT_ERROR = 3
FLASH_STATUS_NOT_CLEARED = 4
FLASH_STATUS_WRITE_ERROR = 5
FLASH_STATUS_ADDRESS_ERROR = 6
FLASH_STATUS_TRIAL_FAILED = 64
# The loader's codes in words.
FLASH_STATUS_MEANINGS = {
    FLASH_STATUS_OK: "no error",
    FLASH_STATUS_NO_VALID_PROGRAM: "no valid program",
    FLASH_STATUS_FORMAT_UNKNOWN: (
        "data format unknown (the header's magic, format or size, or another device's image)"
    ),
    FLASH_STATUS_FORMAT_ERROR: (
        "data format error (the CRC does not match, or the stream ended short or ran past its "
        "length)"
    ),
    FLASH_STATUS_NOT_CLEARED: "flash not cleared (data before clear)",
    FLASH_STATUS_WRITE_ERROR: "flash write error (an erase or program failed or read back wrong)",
    FLASH_STATUS_ADDRESS_ERROR: "general address error (the image does not fit the slot)",
    FLASH_STATUS_TRIAL_FAILED: (
        "the application was started 3 times and never became healthy on the bus (a hang, a fault "
        "or a lock-up before it talks): the loader stays"
    ),
}
