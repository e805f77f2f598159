//! On-target: bxCAN in silent loopback mode, through the firmware's own glue
//! (`board::init`, `can::start`, `CanPort`). Needs a Blue Pill and a probe, no transceiver:
//! `cargo test --target thumbv7m-none-eabi -p handwheel-firmware --test can_loopback`.
#![no_std]
#![no_main]

use defmt_rtt as _;
use handwheel_firmware as _;

use handwheel_firmware::can::{CanPort, Frame, RxQueue};
use handwheel_firmware::pac;

/// Sends `frames` through the queue and collects what comes back, pumping the queue the
/// way the TX interrupt does.
pub fn round_trip(
    port: &mut CanPort,
    rx: &mut RxQueue,
    frames: &[Frame],
) -> heapless::Vec<Frame, 32> {
    let (mut producer, mut consumer) = rx.split();
    for frame in frames {
        defmt::unwrap!(port.send(*frame).ok());
    }
    let mut received = heapless::Vec::new();
    // 1 Mbit/s: a frame takes about 0.1 ms; give the whole batch 10 ms.
    for _ in 0..10_000 {
        port.on_transmit_room();
        defmt::assert!(!port.on_receive(&mut producer), "receive overrun");
        while let Some(frame) = consumer.dequeue() {
            defmt::unwrap!(received.push(frame).ok());
        }
        cortex_m::asm::delay(72);
    }
    received
}

pub fn frame(id: u16, data: &[u8]) -> Frame {
    defmt::unwrap!(Frame::new(id, data))
}

/// Enters (`true`) or leaves bxCAN's initialisation mode, in which pending mailboxes are
/// kept but not transmitted.
pub fn hold_transmission(hold: bool) {
    // SAFETY: test-only register glue. The test owns the controller (through `CanPort`)
    // and runs single-threaded with the CAN interrupts masked in the NVIC; the modify
    // changes only INRQ, and the loop waits for the mode change bxCAN acknowledges in
    // INAK, as bxcan's own configuration code does.
    let can = unsafe { &*pac::CAN::ptr() };
    can.mcr().modify(|_, w| w.inrq().bit(hold));
    while can.msr().read().inak().bit() != hold {}
}

#[defmt_test::tests]
mod tests {
    use super::{frame, hold_transmission, round_trip};
    use canopen_slave::{NodeId, RxFilter};
    use handwheel_core::BitRate;
    use handwheel_firmware::board;
    use handwheel_firmware::can::{self, CanPort, Frame, Mode, RxQueue, RX_QUEUE_LEN};
    use handwheel_firmware::pac;

    const NODE_ID: u8 = 16;

    struct State {
        port: CanPort,
        rx: RxQueue,
    }

    #[init]
    fn init() -> State {
        let dp = defmt::unwrap!(pac::Peripherals::take());
        let board = board::init(dp);
        let node = defmt::unwrap!(NodeId::new(NODE_ID).ok());
        let can = can::start(
            board.can,
            BitRate::Kbit1000,
            RxFilter::new(node),
            Mode::SilentLoopback,
        );
        let mut port = CanPort::new(can);
        // `can::start` only asks the controller to join; in loopback it sees its own
        // recessive TX at once, so this takes a few bit times.
        while !port.switch_bit_rate(BitRate::Kbit1000) {}
        State {
            port,
            rx: RxQueue::new(),
        }
    }

    #[test]
    fn accepted_ids_come_back_intact(state: &mut State) {
        let sent = [
            frame(0x000, &[0x01, NODE_ID]), // NMT start
            frame(0x080, &[]),              // SYNC
            frame(
                0x600 + u16::from(NODE_ID),
                &[0x40, 0x00, 0x10, 0, 0, 0, 0, 0],
            ), // SDO
            frame(0x701, &[0x05]),          // a heartbeat
            frame(0x77F, &[0x7F]),          // the last heartbeat id
        ];
        let received = round_trip(&mut state.port, &mut state.rx, &sent);
        defmt::assert_eq!(received.as_slice(), &sent[..]);
    }

    #[test]
    fn other_ids_are_filtered_out(state: &mut State) {
        let sent = [
            frame(0x600 + u16::from(NODE_ID) + 1, &[0x40]), // another node's SDO
            frame(0x580 + u16::from(NODE_ID), &[0x60]),     // our own SDO response
            frame(0x190, &[1, 2, 3, 4]),                    // a TPDO
            frame(0x090, &[0x00, 0x10]),                    // an EMCY
            frame(0x700, &[]), // 0x700 is no node's heartbeat... but in the mask
        ];
        let received = round_trip(&mut state.port, &mut state.rx, &sent);
        // The heartbeat mask passes 0x700..0x77F as a block, 0x700 included.
        defmt::assert_eq!(received.as_slice(), &sent[4..]);
    }

    #[test]
    fn a_moved_sync_is_received_on_its_new_identifier_only(state: &mut State) {
        let node = defmt::unwrap!(NodeId::new(NODE_ID).ok());
        state.port.set_rx_filter(RxFilter::with_sync(node, 0x081));
        let sent = [frame(0x080, &[]), frame(0x081, &[])];
        let received = round_trip(&mut state.port, &mut state.rx, &sent);
        state.port.set_rx_filter(RxFilter::new(node));
        defmt::assert_eq!(received.as_slice(), &sent[1..]);
    }

    #[test]
    fn a_burst_longer_than_the_mailboxes_arrives_complete_and_in_order(state: &mut State) {
        let mut sent: heapless::Vec<Frame, 12> = heapless::Vec::new();
        for i in 0..12u8 {
            defmt::unwrap!(sent.push(frame(0x701, &[i])).ok());
        }
        let received = round_trip(&mut state.port, &mut state.rx, &sent);
        defmt::assert_eq!(received.as_slice(), sent.as_slice());
    }

    #[test]
    fn a_full_queue_refuses_without_dropping(state: &mut State) {
        // Hold transmission (initialisation mode) so nothing leaves the mailboxes.
        hold_transmission(true);
        let mut accepted = 0;
        let mut refused = 0;
        for i in 0..(can::TX_QUEUE_LEN + 3 + 4) as u8 {
            match state.port.send(frame(0x701, &[i])) {
                Ok(()) => accepted += 1,
                Err(_) => refused += 1,
            }
        }
        // Three frames sit in the mailboxes, TX_QUEUE_LEN in the queue.
        defmt::assert_eq!(accepted, can::TX_QUEUE_LEN + 3);
        defmt::assert_eq!(refused, 4);
        hold_transmission(false);
        let received = round_trip(&mut state.port, &mut state.rx, &[]);
        defmt::assert_eq!(received.len(), accepted);
        for (i, f) in received.iter().enumerate() {
            defmt::assert_eq!(f.data(), &[i as u8]);
        }
        defmt::assert!(RX_QUEUE_LEN > 1);
    }

    #[test]
    fn a_displaced_frame_is_sent_later_not_lost(state: &mut State) {
        // With transmission held, three ascending-priority frames fill the mailboxes; a
        // fourth, more urgent one makes bxcan abort the least urgent and hand it back.
        hold_transmission(true);
        let displaced_before = state.port.stats().tx_displaced;
        let sent = [
            frame(0x703, &[3]),
            frame(0x702, &[2]),
            frame(0x701, &[1]),
            frame(0x000, &[0x01, 0x00]),
        ];
        for f in sent {
            defmt::unwrap!(state.port.send(f).ok());
        }
        defmt::assert_eq!(state.port.stats().tx_displaced, displaced_before + 1);
        defmt::assert_eq!(state.port.queued(), 1);
        hold_transmission(false);
        let received = round_trip(&mut state.port, &mut state.rx, &[]);
        // Priority order on the bus; 0x703 came back from the queue, once.
        defmt::assert_eq!(
            received.as_slice(),
            &[sent[3], sent[2], sent[1], sent[0]][..]
        );
    }
}
