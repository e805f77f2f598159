//! The QEMU board's CAN port: CAN over SLCAN (Lawicel ASCII) on USART1, for python-can's
//! `slcan` interface on the host end of QEMU's TCP bridge.
//!
//! [`CanPort`] has the methods the CAN tasks call on the board's bxCAN port, so `can_rx0`,
//! `can_tx`, `can_sce` and the `canopen` task's [`TxSink`](crate::can::TxSink) are the same
//! code. The controller's parts are played by:
//!
//! - the receive FIFO and its interrupt: the USART1 interrupt handler below (board layer,
//!   priority 3, outside the RTIC app) moves received bytes into a byte queue and, at the end
//!   of each SLCAN line (`\r`) or when the queue is full, pends USB_LP_CAN_RX0, as bxCAN
//!   pends it for a frame in FIFO 0. No byte is lost on the way: a full queue leaves the
//!   byte in the USART, and QEMU holds the next ones back in the socket until it is read;
//! - receive draining: `can_rx0` calls [`CanPort::drain_fifo0`], which runs the queued bytes
//!   through `sim_io::slcan`, answers each command on USART1, and puts the host's data frames
//!   into the receive queue for `canopen`, after the same acceptance filter as the board's
//!   bxCAN (NMT, SYNC, this node's SDO requests, heartbeats);
//! - the transmit mailboxes: USART1 itself. Frames wait in the same FIFO transmit queue and
//!   are written out (encoded by `sim_io::slcan`) while the SLCAN channel is open. It powers
//!   up open, because QEMU drops the host's opening `O` when it arrives before `init` has
//!   enabled USART1: the boot-up frame goes out at boot (after
//!   [`BOOT_UP_DELAY_MS`](super::board::BOOT_UP_DELAY_MS)), and the master reads it from the
//!   socket when it listens. After the host's `C` frames stay queued until `O`, as a CAN
//!   controller keeps retrying a frame that nobody acknowledges;
//! - the error state: a serial link has no error counters: always error-active, and the SCE
//!   interrupt never comes.

use core::cell::RefCell;

use crate::pac::{self, interrupt, Interrupt};
use canopen_slave::RxFilter;
use cortex_m::interrupt::Mutex;
use handwheel_core::BitRate;
use sim_io::slcan::{CanFrame, SlcanPort};

use super::usart::{UsartRx, UsartTx};
use crate::can::{CanStats, Frame, Mode, TxQueue, RX_QUEUE_LEN, TX_QUEUE_LEN};

/// Bytes the queue from the USART1 interrupt to `can_rx0` holds, plus one. A few SLCAN
/// lines (a frame line is at most 22 bytes); `can_rx0` empties it after every line, and a
/// full queue only makes the host wait.
pub const RX_BYTES_LEN: usize = 128;
/// The byte queue between the USART1 interrupt and `can_rx0`.
pub type RxBytes = heapless::spsc::Queue<u8, RX_BYTES_LEN>;
type RxBytesProducer = heapless::spsc::Producer<'static, u8, RX_BYTES_LEN>;
type RxBytesConsumer = heapless::spsc::Consumer<'static, u8, RX_BYTES_LEN>;

/// What the USART1 interrupt owns: the receiving half of USART1 and the byte queue's
/// producer.
type RxState = (UsartRx<pac::USART1>, RxBytesProducer);

/// The USART1 interrupt's state, handed over once by `board::init`.
static RX_HANDOFF: Mutex<RefCell<Option<RxState>>> = Mutex::new(RefCell::new(None));

/// USART1 as the board hands it over: its transmitting half and the received bytes.
pub struct SlcanLink {
    tx: UsartTx<pac::USART1>,
    rx: RxBytesConsumer,
}

impl SlcanLink {
    /// Hands the receiving half and the queue's producer to the USART1 interrupt (enable the
    /// interrupt only after this), and keeps the rest for the CAN port.
    pub fn new(
        rx: UsartRx<pac::USART1>,
        tx: UsartTx<pac::USART1>,
        bytes: &'static mut RxBytes,
    ) -> Self {
        let (producer, consumer) = bytes.split();
        cortex_m::interrupt::free(|cs| {
            RX_HANDOFF.borrow(cs).replace(Some((rx, producer)));
        });
        Self { tx, rx: consumer }
    }
}

/// USART1 received a byte: queue it; at the end of a line or with the queue full, pend the
/// CAN RX0 interrupt (`can_rx0`).
///
/// Scheduling: this handler and `can_rx0` have the same priority, so neither preempts the
/// other, and both wait while a task holds the `can` lock. With the queue full the byte stays
/// in the USART: RXNE keeps this interrupt pending, but at equal priority the NVIC takes the
/// lower exception number first, `can_rx0` (USB_LP_CAN_RX0, 20) before USART1 (37), so the
/// queue is drained before this handler runs again. Meanwhile QEMU, which delivers a byte
/// only while RXNE is clear, leaves the rest in the socket.
#[interrupt]
fn USART1() {
    static mut STATE: Option<RxState> = None;
    if STATE.is_none() {
        *STATE = cortex_m::interrupt::free(|cs| RX_HANDOFF.borrow(cs).take());
    }
    let Some((usart, bytes)) = STATE.as_mut() else {
        // Unreachable: the interrupt is enabled after the handoff.
        return;
    };
    let mut line_end = false;
    while bytes.ready() {
        let Some(byte) = usart.read() else {
            break;
        };
        // `ready` said there is room.
        let _ = bytes.enqueue(byte);
        line_end |= byte == b'\r';
    }
    if line_end || !bytes.ready() {
        rtic::pend(Interrupt::USB_LP_CAN_RX0);
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

/// The SLCAN link and its transmit queue.
pub struct CanPort {
    controller: Controller,
    queue: TxQueue<TX_QUEUE_LEN>,
    stats: CanStats,
}

impl CanPort {
    /// Wraps the started link.
    pub fn new(controller: Controller) -> Self {
        Self {
            controller,
            queue: TxQueue::new(),
            stats: CanStats::default(),
        }
    }

    /// Queues `frame` and writes out what the open channel takes. Gives the frame back when
    /// the queue is full; nothing already queued is dropped.
    pub fn send(&mut self, frame: Frame) -> Result<(), Frame> {
        let result = self.queue.push(frame);
        if result.is_err() {
            self.stats.tx_refused += 1;
        }
        self.pump();
        result
    }

    /// The board's TX interrupt (never pended here: the serial link has no mailboxes to
    /// wait for, the queue is written out whenever the channel is open).
    pub fn on_mailbox_empty(&mut self) {
        self.pump();
    }

    fn pump(&mut self) {
        let c = &mut self.controller;
        while let Some(next) = self.queue.front() {
            // Engine frames are always valid 11-bit frames, so this always succeeds.
            if let Some(frame) = CanFrame::new(next.id(), next.data()) {
                // `None` while the host has closed the channel (`C`): keep the frame queued.
                let Some(line) = c.slcan.encode(&frame, now_ms()) else {
                    break;
                };
                c.link.tx.write_all(line.as_bytes());
            }
            self.queue.pop_front();
        }
    }

    /// The RX0 interrupt: runs the bytes the host sent through the SLCAN protocol, answers
    /// each command, moves the host's frames for this node to `rx`, and writes out the
    /// transmit queue if the channel is open. Returns `true` when frames were lost (`rx` full,
    /// as on the board when `canopen` falls behind).
    pub fn drain_fifo0(
        &mut self,
        rx: &mut heapless::spsc::Producer<'_, Frame, RX_QUEUE_LEN>,
    ) -> bool {
        let mut lost = false;
        let c = &mut self.controller;
        while let Some(byte) = c.link.rx.dequeue() {
            let Some(outcome) = c.slcan.push(byte) else {
                continue;
            };
            c.link.tx.write_all(outcome.reply);
            let frame = outcome
                .frame
                // What the board's bxCAN filter banks pass (`can::set_filters`).
                .filter(|f| c.filter.accepts(f.id))
                .and_then(|f| Frame::new(f.id, f.payload()).ok());
            if let Some(frame) = frame {
                if rx.enqueue(frame).is_ok() {
                    self.stats.rx_frames += 1;
                } else {
                    self.stats.rx_overruns += 1;
                    lost = true;
                }
            }
        }
        // The host may just have opened the channel: send what waited for it.
        self.pump();
        lost
    }

    /// Replaces the acceptance filter (the device's identifiers changed: 0x1005, or a new
    /// node-ID).
    pub fn set_rx_filter(&mut self, filter: RxFilter) {
        self.controller.filter = filter;
    }

    /// LSS activate bit timing: a serial line has no bit rate, so nothing changes.
    pub fn set_bit_rate(&mut self, _rate: BitRate) {}

    /// The SCE interrupt: never raised on the serial link.
    pub fn on_status_change(&mut self) {}

    /// Counters since start-up.
    pub fn stats(&self) -> CanStats {
        self.stats
    }

    /// Frames waiting in the software queue.
    pub fn queued(&self) -> usize {
        self.queue.len()
    }
}
