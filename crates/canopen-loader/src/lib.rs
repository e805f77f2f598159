//! The handwheel's resident CANopen loader (docs/FIRMWARE-UPDATE.md), as host-testable
//! `no_std` code: the image header and its seal ([`header`]), the memory map ([`layout`]),
//! the boot decision across resets, its trial count and listening window ([`boot`]),
//! the CiA 302-3 program download into the application slot and the boot check
//! ([`program`]), and the loader's minimal CANopen node over the engine's SDO server
//! ([`node`]). The firmware (`loader/`) only adds the registers: flash controller, CAN, the
//! jump.
#![cfg_attr(not(test), no_std)]

pub mod boot;
pub mod header;
pub mod layout;
pub mod node;
pub mod program;

pub use boot::{is_rescue_request, Boot, BootRecord, StayReason};
pub use header::{crc32, seal, Crc32, DeviceId, HeaderError, ImageHeader, SealError, MAGIC};
pub use node::{LoaderConfig, LoaderNode, Request};
pub use program::{
    valid_application, Control, ControlAction, Flash, FlashError, FlashStatus, Program,
};
