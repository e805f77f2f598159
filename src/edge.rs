//! The wheel state the edge task shares with the CAN side.
//!
//! The edge task (`wheel_edge` in `src/main.rs`, bound to EXTI9_5) and the CAN-side task
//! share `handwheel_core::EdgeState` as an RTIC `#[shared]` resource. The CAN side's
//! `handwheel_core::LinkedWheel` holds RTIC's proxy of it, an RTIC `Mutex`: the resource's
//! ceiling is the edge's priority, the highest there is, so the lock is the critical section
//! (PRIMASK) for the few instructions of a snapshot or a command, and RTIC guarantees that
//! the two never touch the state at the same time.

use crate::pac::Interrupt;

/// The interrupt whose task wakes the CAN side for a feed frame (`feed_due`): the edge pends
/// it after a detent, one store to the NVIC instead of a wake-up.
pub const FEED_DUE: Interrupt = Interrupt::TIM2;
