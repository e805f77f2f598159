//! Board glue of the CANopen CNC handwheel for the STM32F103C8 (Blue Pill class), and of
//! its QEMU variant (`--features qemu`, module [`qemu`]).
//!
//! The RTIC application (`src/main.rs`) binds interrupts and moves data between these
//! modules and the host-tested crates; every decision about decoding, feed and CANopen
//! lives there, not here.
//!
//! - [`board`]: clocks, the pin map, wheel and switch inputs, LEDs, reset cause, unique ID.
//! - [`can`]: bxCAN bit timing, filters, transmit queue, receive draining, error state.
//! - [`storage`]: the parameter page's erase and program in flash (0x1010/0x1011, LSS store).
//! - [`node_config`]: node-ID and bit rate from the DIP switch or the stored parameters
//!   (re-exported from the host-tested `handwheel-device`, like the record layout in
//!   `storage::record`).
//! - [`events`]: interrupt-to-task wake-ups.
//! - [`round_log`]: the log lines of a `canopen` round (bus errors, lost frames, encoder
//!   errors, selections, bit-rate switches).
//! - [`edge`]: the CAN side's access to the wheel state it shares with the edge task.
//! - [`parts`]: the one `Board` both variants' `init` return, over their part types.
//! - [`priority`]: the interrupt priorities the firmware programs itself.
//!
//! Linking this crate also brings the panic handler (a defmt log line, then UDF) and the
//! image's own `memcpy` (module `mem`: a byte loop that replaces compiler-builtins' 1 KiB
//! word-wise one to keep the image inside its flash budget).
//!
//! Board variants (Cargo features, exactly one): `board` (default) builds the application
//! for the STM32F103C8 over [`board`]; `qemu` builds the same application for
//! `qemu-system-arm -M stm32vldiscovery` over [`qemu::board`], where the CAN port runs SLCAN
//! on USART1, the parameters stay in RAM, and a stimulus line on USART2 drives the simulated
//! inputs. Both layers always build; the application (`src/main.rs`) picks one, and binds
//! the QEMU layer's two USART interrupts to tasks of its own, which is the only other place
//! the feature is named.
#![no_std]
#![warn(missing_docs)]

pub mod board;
pub mod can;
pub mod edge;
pub mod events;
mod mem;
pub use handwheel_device::node_config;
#[cfg(feature = "stack-overflow-test")]
pub mod overflow;
mod panic;
pub mod parts;
pub mod priority;
pub mod qemu;
pub mod round_log;
pub mod storage;

/// The STM32F103's peripheral access crate, as stm32f1xx-hal re-exports it.
pub use stm32f1xx_hal::pac;
