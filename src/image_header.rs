//! The application's image header (docs/FIRMWARE-UPDATE.md): the first bytes of its slot,
//! which the resident loader checks before it starts the application.
//!
//! The source defines it unsealed (`length` and `crc` all ones, erased flash); the link step
//! seals the ELF (tools/seal: the image's length and CRC-32 written in), so every linked image
//! carries its own. `header.x` places the section at `ORIGIN(HEADER)` (memory.x), right
//! before the vector table.

use canopen_loader::header::{
    CRC_AT, FORMAT, HEADER_LEN, LENGTH_AT, MAGIC, PRODUCT, PRODUCT_CODE_AT, RESERVED_AT, UNSET,
    VENDOR_ID_AT, VERSION_AT,
};
use canopen_loader::layout::HEADER_SLOT as SLOT;
use handwheel_device::od::IDENTITY;

/// The header's fields, in bytes; the rest of the slot is padding.
const HEADER_SIZE: u16 = HEADER_LEN as u16;

/// The header as it lies in flash, little-endian.
#[repr(C)]
pub struct ImageHeader {
    magic: u32,
    format: u16,
    header_size: u16,
    vendor_id: u32,
    product_code: u32,
    version: u32,
    /// Bytes of the image after the slot: set by the seal.
    length: u32,
    /// CRC-32 (zlib's) of those bytes: set by the seal.
    crc: u32,
    reserved: u32,
    padding: [u8; SLOT - HEADER_SIZE as usize],
}

const _: () = assert!(core::mem::size_of::<ImageHeader>() == SLOT);
// The layout is the contract's (crates/canopen-loader), field by field.
const _: () = assert!(core::mem::offset_of!(ImageHeader, vendor_id) == VENDOR_ID_AT);
const _: () = assert!(core::mem::offset_of!(ImageHeader, product_code) == PRODUCT_CODE_AT);
const _: () = assert!(core::mem::offset_of!(ImageHeader, version) == VERSION_AT);
const _: () = assert!(core::mem::offset_of!(ImageHeader, length) == LENGTH_AT);
const _: () = assert!(core::mem::offset_of!(ImageHeader, crc) == CRC_AT);
const _: () = assert!(core::mem::offset_of!(ImageHeader, reserved) == RESERVED_AT);
const _: () = assert!(core::mem::offset_of!(ImageHeader, padding) == HEADER_LEN);

/// This image's header, unsealed in the source. `#[used]`: nothing in the code refers to it
/// but [`own_crc`]; the loader reads it.
#[link_section = ".image_header"]
#[used]
pub static IMAGE_HEADER: ImageHeader = ImageHeader {
    magic: MAGIC,
    format: FORMAT,
    header_size: HEADER_SIZE,
    vendor_id: PRODUCT.vendor_id,
    product_code: PRODUCT.product_code,
    version: IDENTITY.revision,
    length: UNSET,
    crc: UNSET,
    reserved: UNSET,
    padding: [0xFF; SLOT - HEADER_SIZE as usize],
};

/// The `crc` of this image's header as the seal wrote it into flash (0x1F56:1): the source's
/// value is the unsealed one, so it is read from memory, never from the constant.
pub fn own_crc() -> u32 {
    // SAFETY: a read of a field of a `static`, through a reference: valid, aligned and never
    // written while the program runs. Volatile so that the compiler reads the flash the seal
    // patched instead of the initialiser it knows.
    unsafe { core::ptr::read_volatile(&IMAGE_HEADER.crc) }
}
