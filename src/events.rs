//! Wake-ups for the CAN-side task, raised from interrupts.
//!
//! Interrupt tasks never do CAN-side work themselves: they set a bit here and wake the one
//! task that owns the device. Bits raised while that task is busy are collected and handled
//! in its next round, so a burst of edges costs one wake-up, not one per edge.

use core::future::poll_fn;
use core::sync::atomic::{AtomicU8, Ordering};
use core::task::Poll;

use rtic_common::waker_registration::CriticalSectionWakerRegistration;

/// A set of pending event bits.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, defmt::Format)]
pub struct EventSet(u8);

impl EventSet {
    /// The wheel completed a detent or changed the feed status: a feed TPDO is due.
    pub const FEED_DUE: Self = Self(1 << 0);
    /// Frames are waiting in the receive queue.
    pub const FRAMES: Self = Self(1 << 1);
    /// Frames were lost on receive.
    pub const RX_OVERRUN: Self = Self(1 << 2);
    /// The controller's error state changed.
    pub const BUS_STATUS: Self = Self(1 << 3);

    /// No bit set.
    pub const fn empty() -> Self {
        Self(0)
    }

    /// Whether every bit of `other` is set.
    pub const fn contains(self, other: Self) -> bool {
        self.0 & other.0 == other.0
    }

    /// Whether no bit is set.
    pub const fn is_empty(self) -> bool {
        self.0 == 0
    }
}

/// Pending bits plus the waker of the task waiting for them.
pub struct Events {
    pending: AtomicU8,
    waker: CriticalSectionWakerRegistration,
}

impl Events {
    /// Nothing pending, nobody waiting.
    pub const fn new() -> Self {
        Self {
            pending: AtomicU8::new(0),
            waker: CriticalSectionWakerRegistration::new(),
        }
    }

    /// Sets `events` and wakes the waiting task. Callable from any priority; a few dozen
    /// cycles (an atomic OR and a short critical section).
    pub fn raise(&self, events: EventSet) {
        self.pending.fetch_or(events.0, Ordering::Release);
        self.waker.wake();
    }

    /// Takes whatever is pending without waiting.
    pub fn take(&self) -> EventSet {
        EventSet(self.pending.swap(0, Ordering::Acquire))
    }

    /// Waits until something is pending and takes it.
    pub async fn wait(&self) -> EventSet {
        poll_fn(|cx| {
            // Register before looking, so a raise between the two still wakes us.
            self.waker.register(cx.waker());
            match self.take() {
                set if set.is_empty() => Poll::Pending,
                set => Poll::Ready(set),
            }
        })
        .await
    }
}

impl core::ops::BitOr for EventSet {
    type Output = Self;

    fn bitor(self, other: Self) -> Self {
        Self(self.0 | other.0)
    }
}

impl Default for Events {
    fn default() -> Self {
        Self::new()
    }
}
