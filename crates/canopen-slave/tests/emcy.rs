//! EMCY producer: frames, error register, pre-defined error field, inhibit time.
mod common;
use canopen_slave::EmcyError;
use common::*;

#[test]
fn raise_and_clear_produce_exact_frames_and_history() {
    let mut b = Bench::new();
    b.dev.raise_error(0x7300, 0x80, [1, 2, 3, 4, 5]).unwrap();
    assert_eq!(b.dev.error_register(), 0x81);
    assert_eq!(b.dev.next_deadline(), Some(ms(0)));
    b.poll_at(ms(1));
    assert_eq!(
        b.take(),
        vec![frame(EMCY, &[0x00, 0x73, 0x81, 1, 2, 3, 4, 5])]
    );
    b.dev.raise_error(0x8110, 0x10, [0; 5]).unwrap();
    b.poll_at(ms(2));
    assert_eq!(
        b.take(),
        vec![frame(EMCY, &[0x10, 0x81, 0x91, 0, 0, 0, 0, 0])]
    );
    assert_eq!(b.upload(0x1001, 0), Ok(vec![0x91]));
    assert_eq!(b.upload_u32(0x1003, 0), 2);
    assert_eq!(b.upload_u32(0x1003, 1), 0x0000_8110);
    assert_eq!(b.upload_u32(0x1003, 2), 0x0201_7300);
    assert_eq!(b.upload(0x1003, 3), Err(0x0800_0024));
    // Raising an active error again does nothing.
    b.dev.raise_error(0x7300, 0x80, [9; 5]).unwrap();
    b.poll_at(ms(3));
    assert_eq!(b.take(), vec![]);
    // Clearing one of two: no frame; the last one: error reset.
    assert!(b.dev.clear_error(0x7300));
    assert!(!b.dev.clear_error(0x7300));
    b.poll_at(ms(4));
    assert_eq!(b.take(), vec![]);
    assert_eq!(b.dev.error_register(), 0x11);
    assert!(b.dev.clear_error(0x8110));
    b.poll_at(ms(5));
    assert_eq!(b.take(), vec![frame(EMCY, &[0; 8])]);
    assert_eq!(b.dev.error_register(), 0);
    // History survives clearing; only a write of 0 empties it.
    assert_eq!(b.upload_u32(0x1003, 0), 2);
    assert_eq!(b.download(0x1003, 0, &[1]), Err(0x0609_0030));
    b.download(0x1003, 0, &[0]).unwrap();
    assert_eq!(b.upload_u32(0x1003, 0), 0);
    assert_eq!(b.upload(0x1003, 1), Err(0x0800_0024));
    assert_eq!(b.download_u32(0x1003, 1, 0), Err(0x0601_0002));
}

#[test]
fn history_keeps_the_newest_four() {
    let mut b = Bench::new();
    for code in [0x1000u16, 0x2000, 0x3000, 0x4000] {
        b.dev.raise_error(code, 0, [0; 5]).unwrap();
    }
    assert_eq!(
        b.dev.raise_error(0x5000, 0, [0; 5]),
        Err(EmcyError::TooManyErrors)
    );
    b.dev.clear_error(0x1000);
    b.dev.raise_error(0x5000, 0, [0; 5]).unwrap();
    assert_eq!(b.upload_u32(0x1003, 0), 4);
    let history: Vec<u32> = (1..=4).map(|s| b.upload_u32(0x1003, s)).collect();
    assert_eq!(history, vec![0x5000, 0x4000, 0x3000, 0x2000]);
    assert_eq!(b.dev.raise_error(0, 0, [0; 5]), Err(EmcyError::ResetCode));
}

#[test]
fn inhibit_time_spaces_frames_without_losing_them() {
    let mut b = Bench::new();
    b.download(0x1017, 0, &0u16.to_le_bytes()).unwrap();
    b.download(0x1015, 0, &100u16.to_le_bytes()).unwrap();
    for code in [0x1000u16, 0x2000, 0x3000] {
        b.dev.raise_error(code, 0, [0; 5]).unwrap();
    }
    let sent: Vec<_> = b
        .run_until(ms(40))
        .into_iter()
        .map(|(t, f)| (t, f.raw_data()[1]))
        .collect();
    assert_eq!(sent, vec![(0, 0x10), (10, 0x20), (20, 0x30)]);
    assert_eq!(b.dev.stats().emcy_overflow, 0);
}

#[test]
fn queue_overflow_is_counted() {
    let mut b = Bench::new();
    b.download(0x1015, 0, &100u16.to_le_bytes()).unwrap();
    for code in [0x1000u16, 0x2000, 0x3000, 0x4000] {
        b.dev.raise_error(code, 0, [0; 5]).unwrap();
    }
    for code in [0x1000u16, 0x2000, 0x3000, 0x4000] {
        b.dev.clear_error(code);
    }
    assert_eq!(
        b.dev.stats().emcy_overflow,
        1,
        "the error reset did not fit"
    );
}

#[test]
fn no_emcy_in_stopped_but_error_recorded() {
    let mut b = Bench::new();
    b.dev.raise_error(0x7300, 0x80, [0; 5]).unwrap();
    b.nmt(0x02, NODE);
    b.take();
    b.poll_at(ms(1));
    assert_eq!(b.take(), vec![], "queued EMCY dropped on entering Stopped");
    b.dev.raise_error(0x6100, 0x01, [0; 5]).unwrap();
    b.poll_at(ms(2));
    assert_eq!(b.take(), vec![]);
    assert_eq!(b.dev.error_register(), 0x81);
    b.nmt(0x80, NODE);
    b.take();
    b.poll_at(ms(3));
    assert_eq!(b.take(), vec![]);
    assert_eq!(b.upload_u32(0x1003, 0), 2);
}

#[test]
fn emcy_cob_id_configuration() {
    let mut b = Bench::new();
    assert_eq!(b.download_u32(0x1014, 0, 0x86), Err(0x0609_0030));
    b.download_u32(0x1014, 0, 0x8000_0085).unwrap();
    b.dev.raise_error(0x7300, 0, [0; 5]).unwrap();
    b.poll_at(ms(1));
    assert_eq!(b.take(), vec![], "EMCY invalid");
    b.download_u32(0x1014, 0, 0x8000_0095).unwrap();
    b.download_u32(0x1014, 0, 0x95).unwrap();
    b.dev.raise_error(0x7301, 0, [0; 5]).unwrap();
    b.poll_at(ms(2));
    assert_eq!(
        b.take(),
        vec![frame(0x95, &[0x01, 0x73, 0x01, 0, 0, 0, 0, 0])]
    );
}

#[test]
fn errors_raised_before_start_go_out_after_boot_up() {
    let mut b = Bench::new_unstarted(canopen_slave::MemoryStorage::new());
    b.dev.raise_error(0x5000, 0, [0; 5]).unwrap();
    b.dev.start(ms(0), &mut b.app, &mut b.tx);
    b.poll_at(ms(0));
    assert_eq!(
        b.take(),
        vec![
            frame(HB, &[0]),
            frame(EMCY, &[0x00, 0x50, 0x01, 0, 0, 0, 0, 0])
        ]
    );
}

#[test]
fn reset_node_forgets_errors() {
    let mut b = Bench::new();
    b.dev.raise_error(0x5000, 0, [0; 5]).unwrap();
    b.nmt(0x81, NODE);
    assert_eq!(
        b.take(),
        vec![frame(HB, &[0])],
        "boot-up, and the queued EMCY is gone"
    );
    assert_eq!(b.dev.error_register(), 0);
    assert_eq!(b.upload_u32(0x1003, 0), 0);
    b.poll_at(ms(1));
    assert_eq!(b.take(), vec![]);
}
