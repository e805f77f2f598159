//! The CANopen engine's frames on the board's bxCAN, for both images: conversions between
//! `canopen_slave::Frame` and bxcan's, and 11-bit identifiers for the acceptance filters.
//! Engine frames are always 11-bit data frames; nothing else is taken in.

use bxcan::{Id, StandardId};
use canopen_slave::Frame;

/// The 11-bit identifier of the low 11 bits of `id` (a COB-ID's).
pub fn standard_id(id: u16) -> StandardId {
    StandardId::new(id & 0x7FF).unwrap_or(StandardId::ZERO)
}

/// The bxcan frame for `frame`.
pub fn to_bxcan(frame: &Frame) -> bxcan::Frame {
    let data = bxcan::Data::new(frame.data()).unwrap_or_else(bxcan::Data::empty);
    bxcan::Frame::new_data(standard_id(frame.id()), data)
}

/// The engine frame for a received bxcan frame; `None` for 29-bit identifiers and remote
/// frames, which no CANopen service of either image uses (the filters keep them out anyway).
pub fn from_bxcan(frame: &bxcan::Frame) -> Option<Frame> {
    let Id::Standard(id) = frame.id() else {
        return None;
    };
    Frame::new(id.as_raw(), frame.data()?).ok()
}

#[cfg(test)]
mod tests {
    use super::*;
    use bxcan::ExtendedId;

    #[test]
    fn a_frame_goes_over_and_comes_back_as_it_was() {
        for (id, data) in [
            (0x000, &[1, 0][..]),
            (0x590, &[0x43, 0, 0x10, 0, 1, 2, 3, 4]),
            (0x7FF, &[]),
        ] {
            let frame = Frame::new(id, data).unwrap();
            let out = to_bxcan(&frame);
            assert_eq!(out.id(), Id::Standard(StandardId::new(id).unwrap()));
            assert_eq!(out.data().map(|d| &d[..]), Some(data));
            assert_eq!(from_bxcan(&out), Some(frame));
        }
    }

    #[test]
    fn extended_and_remote_frames_are_not_taken_in() {
        let extended = bxcan::Frame::new_data(ExtendedId::new(0x590).unwrap(), [1, 2]);
        assert_eq!(from_bxcan(&extended), None);
        let remote = bxcan::Frame::new_remote(StandardId::new(0x710).unwrap(), 1);
        assert_eq!(from_bxcan(&remote), None);
    }

    #[test]
    fn an_identifier_keeps_its_low_11_bits() {
        assert_eq!(standard_id(0x0590), StandardId::new(0x590).unwrap());
        assert_eq!(standard_id(0x8590), StandardId::new(0x590).unwrap());
    }
}
