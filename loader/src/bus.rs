//! bxCAN for the loader: bit timing, an acceptance filter for NMT and the node's SDO
//! requests, polled receive and transmit (no interrupts).

use bxcan::filter::ListEntry16;
use bxcan::{Fifo, Id, StandardId};
use canopen_slave::frame::cob;
use canopen_slave::{Frame, NodeId};
use handwheel_core::BitRate;
use stm32f1xx_hal::can::Can;
use stm32f1xx_hal::gpio::PullUp;
use stm32f1xx_hal::pac;

/// The controller.
pub type Bxcan = bxcan::Can<Can<pac::CAN, PullUp>>;
/// Frames waiting for a mailbox.
pub type TxQueue = heapless::Deque<Frame, 8>;

fn standard_id(id: u16) -> StandardId {
    StandardId::new(id & 0x7FF).unwrap_or(StandardId::ZERO)
}

/// Configures the bit timing and the filter (NMT and this node's SDO requests, data frames
/// only) and asks the controller to join the bus; it does once it has seen the bus idle.
pub fn start(can: Can<pac::CAN, PullUp>, bit_rate: BitRate, node: NodeId) -> Bxcan {
    // The board's bit timing, the application's (handwheel_board::bit_timing).
    let btr = handwheel_board::bit_timing::btr(bit_rate.code());
    let mut can = bxcan::Can::builder(can)
        .set_bit_timing(btr)
        .leave_disabled();
    let nmt = ListEntry16::data_frames_with_id(standard_id(cob::NMT));
    let sdo = ListEntry16::data_frames_with_id(standard_id(node.cob_id(cob::SDO_RX)));
    can.modify_filters()
        .clear()
        .enable_bank(0, Fifo::Fifo0, [nmt, sdo, nmt, sdo]);
    // `WouldBlock` only says that it has not joined yet.
    let _ = can.enable_non_blocking();
    can
}

/// The next received frame the node can take; `None` when the FIFO is empty.
pub fn receive(can: &mut Bxcan) -> Option<Frame> {
    loop {
        match can.receive() {
            Ok(frame) => {
                let Id::Standard(id) = frame.id() else {
                    continue;
                };
                let Some(data) = frame.data() else {
                    continue;
                };
                if let Ok(frame) = Frame::new(id.as_raw(), data) {
                    return Some(frame);
                }
            }
            // A lost frame: the master repeats or times out.
            Err(nb::Error::Other(_overrun)) => {}
            Err(nb::Error::WouldBlock) => return None,
        }
    }
}

/// Moves queued frames into free mailboxes, in order.
pub fn transmit(can: &mut Bxcan, queue: &mut TxQueue) {
    while let Some(frame) = queue.front() {
        let data = bxcan::Data::new(frame.data()).unwrap_or_else(bxcan::Data::empty);
        let out = bxcan::Frame::new_data(standard_id(frame.id()), data);
        match can.transmit(&out) {
            Ok(status) => {
                queue.pop_front();
                if let Some(displaced) = status.dequeued_frame() {
                    // A pending frame of lower priority made room: it goes again later.
                    if let (Id::Standard(id), Some(data)) = (displaced.id(), displaced.data()) {
                        if let Ok(frame) = Frame::new(id.as_raw(), data) {
                            let _ = queue.push_front(frame);
                        }
                    }
                    return;
                }
            }
            Err(nb::Error::WouldBlock) => return,
            Err(nb::Error::Other(never)) => match never {},
        }
    }
}
