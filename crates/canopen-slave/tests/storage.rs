//! Store (0x1010) and restore (0x1011) through the in-memory storage.
mod common;
use canopen_slave::MemoryStorage;
use common::*;

const SAVE: u32 = 0x6576_6173;
const LOAD: u32 = 0x6461_6F6C;

/// Changes a handful of parameters and application values away from their defaults.
fn customise(b: &mut Bench) {
    b.download(0x1017, 0, &250u16.to_le_bytes()).unwrap();
    b.download_u32(0x1016, 1, 0x0007_0064).unwrap();
    b.download(0x1800, 5, &50u16.to_le_bytes()).unwrap();
    b.download(0x1015, 0, &7u16.to_le_bytes()).unwrap();
    b.download_u32(0x1801, 1, 0x8000_0285).unwrap();
    b.download(0x1A01, 0, &[0]).unwrap();
    b.download_u32(0x1A01, 1, 0x6004_0020).unwrap();
    b.download(0x1A01, 0, &[1]).unwrap();
    b.download(0x2000, 0, &[1]).unwrap();
    b.download(0x2100, 5, &[9]).unwrap();
}

/// NMT reset node / communication; the boot-up must be the only frame.
fn reset(b: &mut Bench, cmd: u8) {
    b.nmt(cmd, NODE);
    assert_eq!(b.take(), vec![frame(HB, &[0])]);
}

fn assert_customised(b: &mut Bench) {
    assert_eq!(b.upload_u32(0x1017, 0), 250);
    assert_eq!(b.upload_u32(0x1016, 1), 0x0007_0064);
    assert_eq!(b.upload_u32(0x1800, 5), 50);
    assert_eq!(b.upload_u32(0x1015, 0), 7);
    assert_eq!(b.upload_u32(0x1801, 1), 0xC000_0285);
    assert_eq!(b.upload_u32(0x1A01, 0), 1);
    assert_eq!(b.upload_u32(0x1A01, 1), 0x6004_0020);
}

fn assert_defaults(b: &mut Bench) {
    assert_eq!(b.upload_u32(0x1017, 0), 1000);
    assert_eq!(b.upload_u32(0x1016, 1), 0);
    assert_eq!(b.upload_u32(0x1800, 5), 100);
    assert_eq!(b.upload_u32(0x1015, 0), 0);
    assert_eq!(b.upload_u32(0x1801, 1), 0x4000_0285);
    assert_eq!(b.upload_u32(0x1A01, 1), 0x6005_0008);
}

#[test]
fn capabilities_and_signature_checks() {
    let mut b = Bench::new();
    assert_eq!(b.upload_u32(0x1010, 0), 3);
    assert_eq!(b.upload_u32(0x1011, 0), 3);
    for sub in 1..=3 {
        assert_eq!(b.upload_u32(0x1010, sub), 1);
        assert_eq!(b.upload_u32(0x1011, sub), 1);
        assert_eq!(b.download_u32(0x1010, sub, LOAD), Err(0x0800_0020));
        assert_eq!(b.download_u32(0x1011, sub, SAVE), Err(0x0800_0020));
    }
    assert_eq!(b.download_u32(0x1010, 4, SAVE), Err(0x0609_0011));
    assert_eq!(b.dev.storage().writes(), 0);
}

#[test]
fn store_all_then_reset_and_power_cycle() {
    let mut b = Bench::new();
    customise(&mut b);
    b.download_u32(0x1010, 1, SAVE).unwrap();
    assert_eq!(b.dev.storage().writes(), 1);
    // Changes after the store are lost at the next reset.
    b.download(0x1017, 0, &300u16.to_le_bytes()).unwrap();
    reset(&mut b, 0x82);
    assert_customised(&mut b);
    assert!(
        b.app.restored.is_empty(),
        "reset communication leaves the application"
    );
    reset(&mut b, 0x81);
    assert_eq!(b.app.restored, vec![vec![1, 9]]);
    assert_eq!(b.app.flag, 1);
    // Power cycle: a new device on the same storage.
    let storage = b.dev.storage().clone();
    let mut b = Bench::with_storage(storage);
    assert_customised(&mut b);
    assert_eq!(b.app.restored, vec![vec![1, 9]]);
    assert_eq!((b.app.flag, b.app.vars[5]), (1, 9));
    // The stored heartbeat time rules from the boot-up on.
    assert_eq!(b.dev.next_deadline(), Some(ms(250)));
}

#[test]
fn restore_defaults_takes_effect_at_the_next_reset() {
    let mut b = Bench::new();
    customise(&mut b);
    b.download_u32(0x1010, 1, SAVE).unwrap();
    b.download_u32(0x1011, 1, LOAD).unwrap();
    assert_eq!(b.dev.storage().bytes(), b"", "storage erased");
    assert_customised(&mut b);
    reset(&mut b, 0x81);
    assert_defaults(&mut b);
    assert!(b.app.restored.is_empty());
}

#[test]
fn sections_are_stored_and_restored_separately() {
    let mut b = Bench::new();
    customise(&mut b);
    // Application only: communication stays default after a reset.
    b.download_u32(0x1010, 3, SAVE).unwrap();
    reset(&mut b, 0x81);
    assert_defaults(&mut b);
    assert_eq!(b.app.restored, vec![vec![1, 9]]);
    // Communication only, keeping the application section.
    customise(&mut b);
    b.app.flag = 0;
    b.download_u32(0x1010, 2, SAVE).unwrap();
    reset(&mut b, 0x81);
    assert_customised(&mut b);
    assert_eq!(b.app.restored.last(), Some(&vec![1, 9]));
    // Restore communication defaults: the application section survives.
    b.download_u32(0x1011, 2, LOAD).unwrap();
    reset(&mut b, 0x81);
    assert_defaults(&mut b);
    assert_eq!(b.app.restored.len(), 3);
    // Restore application defaults: nothing left, storage erased.
    b.download_u32(0x1011, 3, LOAD).unwrap();
    assert_eq!(b.dev.storage().bytes(), b"");
    reset(&mut b, 0x81);
    assert_eq!(b.app.restored.len(), 3);
}

#[test]
fn corrupt_blob_falls_back_to_defaults() {
    let mut b = Bench::new();
    customise(&mut b);
    b.download_u32(0x1010, 1, SAVE).unwrap();
    let good = b.dev.storage().clone();
    for i in 0..good.bytes().len() {
        let mut bad = good.clone();
        bad.bytes_mut()[i] ^= 0x40;
        let mut b = Bench::with_storage(bad);
        assert_defaults(&mut b);
        assert!(b.app.restored.is_empty(), "byte {i}");
    }
    // Truncated blobs too.
    let mut short = MemoryStorage::new();
    use canopen_slave::Storage;
    short
        .store(ms(0), &good.bytes()[..good.bytes().len() - 1])
        .unwrap();
    let mut b = Bench::with_storage(short);
    assert_defaults(&mut b);
}

#[test]
fn store_fails_cleanly_when_the_medium_fails() {
    struct Broken;
    impl canopen_slave::Storage for Broken {
        fn load(&mut self, _buf: &mut [u8]) -> usize {
            0
        }
        fn store(
            &mut self,
            _now: canopen_slave::Instant,
            _blob: &[u8],
        ) -> Result<(), canopen_slave::StorageError> {
            Err(canopen_slave::StorageError::WriteFailed)
        }
    }
    let od = OD;
    let mut dev = canopen_slave::Device::new(
        canopen_slave::Config::new(canopen_slave::NodeId::new(NODE).unwrap()),
        od,
        Broken,
    );
    let mut app = TestApp::default();
    let mut tx = Sink::default();
    dev.start(ms(0), &mut app, &mut tx);
    tx.frames.clear();
    dev.on_frame(
        ms(0),
        &frame(SDO_RX, &req(0x23, 0x1010, 1, SAVE.to_le_bytes())),
        &mut app,
        &mut tx,
    );
    assert_eq!(
        tx.frames,
        vec![frame(SDO_TX, &abort(0x1010, 1, 0x0606_0000))]
    );
}

/// A storage that takes nothing, with a fixed error, and records when it was asked.
struct Refusing {
    error: canopen_slave::StorageError,
    asked: Vec<canopen_slave::Instant>,
}

impl canopen_slave::Storage for Refusing {
    fn load(&mut self, _buf: &mut [u8]) -> usize {
        0
    }
    fn store(
        &mut self,
        now: canopen_slave::Instant,
        _blob: &[u8],
    ) -> Result<(), canopen_slave::StorageError> {
        self.asked.push(now);
        Err(self.error)
    }
    fn store_node(
        &mut self,
        now: canopen_slave::Instant,
        _: u8,
        _: u8,
    ) -> Result<(), canopen_slave::StorageError> {
        self.asked.push(now);
        Err(self.error)
    }
}

fn device_on(storage: Refusing) -> (canopen_slave::Device<Refusing>, TestApp, Sink) {
    let node = canopen_slave::NodeId::new(NODE).unwrap();
    let mut dev = canopen_slave::Device::new(canopen_slave::Config::new(node), OD, storage);
    let mut app = TestApp::default();
    let mut tx = Sink::default();
    dev.start(ms(0), &mut app, &mut tx);
    tx.frames.clear();
    (dev, app, tx)
}

#[test]
fn a_spent_wear_budget_aborts_with_0x08000020_and_lss_error_255_1() {
    let (mut dev, mut app, mut tx) = device_on(Refusing {
        error: canopen_slave::StorageError::WearLimit,
        asked: Vec::new(),
    });
    for (index, signature) in [(0x1010, SAVE), (0x1011, LOAD)] {
        dev.on_frame(
            ms(7),
            &frame(SDO_RX, &req(0x23, index, 1, signature.to_le_bytes())),
            &mut app,
            &mut tx,
        );
        assert_eq!(
            tx.frames,
            vec![frame(SDO_TX, &abort(index, 1, 0x0800_0020))]
        );
        tx.frames.clear();
    }
    // LSS: configuration state, then store configuration.
    dev.on_frame(
        ms(8),
        &frame(0x7E5, &[0x04, 1, 0, 0, 0, 0, 0, 0]),
        &mut app,
        &mut tx,
    );
    dev.on_frame(
        ms(9),
        &frame(0x7E5, &[0x17, 0, 0, 0, 0, 0, 0, 0]),
        &mut app,
        &mut tx,
    );
    assert_eq!(
        tx.frames,
        vec![frame(0x7E4, &[0x17, 255, 1, 0, 0, 0, 0, 0])]
    );
    // The storage was told the time of each request (its budget runs on it).
    assert_eq!(dev.storage().asked, vec![ms(7), ms(7), ms(9)]);
}

#[test]
fn stores_the_application_forbids_are_refused_with_0x08000022_and_write_nothing() {
    let mut b = Bench::new();
    customise(&mut b);
    b.app.store_refused = true;
    for sub in 1..=3 {
        assert_eq!(b.download_u32(0x1010, sub, SAVE), Err(0x0800_0022));
        assert_eq!(b.download_u32(0x1011, sub, LOAD), Err(0x0800_0022));
    }
    // A wrong signature is still a wrong signature: 0x08000020 before the device state.
    assert_eq!(b.download_u32(0x1010, 1, LOAD), Err(0x0800_0020));
    assert_eq!(b.dev.storage().writes(), 0);
    // LSS store configuration: error 255, spec 2; nothing stored.
    b.rx(frame(0x7E5, &[0x04, 1, 0, 0, 0, 0, 0, 0]));
    b.rx(frame(0x7E5, &[0x17, 0, 0, 0, 0, 0, 0, 0]));
    assert_eq!(b.take(), vec![frame(0x7E4, &[0x17, 255, 2, 0, 0, 0, 0, 0])]);
    assert_eq!(b.dev.storage().node(), None);
    // Other LSS services go on as before.
    b.rx(frame(0x7E5, &[0x5E, 0, 0, 0, 0, 0, 0, 0]));
    assert_eq!(
        b.take(),
        vec![frame(0x7E4, &[0x5E, NODE, 0, 0, 0, 0, 0, 0])]
    );
    // Allowed again: both go through.
    b.app.store_refused = false;
    b.download_u32(0x1010, 1, SAVE).unwrap();
    b.rx(frame(0x7E5, &[0x17, 0, 0, 0, 0, 0, 0, 0]));
    assert_eq!(b.take(), vec![frame(0x7E4, &[0x17, 0, 0, 0, 0, 0, 0, 0])]);
    assert_eq!(b.dev.storage().writes(), 1);
    assert_eq!(b.dev.storage().node(), Some((NODE, 0)));
    reset(&mut b, 0x81);
    assert_customised(&mut b);
}
