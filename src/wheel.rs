//! The shared [`Handwheel`] as seen from the CAN side.

use handwheel_core::{Handwheel, WheelAccess};

/// [`WheelAccess`] over an RTIC lock of the `wheel` resource.
///
/// Every `with_wheel` call is one lock: it raises the running priority to the EXTI task's
/// for the duration of the closure, so closures must stay short (one object access). The
/// CAN side never holds the wheel across a whole frame, and the EXTI task's latency stays
/// bounded by the longest single access.
pub struct SharedWheel<M>(pub M);

impl<M: rtic::Mutex<T = Handwheel>> WheelAccess for SharedWheel<M> {
    #[inline]
    fn with_wheel<R>(&mut self, f: impl FnOnce(&mut Handwheel) -> R) -> R {
        self.0.lock(f)
    }
}
