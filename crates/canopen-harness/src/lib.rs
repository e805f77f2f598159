//! The engine's frame-sequence harness: one body, [`frames`], shared by the cargo-fuzz
//! target (`crates/canopen-slave/fuzz`, nightly) and the seeded random loop of
//! `cargo xtask test` (the `random-frames` binary here, stable).
//!
//! It feeds a device arbitrary (time step, frame) sequences, with application activity
//! (PDO requests, errors raised and cleared, mapped data changing) driven by the same bytes,
//! and RPDO1 ([`RPDO`]) writing two objects, whose table ranges the application's `write`
//! asserts were checked;
//! an input of odd length starts with the second SDO server (0x1201) configured on
//! [`SDO2_RX`] / [`SDO2_TX`].
//! It asserts that nothing panics, that every frame the engine must ignore leaves it (and
//! the application) untouched and silent, that `poll` leaves no overdue work behind, and
//! that outgoing frames are well-formed. [`random_input`] makes inputs for the stable loop.

use canopen_slave::{
    standard_objects, Access, Application, CommDefaults, Config, DataType, Device, Frame,
    FrameSink, Identity, Instant, MemoryStorage, NmtState, NodeId, Od, OdEntry, RpdoDefaults,
    SdoAbort, SinkFull, TpdoDefaults, STANDARD_OBJECTS,
};

const NODE: u8 = 0x22;
/// The second SDO server's identifiers when a sequence configures it (free ones).
pub const SDO2_RX: u16 = 0x6A2;
/// See [`SDO2_RX`].
pub const SDO2_TX: u16 = 0x6B2;
/// RPDO1's default identifier.
pub const RPDO: u16 = 0x200 + NODE as u16;

const IDENTITY: Identity = Identity {
    device_type: 0x196,
    vendor_id: 1,
    product_code: 2,
    revision: 3,
    device_name: "fuzzed device name",
    hardware_version: "A",
    software_version: "0.0.1",
};

const DEFAULTS: CommDefaults = CommDefaults {
    heartbeat_ms: 50,
    heartbeat_consumers: [0x0001_0032, 0],
    emcy_inhibit_100us: 10,
    rpdo: [RpdoDefaults {
        cob_id_base: 0x200,
        transmission_type: 255,
        event_timer_ms: 30,
        mapping: &[0x2000_0008, 0x0005_0008, 0x2001_0010],
    }],
    tpdo: [
        TpdoDefaults {
            cob_id_base: 0x180,
            transmission_type: 254,
            inhibit_100us: 5,
            event_timer_ms: 20,
            mapping: &[0x6004_0020, 0x2000_0008],
        },
        TpdoDefaults {
            cob_id_base: 0x280,
            transmission_type: 1,
            inhibit_100us: 0,
            event_timer_ms: 0,
            mapping: &[0x2001_0010],
        },
    ],
};

static STANDARD: [OdEntry; STANDARD_OBJECTS] = standard_objects(&IDENTITY, &DEFAULTS);
static OBJECTS: [OdEntry; 4] = [
    OdEntry::app(0x2000, 0, DataType::U8, Access::Rw)
        .range(0, 1)
        .mappable(),
    OdEntry::app(0x2001, 0, DataType::I16, Access::Rw)
        .range(-500, 500)
        .mappable(),
    OdEntry::app(0x2002, 0, DataType::VisibleString, Access::Rw),
    OdEntry::app(0x6004, 0, DataType::I32, Access::Ro).mappable(),
];
static OD: Od = Od::checked(&[&STANDARD, &OBJECTS]);

#[derive(Clone, Default, PartialEq, Debug)]
struct App {
    flag: u8,
    level: i16,
    text: ([u8; 32], usize),
    position: i32,
    events: u32,
    rpdos: u32,
    rpdo_timeouts: u32,
}

impl Application for App {
    fn read(&mut self, index: u16, _sub: u8, buf: &mut [u8]) -> Result<usize, SdoAbort> {
        let (bytes, n): ([u8; 32], usize) = match index {
            0x2000 => ([self.flag; 32], 1),
            0x2001 => {
                let mut b = [0; 32];
                b[..2].copy_from_slice(&self.level.to_le_bytes());
                (b, 2)
            }
            0x2002 => self.text,
            _ => {
                let mut b = [0; 32];
                b[..4].copy_from_slice(&self.position.to_le_bytes());
                (b, 4)
            }
        };
        buf.get_mut(..n)
            .ok_or(SdoAbort::OutOfMemory)?
            .copy_from_slice(&bytes[..n]);
        Ok(n)
    }

    fn write(&mut self, index: u16, _sub: u8, data: &[u8]) -> Result<(), SdoAbort> {
        match (index, data) {
            (0x2000, [v]) => self.flag = *v,
            (0x2001, [a, b]) => self.level = i16::from_le_bytes([*a, *b]),
            (0x2002, d) => {
                self.text.0[..d.len()].copy_from_slice(d);
                self.text.1 = d.len();
            }
            _ => panic!("engine passed an unchecked write: {index:#x} {data:?}"),
        }
        Ok(())
    }

    fn on_tpdo_sent(&mut self, _pdo: u8) {
        self.events += 1;
    }

    fn on_rpdo(&mut self, _pdo: u8) {
        self.rpdos += 1;
    }

    fn on_rpdo_timeout(&mut self, _pdo: u8) {
        self.rpdo_timeouts += 1;
    }

    fn save_application(&self, buf: &mut [u8]) -> usize {
        buf[0] = self.flag;
        1
    }

    fn restore_application(&mut self, data: &[u8]) -> Result<(), (u16, u8)> {
        if let [flag] = *data {
            self.flag = flag;
        }
        Ok(())
    }
}

#[derive(Default)]
struct Sink(Vec<Frame>, usize);

impl FrameSink for Sink {
    fn send(&mut self, frame: Frame) -> Result<(), SinkFull> {
        // Refuse now and then, to exercise the retry paths.
        self.1 += 1;
        if self.1.is_multiple_of(13) {
            return Err(SinkFull);
        }
        self.0.push(frame);
        Ok(())
    }
}

/// `sync`: the SYNC identifier (0x1005, which a write may move, onto an identifier the
/// second SDO server may have had before); `sdo2`: the second SDO server's request
/// identifier while 0x1201 makes it valid; `rpdo`: RPDO1's while 0x1400:1 makes it valid.
fn must_ignore(id: u16, dlc: usize, sync: u16, sdo2: Option<u16>, rpdo: Option<u16>) -> bool {
    let sdo = id == 0x600 + u16::from(NODE) || Some(id) == sdo2;
    let known = id == 0 || id == sync || sdo || Some(id) == rpdo || (0x701..=0x77F).contains(&id);
    !known || (id == 0 && dlc != 2) || (sdo && dlc != 8)
}

/// COB-ID `index:sub`, read through the device's checked read path.
fn cob_id(dev: &mut Device<MemoryStorage>, app: &mut App, index: u16, sub: u8) -> u32 {
    let mut buf = [0; 4];
    dev.read(index, sub, &mut buf, app)
        .expect("a COB-ID of the dictionary");
    u32::from_le_bytes(buf)
}

/// The second SDO server's (request, reply) identifiers while 0x1201:1 and :2 are both
/// valid (bit 31 clear).
fn second_sdo(dev: &mut Device<MemoryStorage>, app: &mut App) -> Option<(u16, u16)> {
    let (rx, tx) = (cob_id(dev, app, 0x1201, 1), cob_id(dev, app, 0x1201, 2));
    ((rx | tx) & 0x8000_0000 == 0).then_some(((rx & 0x7FF) as u16, (tx & 0x7FF) as u16))
}

/// What one run of [`frames`] went through, to tell how deep a generator gets.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Outcome {
    /// Frames given to the device.
    pub frames: u32,
    /// Of those, frames received in Operational.
    pub operational: u32,
    /// Frames the device sent (accepted by the sink).
    pub sent: u32,
}

/// Runs one sequence: `input` is read as records of (time step in 0.5 ms, identifier
/// selector, identifier low byte, length and application action, data bytes); a record cut
/// short by the end of `input` keeps the bytes there are. Panics when an invariant does not
/// hold (see the crate documentation).
pub fn frames(input: &[u8]) -> Outcome {
    let mut outcome = Outcome::default();
    let node = NodeId::new(NODE).unwrap();
    let mut dev = Device::new(Config::new(node), OD, MemoryStorage::new());
    let mut app = App::default();
    let mut tx = Sink::default();
    let mut now = 0u64;
    dev.start(Instant::ZERO, &mut app, &mut tx);
    if input.len() % 2 == 1 {
        for (sub, id) in [(1, SDO2_RX), (2, SDO2_TX)] {
            let value = u32::from(id).to_le_bytes();
            dev.write(Instant::ZERO, 0x1201, sub, &value, &mut app)
                .expect("free identifiers");
        }
    }

    let mut bytes = input;
    while let [dt, sel, id_lo, len, rest @ ..] = bytes {
        now += u64::from(*dt) * 500;
        let id = match sel % 8 {
            0 => 0,
            1 => 0x80,
            2 | 3 => 0x600 + u16::from(NODE),
            4 => 0x700 + u16::from(*id_lo & 0x7F),
            5 => SDO2_RX,
            6 => RPDO,
            _ => (u16::from(*sel) << 8 | u16::from(*id_lo)) & 0x7FF,
        };
        let dlc = usize::from(*len % 9).min(rest.len());
        let (data, tail) = rest.split_at(dlc);
        bytes = tail;
        let frame = Frame::new(id, data).unwrap();
        let t = Instant::from_micros(now);

        // Application-side activity driven by the input too.
        match len >> 4 {
            1 => {
                let _ = dev.request_tpdo(1 + (len & 1));
            }
            2 => {
                let _ = dev.raise_error(0x1000 | u16::from(*id_lo), 0x80, [0; 5]);
            }
            3 => {
                dev.clear_error(0x1000 | u16::from(*id_lo));
            }
            4 => app.position = app.position.wrapping_add(i32::from(*dt)),
            _ => {}
        }

        tx.0.clear();
        outcome.frames += 1;
        if dev.nmt_state() == NmtState::Operational {
            outcome.operational += 1;
        }
        let sdo2 = second_sdo(&mut dev, &mut app);
        // Bit 31 means nothing to a SYNC consumer.
        let sync = (cob_id(&mut dev, &mut app, 0x1005, 0) & 0x7FF) as u16;
        let rpdo = cob_id(&mut dev, &mut app, 0x1400, 1);
        let rpdo = (rpdo & 0x8000_0000 == 0).then_some((rpdo & 0x7FF) as u16);
        if must_ignore(id, dlc, sync, sdo2.map(|(rx, _)| rx), rpdo) {
            let (dev_before, app_before) = (dev.clone(), app.clone());
            dev.on_frame(t, &frame, &mut app, &mut tx);
            assert_eq!(
                dev, dev_before,
                "ignored frame changed the device: {frame:?}"
            );
            assert_eq!(app, app_before, "ignored frame changed the application");
            assert!(tx.0.is_empty(), "ignored frame produced output");
        } else {
            dev.on_frame(t, &frame, &mut app, &mut tx);
        }
        dev.poll(t, &mut app, &mut tx);
        // poll leaves no overdue work behind (a refused frame is retried 1 ms later).
        if let Some(deadline) = dev.next_deadline() {
            assert!(deadline > t, "deadline {deadline:?} not after {t:?}");
        }
        // A reply of the second server may follow a write that gave 0x1201 up.
        let sdo2_tx = sdo2.or(second_sdo(&mut dev, &mut app)).map(|(_, tx)| tx);
        for f in &tx.0 {
            assert!(f.dlc() <= 8);
            let ours = [0x580 + u16::from(NODE), 0x80 + u16::from(NODE)];
            if ours.contains(&f.id()) || Some(f.id()) == sdo2_tx {
                assert_eq!(f.dlc(), 8);
            }
        }
        outcome.sent += tx.0.len() as u32;
    }
    outcome
}

/// A small, fast generator (xorshift64*) for the stable loop: reproducible from its seed.
#[derive(Clone, Debug)]
pub struct Rng(u64);

impl Rng {
    /// A generator for sequence `index` of the run seeded with `seed` (splitmix64 of the
    /// two, so that neighbouring indices give unrelated streams).
    pub fn for_sequence(seed: u64, index: u64) -> Self {
        let mut z = seed ^ index.wrapping_mul(0x9E37_79B9_7F4A_7C15);
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        // xorshift must not start at 0.
        Self(z | 1)
    }

    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        let mut x = self.0;
        x ^= x >> 12;
        x ^= x << 25;
        x ^= x >> 27;
        self.0 = x;
        x.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
}

/// Most records [`random_input`] makes.
pub const MAX_RECORDS: u64 = 40;

/// Objects a shaped SDO request names: the dictionary's, and one that is not there.
const INDICES: [u16; 24] = [
    0x1000, 0x1001, 0x1003, 0x1005, 0x1008, 0x1010, 0x1011, 0x1014, 0x1015, 0x1016, 0x1017, 0x1018,
    0x1201, 0x1400, 0x1600, 0x1800, 0x1801, 0x1A00, 0x1A01, 0x2000, 0x2001, 0x2002, 0x6004, 0x1234,
];

/// Values a shaped SDO download carries: signatures of 0x1010 / 0x1011, mapping entries,
/// COB-IDs (valid, invalid, clashing; the second SDO server's), heartbeat entries, and the
/// edges of the ranges.
const VALUES: [u32; 22] = [
    RPDO as u32,
    0x8000_0000 | RPDO as u32,
    0x0007_0020,
    SDO2_RX as u32,
    SDO2_TX as u32,
    0x8000_0000 | SDO2_RX as u32,
    0x6576_6173,
    0x6461_6F6C,
    0x6004_0020,
    0x2000_0008,
    0x2001_0010,
    0x2002_0008,
    0x8000_01A2,
    0x4000_01A2,
    0x0000_0080,
    0x0000_00A2,
    0x0000_0722,
    0x0001_0032,
    0x0022_0032,
    0,
    1,
    0xFFFF_FFFF,
];

/// SDO command bytes: expedited downloads of 1..4 bytes, a segmented download, an upload,
/// segments of either direction, block commands (not supported) and an abort.
const SDO_COMMANDS: [u8; 12] = [
    0x2F, 0x2B, 0x27, 0x23, 0x21, 0x40, 0x60, 0x70, 0x00, 0x10, 0xC0, 0x80,
];

impl Rng {
    /// A number below `n` (`n` > 0; the bias is negligible for small `n`).
    pub fn below(&mut self, n: u64) -> u64 {
        self.next_u64() % n
    }

    fn byte(&mut self) -> u8 {
        self.next_u64() as u8
    }

    fn pick<T: Copy>(&mut self, from: &[T]) -> T {
        from[self.below(from.len() as u64) as usize]
    }
}

/// Fills `buf` with one random input for [`frames`]: up to [`MAX_RECORDS`] records. Half
/// of them are shaped so that a random loop gets past the first checks as a coverage-guided
/// fuzzer would: NMT commands to this node or all nodes, SDO requests for the dictionary's
/// objects with meaningful values, heartbeats with valid states; the rest are random bytes.
pub fn random_input(rng: &mut Rng, buf: &mut Vec<u8>) {
    buf.clear();
    for _ in 0..rng.below(MAX_RECORDS + 1) {
        // Mostly short time steps, so that timers run but do not always expire.
        let dt = if rng.below(4) == 0 {
            rng.byte()
        } else {
            rng.byte() % 8
        };
        let sel = rng.byte();
        let id_lo = rng.byte();
        let mut data = [0u8; 8];
        for d in &mut data {
            *d = rng.byte();
        }
        let mut dlc = rng.below(9) as u8;
        if rng.below(2) == 0 {
            match sel % 8 {
                0 => {
                    let cs = rng.pick(&[0x01, 0x02, 0x80, 0x81, 0x82]);
                    data[..2].copy_from_slice(&[cs, rng.pick(&[0, NODE])]);
                    dlc = 2;
                }
                1 => dlc = rng.below(2) as u8,
                2 | 3 | 5 => {
                    let [i0, i1] = rng.pick(&INDICES).to_le_bytes();
                    let sub = rng.below(10) as u8;
                    data[..4].copy_from_slice(&[rng.pick(&SDO_COMMANDS), i0, i1, sub]);
                    if rng.below(2) == 0 {
                        data[4..].copy_from_slice(&rng.pick(&VALUES).to_le_bytes());
                    }
                    dlc = 8;
                }
                4 => {
                    data[0] = rng.pick(&[0x00, 0x04, 0x05, 0x7F]);
                    dlc = 1;
                }
                // RPDO1: its mapped length or around it, values in and out of range.
                6 => {
                    data[0] = rng.below(3) as u8;
                    dlc = rng.pick(&[3, 4, 4, 4, 5, 8]);
                }
                _ => {}
            }
        }
        // The length byte carries the application action (high nibble) and the DLC (the
        // byte modulo 9); find the byte that has both.
        let action = rng.below(16) as u8;
        let len = (0..16)
            .map(|k| action * 16 + k)
            .find(|b| b % 9 == dlc)
            .unwrap_or(dlc);
        buf.extend_from_slice(&[dt, sel, id_lo, len]);
        buf.extend_from_slice(&data[..usize::from(dlc)]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn random_sequences_keep_the_invariants() {
        let mut input = Vec::new();
        for i in 0..2_000 {
            random_input(&mut Rng::for_sequence(1, i), &mut input);
            let outcome = frames(&input);
            assert!(outcome.frames > 0 || input.is_empty());
        }
    }

    #[test]
    fn inputs_are_reproducible_from_seed_and_index() {
        let (mut a, mut b) = (Vec::new(), Vec::new());
        random_input(&mut Rng::for_sequence(7, 3), &mut a);
        random_input(&mut Rng::for_sequence(7, 3), &mut b);
        assert_eq!(a, b);
        random_input(&mut Rng::for_sequence(7, 4), &mut b);
        assert_ne!(a, b);
    }
}
