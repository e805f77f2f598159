//! Heartbeat consumer (0x1016): configuration checks, timeout, EMCY and recovery.
mod common;
use canopen_slave::ErrorIndication;
use common::*;

#[test]
fn duplicate_node_is_refused() {
    let mut b = Bench::new();
    b.download_u32(0x1016, 1, 0x0007_0064).unwrap();
    assert_eq!(b.download_u32(0x1016, 2, 0x0007_00C8), Err(0x0604_0043));
    assert_eq!(b.upload_u32(0x1016, 2), 0);
    // A zero time disables the entry, so it does not clash.
    b.download_u32(0x1016, 2, 0x0007_0000).unwrap();
    // Rewriting the same entry is not a clash with itself.
    b.download_u32(0x1016, 1, 0x0007_0096).unwrap();
    assert_eq!(b.upload_u32(0x1016, 0), 2);
    assert_eq!(b.upload(0x1016, 3), Err(0x0609_0011));
}

#[test]
fn monitoring_starts_with_the_first_heartbeat() {
    let mut b = Bench::new();
    b.download_u32(0x1016, 1, 0x0007_0064).unwrap();
    b.download(0x1017, 0, &0u16.to_le_bytes()).unwrap();
    assert_eq!(b.run_until(ms(5000)), vec![]);
    assert!(b.app.lost.is_empty());
}

#[test]
fn timeout_raises_emcy_once_and_recovery_clears_it() {
    let mut b = Bench::new();
    b.download(0x1017, 0, &0u16.to_le_bytes()).unwrap();
    b.download_u32(0x1016, 1, 0x0007_0064).unwrap();
    b.rx_at(ms(1000), frame(0x707, &[0x05]));
    assert_eq!(b.dev.next_deadline(), Some(ms(1100)));
    b.poll_at(ms(1099));
    assert_eq!(b.take(), vec![]);
    b.poll_at(ms(1100));
    // 0x8130, error register = communication | generic, node-ID in the first info byte.
    assert_eq!(
        b.take(),
        vec![frame(EMCY, &[0x30, 0x81, 0x11, 7, 0, 0, 0, 0])]
    );
    assert_eq!(b.app.lost, vec![7]);
    assert_eq!(b.dev.error_register(), 0x11);
    assert_eq!(b.dev.error_indication(), ErrorIndication::ErrorControlEvent);
    assert_eq!(b.upload_u32(0x1003, 0), 1);
    assert_eq!(b.upload_u32(0x1003, 1), 0x0007_8130);
    // One-shot: nothing more while the node stays silent.
    assert_eq!(b.run_until(ms(3000)), vec![]);
    assert_eq!(b.app.lost, vec![7]);
    // The node is back: the error clears and the error-reset EMCY follows.
    b.rx_at(ms(3000), frame(0x707, &[0x05]));
    assert_eq!(b.dev.error_register(), 0);
    assert_eq!(b.dev.error_indication(), ErrorIndication::NoError);
    b.poll_at(ms(3000));
    assert_eq!(b.take(), vec![frame(EMCY, &[0, 0, 0, 0, 0, 0, 0, 0])]);
    // Re-armed: a second loss is reported again.
    b.poll_at(ms(3100));
    assert_eq!(
        b.take(),
        vec![frame(EMCY, &[0x30, 0x81, 0x11, 7, 0, 0, 0, 0])]
    );
    assert_eq!(b.app.lost, vec![7, 7]);
}

#[test]
fn each_heartbeat_rearms_the_deadline() {
    let mut b = Bench::new();
    b.download(0x1017, 0, &0u16.to_le_bytes()).unwrap();
    b.download_u32(0x1016, 2, 0x0010_0032).unwrap();
    for t in (0..1000).step_by(40) {
        b.rx_at(ms(t), frame(0x710, &[0x7F]));
        b.poll_at(ms(t + 39));
    }
    assert_eq!(b.take(), vec![]);
    // Wrong DLC is not a heartbeat.
    b.rx_at(ms(1000), frame(0x710, &[0x7F, 0]));
    b.poll_at(ms(1010));
    assert_eq!(b.app.lost, vec![0x10]);
}

#[test]
fn loss_in_stopped_is_recorded_without_emcy() {
    let mut b = Bench::new();
    b.download(0x1017, 0, &0u16.to_le_bytes()).unwrap();
    b.download_u32(0x1016, 1, 0x0007_0064).unwrap();
    b.nmt(0x02, NODE);
    b.rx_at(ms(0), frame(0x707, &[0x05]));
    b.poll_at(ms(200));
    assert_eq!(b.take(), vec![]);
    assert_eq!(b.app.lost, vec![7]);
    assert_eq!(b.dev.error_register(), 0x11);
    b.nmt(0x80, NODE);
    b.poll_at(ms(300));
    assert_eq!(b.take(), vec![], "no late EMCY after leaving Stopped");
}

#[test]
fn invalid_consumer_entries_are_refused_with_cia_301_codes() {
    let mut b = Bench::new();
    b.download_u32(0x1016, 1, 0x0007_0064).unwrap();
    // (entry, abort): reserved bits, node-IDs 0 (with a time), above 127, and our own.
    let cases = [
        (0x0107_0064, 0x0609_0030),
        (0x8000_0000, 0x0609_0030),
        (0x0000_0064, 0x0609_0030),
        (0x0080_0064, 0x0609_0030),
        (0x00FF_0001, 0x0609_0030),
        (0x00FF_0000, 0x0609_0030),
        (u32::from(NODE) << 16 | 0x64, 0x0609_0030),
        (u32::from(NODE) << 16, 0x0609_0030),
        // Node 7 is monitored by sub 1 already.
        (0x0007_00C8, 0x0604_0043),
    ];
    for (entry, code) in cases {
        assert_eq!(b.download_u32(0x1016, 2, entry), Err(code), "{entry:#010x}");
        assert_eq!(
            b.upload_u32(0x1016, 2),
            0,
            "{entry:#010x} left sub 2 unchanged"
        );
    }
    assert_eq!(b.upload_u32(0x1016, 1), 0x0007_0064);
    // What stays valid: a disabled entry (time 0, or all zero) and another node.
    for entry in [0x0000_0000, 0x0009_0000, 0x007F_FFFF, 0x0001_0001] {
        assert_eq!(b.download_u32(0x1016, 2, entry), Ok(()), "{entry:#010x}");
        assert_eq!(b.upload_u32(0x1016, 2), entry);
    }
}

/// The application's view of a loss: `on_heartbeat_lost` once, then
/// `on_heartbeat_restored` once every lost node is back, whatever ends the loss.
#[test]
fn restored_hook_ends_every_loss_once() {
    let mut b = Bench::new();
    b.download(0x1017, 0, &0u16.to_le_bytes()).unwrap();
    b.download_u32(0x1016, 1, 0x0007_0064).unwrap();
    b.download_u32(0x1016, 2, 0x0009_0064).unwrap();
    b.rx_at(ms(0), frame(0x707, &[0x05]));
    b.rx_at(ms(0), frame(0x709, &[0x05]));
    b.poll_at(ms(100));
    assert_eq!(b.app.lost, vec![7, 9]);
    assert_eq!(b.app.restored_heartbeats, 0);
    // One node back is not enough.
    b.rx_at(ms(150), frame(0x707, &[0x05]));
    assert_eq!(b.app.restored_heartbeats, 0);
    assert_eq!(b.dev.error_register(), 0x11);
    b.rx_at(ms(160), frame(0x709, &[0x05]));
    assert_eq!(b.app.restored_heartbeats, 1);
    assert_eq!(b.dev.error_register(), 0);
    // A second loss, ended by the master disabling the entry instead of coming back.
    b.poll_at(ms(300));
    assert_eq!(b.app.lost, vec![7, 9, 7, 9]);
    b.take();
    b.download_u32(0x1016, 1, 0).unwrap();
    assert_eq!(b.app.restored_heartbeats, 1, "node 9 is still lost");
    b.download_u32(0x1016, 2, 0x0009_0000).unwrap();
    assert_eq!(b.app.restored_heartbeats, 2);
    assert_eq!(b.dev.error_register(), 0);
    // A third, ended by reset communication (the consumers start over).
    b.take();
    b.download_u32(0x1016, 1, 0x0007_0064).unwrap();
    b.rx_at(ms(400), frame(0x707, &[0x05]));
    b.poll_at(ms(500));
    assert_eq!(b.app.lost.len(), 5);
    b.take();
    b.nmt(0x82, NODE);
    assert_eq!(b.app.restored_heartbeats, 3);
    assert_eq!(b.dev.error_register(), 0);
}
