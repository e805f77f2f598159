//! A device over two simulated flash pages, booted as the firmware boots it, for the tests
//! of power cuts during stores and of stored values the device must not trust.
#![allow(dead_code)]

use canopen_slave::{Frame, FrameSink, Instant, SinkFull};
use handwheel_core::{AbLevels, DecoderConfig, EdgeState, LinkedWheel};
use handwheel_device::node_config::select;
use handwheel_device::page::{Flash, FlashError, ParameterPage, PAGES, PAGE_SIZE};
use handwheel_device::record::NodeSettings;
use handwheel_device::HandwheelDevice;

/// Engine time of every step: no debt is paid back during the test.
pub const NOW: Instant = Instant::from_millis(1);
pub const SERIAL: u32 = 0xC0FF_EE00;

/// Where power is cut: before flash operation `n` (it never starts), or inside it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Cut {
    Before(usize),
    Inside(usize, u64),
}

/// Two flash pages as NOR flash behaves, counting operations, with at most one power cut.
#[derive(Clone, Debug)]
pub struct CutFlash {
    pub bytes: Vec<u8>,
    /// Operations asked for so far (half-word programs and page erases).
    pub ops: usize,
    /// Erases that started (completed or cut inside).
    pub erases: u64,
    pub cut: Option<Cut>,
    /// Power is off: nothing more happens.
    pub dead: bool,
}

/// splitmix64: the seeded choices of a cut inside an operation.
pub fn mix(state: &mut u64) -> u64 {
    *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
    let mut z = *state;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

impl CutFlash {
    pub fn new() -> Self {
        Self {
            bytes: vec![0xFF; PAGES * PAGE_SIZE],
            ops: 0,
            erases: 0,
            cut: None,
            dead: false,
        }
    }

    /// The flash after the power came back: the same bytes, no cut planned, counting anew.
    pub fn powered_up(&self) -> Self {
        Self {
            bytes: self.bytes.clone(),
            ops: 0,
            erases: self.erases,
            cut: None,
            dead: false,
        }
    }

    /// Starts an operation: `Ok(None)` to do it, `Ok(Some(seed))` to cut inside it, `Err` when
    /// the power is (now) off.
    pub fn start(&mut self) -> Result<Option<u64>, FlashError> {
        if self.dead {
            return Err(FlashError::Controller);
        }
        let op = self.ops;
        self.ops += 1;
        match self.cut {
            Some(Cut::Before(n)) if n == op => {
                self.dead = true;
                Err(FlashError::Controller)
            }
            Some(Cut::Inside(n, seed)) if n == op => {
                self.dead = true;
                Ok(Some(seed))
            }
            _ => Ok(None),
        }
    }
}

impl Flash for CutFlash {
    fn page(&self, page: usize) -> &[u8] {
        self.bytes
            .get(page * PAGE_SIZE..(page + 1) * PAGE_SIZE)
            .unwrap_or(&[])
    }

    fn erase(&mut self, page: usize) -> Result<(), FlashError> {
        assert!(page < PAGES);
        let cut = self.start()?;
        self.erases += 1;
        let range = page * PAGE_SIZE..(page + 1) * PAGE_SIZE;
        let Some(mut seed) = cut else {
            self.bytes[range].fill(0xFF);
            return Ok(());
        };
        // Cut inside: a seeded half of the half-words erased, the rest as they were.
        for pair in self.bytes[range].chunks_exact_mut(2) {
            if mix(&mut seed) & 1 == 1 {
                pair.fill(0xFF);
            }
        }
        Err(FlashError::Erase)
    }

    fn program(&mut self, page: usize, offset: usize, bytes: &[u8]) -> Result<(), FlashError> {
        assert!(page < PAGES && offset.is_multiple_of(2) && offset + bytes.len() <= PAGE_SIZE);
        for (i, pair) in bytes.chunks_exact(2).enumerate() {
            let cut = self.start()?;
            let at = page * PAGE_SIZE + offset + 2 * i;
            let old = u16::from_le_bytes([self.bytes[at], self.bytes[at + 1]]);
            let new = u16::from_le_bytes([pair[0], pair[1]]);
            assert!(
                old == 0xFFFF || new == 0,
                "programming a half-word that is not erased, at {at}"
            );
            let value = match cut {
                None => new,
                // Cut inside: only a seeded part of the bits to clear are cleared.
                Some(mut seed) => old & !(old & !new & mix(&mut seed) as u16),
            };
            self.bytes[at..at + 2].copy_from_slice(&value.to_le_bytes());
            if cut.is_some() {
                return Err(FlashError::Program);
            }
        }
        Ok(())
    }
}

pub struct Sink(pub Vec<Frame>);

impl FrameSink for Sink {
    fn send(&mut self, frame: Frame) -> Result<(), SinkFull> {
        self.0.push(frame);
        Ok(())
    }
}

/// The device as the firmware boots it over the flash.
pub struct Node {
    pub device: HandwheelDevice<ParameterPage<CutFlash>>,
    pub wheel: LinkedWheel<EdgeState>,
    pub settings: NodeSettings,
    /// The debt the budget started from, in units of 2^26 us.
    pub debt: u16,
    /// The frames of the boot.
    pub booted: Vec<Frame>,
    /// Engine time of the next exchange: [`NOW`] after a boot; a test moves it on to let
    /// powered time pass.
    pub now: Instant,
}

impl Node {
    pub fn boot(flash: CutFlash) -> Self {
        let mut page = ParameterPage::new(flash);
        let debt = page.stored_debt();
        let stored = page.stored().map(|(settings, _)| settings);
        let (settings, _) = select(0, stored);
        page.set_settings(settings);
        let mut device =
            HandwheelDevice::with_settings(settings.node_id, settings.bit_rate, SERIAL, page);
        let mut wheel = LinkedWheel::local(DecoderConfig::default(), AbLevels::from_bits(0));
        let mut tx = Sink(Vec::new());
        device.start(NOW, &mut wheel, &mut tx);
        let node = u16::from(settings.node_id_byte());
        assert!(
            tx.0.iter()
                .any(|f| f.id() == 0x700 + node && f.data() == [0]),
            "boot-up of node {node}"
        );
        Self {
            device,
            wheel,
            settings,
            debt,
            booted: tx.0,
            now: NOW,
        }
    }

    pub fn flash(&mut self) -> CutFlash {
        self.device.engine().storage().flash().clone()
    }

    pub fn exchange(&mut self, id: u16, data: &[u8]) -> Vec<Frame> {
        let mut tx = Sink(Vec::new());
        let frame = Frame::new(id, data).unwrap();
        self.device
            .on_frame(self.now, &frame, &mut self.wheel, &mut tx);
        self.device.poll(self.now, &mut self.wheel, &mut tx);
        tx.0
    }

    pub fn node_id(&self) -> u16 {
        u16::from(self.settings.node_id_byte())
    }

    /// An expedited SDO request; the answer's data bytes, or the abort code.
    pub fn sdo(&mut self, request: [u8; 8]) -> Result<[u8; 8], u32> {
        let node = self.node_id();
        let answers = self.exchange(0x600 + node, &request);
        let answer = answers
            .iter()
            .find(|f| f.id() == 0x580 + node)
            .expect("an SDO answer");
        let data: [u8; 8] = answer.data().try_into().unwrap();
        if data[0] == 0x80 {
            return Err(u32::from_le_bytes(data[4..8].try_into().unwrap()));
        }
        Ok(data)
    }

    pub fn write_u16(&mut self, index: u16, sub: u8, value: u16) -> Result<(), u32> {
        let [i0, i1] = index.to_le_bytes();
        let [v0, v1] = value.to_le_bytes();
        self.sdo([0x2B, i0, i1, sub, v0, v1, 0, 0]).map(|_| ())
    }

    pub fn write_u32(&mut self, index: u16, sub: u8, value: u32) -> Result<(), u32> {
        let [i0, i1] = index.to_le_bytes();
        let [v0, v1, v2, v3] = value.to_le_bytes();
        self.sdo([0x23, i0, i1, sub, v0, v1, v2, v3]).map(|_| ())
    }

    pub fn read_u16(&mut self, index: u16, sub: u8) -> u16 {
        let [i0, i1] = index.to_le_bytes();
        let data = self
            .sdo([0x40, i0, i1, sub, 0, 0, 0, 0])
            .unwrap_or_else(|code| panic!("upload {index:#06x}:{sub} aborted {code:#010x}"));
        u16::from_le_bytes([data[4], data[5]])
    }

    /// LSS "store configuration" of `node` at bit-timing index `timing`; the LSS error code.
    pub fn lss_store(&mut self, node: u8, timing: u8) -> u8 {
        self.exchange(0x7E5, &[0x04, 1, 0, 0, 0, 0, 0, 0]);
        for (request, what) in [
            ([0x11, node, 0, 0, 0, 0, 0, 0], "configure node-ID"),
            ([0x13, 0, timing, 0, 0, 0, 0, 0], "configure bit timing"),
        ] {
            let answer = self.exchange(0x7E5, &request);
            assert_eq!(answer[0].data()[1], 0, "{what}");
        }
        let answer = self.exchange(0x7E5, &[0x17, 0, 0, 0, 0, 0, 0, 0]);
        self.exchange(0x7E5, &[0x04, 0, 0, 0, 0, 0, 0, 0]);
        let store = answer.iter().find(|f| f.id() == 0x7E4).expect("LSS answer");
        store.data()[1]
    }

    /// What a boot found: node-ID, bit rate, producer heartbeat (0x1017), unit-step backlog
    /// bound (0x2040:3).
    pub fn state(&mut self) -> State {
        State {
            node: self.settings.node_id_byte(),
            kbit: self.settings.bit_rate.kbit_per_second(),
            heartbeat: self.read_u16(0x1017, 0),
            backlog: self.read_u16(0x2040, 3),
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct State {
    pub node: u8,
    pub kbit: u32,
    pub heartbeat: u16,
    pub backlog: u16,
}

pub const SAVE: u32 = 0x6576_6173;
pub const LOAD: u32 = 0x6461_6F6C;
