//! A device over the two parameter pages in the board's power-cut flash model, booted as the
//! firmware boots it, for the tests of power cuts during stores and of stored values the
//! device must not trust.
#![allow(dead_code)]

use canopen_slave::{Frame, FrameSink, Instant, SinkFull};
#[allow(unused_imports)] // each test binary uses a part
pub use handwheel_board::flash::model::{mix, Cut, CutFlash};
use handwheel_core::{AbLevels, DecoderConfig, EdgeState, LinkedWheel};
use handwheel_device::HandwheelDevice;
use handwheel_storage::node_config::select;
use handwheel_storage::page::{ParameterPage, PAGES};
use handwheel_storage::record::NodeSettings;

/// Engine time of every step: no debt is paid back during the test.
pub const NOW: Instant = Instant::from_millis(1);
pub const SERIAL: u32 = 0xC0FF_EE00;

/// The parameter pages, erased: the board's power-cut flash model (the one both images'
/// tests use) over the two pages.
pub fn erased_pages() -> CutFlash {
    CutFlash::erased(PAGES)
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
