//! The CAN port: the transmit queue, the statistics and the interrupt entry points, over a
//! [`CanLink`] that is the controller (bxCAN, `bxcan_port`).

use canopen_slave::RxFilter;
use handwheel_core::BitRate;
use handwheel_device::TransmitState;

use super::bus::{BusState, ErrorCounters};
use super::{CanStats, Frame, TxQueue, RX_QUEUE_LEN, TX_QUEUE_LEN};

/// The controller takes no frame now; its transmit interrupt resumes the queue.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Busy;

/// One step of draining the receive side.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Received {
    /// A frame that passed the acceptance filter.
    Frame(Frame),
    /// The controller lost frames (its FIFO overran); more may follow.
    Overrun,
}

/// What the port needs of the controller: bxcan's `Can` (`bxcan_port::Bxcan`) gets these
/// methods through this trait, a foreign type having no inherent methods of this crate.
pub trait CanLink {
    /// Offers `frame` for transmission. `Ok(None)`: taken; `Ok(Some(displaced))`: taken, and
    /// a less urgent pending frame came back out of the controller (it goes back to the head
    /// of the queue); `Err(Busy)`: nothing taken.
    fn transmit(&mut self, frame: &Frame) -> Result<Option<Frame>, Busy>;
    /// The next received frame that passes the acceptance filter, or `None` when the
    /// receive side is empty.
    fn receive(&mut self) -> Option<Received>;
    /// The transmit interrupt came: acknowledge it. Returns whether a frame that left a
    /// mailbox was acknowledged on the bus (not aborted).
    fn acknowledge_transmit(&mut self) -> bool;
    /// No frame waits in the controller.
    fn idle(&self) -> bool;
    /// Withdraws every frame the controller holds that is not on the bus yet.
    fn abort_pending(&mut self);
    /// The status-change interrupt came: acknowledge it.
    fn acknowledge_status(&mut self);
    /// The controller's error state and counters now.
    fn status(&self) -> (BusState, ErrorCounters);
    /// Passes exactly what `filter` accepts from now on.
    fn set_rx_filter(&mut self, filter: RxFilter);
    /// One step of a switch to `rate` (LSS activate bit timing): a few register accesses,
    /// never a wait for the bus. `true` once the controller is on the bus at `rate`.
    fn switch_bit_rate(&mut self, rate: BitRate) -> bool;
}

/// The controller and its transmit queue: the one RTIC resource around the controller.
pub struct CanPort<L> {
    link: L,
    queue: TxQueue<TX_QUEUE_LEN>,
    stats: CanStats,
    /// The path ran empty since the device last asked (`transmit_state`).
    ran_empty: bool,
    /// A frame of ours was acknowledged on the bus since start-up.
    acknowledged: bool,
}

impl<L: CanLink> CanPort<L> {
    /// Wraps a started controller.
    pub fn new(link: L) -> Self {
        Self {
            link,
            queue: TxQueue::new(),
            stats: CanStats::default(),
            ran_empty: false,
            acknowledged: false,
        }
    }

    /// Queues `frame` and hands the controller as many queued frames as it takes. Gives the
    /// frame back when the queue is full; nothing already queued is dropped.
    pub fn send(&mut self, frame: Frame) -> Result<(), Frame> {
        let result = self.queue.push(frame);
        if result.is_err() {
            self.stats.tx_refused += 1;
        }
        self.pump();
        result
    }

    /// The transmit interrupt: the controller has room again.
    pub fn on_transmit_room(&mut self) {
        if self.link.acknowledge_transmit() {
            self.acknowledged = true;
        }
        self.pump();
        self.note_if_empty();
    }

    /// Discards every frame not on the bus yet: the queue and what the controller holds (a
    /// reset of communication, or a transmit path blocked for too long).
    pub fn discard_pending(&mut self) {
        self.queue.clear();
        self.link.abort_pending();
        self.note_if_empty();
    }

    fn note_if_empty(&mut self) {
        if self.queue.is_empty() && self.link.idle() {
            self.ran_empty = true;
        }
    }

    /// Whether frames wait, and whether the path ran empty since the last call (for the
    /// device's stall watch).
    pub fn transmit_state(&mut self) -> TransmitState {
        TransmitState {
            waiting: !self.queue.is_empty() || !self.link.idle(),
            ran_empty: core::mem::take(&mut self.ran_empty),
        }
    }

    fn pump(&mut self) {
        while let Some(next) = self.queue.front() {
            match self.link.transmit(next) {
                Ok(displaced) => {
                    self.queue.pop_front();
                    if let Some(displaced) = displaced {
                        // The pop above made room, so this cannot fail.
                        let _ = self.queue.requeue(displaced);
                        self.stats.tx_displaced += 1;
                    }
                }
                Err(Busy) => break,
            }
        }
    }

    /// The receive interrupt: moves every received frame to `rx`, then hands the controller
    /// the queued frames it has room for. Returns `true` when frames were lost (the
    /// controller overran, or `rx` was full).
    pub fn on_receive(
        &mut self,
        rx: &mut heapless::spsc::Producer<'_, Frame, RX_QUEUE_LEN>,
    ) -> bool {
        let mut lost = false;
        while let Some(received) = self.link.receive() {
            let accepted = match received {
                Received::Frame(frame) => rx.enqueue(frame).is_ok(),
                Received::Overrun => false,
            };
            if accepted {
                self.stats.rx_frames += 1;
            } else {
                self.stats.rx_overruns += 1;
                lost = true;
            }
        }
        self.pump();
        lost
    }

    /// The status-change interrupt: the error state changed (the `canopen` task reads it).
    pub fn on_status_change(&mut self) {
        self.link.acknowledge_status();
    }

    /// The controller's error state and counters now.
    pub fn status(&self) -> (BusState, ErrorCounters) {
        self.link.status()
    }

    /// Re-programs the acceptance filter (the device's identifiers changed: 0x1005, or a new
    /// node-ID).
    pub fn set_rx_filter(&mut self, filter: RxFilter) {
        self.link.set_rx_filter(filter);
    }

    /// One step of the switch to `rate` (LSS activate bit timing, after its switch delay):
    /// `true` once the controller is on the bus at `rate`. Called once per round of the
    /// CAN-side task until then (`handwheel_device::RateSwitch` keeps the time).
    pub fn switch_bit_rate(&mut self, rate: BitRate) -> bool {
        self.link.switch_bit_rate(rate)
    }

    /// Whether a frame of ours was acknowledged on the bus since start-up: another node
    /// took it, so the node talks at the bus's bit rate (the trial boot's confirmation).
    pub fn frame_acknowledged(&self) -> bool {
        self.acknowledged
    }

    /// Counters since start-up.
    pub fn stats(&self) -> CanStats {
        self.stats
    }

    /// Frames waiting in the software queue.
    pub fn queued(&self) -> usize {
        self.queue.len()
    }

    /// Gives the controller back (tests).
    pub fn free(self) -> L {
        self.link
    }
}
