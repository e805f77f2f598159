//! The hardware-independent heart of the CANopen CNC handwheel.
//!
//! Everything here is `no_std`, allocation-free and tested on the host. The firmware only
//! moves pin levels and frames in and out of these types:
//!
//! - [`decoder`]: A/B quadrature to counts and detents, from the levels read in the EXTI ISR.
//! - [`edge`]: the wheel state the edge task and the CAN side share (the decoder and its
//!   totals), and how the CAN side reaches it.
//! - [`standstill`]: notices a wheel at rest, so that the decoder learns its rest levels.
//! - [`selector`]: debounced 5-position axis switch and 3-position multiplier switch.
//! - [`feed`]: the feed status bits and the unit step, shared by the two below.
//! - [`accumulator`]: detents to a cumulative feed position (and the paper's bounded
//!   unit-step backlog), gated by enable, axis and the master's presence.
//! - [`wheel`]: the CAN side's wheel: the shared decoder as last taken in, the settings
//!   asked of it, and the accumulator; reached as an RTIC `Mutex`, with the edge's motion
//!   taken in at named points of a round.
//! - [`outbox`]: holds each selection epoch's final state until the bus takes it, so that
//!   no epoch ends unseen while the bus is blocked.
//! - [`pdo`]: the 8-byte feed record and the paper's 1-byte unit-step format.
//! - [`bittiming`]: bxCAN `BTR` values for the CiA bit-rate table.
#![no_std]

pub mod accumulator;
pub mod bittiming;
pub mod decoder;
pub mod edge;
pub mod feed;
pub mod outbox;
pub mod pdo;
pub mod selector;
pub mod standstill;
pub mod wheel;

pub use accumulator::{
    FeedAccumulator, SessionRefusal, StopReason, DEFAULT_STEP_BACKLOG, PROBE_NONCE_MASK,
};
pub use bittiming::{btr_table, BitRate, BitTiming, BitTimingError};
pub use decoder::{
    AbLevels, CountsPerDetent, DecoderConfig, EdgeOutcome, QuadratureDecoder, Transition,
};
pub use edge::{EdgeSnapshot, EdgeState, Mutex};
pub use feed::{FeedState, FeedStatus, UnitStep};
pub use outbox::{FeedOutbox, SequencePace, HELD_EPOCHS, MAX_DROP_GAP, SEQUENCE_BURST};
pub use pdo::{CounterStride, FeedRecord, FeedRecordError, RecordField, UnitStepEncoder};
pub use selector::{
    Axis, Debouncer, Multiplier, Selection, Selector, SelectorInput, SelectorLines,
    DEFAULT_DEBOUNCE_SAMPLES,
};
pub use standstill::{Settle, Standstill, STANDSTILL_MS};
pub use wheel::{Handwheel, Intake, LinkedWheel, Wheel};
