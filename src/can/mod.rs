//! CAN glue: the transmit queue, receive draining and the controller's error state, over
//! bxCAN.
//!
//! [`CanPort`] is the one RTIC resource around the controller. The RX0, TX and SCE interrupt
//! tasks and the CAN-side software task share it; each use is a few register accesses. It
//! is the queue and statistics ([`port::CanPort`]) over the controller's few operations
//! ([`port::CanLink`]): bxCAN (bit timing, acceptance filters, mailboxes, FIFO 0) in
//! `bxcan_port` ([`CanPort`]).

pub mod bus;
mod bxcan_port;
mod frame;
pub mod port;
mod tx_queue;

pub use bxcan_port::{btr, set_filters, start, Bxcan, BTR_TABLE};

/// The board's CAN port: the shared queue and statistics over bxCAN.
pub type CanPort = port::CanPort<Bxcan>;
use canopen_slave::{FrameSink, RxFilter, SinkFull};
pub use frame::Frame;
use handwheel_core::BitRate;
use handwheel_device::{CanIo, TransmitState};
use port::CanLink;
pub use tx_queue::TxQueue;

/// Frames the transmit queue holds. Each is 12 bytes. Sized for a burst of one of everything
/// the device sends (TPDOs, heartbeat, SDO response, EMCYs) while the bus is busy.
pub const TX_QUEUE_LEN: usize = 16;
/// Capacity of the receive queue between the RX0 interrupt and the CAN-side task, plus one
/// (heapless' SPSC queue keeps one slot free).
pub const RX_QUEUE_LEN: usize = 16;

/// The receive queue: filled by the RX0 interrupt, drained by the CAN-side task.
pub type RxQueue = heapless::spsc::Queue<Frame, RX_QUEUE_LEN>;
/// The RX0 interrupt's end of the receive queue.
pub type RxProducer = heapless::spsc::Producer<'static, Frame, RX_QUEUE_LEN>;
/// The CAN-side task's end of the receive queue.
pub type RxConsumer = heapless::spsc::Consumer<'static, Frame, RX_QUEUE_LEN>;

/// Operating mode of the controller.
#[derive(Clone, Copy, Debug, PartialEq, Eq, defmt::Format)]
pub enum Mode {
    /// On the bus.
    Normal,
    /// Transmitted frames are received back internally and nothing reaches the pins: the
    /// on-target test mode, which needs no transceiver or other node.
    SilentLoopback,
}

/// Counters the CAN-side task turns into log lines and EMCYs.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, defmt::Format)]
pub struct CanStats {
    /// Frames received into the software queue.
    pub rx_frames: u32,
    /// Frames lost on receive: hardware FIFO overruns plus a full software queue.
    pub rx_overruns: u32,
    /// Frames bxCAN pushed out of a mailbox for a more urgent one (re-queued, not lost).
    pub tx_displaced: u32,
    /// Frames refused because the transmit queue was full (the sender keeps them).
    pub tx_refused: u32,
}

/// The `canopen` task's CAN port, as the step function's [`CanIo`]: the receive queue's
/// consumer end and the shared [`CanPort`], one short lock per call.
///
/// The lock raises the running priority to the CAN interrupts' level for a queue insert, a
/// few mailbox writes or a register read, never for the device's own processing.
pub struct CanSide<'a, M, C> {
    rx: &'a mut RxConsumer,
    port: M,
    /// The millisecond tick (the monotonic's), which dates the transmit path's state.
    clock: C,
    /// The error counters as last read with the bus state, for the log.
    pub counters: bus::ErrorCounters,
}

impl<'a, M, C> CanSide<'a, M, C> {
    /// The task's end of the receive queue, its proxy of the port and the tick that dates
    /// what the port reports (`CanIo::dated_transmit_state`; callable at the CAN interrupts'
    /// priority).
    pub fn new(rx: &'a mut RxConsumer, port: M, clock: C) -> Self {
        Self {
            rx,
            port,
            clock,
            counters: bus::ErrorCounters::default(),
        }
    }

    /// Programs the acceptance filter.
    pub fn set_rx_filter<L: CanLink>(&mut self, filter: RxFilter)
    where
        M: rtic::Mutex<T = port::CanPort<L>>,
    {
        self.port.lock(|port| port.set_rx_filter(filter));
    }
}

impl<L: CanLink, M: rtic::Mutex<T = port::CanPort<L>>, C> FrameSink for CanSide<'_, M, C> {
    /// Queues `frame`; a full queue refuses it (the engine counts and, for TPDOs and EMCYs,
    /// retries).
    fn send(&mut self, frame: Frame) -> Result<(), SinkFull> {
        self.port
            .lock(|port| port.send(frame))
            .map_err(|_| SinkFull)
    }

    /// Discards the queue and aborts the mailboxes (a reset of communication).
    fn discard_pending(&mut self) {
        self.port.lock(|port| port.discard_pending());
    }
}

impl<L: CanLink, M: rtic::Mutex<T = port::CanPort<L>>, C: Fn() -> u32> CanIo for CanSide<'_, M, C> {
    fn receive(&mut self) -> Option<Frame> {
        self.rx.dequeue()
    }

    fn bus_state(&mut self) -> bus::BusState {
        let (state, counters) = self.port.lock(|port| port.status());
        self.counters = counters;
        state
    }

    fn rx_overruns(&mut self) -> u32 {
        self.port.lock(|port| port.stats().rx_overruns)
    }

    fn transmit_state(&mut self) -> TransmitState {
        self.port.lock(|port| port.transmit_state())
    }

    /// The state and the tick under the one lock: the interrupts that could hold the task up
    /// between the two (the CAN ones, and whatever shares their priority) are masked there.
    fn dated_transmit_state(&mut self, _now_ms: u32) -> (TransmitState, u32) {
        let clock = &self.clock;
        self.port.lock(|port| (port.transmit_state(), clock()))
    }

    fn switch_bit_rate(&mut self, rate: BitRate) -> bool {
        self.port.lock(|port| port.switch_bit_rate(rate))
    }

    fn frame_acknowledged(&mut self) -> bool {
        self.port.lock(|port| port.frame_acknowledged())
    }
}
