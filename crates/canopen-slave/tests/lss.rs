//! LSS (CiA 305) through the whole engine: node-ID changes at reset communication, the
//! unconfigured node (no boot-up, LSS only), store configuration, the acceptance filter.
mod common;

use canopen_slave::{Config, Device, Frame, Instant, MemoryStorage, NmtState, NodeId, RxFilter};
use common::*;

const LSS_RX: u16 = 0x7E5;
const LSS_TX: u16 = 0x7E4;

fn lss(b: &mut Bench, data: [u8; 8]) -> Vec<Frame> {
    b.rx(frame(LSS_RX, &data));
    b.take()
}

fn lss_reply(b: &mut Bench, data: [u8; 8]) -> Option<[u8; 8]> {
    let frames = lss(b, data);
    assert!(frames.len() <= 1, "{frames:?}");
    frames.first().map(|f| {
        assert_eq!((f.id(), f.dlc()), (LSS_TX, 8));
        *f.raw_data()
    })
}

const CONFIGURATION: [u8; 8] = [0x04, 1, 0, 0, 0, 0, 0, 0];
const WAITING: [u8; 8] = [0x04, 0, 0, 0, 0, 0, 0, 0];

fn configure_node(b: &mut Bench, id: u8) {
    assert_eq!(lss_reply(b, CONFIGURATION), None);
    assert_eq!(
        lss_reply(b, [0x11, id, 0, 0, 0, 0, 0, 0]),
        Some([0x11, 0, 0, 0, 0, 0, 0, 0])
    );
    assert_eq!(lss_reply(b, WAITING), None);
}

#[test]
fn new_node_id_takes_effect_at_reset_communication() {
    let mut b = Bench::new();
    configure_node(&mut b, 9);
    // Still node 5 until the reset.
    assert_eq!(b.dev.node_id(), NodeId::new(NODE).ok());
    assert!(b.sdo(req(0x40, 0x1000, 0, [0; 4])).is_some());
    b.nmt(0x82, NODE);
    let frames = b.take();
    assert_eq!(frames.len(), 1);
    assert_eq!((frames[0].id(), frames[0].data()), (0x709, &[0u8][..]));
    assert_eq!(b.dev.node_id(), NodeId::new(9).ok());
    let filter = RxFilter::new(NodeId::new(9).unwrap()).with_rpdo(Some(0x209));
    assert_eq!(b.dev.rx_filter(), filter);
    // The old SDO channel is gone, the new one answers; NMT addresses node 9.
    b.rx(frame(SDO_RX, &req(0x40, 0x1000, 0, [0; 4])));
    assert!(b.take().is_empty());
    b.rx(frame(0x609, &req(0x40, 0x1000, 0, [0; 4])));
    assert_eq!(b.take()[0].id(), 0x589);
    // And it stays 9 across a reset node.
    b.nmt(0x81, 9);
    assert_eq!(b.take()[0].id(), 0x709);
}

#[test]
fn unconfigured_node_sends_nothing_and_answers_lss_only() {
    let mut b = Bench::new();
    configure_node(&mut b, 0xFF);
    b.nmt(0x82, 0);
    assert!(b.take().is_empty(), "no boot-up");
    assert_eq!(b.dev.node_id(), None);
    assert_eq!(b.dev.nmt_state(), NmtState::Initialising);
    assert_eq!(b.dev.rx_filter(), RxFilter::unconfigured());
    // Nothing but LSS: no heartbeat, NMT and SDO ignored.
    assert!(b.run_until(ms(5000)).is_empty());
    b.nmt(0x01, 0);
    b.rx(frame(SDO_RX, &req(0x40, 0x1000, 0, [0; 4])));
    assert!(b.take().is_empty());
    assert_eq!(b.dev.next_deadline(), None);
    assert_eq!(
        lss_reply(&mut b, [0x4C, 0, 0, 0, 0, 0, 0, 0]),
        Some([0x50, 0, 0, 0, 0, 0, 0, 0])
    );
    // Configured by LSS: back to waiting initialises the node with its new node-ID.
    assert_eq!(lss_reply(&mut b, CONFIGURATION), None);
    assert_eq!(
        lss_reply(&mut b, [0x5E, 0, 0, 0, 0, 0, 0, 0]),
        Some([0x5E, 0xFF, 0, 0, 0, 0, 0, 0])
    );
    lss_reply(&mut b, [0x11, 3, 0, 0, 0, 0, 0, 0]);
    let frames = lss(&mut b, WAITING);
    assert_eq!(frames.len(), 1);
    assert_eq!((frames[0].id(), frames[0].data()), (0x703, &[0u8][..]));
    assert_eq!(b.dev.nmt_state(), NmtState::PreOperational);
}

#[test]
fn node_configured_unconfigured_at_power_on() {
    let mut dev = Device::new(Config::with_node(None), OD, MemoryStorage::new());
    let mut app = TestApp::default();
    let mut tx = Sink::default();
    dev.start(Instant::ZERO, &mut app, &mut tx);
    assert!(tx.frames.is_empty());
    dev.poll(ms(10_000), &mut app, &mut tx);
    assert!(tx.frames.is_empty());
    let f = frame(LSS_RX, &[0x4C, 0, 0, 0, 0, 0, 0, 0]);
    dev.on_frame(ms(1), &f, &mut app, &mut tx);
    assert_eq!(tx.frames[0].raw_data(), &[0x50, 0, 0, 0, 0, 0, 0, 0]);
}

#[test]
fn lss_address_is_the_identity_object() {
    let mut b = Bench::new();
    lss(&mut b, CONFIGURATION);
    let mut inquire = |cs: u8| {
        let r = lss_reply(&mut b, [cs, 0, 0, 0, 0, 0, 0, 0]).unwrap();
        assert_eq!(r[0], cs);
        u32::from_le_bytes([r[1], r[2], r[3], r[4]])
    };
    assert_eq!(inquire(0x5A), IDENTITY.vendor_id);
    assert_eq!(inquire(0x5B), IDENTITY.product_code);
    assert_eq!(inquire(0x5C), IDENTITY.revision);
    assert_eq!(inquire(0x5D), 0xDEAD_BEEF);
    assert_eq!(inquire(0x5E) & 0xFF, u32::from(NODE));
}

#[test]
fn store_configuration_reaches_the_storage_and_bit_timing_switches_after_the_delay() {
    let mut b = Bench::new();
    lss(&mut b, CONFIGURATION);
    lss(&mut b, [0x11, 7, 0, 0, 0, 0, 0, 0]);
    assert_eq!(
        lss_reply(&mut b, [0x13, 0, 2, 0, 0, 0, 0, 0]),
        Some([0x13, 0, 0, 0, 0, 0, 0, 0])
    );
    assert_eq!(
        lss_reply(&mut b, [0x17, 0, 0, 0, 0, 0, 0, 0]),
        Some([0x17, 0, 0, 0, 0, 0, 0, 0])
    );
    assert_eq!(b.dev.storage().node(), Some((7, 2)));
    b.rx_at(ms(100), frame(LSS_RX, &[0x15, 50, 0, 0, 0, 0, 0, 0]));
    assert!(b.take().is_empty());
    assert!(b.dev.next_deadline().unwrap() <= ms(150));
    assert_eq!(b.dev.take_bit_timing_switch(ms(149)), None);
    assert_eq!(b.dev.take_bit_timing_switch(ms(150)), Some(2));
    assert_eq!(b.dev.lss().active_bit_timing(), 2);
}
