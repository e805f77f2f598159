//! bxCAN for the loader: bit timing, an acceptance filter for NMT and the node's SDO
//! requests, polled receive and transmit (no interrupts).

use bxcan::filter::ListEntry16;
use bxcan::Fifo;
use canopen_slave::frame::cob;
use canopen_slave::{Frame, NodeId};
use handwheel_board::frame::{from_bxcan, standard_id, to_bxcan};
use handwheel_core::BitRate;
use stm32f1xx_hal::can::Can;
use stm32f1xx_hal::gpio::PullUp;
use stm32f1xx_hal::pac;

/// The controller.
pub type Bxcan = bxcan::Can<Can<pac::CAN, PullUp>>;
/// Frames waiting for a mailbox.
pub type TxQueue = heapless::Deque<Frame, 8>;

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
                if let Some(frame) = from_bxcan(&frame) {
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
        match can.transmit(&to_bxcan(frame)) {
            Ok(status) => {
                queue.pop_front();
                if let Some(displaced) = status.dequeued_frame() {
                    // A pending frame of lower priority made room: it goes again later.
                    if let Some(frame) = from_bxcan(displaced) {
                        let _ = queue.push_front(frame);
                    }
                    return;
                }
            }
            Err(nb::Error::WouldBlock) => return,
            Err(nb::Error::Other(never)) => match never {},
        }
    }
}
