//! The board's CAN port: bxCAN bit timing, acceptance filters, the three transmit
//! mailboxes and receive FIFO 0.

use bxcan::filter::{ListEntry16, Mask16};
use bxcan::{Fifo, Interrupts, StandardId};
use canopen_slave::RxFilter;
use handwheel_core::{BitRate, BitTiming};

use super::{bus, frame, CanStats, Frame, Mode, TxQueue, RX_QUEUE_LEN, TX_QUEUE_LEN};
use crate::board::{CanInstance, APB1_HZ};

/// The configured controller.
pub type Bxcan = bxcan::Can<CanInstance>;

/// `CAN_BTR` timing bits for every rate of [`BitRate::ALL`] (by code) at the 36 MHz APB1
/// clock, from `handwheel-core`'s search, evaluated at compile time: the build fails if a
/// table rate has no exact timing, and the image carries no 64-bit division.
pub const BTR_TABLE: [u32; 8] = {
    let mut table = [0; 8];
    let mut code = 0;
    while code < 8 {
        let rate = BitRate::ALL[code];
        table[code] = match BitTiming::for_bitrate(APB1_HZ, rate.bits_per_second()) {
            Ok(timing) => timing.btr(),
            Err(_) => panic!("a table bit rate has no exact bxCAN timing at 36 MHz"),
        };
        code += 1;
    }
    table
};

/// The `CAN_BTR` timing bits for `rate`.
pub const fn btr(rate: BitRate) -> u32 {
    BTR_TABLE[rate.code() as usize]
}

/// Configures bit timing, the acceptance filters for `filter` and interrupts, and starts the
/// controller.
///
/// Returns once the controller is in normal mode, which needs 11 recessive bits on RX: on
/// a silent bus that is immediate, on a busy one at most a frame's time.
pub fn start(instance: CanInstance, bit_rate: BitRate, filter: RxFilter, mode: Mode) -> Bxcan {
    let loopback = mode == Mode::SilentLoopback;
    let mut can = bxcan::Can::builder(instance)
        .set_bit_timing(btr(bit_rate))
        .set_loopback(loopback)
        .set_silent(loopback)
        .leave_disabled();
    set_filters(&mut can, filter);
    // FIFO 0 pending covers "full" too; the overrun interrupt makes a lost frame visible
    // even if the FIFO had been drained in between.
    can.enable_interrupts(
        Interrupts::TRANSMIT_MAILBOX_EMPTY
            | Interrupts::FIFO0_MESSAGE_PENDING
            | Interrupts::FIFO0_OVERRUN,
    );
    bus::enable_status_interrupts();
    // Also sets ABOM: after bus-off the controller rejoins on its own once it has seen
    // 128 x 11 recessive bits.
    nb::block!(can.enable_non_blocking()).unwrap_or_else(|never| match never {});
    can
}

/// Programs the acceptance filters to pass exactly what `filter` accepts; everything else
/// is dropped in hardware.
///
/// Bank 0 lists NMT, SYNC (wherever 0x1005 put it), our SDO request and LSS (0x7E5); an
/// unconfigured node's filter repeats NMT and LSS in the SYNC and SDO entries. Bank 1 passes every
/// heartbeat (0x700..0x77F) for the heartbeat consumer, which picks its producers itself.
/// Data frames only: RTR is not served. Reprogramming while running (RM0008 24.7.4: the
/// banks are deactivated in filter init mode) can miss a frame that arrives in those few
/// register writes; only a master's reconfiguration triggers it.
pub fn set_filters(can: &mut Bxcan, filter: RxFilter) {
    let data = |id: u16| ListEntry16::data_frames_with_id(standard_id(id));
    let (base, mask) = filter.heartbeats();
    let mut heartbeats = Mask16::frames_with_std_id(standard_id(base), standard_id(mask));
    heartbeats.data_frames_only();
    let mut filters = can.modify_filters();
    filters.clear();
    filters.enable_bank(
        0,
        Fifo::Fifo0,
        [
            data(filter.nmt()),
            data(filter.sync()),
            data(filter.sdo_request()),
            // LSS requests (CiA 305), for node-ID and bit-rate configuration.
            data(filter.lss()),
        ],
    );
    filters.enable_bank(1, Fifo::Fifo0, [heartbeats, heartbeats]);
}

fn standard_id(id: u16) -> StandardId {
    StandardId::new(id & 0x7FF).unwrap_or(StandardId::ZERO)
}

/// The controller and its transmit queue.
pub struct CanPort {
    can: Bxcan,
    queue: TxQueue<TX_QUEUE_LEN>,
    stats: CanStats,
}

impl CanPort {
    /// Wraps a started controller.
    pub fn new(can: Bxcan) -> Self {
        Self {
            can,
            queue: TxQueue::new(),
            stats: CanStats::default(),
        }
    }

    /// Queues `frame` and hands as many queued frames to the mailboxes as they take.
    /// Gives the frame back when the queue is full; nothing already queued is dropped.
    pub fn send(&mut self, frame: Frame) -> Result<(), Frame> {
        let result = self.queue.push(frame);
        if result.is_err() {
            self.stats.tx_refused += 1;
        }
        self.pump();
        result
    }

    /// The TX interrupt: a mailbox became free.
    pub fn on_mailbox_empty(&mut self) {
        self.can.clear_tx_interrupt();
        self.pump();
    }

    fn pump(&mut self) {
        while let Some(next) = self.queue.front() {
            match self.can.transmit(&frame::to_bxcan(next)) {
                Ok(status) => {
                    self.queue.pop_front();
                    if let Some(displaced) = status.dequeued_frame().and_then(frame::from_bxcan) {
                        // The pop above made room, so this cannot fail.
                        let _ = self.queue.requeue(displaced);
                        self.stats.tx_displaced += 1;
                    }
                }
                // Every pending mailbox outranks the next frame: the TX interrupt resumes.
                Err(nb::Error::WouldBlock) => break,
                Err(nb::Error::Other(never)) => match never {},
            }
        }
    }

    /// The RX0 interrupt: moves every frame from the hardware FIFO to `rx`. Returns `true`
    /// when frames were lost (FIFO overrun or `rx` full).
    pub fn drain_fifo0(
        &mut self,
        rx: &mut heapless::spsc::Producer<'_, Frame, RX_QUEUE_LEN>,
    ) -> bool {
        let mut lost = false;
        loop {
            match self.can.receive() {
                Ok(frame) => {
                    let Some(frame) = frame::from_bxcan(&frame) else {
                        continue;
                    };
                    if rx.enqueue(frame).is_ok() {
                        self.stats.rx_frames += 1;
                    } else {
                        self.stats.rx_overruns += 1;
                        lost = true;
                    }
                }
                Err(nb::Error::WouldBlock) => break,
                // bxcan reports the overrun once and clears the flag; the frames still in
                // the FIFO come on the next rounds of this loop.
                Err(nb::Error::Other(_overrun)) => {
                    self.stats.rx_overruns += 1;
                    lost = true;
                }
            }
        }
        lost
    }

    /// The SCE interrupt: acknowledges an error-state change.
    pub fn on_status_change(&mut self) {
        bus::acknowledge_status_change();
    }

    /// Re-programs the acceptance filters (the device's identifiers changed: 0x1005, or a
    /// new node-ID).
    pub fn set_rx_filter(&mut self, filter: RxFilter) {
        set_filters(&mut self.can, filter);
    }

    /// Switches to `rate` (LSS activate bit timing, after its switch delay): the controller
    /// goes through initialisation mode, keeping filters and interrupts, and rejoins after
    /// 11 recessive bits at the new rate.
    pub fn set_bit_rate(&mut self, rate: BitRate) {
        self.can.modify_config().set_bit_timing(btr(rate)).enable();
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
    pub fn free(self) -> Bxcan {
        self.can
    }
}
