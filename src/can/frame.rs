//! Conversions between the CANopen engine's frame and bxcan's: the board crate's, which the
//! resident loader uses too.

pub use canopen_slave::Frame;
pub use handwheel_board::frame::{from_bxcan, standard_id, to_bxcan};
