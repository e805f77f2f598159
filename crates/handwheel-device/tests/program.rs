//! The application's side of CiA 302-3 program download (docs/FIRMWARE-UPDATE.md): 0x1F51:1
//! "stop" resets into the resident loader, only in Pre-operational with the feed disabled;
//! 0x1F51:1 "confirm" (0x80) ends the trial boot; 0x1F56:1 is the running image's CRC,
//! 0x1F57:1 is 0.

mod common;

use canopen_slave::{MemoryStorage, NodeId};
use common::{Bench, NODE};
use handwheel_core::{Axis, Multiplier, Mutex};
use handwheel_device::HandwheelDevice;

const PROGRAM_CONTROL: u16 = 0x1F51;
const DEVICE_STATE: u32 = 0x0800_0022;
const INVALID_VALUE: u32 = 0x0609_0030;
const READ_ONLY: u32 = 0x0601_0002;

fn bench_with_crc(crc: u32) -> Bench {
    let device = HandwheelDevice::new(NodeId::new(NODE).unwrap(), 1, MemoryStorage::new())
        .with_software_id(crc);
    Bench::with_device(device)
}

#[test]
fn the_objects_read_as_the_running_application() {
    let mut b = bench_with_crc(0x8BAD_F00D);
    assert_eq!(b.sdo_upload(0x1F51, 0), Ok(vec![1]), "highest sub-index");
    assert_eq!(b.sdo_upload(0x1F51, 1), Ok(vec![1]), "started");
    assert_eq!(b.sdo_upload(0x1F56, 0), Ok(vec![1]));
    assert_eq!(b.read_u32(0x1F56, 1), 0x8BAD_F00D);
    assert_eq!(b.sdo_upload(0x1F56, 1).unwrap().len(), 4, "U32");
    assert_eq!(b.sdo_upload(0x1F57, 1), Ok(vec![0, 0, 0, 0]));
    // Only the program control is writable.
    assert_eq!(b.sdo_write(0x1F56, 1, &[0; 4]), Err(READ_ONLY));
    assert_eq!(b.sdo_write(0x1F57, 1, &[0; 4]), Err(READ_ONLY));
    assert_eq!(
        b.sdo_upload(0x1F50, 1),
        Err(0x0602_0000),
        "the download is the loader's"
    );
    // Without a CRC given, 0x1F56 reads 0; a reset node keeps the image's CRC.
    assert_eq!(Bench::new().read_u32(0x1F56, 1), 0);
    b.nmt(0x81);
    b.take();
    assert_eq!(b.read_u32(0x1F56, 1), 0x8BAD_F00D);
}

#[test]
fn stop_in_pre_operational_answers_then_asks_for_the_loader() {
    let mut b = bench_with_crc(1);
    assert!(!b.device.loader_requested());
    assert_eq!(b.sdo_write(PROGRAM_CONTROL, 1, &[0]), Ok(()), "answered");
    assert!(b.device.loader_requested());
}

#[test]
fn start_is_already_done_and_clear_is_the_loaders() {
    let mut b = bench_with_crc(1);
    assert_eq!(b.sdo_write(PROGRAM_CONTROL, 1, &[1]), Ok(()));
    assert_eq!(b.sdo_write(PROGRAM_CONTROL, 1, &[3]), Err(DEVICE_STATE));
    for value in [2, 4, 0x7F, 0x81, 0xFF] {
        assert_eq!(
            b.sdo_write(PROGRAM_CONTROL, 1, &[value]),
            Err(INVALID_VALUE),
            "{value}"
        );
    }
    assert!(
        !b.device.loader_requested(),
        "nothing but stop enters the loader"
    );
    assert_eq!(
        b.sdo_write(PROGRAM_CONTROL, 1, &[0, 0]),
        Err(0x0607_0012),
        "a U8: too long"
    );
}

#[test]
fn confirm_ends_the_trial_boot_in_pre_operational() {
    let mut b = bench_with_crc(1);
    assert!(!b.device.start_confirmed());
    b.nmt(0x01);
    b.take();
    assert_eq!(
        b.sdo_write(PROGRAM_CONTROL, 1, &[0x80]),
        Err(DEVICE_STATE),
        "as every 0x1F51 write, only in Pre-operational"
    );
    assert!(!b.device.start_confirmed());
    b.nmt(0x80);
    assert_eq!(b.sdo_write(PROGRAM_CONTROL, 1, &[0x80]), Ok(()));
    assert!(b.device.start_confirmed());
    assert!(!b.device.loader_requested(), "and nothing else");
    assert_eq!(b.sdo_upload(0x1F51, 1), Ok(vec![1]), "still started");
}

#[test]
fn every_write_is_refused_outside_pre_operational() {
    let mut b = bench_with_crc(1);
    b.nmt(0x01);
    b.take();
    for value in [0, 1, 3] {
        assert_eq!(
            b.sdo_write(PROGRAM_CONTROL, 1, &[value]),
            Err(DEVICE_STATE),
            "{value}"
        );
    }
    // A value that means nothing is refused as such in any state.
    assert_eq!(b.sdo_write(PROGRAM_CONTROL, 1, &[2]), Err(INVALID_VALUE));
    assert!(!b.device.loader_requested());
    // Back in Pre-operational the stop goes through.
    b.nmt(0x80);
    assert_eq!(b.sdo_write(PROGRAM_CONTROL, 1, &[0]), Ok(()));
    assert!(b.device.loader_requested());
}

#[test]
fn stop_is_refused_while_the_feed_is_enabled() {
    // Operational with the feed on: refused, and the wheel keeps going.
    let mut b = Bench::operational_enabled(Axis::X, Multiplier::X1);
    assert_eq!(b.sdo_write(PROGRAM_CONTROL, 1, &[0]), Err(DEVICE_STATE));
    b.turn(2);
    assert_eq!(b.read_u32(0x6004, 0), 2);
    // Leaving Operational disables the feed: then the stop is accepted.
    b.nmt(0x80);
    assert_eq!(b.read_u32(0x2000, 0), 0);
    let mut b2 = bench_with_crc(1);
    // Pre-operational but the feed on (not reachable through the bus, since the feed only
    // starts in Operational; the check stands on its own): refused.
    b2.wheel.lock(|w| w.feed.set_enabled(true));
    assert_eq!(b2.sdo_write(PROGRAM_CONTROL, 1, &[0]), Err(DEVICE_STATE));
    assert!(!b2.device.loader_requested());
    b2.wheel.lock(|w| w.feed.set_enabled(false));
    assert_eq!(b2.sdo_write(PROGRAM_CONTROL, 1, &[0]), Ok(()));
    assert_eq!(b.sdo_write(PROGRAM_CONTROL, 1, &[0]), Ok(()));
    assert!(b.device.loader_requested());
}
