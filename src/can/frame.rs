//! Conversions between the CANopen engine's frame and bxcan's (the board's port only).

use bxcan::{Id, StandardId};
pub use canopen_slave::Frame;

/// The bxcan frame for `frame` (engine frames are always 11-bit data frames).
pub fn to_bxcan(frame: &Frame) -> bxcan::Frame {
    let id = StandardId::new(frame.id()).unwrap_or(StandardId::MAX);
    let data = bxcan::Data::new(frame.data()).unwrap_or_else(bxcan::Data::empty);
    bxcan::Frame::new_data(id, data)
}

/// The engine frame for a received bxcan frame; `None` for 29-bit ids and remote frames,
/// which no CANopen service of this device uses (the filters keep them out anyway).
pub fn from_bxcan(frame: &bxcan::Frame) -> Option<Frame> {
    let Id::Standard(id) = frame.id() else {
        return None;
    };
    Frame::new(id.as_raw(), frame.data()?).ok()
}
