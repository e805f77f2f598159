//! Transmit PDOs: timing of every transmission type, mapping, configuration aborts.
mod common;
use canopen_slave::{Instant, NoSuchPdo};
use common::*;

fn tpdo1(position: i32, var4: u32) -> canopen_slave::Frame {
    let mut d = position.to_le_bytes().to_vec();
    d.extend_from_slice(&var4.to_le_bytes());
    frame(TPDO1, &d)
}

#[test]
fn entry_to_operational_sends_tpdo1_only() {
    let mut b = Bench::new();
    b.app.position = -2;
    b.app.vars[4] = 0x0102_0304;
    b.app.buttons = 0x81;
    b.now = ms(7);
    b.nmt(0x01, NODE);
    assert_eq!(b.take(), vec![frame(HB, &[0x05]), tpdo1(-2, 0x0102_0304)]);
    assert_eq!(b.app.tpdo_sent, vec![1]);
}

#[test]
fn a_tpdo_carries_what_the_application_holds_for_it_and_sdo_the_present_value() {
    let mut b = Bench::new();
    b.app.position = 40;
    b.app.held_position = Some(30);
    b.nmt(0x01, NODE);
    assert_eq!(b.take(), vec![frame(HB, &[0x05]), tpdo1(30, 0)]);
    assert_eq!(b.upload(0x6004, 0).unwrap(), 40i32.to_le_bytes().to_vec());
    b.app.held_position = None;
    b.dev.request_tpdo(1).unwrap();
    let sent: Vec<_> = b.run_until(ms(10)).into_iter().map(|(_, f)| f).collect();
    assert_eq!(sent, vec![tpdo1(40, 0)]);
}

#[test]
fn no_pdo_outside_operational() {
    let mut b = Bench::new();
    b.dev.request_tpdo(1).unwrap();
    b.dev.request_tpdo(2).unwrap();
    b.download(0x1017, 0, &0u16.to_le_bytes()).unwrap();
    assert_eq!(b.run_until(ms(500)), vec![]);
    b.nmt(0x01, NODE);
    b.nmt(0x02, NODE);
    b.take();
    b.dev.request_tpdo(1).unwrap();
    assert_eq!(b.run_until(ms(1000)), vec![]);
    assert_eq!(b.dev.request_tpdo(0), Err(NoSuchPdo));
    assert_eq!(b.dev.request_tpdo(3), Err(NoSuchPdo));
}

#[test]
fn event_driven_respects_inhibit_time() {
    let mut b = Bench::operational();
    b.download(0x1017, 0, &0u16.to_le_bytes()).unwrap();
    // TPDO2: inhibit 2 ms, no event timer. A first frame at t = 0 starts the inhibit time.
    b.dev.request_tpdo(2).unwrap();
    b.poll_at(ms(0));
    assert_eq!(b.take(), vec![frame(TPDO2, &[0])]);
    b.poll_at(ms(1));
    b.app.buttons = 1;
    b.dev.request_tpdo(2).unwrap();
    assert_eq!(b.dev.next_deadline(), Some(ms(2)));
    b.poll_at(Instant::from_micros(1999));
    assert_eq!(b.take(), vec![]);
    b.poll_at(ms(2));
    assert_eq!(b.take(), vec![frame(TPDO2, &[1])]);
    // A burst of requests collapses into one frame per inhibit time, with the latest data.
    b.now = Instant::from_micros(2500);
    b.dev.request_tpdo(2).unwrap();
    b.app.buttons = 2;
    b.dev.request_tpdo(2).unwrap();
    b.app.buttons = 3;
    let sent: Vec<_> = b
        .run_until(ms(10))
        .into_iter()
        .filter(|(_, f)| f.id() == TPDO2)
        .collect();
    assert_eq!(sent, vec![(4, frame(TPDO2, &[3]))]);
    assert_eq!(b.dev.next_deadline(), Some(ms(100)), "TPDO1 event timer");
}

#[test]
fn event_timer_sends_periodically_and_restarts_on_events() {
    let mut b = Bench::operational();
    b.download(0x1017, 0, &0u16.to_le_bytes()).unwrap();
    let sent = b.run_until(ms(250));
    assert_eq!(
        sent,
        vec![(100, tpdo1(0, 0)), (200, tpdo1(0, 0))],
        "TPDO1 every 100 ms, TPDO2 has no timer"
    );
    b.poll_at(ms(230));
    b.app.position = 5;
    b.dev.request_tpdo(1).unwrap();
    b.poll_at(ms(230));
    assert_eq!(b.take(), vec![tpdo1(5, 0)]);
    let sent = b.run_until(ms(340));
    assert_eq!(sent, vec![(330, tpdo1(5, 0))]);
}

#[test]
fn event_timer_write_takes_effect_at_once() {
    let mut b = Bench::operational();
    b.download(0x1017, 0, &0u16.to_le_bytes()).unwrap();
    b.poll_at(ms(50));
    b.download(0x1800, 5, &20u16.to_le_bytes()).unwrap();
    assert_eq!(b.dev.next_deadline(), Some(ms(70)));
    b.download(0x1800, 5, &0u16.to_le_bytes()).unwrap();
    assert_eq!(b.dev.next_deadline(), None);
    assert_eq!(b.run_until(ms(1000)), vec![]);
}

fn sync() -> canopen_slave::Frame {
    frame(0x080, &[])
}

#[test]
fn synchronous_acyclic_sends_at_next_sync_after_request() {
    let mut b = Bench::new();
    b.download(0x1800, 2, &[0]).unwrap();
    b.nmt(0x01, NODE);
    let frames = b.take();
    assert!(
        frames.iter().all(|f| f.id() != TPDO1),
        "type 0 not sent on entry"
    );
    b.rx(sync());
    assert_eq!(b.take(), vec![]);
    b.app.position = 9;
    b.dev.request_tpdo(1).unwrap();
    b.poll_at(ms(1));
    assert!(b.take().is_empty(), "waits for SYNC");
    b.rx(sync());
    assert_eq!(b.take(), vec![tpdo1(9, 0)]);
    b.rx(sync());
    assert_eq!(b.take(), vec![]);
    // SYNC with a counter byte is accepted, longer ones are not SYNC.
    b.dev.request_tpdo(1).unwrap();
    b.rx(frame(0x080, &[1, 2]));
    assert_eq!(b.take(), vec![]);
    b.rx(frame(0x080, &[1]));
    assert_eq!(b.take(), vec![tpdo1(9, 0)]);
}

#[test]
fn synchronous_cyclic_sends_every_nth_sync() {
    let mut b = Bench::new();
    b.download(0x1800, 2, &[3]).unwrap();
    b.download(0x1801, 2, &[1]).unwrap();
    b.rx(sync());
    assert_eq!(b.take(), vec![], "no PDO in pre-operational");
    b.nmt(0x01, NODE);
    b.take();
    let mut log = Vec::new();
    for n in 1..=7 {
        b.rx(sync());
        for f in b.take() {
            log.push((n, f.id()));
        }
    }
    assert_eq!(
        log,
        vec![
            (1, TPDO2),
            (2, TPDO2),
            (3, TPDO1),
            (3, TPDO2),
            (4, TPDO2),
            (5, TPDO2),
            (6, TPDO1),
            (6, TPDO2),
            (7, TPDO2),
        ]
    );
}

#[test]
fn sync_cob_id_is_configurable() {
    let mut b = Bench::new();
    b.download(0x1800, 2, &[1]).unwrap();
    b.download_u32(0x1005, 0, 0x90).unwrap();
    assert_eq!(b.download_u32(0x1005, 0, 0x4000_0080), Err(0x0609_0030));
    assert_eq!(b.download_u32(0x1005, 0, 0x2000_0080), Err(0x0609_0030));
    b.nmt(0x01, NODE);
    b.take();
    b.rx(sync());
    assert_eq!(b.take(), vec![]);
    b.rx(frame(0x090, &[]));
    assert_eq!(b.take(), vec![tpdo1(0, 0)]);
}

#[test]
fn remapping_by_the_cia_procedure() {
    let mut b = Bench::new();
    b.app.buttons = 0xAA;
    b.app.position = 0x0102_0304;
    b.download_u32(0x1800, 1, 0x8000_0185).unwrap();
    b.download(0x1A00, 0, &[0]).unwrap();
    b.download_u32(0x1A00, 1, 0x6005_0008).unwrap();
    b.download_u32(0x1A00, 2, 0x6004_0020).unwrap();
    b.download(0x1A00, 0, &[2]).unwrap();
    b.download_u32(0x1800, 1, 0x0000_0185).unwrap();
    b.nmt(0x01, NODE);
    let frames = b.take();
    assert_eq!(frames[1], frame(TPDO1, &[0xAA, 0x04, 0x03, 0x02, 0x01]));
    assert_eq!(b.upload_u32(0x1A00, 0), 2);
    assert_eq!(b.upload_u32(0x1A00, 2), 0x6004_0020);
}

#[test]
fn moving_a_pdo_to_another_can_id() {
    let mut b = Bench::new();
    assert_eq!(b.download_u32(0x1800, 1, 0x0000_0195), Err(0x0609_0030));
    b.download_u32(0x1800, 1, 0x8000_0195).unwrap();
    b.download_u32(0x1800, 1, 0x4000_0195).unwrap();
    b.nmt(0x01, NODE);
    assert_eq!(b.take()[1].id(), 0x195);
}

#[test]
fn mapping_aborts() {
    let mut b = Bench::new();
    // The PDO is valid: the mapping is locked.
    assert_eq!(b.download_u32(0x1A00, 1, 0x6005_0008), Err(0x0601_0000));
    assert_eq!(b.download(0x1A00, 0, &[0]), Err(0x0601_0000));
    b.download_u32(0x1800, 1, 0x8000_0185).unwrap();
    // Entries are locked until sub 0 is 0.
    assert_eq!(b.download_u32(0x1A00, 1, 0x6005_0008), Err(0x0601_0000));
    b.download(0x1A00, 0, &[0]).unwrap();
    assert_eq!(b.download_u32(0x1A00, 1, 0x7000_0020), Err(0x0602_0000));
    assert_eq!(b.download_u32(0x1A00, 1, 0x6004_0120), Err(0x0609_0011));
    assert_eq!(b.download_u32(0x1A00, 1, 0x6006_0010), Err(0x0604_0041));
    assert_eq!(b.download_u32(0x1A00, 1, 0x6004_0010), Err(0x0604_0041));
    assert_eq!(b.download_u32(0x1A00, 1, 0x2000_0008), Err(0x0604_0041));
    assert_eq!(b.download_u32(0x1A00, 1, 0x1008_0008), Err(0x0604_0041));
    assert_eq!(b.download(0x1A00, 0, &[9]), Err(0x0604_0042));
    b.download_u32(0x1A00, 3, 0x6005_0008).unwrap();
    // Sub 0 = 3 checks all three entries: 32 + 32 + 8 bits > 64.
    assert_eq!(b.download(0x1A00, 0, &[3]), Err(0x0604_0042));
    assert_eq!(b.upload_u32(0x1A00, 0), 0);
    b.download(0x1A00, 0, &[2]).unwrap();
    // Entry 4 is empty: mapping it is refused.
    b.download(0x1A00, 0, &[0]).unwrap();
    assert_eq!(b.download(0x1A00, 0, &[4]), Err(0x0602_0000));
    assert_eq!(b.download_u32(0x1A00, 9, 0), Err(0x0609_0011));
}

#[test]
fn communication_parameter_aborts() {
    let mut b = Bench::new();
    assert_eq!(b.download_u32(0x1800, 1, 0x2000_0185), Err(0x0609_0030));
    assert_eq!(b.download_u32(0x1800, 1, 0x0000_0186), Err(0x0609_0030));
    assert_eq!(b.download_u32(0x1800, 1, 0x0001_0185), Err(0x0609_0030));
    for ty in [241u8, 250, 251, 252, 253] {
        assert_eq!(b.download(0x1800, 2, &[ty]), Err(0x0609_0030), "type {ty}");
    }
    for ty in [0u8, 1, 240, 254, 255] {
        assert_eq!(b.download(0x1800, 2, &[ty]), Ok(()), "type {ty}");
    }
    assert_eq!(b.download(0x1800, 3, &[1, 0]), Err(0x0609_0030));
    b.download_u32(0x1800, 1, 0x8000_0185).unwrap();
    b.download(0x1800, 3, &[1, 0]).unwrap();
    // Restricted CAN-IDs cannot be made valid.
    assert_eq!(b.download_u32(0x1800, 1, 0x0000_0605), Err(0x0609_0030));
    assert_eq!(b.download_u32(0x1800, 1, 0x0000_0705), Err(0x0609_0030));
    assert_eq!(b.upload(0x1800, 4), Err(0x0609_0011));
    assert_eq!(b.upload(0x1800, 6), Err(0x0609_0011));
    assert_eq!(b.download(0x1800, 4, &[0, 0]), Err(0x0609_0011));
}

#[test]
fn full_sink_retries_the_pdo() {
    let mut b = Bench::operational();
    b.download(0x1017, 0, &0u16.to_le_bytes()).unwrap();
    b.tx.capacity = Some(0);
    b.poll_at(ms(10));
    b.dev.request_tpdo(2).unwrap();
    b.poll_at(ms(10));
    assert_eq!(b.dev.stats().tx_refused, 1);
    assert_eq!(b.dev.next_deadline(), Some(ms(11)), "retry in 1 ms");
    b.tx.capacity = None;
    b.poll_at(ms(11));
    assert_eq!(b.take(), vec![frame(TPDO2, &[0])]);
}

#[test]
fn unreadable_mapped_object_is_counted_not_sent() {
    let mut b = Bench::new();
    b.download(0x1017, 0, &0u16.to_le_bytes()).unwrap();
    b.app.position_fault = true;
    b.nmt(0x01, NODE);
    assert_eq!(b.take(), vec![]);
    assert_eq!(b.dev.stats().tpdo_errors, 1);
    assert_eq!(b.app.tpdo_sent, Vec::<u8>::new());
    // The event is dropped, not retried in a loop; the event timer tries again.
    assert_eq!(b.dev.next_deadline(), Some(ms(100)));
    b.app.position_fault = false;
    b.poll_at(ms(100));
    assert_eq!(b.take(), vec![tpdo1(0, 0)]);
}

#[test]
fn mapping_of_a_readable_record_member() {
    let mut b = Bench::new();
    b.download_u32(0x1801, 1, 0x8000_0285).unwrap();
    b.download(0x1A01, 0, &[0]).unwrap();
    b.download_u32(0x1A01, 1, 0x2100_0420).unwrap();
    b.download(0x1A01, 0, &[1]).unwrap();
    b.download_u32(0x1801, 1, 0x285).unwrap();
    b.app.vars[4] = 0xCAFE_F00D;
    b.nmt(0x01, NODE);
    b.dev.request_tpdo(2).unwrap();
    b.poll_at(b.now);
    let frames = b.take();
    assert_eq!(
        frames.last(),
        Some(&frame(TPDO2, &0xCAFE_F00Du32.to_le_bytes()))
    );
}

#[test]
fn application_can_withdraw_a_requested_pdo() {
    let mut b = Bench::operational();
    b.download(0x1017, 0, &0u16.to_le_bytes()).unwrap();
    b.take();
    b.app.withdraw = vec![2];
    b.dev.request_tpdo(2).unwrap();
    b.poll_at(ms(1));
    assert_eq!(b.take(), vec![], "withdrawn: nothing sent");
    assert_eq!(b.dev.stats().tpdo_errors, 0, "a withdrawal is not an error");
    // The withdrawal started no inhibit time: the next event goes out at once.
    b.app.withdraw.clear();
    b.app.buttons = 5;
    b.dev.request_tpdo(2).unwrap();
    b.poll_at(ms(1));
    assert_eq!(b.take(), vec![frame(TPDO2, &[5])]);
    assert_eq!(b.app.tpdo_sent.last(), Some(&2));
}
