//! Board glue of the CANopen CNC handwheel for the STM32F103C8 (Blue Pill class).
//!
//! The RTIC application (`src/main.rs`) binds interrupts and moves data between these
//! modules and the host-tested crates; every decision about decoding, feed and CANopen
//! lives there, not here.
//!
//! - [`board`]: clocks, the pin map, wheel and switch inputs, LEDs, reset cause, unique ID.
//! - [`can`]: bxCAN bit timing, filters, transmit queue, receive draining, error state.
//! - [`storage`]: the parameter pages' erase and program in flash (0x1010/0x1011, LSS store).
//! - [`node_config`]: node-ID and bit rate from the DIP switch or the stored parameters
//!   (re-exported from the host-tested `handwheel-device`, like the record layout in
//!   `storage::record`).
//! - [`events`]: interrupt-to-task wake-ups.
//! - [`round_log`]: the log lines of a `canopen` round (bus errors, lost frames, encoder
//!   errors, selections, bit-rate switches).
//! - [`edge`]: the CAN side's access to the wheel state it shares with the edge task.
//! - [`priority`]: the interrupt priorities the firmware programs itself.
//! - [`image_header`]: the image header the resident loader checks (sealed at link time), and
//!   [`handoff`]: the request to stay in the loader, written before the reset into it.
//!
//! Linking this crate also brings the panic handler (a defmt log line, then UDF), and the
//! board crate (`handwheel_board`, shared with the resident loader) the image's memory
//! routines (byte loops that replace compiler-builtins' larger word-wise ones to keep the
//! image inside its flash budget).
#![no_std]
#![warn(missing_docs)]

pub mod board;
pub mod can;
pub mod edge;
pub mod events;
pub mod handoff;
pub mod image_header;
pub use handwheel_storage::node_config;
#[cfg(feature = "stack-overflow-test")]
pub mod overflow;
mod panic;
pub mod priority;
pub mod round_log;
pub mod storage;

/// The STM32F103's peripheral access crate, as stm32f1xx-hal re-exports it.
pub use stm32f1xx_hal::pac;
