//! The handwheel's parameter pages, the one piece of flash both images read: the
//! application stores its parameters there (0x1010, LSS "store configuration") and reads
//! them at every boot; the resident loader reads only the node-ID and bit rate, so that it
//! answers where the application would (docs/FIRMWARE-UPDATE.md). Neither the object
//! dictionary nor the device is here: the device's parameters are an opaque blob.
//!
//! - [`record`]: the byte layout of one stored state under its CRC-32.
//! - [`page`]: the two-page log over erasable flash that no power cut and no master can
//!   break, with its wear budget; the engine's `Storage`.
//! - [`node_config`]: the node-ID and bit rate in force, from the DIP switch or the stored
//!   record, and the serial number from the chip's unique ID.
#![no_std]

pub mod node_config;
pub mod page;
pub mod record;
