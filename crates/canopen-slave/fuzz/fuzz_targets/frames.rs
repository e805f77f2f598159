//! Feeds the engine arbitrary (time step, frame) sequences. Asserts that nothing panics,
//! that every frame the engine must ignore leaves it (and the application) untouched and
//! silent, and that outgoing frames are well-formed.
#![no_main]

use canopen_slave::{
    standard_objects, Access, Application, CommDefaults, Config, DataType, Device, Frame,
    FrameSink, Identity, Instant, MemoryStorage, NodeId, Od, OdEntry, SdoAbort, SinkFull,
    TpdoDefaults, STANDARD_OBJECTS,
};
use libfuzzer_sys::fuzz_target;

const NODE: u8 = 0x22;

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

    fn save_application(&self, buf: &mut [u8]) -> usize {
        buf[0] = self.flag;
        1
    }

    fn restore_application(&mut self, data: &[u8]) {
        if let [flag] = *data {
            self.flag = flag;
        }
    }
}

#[derive(Default)]
struct Sink(Vec<Frame>, usize);

impl FrameSink for Sink {
    fn send(&mut self, frame: Frame) -> Result<(), SinkFull> {
        // Refuse now and then, to exercise the retry paths.
        self.1 += 1;
        if self.1 % 13 == 0 {
            return Err(SinkFull);
        }
        self.0.push(frame);
        Ok(())
    }
}

fn must_ignore(id: u16, dlc: usize) -> bool {
    let sdo = 0x600 + u16::from(NODE);
    let known = id == 0 || id == 0x80 || id == sdo || (0x701..=0x77F).contains(&id);
    !known || (id == 0 && dlc != 2) || (id == sdo && dlc != 8)
}

fuzz_target!(|input: &[u8]| {
    let node = NodeId::new(NODE).unwrap();
    let mut dev = Device::new(Config::new(node), OD, MemoryStorage::new());
    let mut app = App::default();
    let mut tx = Sink::default();
    let mut now = 0u64;
    dev.start(Instant::ZERO, &mut app, &mut tx);

    let mut bytes = input;
    while let [dt, sel, id_lo, len, rest @ ..] = bytes {
        now += u64::from(*dt) * 500;
        let id = match sel % 8 {
            0 => 0,
            1 => 0x80,
            2 | 3 => 0x600 + u16::from(NODE),
            4 => 0x700 + u16::from(*id_lo & 0x7F),
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
        if must_ignore(id, dlc) {
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
        for f in &tx.0 {
            assert!(f.dlc() <= 8);
            if f.id() == 0x580 + u16::from(NODE) || f.id() == 0x80 + u16::from(NODE) {
                assert_eq!(f.dlc(), 8);
            }
        }
    }
});
