//! NMT state machine, boot-up and heartbeat producer.
mod common;
use canopen_slave::{MemoryStorage, NmtState};
use common::*;

#[test]
fn start_sends_exact_bootup_and_enters_preoperational() {
    let mut b = Bench::new_unstarted(MemoryStorage::new());
    assert_eq!(b.dev.nmt_state(), NmtState::Initialising);
    b.dev.start(ms(0), &mut b.app, &mut b.tx);
    assert_eq!(b.take(), vec![frame(0x705, &[0x00])]);
    assert_eq!(b.dev.nmt_state(), NmtState::PreOperational);
    assert_eq!(b.app.states, vec![NmtState::PreOperational]);
    // No heartbeat right after the boot-up: the first one comes one period later.
    assert_eq!(b.dev.next_deadline(), Some(ms(1000)));
    assert_eq!(b.run_until(ms(999)), vec![]);
    assert_eq!(b.run_until(ms(1000)), vec![(1000, frame(HB, &[0x7F]))]);
}

#[test]
fn frames_before_start_are_ignored() {
    let mut b = Bench::new_unstarted(MemoryStorage::new());
    b.nmt(0x01, NODE);
    b.rx(frame(SDO_RX, &req(0x40, 0x1000, 0, [0; 4])));
    b.poll_at(ms(5000));
    assert_eq!(b.take(), vec![]);
    assert_eq!(b.dev.nmt_state(), NmtState::Initialising);
    assert_eq!(b.dev.next_deadline(), None);
}

#[test]
fn start_stop_preop_addressed_and_broadcast() {
    for target in [NODE, 0] {
        let mut b = Bench::new();
        b.now = ms(10);
        b.nmt(0x01, target);
        assert_eq!(b.dev.nmt_state(), NmtState::Operational);
        let frames = b.take();
        assert_eq!(
            frames[0],
            frame(HB, &[0x05]),
            "heartbeat right after the change"
        );

        b.nmt(0x02, target);
        assert_eq!(b.dev.nmt_state(), NmtState::Stopped);
        assert_eq!(b.take(), vec![frame(HB, &[0x04])]);

        b.nmt(0x80, target);
        assert_eq!(b.dev.nmt_state(), NmtState::PreOperational);
        assert_eq!(b.take(), vec![frame(HB, &[0x7F])]);

        b.nmt(0x01, target);
        b.take();
        b.nmt(0x80, target);
        assert_eq!(b.take(), vec![frame(HB, &[0x7F])]);
        assert_eq!(
            b.app.states,
            vec![
                NmtState::PreOperational,
                NmtState::Operational,
                NmtState::Stopped,
                NmtState::PreOperational,
                NmtState::Operational,
                NmtState::PreOperational,
            ]
        );
    }
}

#[test]
fn command_to_the_current_state_changes_nothing() {
    let mut b = Bench::operational();
    b.nmt(0x01, NODE);
    assert_eq!(b.take(), vec![]);
    assert_eq!(b.app.states.len(), 2);
}

#[test]
fn reset_node_resets_application_and_boots_up() {
    for target in [NODE, 0] {
        let mut b = Bench::operational();
        b.app.flag = 1;
        b.app.states.clear();
        b.nmt(0x81, target);
        assert_eq!(b.take(), vec![frame(HB, &[0x00])]);
        assert_eq!(b.dev.nmt_state(), NmtState::PreOperational);
        assert_eq!(b.app.resets, 1);
        assert_eq!(b.app.flag, 0);
        assert_eq!(
            b.app.states,
            vec![NmtState::Initialising, NmtState::PreOperational]
        );
    }
}

#[test]
fn reset_communication_restores_defaults_and_boots_up() {
    for target in [NODE, 0] {
        let mut b = Bench::new();
        b.download(0x1017, 0, &500u16.to_le_bytes()).unwrap();
        b.download_u32(0x1016, 1, 0x0007_0064).unwrap();
        b.download_u32(0x1800, 1, 0x8000_0185).unwrap();
        b.download(0x1800, 3, &50u16.to_le_bytes()).unwrap();
        b.download_u32(0x1005, 0, 0x90).unwrap();
        b.download(0x2000, 0, &[1]).unwrap();
        b.nmt(0x82, target);
        assert_eq!(b.take(), vec![frame(HB, &[0x00])]);
        assert_eq!(b.dev.nmt_state(), NmtState::PreOperational);
        assert_eq!(b.upload_u32(0x1017, 0), 1000);
        assert_eq!(b.upload_u32(0x1016, 1), 0);
        assert_eq!(b.upload_u32(0x1800, 1), 0x4000_0185);
        assert_eq!(b.upload_u32(0x1800, 3), 20);
        assert_eq!(b.upload_u32(0x1005, 0), 0x80);
        // The application is not reset by a communication reset.
        assert_eq!(b.app.resets, 0);
        assert_eq!(b.app.flag, 1);
    }
}

#[test]
fn foreign_node_bad_dlc_and_unknown_commands_are_ignored() {
    let mut b = Bench::new();
    let before = b.dev.clone();
    for f in [
        frame(0, &[0x01, NODE + 1]),
        frame(0, &[0x01, 127]),
        frame(0, &[0x01]),
        frame(0, &[0x01, NODE, 0]),
        frame(0, &[]),
        frame(0, &[0x03, NODE]),
        frame(0, &[0x00, 0]),
        frame(0, &[0x83, 0]),
    ] {
        b.rx(f);
        assert_eq!(b.take(), vec![], "{f:?}");
        assert_eq!(b.dev, before, "{f:?}");
    }
}

#[test]
fn heartbeat_period_and_state_bytes() {
    let mut b = Bench::new();
    let sent = b.run_until(ms(2500));
    assert_eq!(
        sent,
        vec![(1000, frame(HB, &[0x7F])), (2000, frame(HB, &[0x7F]))]
    );
    b.now = ms(2500);
    b.nmt(0x02, NODE);
    assert_eq!(b.take(), vec![frame(HB, &[0x04])]);
    // The timer restarts with the state-change heartbeat.
    assert_eq!(b.dev.next_deadline(), Some(ms(3500)));
    let sent = b.run_until(ms(4600));
    assert_eq!(
        sent,
        vec![(3500, frame(HB, &[0x04])), (4500, frame(HB, &[0x04]))]
    );
}

#[test]
fn heartbeat_write_restarts_timer_and_zero_disables() {
    let mut b = Bench::new();
    b.poll_at(ms(300));
    b.download(0x1017, 0, &500u16.to_le_bytes()).unwrap();
    assert_eq!(b.dev.next_deadline(), Some(ms(800)));
    let sent = b.run_until(ms(1400));
    assert_eq!(
        sent,
        vec![(800, frame(HB, &[0x7F])), (1300, frame(HB, &[0x7F]))]
    );
    b.download(0x1017, 0, &0u16.to_le_bytes()).unwrap();
    assert_eq!(b.dev.next_deadline(), None);
    assert_eq!(b.run_until(ms(5000)), vec![]);
    // No heartbeat on a state change either, but the boot-up is always sent.
    b.nmt(0x01, NODE);
    assert!(b.take().iter().all(|f| f.id() != HB));
}

#[test]
fn late_poll_does_not_burst_heartbeats() {
    let mut b = Bench::new();
    b.poll_at(ms(3700));
    assert_eq!(b.take(), vec![frame(HB, &[0x7F])]);
    assert_eq!(b.dev.next_deadline(), Some(ms(4700)));
}

#[test]
fn stopped_keeps_heartbeat_but_no_sdo() {
    let mut b = Bench::new();
    b.nmt(0x02, NODE);
    b.take();
    assert_eq!(b.sdo(req(0x40, 0x1000, 0, [0; 4])), None);
    assert_eq!(b.sdo(req(0x2F, 0x2000, 0, [1, 0, 0, 0])), None);
    assert_eq!(b.app.flag, 0);
    assert_eq!(b.run_until(ms(1000)), vec![(1000, frame(HB, &[0x04]))]);
}
