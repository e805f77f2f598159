//! The wheel's edge interrupt (EXTI9_5), bound here rather than as an RTIC task, and the CAN
//! side's link to it.
//!
//! RTIC wraps every hardware task above priority 1 in a BASEPRI save and restore, and a
//! resource shared with the CAN side in a lock; the edge needs neither. Its state (the pins
//! and the decoder) is its own, installed by [`start`] before its interrupt is unmasked, and
//! everything it tells or is told crosses `handwheel_core::EdgeChannel` as atomics. So the
//! handler is the acknowledge, the port read, the decode and at most one NVIC pend.
//!
//! What the CAN side asks of the decoder (settings, a settle at standstill) is applied by a
//! second handler, on [`KICK`]'s vector, which the CAN side pends after posting: at the same
//! priority as the edge, so the two never preempt each other and the decoder has one user
//! at a time, and the edge's own path never looks at commands.

use core::cell::UnsafeCell;
use core::mem::MaybeUninit;
use core::sync::atomic::{AtomicBool, Ordering};

use cortex_m::peripheral::NVIC;
use handwheel_core::{DecoderConfig, EdgeChannel, EdgeDecoder, EdgeLink};

use crate::board::WheelInputs;
use crate::pac::{interrupt, Interrupt};
use crate::priority;

/// The interrupt that wakes the CAN side for a feed frame (the `feed_due` task).
pub const FEED_DUE: Interrupt = Interrupt::TIM2;
/// The vector the CAN side pends to have its commands applied (the timer itself is unused).
pub const KICK: Interrupt = Interrupt::TIM4;

/// What the edge interrupt owns.
struct EdgeTask {
    inputs: WheelInputs,
    decoder: EdgeDecoder,
}

/// The channel, and the edge task's state, written once by [`start`] and then only touched
/// by the two handlers. One static, so that the handlers reach both from one base address.
struct Edge {
    channel: EdgeChannel,
    task: UnsafeCell<MaybeUninit<EdgeTask>>,
}

// SAFETY: the channel is atomics. `start` writes the task once, guarded by `STARTED`, before
// it unmasks EXTI9_5 and the kick; from then on only those two handlers reach it, both at
// `priority::WHEEL`, and an exception never preempts one of its own priority, so there is
// never more than one reference to the task.
unsafe impl Sync for Edge {}

static EDGE: Edge = Edge {
    channel: EdgeChannel::new(),
    task: UnsafeCell::new(MaybeUninit::uninit()),
};
static STARTED: AtomicBool = AtomicBool::new(false);

/// Hands the wheel's inputs to the edge interrupt, with a decoder at rest on the levels read
/// now, and unmasks it and the kick at [`priority::WHEEL`]. Returns the CAN side's link to
/// it. Call once, from `init` (a second call returns `None` and changes nothing).
pub fn start(inputs: WheelInputs, config: DecoderConfig, nvic: &mut NVIC) -> Option<PendedEdge> {
    if STARTED.swap(true, Ordering::Relaxed) {
        return None;
    }
    let decoder = EdgeDecoder::new(config, inputs.levels(), &EDGE.channel);
    // SAFETY: the first and only write (guarded by `STARTED`), before EXTI9_5 is unmasked
    // below, so the handler cannot be looking at the slot.
    unsafe { (*EDGE.task.get()).write(EdgeTask { inputs, decoder }) };
    for interrupt in [Interrupt::EXTI9_5, KICK] {
        // SAFETY: neither is an RTIC task, so no RTIC lock depends on their priority; the
        // handlers' state is in place. (A pend before this point, by the QEMU stimulus, runs
        // now.)
        unsafe {
            nvic.set_priority(interrupt, priority::hardware(priority::WHEEL));
            NVIC::unmask(interrupt);
        }
    }
    Some(PendedEdge { _private: () })
}

/// One wheel edge: acknowledge, read A and B in one port read, decode, publish; pend
/// `feed_due` after a detent.
#[interrupt]
fn EXTI9_5() {
    // SAFETY: the handler runs only once `start` has filled the slot and unmasked it, and
    // nothing else uses the slot while it runs (see `Edge`).
    let task = unsafe { (*EDGE.task.get()).assume_init_mut() };
    let levels = task.inputs.acknowledge_edge();
    if task.decoder.on_edge(levels, &EDGE.channel) {
        NVIC::pend(FEED_DUE);
    }
}

/// The CAN side posted commands for the decoder: apply them.
#[interrupt]
fn TIM4() {
    // SAFETY: as for `EXTI9_5`, at the same priority.
    let task = unsafe { (*EDGE.task.get()).assume_init_mut() };
    task.decoder.on_kick(&EDGE.channel);
}

/// The CAN side's [`EdgeLink`]: the static channel, and a kick that pends [`KICK`], which
/// preempts the caller at once.
pub struct PendedEdge {
    _private: (),
}

impl EdgeLink for PendedEdge {
    fn channel(&self) -> &EdgeChannel {
        &EDGE.channel
    }

    fn kick(&mut self) {
        NVIC::pend(KICK);
    }
}
