//! The CANopen CNC handwheel as a device: the `canopen-slave` engine bound to
//! `handwheel-core`'s wheel through the handwheel's object dictionary.
//!
//! Host-tested and hardware-free; the firmware creates one [`Node`] around a
//! [`HandwheelDevice`] and calls its step function, [`Node::poll`], with the time, its CAN
//! port ([`CanIo`]), the switch lines and the CAN side's [`handwheel_core::LinkedWheel`] (the
//! edge task owns the decoder); it applies the [`Outputs`] (LEDs, acceptance filter, log
//! lines) and sleeps as long as they say.
//!
//! Safety behaviour lives here and in `handwheel-core`, not in the firmware:
//! - feed can only be enabled (0x2000 = 1) in Operational (abort 0x08000022 otherwise);
//! - leaving Operational, or losing the master's heartbeat (0x1016), stops the feed,
//!   discards pending unit steps and disables feed until the master enables it again;
//! - [`node`] is everything the firmware loop decides, one round per call: joining the bus at
//!   power-on, the switches, the bus state and lost frames (EMCYs), the transmit stall, LSS
//!   bit-rate switches, the acceptance filter, the LEDs and the sleep;
//! - [`duties`] decides the firmware loop's periodic work (switches, standstill, LEDs) and how
//!   long it may sleep;
//! - [`rate_switch`] times the CAN controller's bit-rate switch after LSS "activate bit
//!   timing", which never waits for the bus, and says when the node is off the bus;
//! - [`node_config`] and [`record`] decide the node-ID and bit rate at boot (DIP switch or
//!   stored) and the byte layout of the stored parameters, and [`page`] how they are written
//!   (nothing when unchanged, a log of records, a budget of erases per time), for any board's
//!   erase-and-program glue;
//! - 0x1010, 0x1011 and LSS store are refused (0x08000022) while the feed is enabled: writing
//!   flash stalls the CPU, and with it the wheel's edges;
//! - 0x1F51:1 = 0 (CiA 302-3 "stop": reset into the resident loader for a firmware update) is
//!   refused (0x08000022) unless Pre-operational with the feed disabled; once answered, the
//!   node's [`Outputs::enter_loader`] tells the firmware to reset;
//! - the paper's unit-step stream (0x2001 = 1) goes out on TPDO2, one frame per step, from a
//!   bounded backlog.
#![no_std]

mod app;
mod device;
pub mod duties;
#[cfg(feature = "mutants")]
#[doc(hidden)]
pub mod mutant;
pub mod node;
pub mod od;
pub mod rate_switch;

pub use app::WheelParameters;
pub use device::{DigitalOutputs, HandwheelDevice, TransmitState, EMCY_ENCODER, TRANSMIT_STALL_MS};
pub use duties::{Duties, Sample};
pub use node::{CanIo, LogEvents, Node, Outputs};
pub use rate_switch::RateSwitch;
