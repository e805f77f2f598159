//! The CAN side's way to the wheel state it shares with the edge task.
//!
//! The edge task (`wheel_edge` in `src/main.rs`, bound to EXTI9_5) and the CAN-side task
//! share `handwheel_core::EdgeState` as an RTIC `#[shared]` resource. The CAN side reaches
//! it through [`SharedEdge`], which makes the RTIC lock `handwheel_core`'s
//! [`EdgeAccess`]: the resource's ceiling is the edge's priority, the highest there is, so the
//! lock is the critical section (PRIMASK) for the few instructions of a snapshot or a
//! command, and RTIC guarantees that the two never touch the state at the same time.

use handwheel_core::{EdgeAccess, EdgeState};

use crate::pac::Interrupt;

/// The interrupt whose task wakes the CAN side for a feed frame (`feed_due`): the edge pends
/// it after a detent, one store to the NVIC instead of a wake-up.
pub const FEED_DUE: Interrupt = Interrupt::TIM2;

/// The RTIC resource proxy of the shared edge state, as an [`EdgeAccess`].
pub struct SharedEdge<M>(pub M);

impl<M: rtic::Mutex<T = EdgeState>> EdgeAccess for SharedEdge<M> {
    #[inline]
    fn lock<R>(&mut self, f: impl FnOnce(&mut EdgeState) -> R) -> R {
        self.0.lock(f)
    }
}
