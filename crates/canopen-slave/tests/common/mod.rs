//! Shared test bench: a small application, its object dictionary and frame helpers.
#![allow(dead_code)]

use canopen_slave::{
    standard_objects, Access, Application, CommDefaults, Config, DataType, Device, Frame,
    FrameSink, Identity, Instant, MemoryStorage, NmtState, NodeId, Od, OdEntry, RpdoDefaults,
    SdoAbort, SinkFull, TpdoDefaults, STANDARD_OBJECTS,
};

pub const NODE: u8 = 5;
pub const SDO_RX: u16 = 0x600 + NODE as u16;
pub const SDO_TX: u16 = 0x580 + NODE as u16;
pub const HB: u16 = 0x700 + NODE as u16;
pub const EMCY: u16 = 0x080 + NODE as u16;
pub const TPDO1: u16 = 0x180 + NODE as u16;
pub const RPDO1: u16 = 0x200 + NODE as u16;
pub const TPDO2: u16 = 0x280 + NODE as u16;
/// The second SDO server's identifiers (0x1201:1 and :2) the tests configure: free ones
/// (0x680..0x6DF is outside CiA 301's restricted ranges).
pub const SDO2_RX: u16 = 0x680 + NODE as u16;
pub const SDO2_TX: u16 = 0x6A0 + NODE as u16;

pub const IDENTITY: Identity = Identity {
    device_type: 0x0002_0196,
    vendor_id: 0x0000_0123,
    product_code: 0x0000_4711,
    revision: 0x0001_0002,
    device_name: "Test handwheel MPG",
    hardware_version: "HW rev B",
    software_version: "1.2.3",
};

pub const DEFAULTS: CommDefaults = CommDefaults {
    heartbeat_ms: 1000,
    heartbeat_consumers: [0, 0],
    emcy_inhibit_100us: 0,
    // Predefined: 0x200 + node-ID, acting at once, no deadline monitoring; 0x6200:1.
    rpdo: [RpdoDefaults {
        mapping: &[0x6200_0108],
        ..RpdoDefaults::predefined(1)
    }],
    tpdo: [
        TpdoDefaults {
            cob_id_base: 0x180,
            transmission_type: 254,
            inhibit_100us: 20,
            event_timer_ms: 100,
            mapping: &[0x6004_0020, 0x2100_0420],
        },
        TpdoDefaults {
            cob_id_base: 0x280,
            transmission_type: 254,
            inhibit_100us: 20,
            event_timer_ms: 0,
            mapping: &[0x6005_0008],
        },
    ],
};

pub static STANDARD: [OdEntry; STANDARD_OBJECTS] = standard_objects(&IDENTITY, &DEFAULTS);

pub static APP_OBJECTS: [OdEntry; 21] = [
    OdEntry::app(0x2000, 0, DataType::U8, Access::Rw).range(0, 1),
    OdEntry::app(0x2001, 0, DataType::U16, Access::Wo),
    OdEntry::highest_sub(0x2100, 7),
    OdEntry::app(0x2100, 1, DataType::Boolean, Access::Rw),
    OdEntry::app(0x2100, 2, DataType::I8, Access::Rw),
    OdEntry::app(0x2100, 3, DataType::I16, Access::Rw).range(-100, 100),
    OdEntry::app(0x2100, 4, DataType::I32, Access::Rw).mappable(),
    OdEntry::app(0x2100, 5, DataType::U8, Access::Rw),
    OdEntry::app(0x2100, 6, DataType::U16, Access::Rw),
    OdEntry::app(0x2100, 7, DataType::U32, Access::Rw).range(10, 1000),
    OdEntry::app(0x2200, 0, DataType::VisibleString, Access::Rw),
    OdEntry::app(0x2300, 0, DataType::U8, Access::Rw),
    OdEntry::app(0x6004, 0, DataType::I32, Access::Ro).mappable(),
    OdEntry::app(0x6005, 0, DataType::U8, Access::Ro).mappable(),
    OdEntry::app(0x6006, 0, DataType::U16, Access::Ro),
    // RPDO targets: outputs, a ranged level, a write-only word, one the application refuses
    // 0xEE for (0x08000022), and one that is not mappable.
    OdEntry::highest_sub(0x6200, 1),
    OdEntry::app(0x6200, 1, DataType::U8, Access::Rw).mappable(),
    OdEntry::app(0x6201, 0, DataType::I16, Access::Rw)
        .range(-100, 100)
        .mappable(),
    OdEntry::app(0x6202, 0, DataType::U32, Access::Wo).mappable(),
    OdEntry::app(0x6203, 0, DataType::U8, Access::Rw).mappable(),
    OdEntry::app(0x6204, 0, DataType::U8, Access::Rw),
];

pub static OD: Od = Od::checked(&[&STANDARD, &APP_OBJECTS]);

/// The application of the tests: plain fields behind the objects, plus a log of hooks.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TestApp {
    pub flag: u8,
    pub write_only: u16,
    pub vars: [u32; 8],
    pub text: Vec<u8>,
    /// 0x2300: the application refuses writes of 7 with 0x08000022.
    pub guarded: u8,
    pub position: i32,
    /// Makes reads of 0x6004 fail, as a sensor fault would.
    pub position_fault: bool,
    /// What TPDO1 carries for 0x6004 instead of `position` (a held state), if set.
    pub held_position: Option<i32>,
    pub buttons: u8,
    pub states: Vec<NmtState>,
    pub lost: Vec<u8>,
    /// Calls of `on_heartbeat_restored`.
    pub restored_heartbeats: u32,
    pub resets: u32,
    pub tpdo_sent: Vec<u8>,
    /// TPDOs the application withdraws when they are about to go out.
    pub withdraw: Vec<u8>,
    pub restored: Vec<Vec<u8>>,
    /// `may_store` answers false: 0x1010, 0x1011 and LSS store are refused.
    pub store_refused: bool,
    /// 0x6200:1, 0x6201, 0x6202, 0x6203, 0x6204.
    pub outputs: u8,
    pub level: i16,
    pub word: u32,
    pub refusing: u8,
    pub plain: u8,
    /// Every write of an object 0x62xx, in order: (index, sub, bytes).
    pub writes: Vec<(u16, u8, Vec<u8>)>,
    /// Calls of `on_rpdo` and `on_rpdo_timeout`.
    pub rpdos: Vec<u8>,
    pub rpdo_timeouts: Vec<u8>,
}

impl Application for TestApp {
    fn read(&mut self, index: u16, sub: u8, buf: &mut [u8]) -> Result<usize, SdoAbort> {
        let bytes: Vec<u8> = match (index, sub) {
            (0x2000, 0) => vec![self.flag],
            (0x2001, 0) => return Err(SdoAbort::WriteOnly),
            (0x2100, 1 | 2 | 5) => vec![self.vars[sub as usize] as u8],
            (0x2100, 3 | 6) => (self.vars[sub as usize] as u16).to_le_bytes().to_vec(),
            (0x2100, 4 | 7) => self.vars[sub as usize].to_le_bytes().to_vec(),
            (0x2200, 0) => self.text.clone(),
            (0x2300, 0) => vec![self.guarded],
            (0x6004, 0) if self.position_fault => return Err(SdoAbort::Hardware),
            (0x6004, 0) => self.position.to_le_bytes().to_vec(),
            (0x6005, 0) => vec![self.buttons],
            (0x6006, 0) => vec![0x34, 0x12],
            (0x6200, 1) => vec![self.outputs],
            (0x6201, 0) => self.level.to_le_bytes().to_vec(),
            (0x6203, 0) => vec![self.refusing],
            (0x6204, 0) => vec![self.plain],
            _ => return Err(SdoAbort::NoObject),
        };
        buf.get_mut(..bytes.len())
            .ok_or(SdoAbort::OutOfMemory)?
            .copy_from_slice(&bytes);
        Ok(bytes.len())
    }

    fn write(&mut self, index: u16, sub: u8, data: &[u8]) -> Result<(), SdoAbort> {
        let mut raw = [0u8; 4];
        raw[..data.len().min(4)].copy_from_slice(&data[..data.len().min(4)]);
        let v = u32::from_le_bytes(raw);
        if index & 0xFF00 == 0x6200 {
            self.check_write(index, sub, data)?;
            self.writes.push((index, sub, data.to_vec()));
        }
        match (index, sub) {
            (0x2000, 0) => self.flag = v as u8,
            (0x2001, 0) => self.write_only = v as u16,
            (0x2100, s) => self.vars[s as usize] = v,
            (0x2200, 0) => self.text = data.to_vec(),
            (0x2300, 0) if v == 7 => return Err(SdoAbort::DeviceState),
            (0x2300, 0) => self.guarded = v as u8,
            (0x6200, 1) => self.outputs = v as u8,
            (0x6201, 0) => self.level = v as i16,
            (0x6202, 0) => self.word = v,
            (0x6203, 0) => self.refusing = v as u8,
            (0x6204, 0) => self.plain = v as u8,
            _ => return Err(SdoAbort::NoObject),
        }
        Ok(())
    }

    fn check_write(&mut self, index: u16, _sub: u8, data: &[u8]) -> Result<(), SdoAbort> {
        match (index, data) {
            (0x6203, [0xEE]) => Err(SdoAbort::DeviceState),
            _ => Ok(()),
        }
    }

    fn on_rpdo(&mut self, pdo: u8) {
        self.rpdos.push(pdo);
    }

    fn on_rpdo_timeout(&mut self, pdo: u8) {
        self.rpdo_timeouts.push(pdo);
    }

    fn on_nmt_state(&mut self, state: NmtState) {
        self.states.push(state);
    }

    fn on_heartbeat_lost(&mut self, node_id: u8) {
        self.lost.push(node_id);
    }

    fn on_heartbeat_restored(&mut self) {
        self.restored_heartbeats += 1;
    }

    fn on_reset_application(&mut self) {
        self.resets += 1;
        self.flag = 0;
    }

    fn tpdo_ready(&mut self, pdo: u8) -> bool {
        !self.withdraw.contains(&pdo)
    }

    fn read_for_tpdo(
        &mut self,
        pdo: u8,
        index: u16,
        sub: u8,
        buf: &mut [u8],
    ) -> Result<usize, SdoAbort> {
        match (pdo, index, sub, self.held_position) {
            (1, 0x6004, 0, Some(held)) => {
                buf[..4].copy_from_slice(&held.to_le_bytes());
                Ok(4)
            }
            _ => self.read(index, sub, buf),
        }
    }

    fn on_tpdo_sent(&mut self, pdo: u8) {
        self.tpdo_sent.push(pdo);
    }

    fn save_application(&self, buf: &mut [u8]) -> usize {
        buf[0] = self.flag;
        buf[1] = self.vars[5] as u8;
        2
    }

    fn restore_application(&mut self, data: &[u8]) -> Result<(), (u16, u8)> {
        self.restored.push(data.to_vec());
        if let [flag, v5] = *data {
            self.flag = flag;
            self.vars[5] = v5.into();
        }
        Ok(())
    }

    fn may_store(&mut self) -> bool {
        !self.store_refused
    }
}

/// A sink that records frames with the time they were sent; optionally limited.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Sink {
    pub frames: Vec<Frame>,
    pub capacity: Option<usize>,
}

impl FrameSink for Sink {
    fn send(&mut self, frame: Frame) -> Result<(), SinkFull> {
        if self.capacity.is_some_and(|c| self.frames.len() >= c) {
            return Err(SinkFull);
        }
        self.frames.push(frame);
        Ok(())
    }
}

pub fn frame(id: u16, data: &[u8]) -> Frame {
    Frame::new(id, data).unwrap()
}

pub fn ms(t: u64) -> Instant {
    Instant::from_millis(t)
}

pub fn abort(index: u16, sub: u8, code: u32) -> [u8; 8] {
    let [i0, i1] = index.to_le_bytes();
    let [c0, c1, c2, c3] = code.to_le_bytes();
    [0x80, i0, i1, sub, c0, c1, c2, c3]
}

pub fn req(cmd: u8, index: u16, sub: u8, data: [u8; 4]) -> [u8; 8] {
    let [i0, i1] = index.to_le_bytes();
    [cmd, i0, i1, sub, data[0], data[1], data[2], data[3]]
}

/// A device plus everything around it, with the time of the last call.
pub struct Bench {
    pub dev: Device<MemoryStorage>,
    pub app: TestApp,
    pub tx: Sink,
    pub now: Instant,
    /// The (request, reply) identifiers [`Bench::sdo`] and the transfers built on it use:
    /// the default server's unless a test picks the second one.
    pub sdo_ids: (u16, u16),
}

impl Bench {
    /// Not started.
    pub fn new_unstarted(storage: MemoryStorage) -> Self {
        let mut config = Config::new(NodeId::new(NODE).unwrap());
        config.serial_number = 0xDEAD_BEEF;
        config.sdo_timeout_ms = 1000;
        Self {
            dev: Device::new(config, OD, storage),
            app: TestApp::default(),
            tx: Sink::default(),
            now: Instant::ZERO,
            sdo_ids: (SDO_RX, SDO_TX),
        }
    }

    /// Started at t = 0, in Pre-operational, sent frames cleared.
    pub fn new() -> Self {
        Self::with_storage(MemoryStorage::new())
    }

    pub fn with_storage(storage: MemoryStorage) -> Self {
        let mut b = Self::new_unstarted(storage);
        b.dev.start(Instant::ZERO, &mut b.app, &mut b.tx);
        b.tx.frames.clear();
        b
    }

    /// Started, then put in Operational at t = 0 with the frames of that cleared.
    pub fn operational() -> Self {
        let mut b = Self::new();
        b.nmt(0x01, NODE);
        b.take();
        b
    }

    pub fn take(&mut self) -> Vec<Frame> {
        std::mem::take(&mut self.tx.frames)
    }

    pub fn rx(&mut self, f: Frame) {
        self.dev.on_frame(self.now, &f, &mut self.app, &mut self.tx);
    }

    pub fn rx_at(&mut self, t: Instant, f: Frame) {
        self.now = t;
        self.rx(f);
    }

    pub fn poll_at(&mut self, t: Instant) {
        self.now = t;
        self.dev.poll(t, &mut self.app, &mut self.tx);
    }

    /// Polls every millisecond from the current time to `until` (inclusive), returning
    /// every frame sent with the time it was sent.
    pub fn run_until(&mut self, until: Instant) -> Vec<(u64, Frame)> {
        let mut out = Vec::new();
        let mut t = self.now.as_micros();
        while t <= until.as_micros() {
            self.poll_at(Instant::from_micros(t));
            for f in self.take() {
                out.push((t / 1000, f));
            }
            t += 1000;
        }
        out
    }

    pub fn nmt(&mut self, cmd: u8, node: u8) {
        self.rx(frame(0, &[cmd, node]));
    }

    /// One SDO request on [`Bench::sdo_ids`]; returns the reply payload (None if there was
    /// no reply).
    pub fn sdo(&mut self, request: [u8; 8]) -> Option<[u8; 8]> {
        let (rx, tx) = self.sdo_ids;
        self.rx(frame(rx, &request));
        let frames = self.take();
        assert!(frames.len() <= 1, "more than one reply: {frames:?}");
        frames.first().map(|f| {
            assert_eq!(f.id(), tx);
            assert_eq!(f.dlc(), 8, "SDO replies have DLC 8");
            *f.raw_data()
        })
    }

    /// Full upload (expedited or segmented); Err is the abort code.
    pub fn upload(&mut self, index: u16, sub: u8) -> Result<Vec<u8>, u32> {
        let r = self.sdo(req(0x40, index, sub, [0; 4])).expect("reply");
        let [i0, i1] = index.to_le_bytes();
        assert_eq!(&r[1..4], &[i0, i1, sub], "multiplexer echoed");
        match r[0] {
            0x80 => Err(u32::from_le_bytes([r[4], r[5], r[6], r[7]])),
            0x41 => {
                let size = u32::from_le_bytes([r[4], r[5], r[6], r[7]]) as usize;
                let mut data = Vec::new();
                let mut toggle = 0u8;
                loop {
                    let s = self
                        .sdo([0x60 | toggle, 0, 0, 0, 0, 0, 0, 0])
                        .expect("segment");
                    if s[0] == 0x80 {
                        return Err(u32::from_le_bytes([s[4], s[5], s[6], s[7]]));
                    }
                    assert_eq!(s[0] & 0x10, toggle, "toggle echoed");
                    let n = 7 - ((s[0] >> 1) & 7) as usize;
                    data.extend_from_slice(&s[1..1 + n]);
                    toggle ^= 0x10;
                    if s[0] & 1 != 0 {
                        break;
                    }
                }
                assert_eq!(data.len(), size);
                Ok(data)
            }
            cmd if cmd & 0xF3 == 0x43 => {
                let n = 4 - ((cmd >> 2) & 3) as usize;
                Ok(r[4..4 + n].to_vec())
            }
            other => panic!("unexpected upload reply {other:#x}"),
        }
    }

    pub fn upload_u32(&mut self, index: u16, sub: u8) -> u32 {
        let d = self.upload(index, sub).expect("upload");
        let mut raw = [0u8; 4];
        raw[..d.len()].copy_from_slice(&d);
        u32::from_le_bytes(raw)
    }

    /// Expedited download of 1..=4 bytes; Err is the abort code.
    pub fn download(&mut self, index: u16, sub: u8, data: &[u8]) -> Result<(), u32> {
        assert!((1..=4).contains(&data.len()));
        let cmd = 0x23 | ((4 - data.len() as u8) << 2);
        let mut d = [0u8; 4];
        d[..data.len()].copy_from_slice(data);
        let r = self.sdo(req(cmd, index, sub, d)).expect("reply");
        let [i0, i1] = index.to_le_bytes();
        assert_eq!(&r[1..4], &[i0, i1, sub], "multiplexer echoed");
        match r[0] {
            0x60 => {
                assert_eq!(&r[4..], &[0, 0, 0, 0]);
                Ok(())
            }
            0x80 => Err(u32::from_le_bytes([r[4], r[5], r[6], r[7]])),
            other => panic!("unexpected download reply {other:#x}"),
        }
    }

    pub fn download_u32(&mut self, index: u16, sub: u8, v: u32) -> Result<(), u32> {
        self.download(index, sub, &v.to_le_bytes())
    }

    /// Segmented download of `data` with the size indicated; Err is the abort code.
    pub fn download_segmented(&mut self, index: u16, sub: u8, data: &[u8]) -> Result<(), u32> {
        let size = (data.len() as u32).to_le_bytes();
        let r = self.sdo(req(0x21, index, sub, size)).expect("reply");
        let code = |r: [u8; 8]| u32::from_le_bytes([r[4], r[5], r[6], r[7]]);
        if r[0] == 0x80 {
            return Err(code(r));
        }
        assert_eq!(r, req(0x60, index, sub, [0; 4]));
        let mut toggle = 0u8;
        let mut chunks = data.chunks(7).peekable();
        loop {
            let chunk = chunks.next().unwrap_or(&[]);
            let last = chunks.peek().is_none();
            let mut seg = [0u8; 8];
            seg[0] = toggle | ((7 - chunk.len() as u8) << 1) | u8::from(last);
            seg[1..1 + chunk.len()].copy_from_slice(chunk);
            let r = self.sdo(seg).expect("segment reply");
            if r[0] == 0x80 {
                return Err(code(r));
            }
            assert_eq!(r, [0x20 | toggle, 0, 0, 0, 0, 0, 0, 0]);
            if last {
                return Ok(());
            }
            toggle ^= 0x10;
        }
    }

    /// Uploads every readable object of the dictionary: a snapshot of the OD's values.
    pub fn snapshot(&mut self) -> Vec<(u16, u8, Result<Vec<u8>, canopen_slave::SdoAbort>)> {
        OD.entries()
            .map(|e| {
                let mut buf = [0u8; 32];
                let r = self
                    .dev
                    .read(e.index(), e.sub(), &mut buf, &mut self.app)
                    .map(|n| buf[..n].to_vec());
                (e.index(), e.sub(), r)
            })
            .collect()
    }
}
