//! The byte-level logic of the QEMU board variant's two serial transports, so that the
//! firmware only moves bytes between a USART and these types.
//!
//! - [`slcan`]: CAN over a serial line in the Lawicel ASCII protocol, as python-can's `slcan`
//!   interface speaks it (USART1). Frames received from the host go to the same CAN-RX path
//!   as frames from the bxCAN on the board; frames the device sends are rendered as
//!   `tIIILDD..\r`.
//! - [`stimulus`]: newline-terminated test commands (USART2) that move the simulated wheel
//!   and selector lines: `turn <n>`, `ab <0..3>`, `axis <off|x|y|z|w|v>`, `mult <1|10|100>`,
//!   each answered with `ok` or `err <reason>`.
//!
//! Both share the bounded [`line::LineAssembler`]: input is taken one byte at a time (as a
//! USART RX interrupt delivers it), a line longer than the buffer is discarded whole and
//! reported, and nothing here allocates, formats or panics on any input.
#![no_std]

pub mod line;
pub mod slcan;
pub mod stimulus;

pub use line::{Line, LineAssembler};
