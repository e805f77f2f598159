//! PDO payloads: the 8-byte feed record and the paper's 1-byte unit-step format.
//!
//! # Feed record (TPDO1 default mapping, 8 bytes, little-endian)
//!
//! | byte | object | content |
//! |---|---|---|
//! | 0-3 | 0x6004 | position, I32: cumulative feed in multiplied units, wrapping |
//! | 4 | 0x2011 | bits 0-2 axis (0 none, 1..5 = X, Y, Z, W, V); bits 3-4 multiplier code (0 = x1, 1 = x10, 2 = x100); bits 5-7 selection epoch mod 8 |
//! | 5 | 0x2030 | bits 0-4 status flags, see [`FeedStatus`]; bits 5-7 session (0x2002) |
//! | 6-7 | 0x2031 | sequence, U16: +1 for every feed record sent or lost, wrapping |
//!
//! [`FeedRecord::FIELDS`] is that table as the device reads it: TPDO1's mapped objects are
//! slices of one encoded snapshot, so the layout is stated here only.
//!
//! The host takes deltas of the position (wrapping subtraction) and applies them to the axis
//! the newer record names, when the two records belong to the same session and epoch, or to
//! consecutive epochs with no record missing in between: the device sends every epoch's final
//! state before anything of the next epoch (the [`outbox`](crate::outbox)), so that delta is
//! exactly the newer epoch's motion. Within an epoch a lost frame costs nothing: the next one
//! carries the truth. The session tells records of different configurations (and so of
//! different power-ups) apart; the 16-bit sequence, whose pace the
//! [`outbox`](crate::outbox)'s budget bounds, tells a copy of an earlier record from a new one.
//!
//! # Unit-step byte (the paper's format, compatibility mode)
//!
//! | bits | content |
//! |---|---|
//! | 0-2 | axis: X = 0 .. V = 4 |
//! | 3 | direction: 1 = forward |
//! | 4-7 | counter: +1 per frame, runs on across direction changes |

use core::ops::Range;

use crate::feed::{FeedState, FeedStatus, UnitStep};
use crate::selector::{Axis, Multiplier};

/// The content of one feed record.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct FeedRecord {
    /// What the record says. Only the low three bits of the epoch and the session travel.
    pub state: FeedState,
    /// Record sequence number (object 0x2031).
    pub sequence: u16,
}

/// Why 8 bytes are not a feed record the device can send.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum FeedRecordError {
    /// Axis field not in 0..=5.
    Axis(u8),
    /// Multiplier code 3.
    Multiplier(u8),
    /// A combination of status flags the device never sends (enabled while the master is
    /// lost: a stop disables, and only enabling clears the loss).
    Status(u8),
}

/// One mapped object of the feed record: where its value lies in the 8 bytes.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub struct RecordField {
    /// Object index.
    pub index: u16,
    /// Sub-index.
    pub sub: u8,
    /// Its bytes in the record.
    pub bytes: Range<usize>,
}

impl FeedRecord {
    /// Length on the wire.
    pub const LEN: usize = 8;

    /// The objects TPDO1 maps by default, in order, and their bytes.
    pub const FIELDS: [RecordField; 4] = [
        RecordField {
            index: 0x6004,
            sub: 0,
            bytes: 0..4,
        },
        RecordField {
            index: 0x2011,
            sub: 0,
            bytes: 4..5,
        },
        RecordField {
            index: 0x2030,
            sub: 0,
            bytes: 5..6,
        },
        RecordField {
            index: 0x2031,
            sub: 0,
            bytes: 6..8,
        },
    ];

    /// The wire bytes.
    pub fn to_bytes(&self) -> [u8; 8] {
        let s = &self.state;
        let p = s.position.to_le_bytes();
        let q = self.sequence.to_le_bytes();
        [
            p[0],
            p[1],
            p[2],
            p[3],
            s.selection_byte(),
            s.status_byte(),
            q[0],
            q[1],
        ]
    }

    /// The bytes of object `index:sub` in this record, if the record carries it.
    pub fn field(&self, index: u16, sub: u8) -> Option<([u8; 8], Range<usize>)> {
        let f = Self::FIELDS
            .iter()
            .find(|f| (f.index, f.sub) == (index, sub))?;
        Some((self.to_bytes(), f.bytes.clone()))
    }

    /// Parses the wire bytes (what a host does). The epoch comes back as its low three bits.
    pub fn from_bytes(bytes: [u8; 8]) -> Result<Self, FeedRecordError> {
        let selection = bytes[4];
        let axis = match selection & 0b111 {
            0 => None,
            v => Some(Axis::from_object_value(v).ok_or(FeedRecordError::Axis(v))?),
        };
        let code = (selection >> 3) & 0b11;
        let multiplier = Multiplier::from_code(code).ok_or(FeedRecordError::Multiplier(code))?;
        let flags = bytes[5] & !(0b111 << FeedState::HIGH_SHIFT);
        let status = FeedStatus::from_bits(flags)
            .filter(|s| !s.contains(FeedStatus::ENABLED.union(FeedStatus::MASTER_LOST)))
            .ok_or(FeedRecordError::Status(bytes[5]))?;
        Ok(Self {
            state: FeedState {
                position: i32::from_le_bytes([bytes[0], bytes[1], bytes[2], bytes[3]]),
                axis,
                multiplier,
                status,
                epoch: selection >> FeedState::HIGH_SHIFT,
                session: bytes[5] >> FeedState::HIGH_SHIFT,
            },
            sequence: u16::from_le_bytes([bytes[6], bytes[7]]),
        })
    }
}

/// How far the unit-step counter moves per frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, Hash)]
pub enum CounterStride {
    /// Bits 4-7 step by one: the format the paper describes for real use.
    #[default]
    One,
    /// Only bits 6-7 move (steps of 4): what the paper's printed experiment shows.
    Four,
}

/// Encodes unit steps into the paper's 1-byte format, keeping the rolling counter.
#[derive(Clone, Copy, Debug, Default, Hash)]
pub struct UnitStepEncoder {
    counter: u8,
    stride: CounterStride,
}

impl UnitStepEncoder {
    /// Counter at 0.
    pub const fn new(stride: CounterStride) -> Self {
        Self { counter: 0, stride }
    }

    /// The byte for `step`; the counter advances for the next frame.
    #[must_use = "the counter advanced: the byte must be sent"]
    pub fn encode(&mut self, step: UnitStep) -> u8 {
        let byte = self.peek(step);
        self.advance();
        byte
    }

    /// The byte `step` would be sent as, without advancing the counter: for a frame that may
    /// still be withdrawn before it reaches the bus.
    pub const fn peek(&self, step: UnitStep) -> u8 {
        (self.counter << 4) | ((step.forward as u8) << 3) | step.axis.paper_index()
    }

    /// Advances the counter: one frame went out.
    pub fn advance(&mut self) {
        let stride = match self.stride {
            CounterStride::One => 1,
            CounterStride::Four => 4,
        };
        self.counter = (self.counter + stride) & 0x0F;
    }

    /// Decodes a unit-step byte into `(step, counter)`; `None` for axis fields 5..7.
    pub const fn decode(byte: u8) -> Option<(UnitStep, u8)> {
        let Some(axis) = Axis::from_object_value((byte & 0b111) + 1) else {
            return None;
        };
        Some((
            UnitStep {
                axis,
                forward: byte & 0b1000 != 0,
            },
            byte >> 4,
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn steps(encoder: &mut UnitStepEncoder, forward: bool, n: usize) -> [u8; 8] {
        let mut out = [0; 8];
        for b in out.iter_mut().take(n) {
            *b = encoder.encode(UnitStep {
                axis: Axis::X,
                forward,
            });
        }
        out
    }

    #[test]
    fn four_forward_then_four_reverse_on_x() {
        let mut enc = UnitStepEncoder::new(CounterStride::One);
        let fwd = steps(&mut enc, true, 4);
        let rev = steps(&mut enc, false, 4);
        assert_eq!(fwd[..4], [0x08, 0x18, 0x28, 0x38]);
        assert_eq!(rev[..4], [0x40, 0x50, 0x60, 0x70]);
    }

    #[test]
    fn papers_printed_experiment_with_counter_stepping_by_four() {
        let mut enc = UnitStepEncoder::new(CounterStride::Four);
        assert_eq!(
            steps(&mut enc, true, 5)[..5],
            [0x08, 0x48, 0x88, 0xC8, 0x08]
        );
        assert_eq!(steps(&mut enc, false, 4)[..4], [0x40, 0x80, 0xC0, 0x00]);
    }

    #[test]
    fn counter_wraps_after_sixteen_frames() {
        let mut enc = UnitStepEncoder::new(CounterStride::One);
        let mut counters = [0u8; 17];
        for c in &mut counters {
            let byte = enc.encode(UnitStep {
                axis: Axis::V,
                forward: false,
            });
            assert_eq!(byte & 0x0F, 4, "V reverse");
            *c = byte >> 4;
        }
        assert_eq!(counters[15], 15);
        assert_eq!(counters[16], 0);
    }

    #[test]
    fn peek_does_not_advance() {
        let mut enc = UnitStepEncoder::new(CounterStride::One);
        let step = UnitStep {
            axis: Axis::Y,
            forward: true,
        };
        assert_eq!(enc.peek(step), 0x09);
        assert_eq!(enc.peek(step), 0x09);
        enc.advance();
        assert_eq!(enc.peek(step), 0x19);
    }

    #[test]
    fn axis_field_per_axis_and_decode_round_trip() {
        let mut enc = UnitStepEncoder::new(CounterStride::One);
        for (i, axis) in Axis::ALL.into_iter().enumerate() {
            let step = UnitStep {
                axis,
                forward: true,
            };
            let byte = enc.encode(step);
            assert_eq!(byte & 0b111, i as u8);
            assert_eq!(UnitStepEncoder::decode(byte), Some((step, i as u8)));
        }
        for field in 5..8u8 {
            assert_eq!(UnitStepEncoder::decode(field), None);
        }
    }

    #[test]
    fn feed_record_layout() {
        let rec = FeedRecord {
            state: FeedState {
                position: -2,
                axis: Some(Axis::Z),
                multiplier: Multiplier::X100,
                status: FeedStatus::ENABLED.union(FeedStatus::ENCODER_ERROR),
                epoch: 5,
                session: 6,
            },
            sequence: 0xA5C3,
        };
        assert_eq!(
            rec.to_bytes(),
            [
                0xFE,
                0xFF,
                0xFF,
                0xFF,
                (5 << 5) | (2 << 3) | 3, // epoch 5, x100, Z
                0b110_00011,
                0xC3,
                0xA5
            ]
        );
        assert_eq!(FeedRecord::from_bytes(rec.to_bytes()), Ok(rec));
    }

    #[test]
    fn fields_cover_the_record_once_and_slice_the_encoding() {
        let mut covered = [0u8; 8];
        for f in &FeedRecord::FIELDS {
            for i in f.bytes.clone() {
                covered[i] += 1;
            }
        }
        assert_eq!(covered, [1; 8]);
        let rec = FeedRecord {
            state: FeedState {
                position: 0x0403_0201,
                axis: Some(Axis::Y),
                multiplier: Multiplier::X10,
                status: FeedStatus::IGNORED_MOTION,
                epoch: 3,
                session: 1,
            },
            sequence: 0x0807,
        };
        let (bytes, range) = rec.field(0x2031, 0).expect("the sequence is a field");
        assert_eq!(&bytes[range], &[0x07, 0x08]);
        let (bytes, range) = rec.field(0x2011, 0).expect("the selection is a field");
        assert_eq!(&bytes[range], &[(3 << 5) | (1 << 3) | 2]);
        assert_eq!(rec.field(0x2010, 1), None, "the axis alone is no field");
    }

    #[test]
    fn only_the_low_three_epoch_bits_travel() {
        let mut rec = FeedRecord {
            state: FeedState {
                position: 7,
                axis: None,
                multiplier: Multiplier::X1,
                status: FeedStatus::IGNORED_MOTION,
                epoch: 0x0B,
                session: 0,
            },
            sequence: 1,
        };
        assert_eq!(rec.to_bytes()[4], 3 << 5);
        rec.state.epoch = 3;
        assert_eq!(FeedRecord::from_bytes(rec.to_bytes()), Ok(rec));
    }

    #[test]
    fn feed_record_rejects_what_the_device_never_sends() {
        let good = [1, 0, 0, 0, 7 << 5, 0, 0, 0];
        assert_eq!(
            FeedRecord::from_bytes(good).map(|r| (r.state.position, r.state.axis, r.state.epoch)),
            Ok((1, None, 7))
        );
        for axis in [6, 7] {
            let mut bad = good;
            bad[4] |= axis;
            assert_eq!(
                FeedRecord::from_bytes(bad),
                Err(FeedRecordError::Axis(axis))
            );
        }
        let mut bad = good;
        bad[4] |= 0b11 << 3;
        assert_eq!(
            FeedRecord::from_bytes(bad),
            Err(FeedRecordError::Multiplier(3))
        );
        let mut bad = good;
        bad[5] = 0x29; // session 1, enabled and master lost
        assert_eq!(
            FeedRecord::from_bytes(bad),
            Err(FeedRecordError::Status(0x29))
        );
    }
}
