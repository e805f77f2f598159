//! The QEMU board's CAN port: CAN over SLCAN (Lawicel ASCII) on USART1, for python-can's
//! `slcan` interface on the host end of QEMU's TCP bridge.
//!
//! [`Controller`] is the QEMU board's [`CanLink`] under the shared
//! [`CanPort`](crate::can::CanPort), so `can_rx0`, `can_tx`, `can_sce` and the `canopen`
//! task's [`TxSink`](crate::can::TxSink) are the same code. The controller's parts are
//! played by:
//!
//! - the receive FIFO and its interrupt: the USART1 interrupt handler below (board layer,
//!   priority 3, outside the RTIC app) moves received bytes into a byte queue and, at the end
//!   of each SLCAN line (`\r`) or when the queue is full, pends USB_LP_CAN_RX0, as bxCAN
//!   pends it for a frame in FIFO 0. No byte is lost on the way: a full queue leaves the
//!   byte in the USART, and QEMU holds the next ones back in the socket until it is read;
//! - receive draining: `can_rx0` calls `CanPort::on_receive`, which takes frames from
//!   [`Controller`]'s `receive`: it runs the queued bytes through `sim_io::slcan`, answers
//!   each command on USART1, and hands over the host's data frames that pass the same
//!   acceptance filter as the board's bxCAN (NMT, SYNC, this node's SDO requests, LSS,
//!   heartbeats);
//! - the transmit mailboxes: USART1 itself. Frames wait in the same FIFO transmit queue and
//!   are written out (encoded by `sim_io::slcan`) while the SLCAN channel is open. It powers
//!   up open, because QEMU drops the host's opening `O` when it arrives before `init` has
//!   enabled USART1: the boot-up frame goes out at boot (after
//!   [`BOOT_UP_DELAY_MS`](super::board::BOOT_UP_DELAY_MS)), and the master reads it from the
//!   socket when it listens. After the host's `C` frames stay queued until `O`, as a CAN
//!   controller keeps retrying a frame that nobody acknowledges;
//! - the error state: a serial link has no error counters: always error-active, and the SCE
//!   interrupt never comes.

use crate::pac::{self, Interrupt};
use canopen_slave::RxFilter;
use handwheel_core::BitRate;
use sim_io::slcan::{CanFrame, SlcanPort};

use super::usart::{UsartRx, UsartTx};
use crate::can::bus::{BusState, ErrorCounters};
use crate::can::port::{Busy, CanLink, Received};
use crate::can::{Frame, Mode};

/// Bytes the queue from the USART1 interrupt to `can_rx0` holds, plus one. A few SLCAN
/// lines (a frame line is at most 22 bytes); `can_rx0` empties it after every line, and a
/// full queue only makes the host wait.
pub const RX_BYTES_LEN: usize = 128;
/// The byte queue between the USART1 interrupt and `can_rx0`.
pub type RxBytes = heapless::spsc::Queue<u8, RX_BYTES_LEN>;
type RxBytesProducer = heapless::spsc::Producer<'static, u8, RX_BYTES_LEN>;
type RxBytesConsumer = heapless::spsc::Consumer<'static, u8, RX_BYTES_LEN>;

/// USART1 as the board hands it over: its transmitting half and the received bytes.
pub struct SlcanLink {
    tx: UsartTx<pac::USART1>,
    rx: RxBytesConsumer,
}

/// The receiving half of USART1 and the byte queue's producer: the QEMU variant's USART1 task
/// owns it (`qemu_usart1` in `src/main.rs`).
pub struct SlcanReceiver {
    usart: UsartRx<pac::USART1>,
    bytes: RxBytesProducer,
}

impl SlcanLink {
    /// The link for the CAN port, and the receiver for the USART1 task.
    pub fn new(
        rx: UsartRx<pac::USART1>,
        tx: UsartTx<pac::USART1>,
        bytes: &'static mut RxBytes,
    ) -> (Self, SlcanReceiver) {
        let (producer, consumer) = bytes.split();
        let receiver = SlcanReceiver {
            usart: rx,
            bytes: producer,
        };
        (Self { tx, rx: consumer }, receiver)
    }
}

impl SlcanReceiver {
    /// USART1 received a byte: queue it; at the end of a line or with the queue full, pend
    /// the CAN RX0 interrupt (`can_rx0`).
    ///
    /// Scheduling: the USART1 task and `can_rx0` have the same priority, so neither preempts
    /// the other, and both wait while a task holds the `can` lock. With the queue full the
    /// byte stays in the USART: RXNE keeps this interrupt pending, but at equal priority the
    /// NVIC takes the lower exception number first, `can_rx0` (USB_LP_CAN_RX0, 20) before
    /// USART1 (37), so the queue is drained before this runs again. Meanwhile QEMU, which
    /// delivers a byte only while RXNE is clear, leaves the rest in the socket.
    pub fn on_interrupt(&mut self) {
        let mut line_end = false;
        while self.bytes.ready() {
            let Some(byte) = self.usart.read() else {
                break;
            };
            // `ready` said there is room.
            let _ = self.bytes.enqueue(byte);
            line_end |= byte == b'\r';
        }
        if line_end || !self.bytes.ready() {
            rtic::pend(Interrupt::USB_LP_CAN_RX0);
        }
    }
}

/// The started link: the USART, the SLCAN protocol state and the acceptance filter.
pub struct Controller {
    link: SlcanLink,
    slcan: SlcanPort,
    filter: RxFilter,
}

/// Starts the link with `filter` as its acceptance filter. The bit rate means nothing on a
/// serial line (SLCAN's `S` commands are accepted and ignored); only [`Mode::Normal`] exists
/// here (loopback is an on-target test mode of the board's bxCAN).
pub fn start(link: SlcanLink, _bit_rate: BitRate, filter: RxFilter, mode: Mode) -> Controller {
    defmt::debug_assert!(mode == Mode::Normal);
    Controller {
        link,
        slcan: SlcanPort::new_open(),
        filter,
    }
}

/// Milliseconds since boot, for SLCAN time stamps (`Z1`): the SysTick monotonic's count.
fn now_ms() -> u32 {
    use rtic_monotonics::TimerQueueBackend;
    rtic_monotonics::systick::SystickBackend::now()
}

impl CanLink for Controller {
    fn transmit(&mut self, frame: &Frame) -> Result<Option<Frame>, Busy> {
        // Engine frames are always valid 11-bit frames, so this always succeeds.
        if let Some(frame) = CanFrame::new(frame.id(), frame.data()) {
            // `None` while the host has closed the channel (`C`): keep the frame queued.
            let line = self.slcan.encode(&frame, now_ms()).ok_or(Busy)?;
            self.link.tx.write_all(line.as_bytes());
        }
        Ok(None)
    }

    /// Runs the bytes the host sent through the SLCAN protocol up to the next data frame
    /// for this node, answering each command on the way.
    fn receive(&mut self) -> Option<Received> {
        while let Some(byte) = self.link.rx.dequeue() {
            let Some(outcome) = self.slcan.push(byte) else {
                continue;
            };
            self.link.tx.write_all(outcome.reply);
            let frame = outcome
                .frame
                // What the board's bxCAN filter banks pass (`can::set_filters`).
                .filter(|f| self.filter.accepts(f.id))
                .and_then(|f| Frame::new(f.id, f.payload()).ok());
            if let Some(frame) = frame {
                return Some(Received::Frame(frame));
            }
        }
        None
    }

    /// Never pended: the serial link has no mailboxes to wait for, the queue is written out
    /// whenever the channel is open.
    fn acknowledge_transmit(&mut self) {}

    /// Nothing waits in a serial link: what it takes is written out.
    fn idle(&self) -> bool {
        true
    }

    fn abort_pending(&mut self) {}

    /// Never raised: a serial link has no error states.
    fn acknowledge_status(&mut self) {}

    /// A serial link has no error counters: always error-active.
    fn status(&self) -> (BusState, ErrorCounters) {
        (BusState::ErrorActive, ErrorCounters::default())
    }

    fn set_rx_filter(&mut self, filter: RxFilter) {
        self.filter = filter;
    }

    /// A serial line has no bit rate: nothing changes, the switch is done at once.
    fn switch_bit_rate(&mut self, _rate: BitRate) -> bool {
        true
    }
}
