//! A bench for the loader: the application slot as NOR flash behaves, with at most one power
//! cut before or inside any operation (`handwheel_board::flash::model`, the model of every
//! power-cut test of either image), the loader's node over it, and an SDO client that drives
//! it frame by frame.
#![allow(dead_code)]

#[allow(unused_imports)] // each test binary uses a part
pub use handwheel_board::flash::model::{mix, Cut, CutFlash};

use canopen_loader::layout::{APP_ORIGIN, HEADER_SLOT, RAM_ORIGIN, SLOT_PAGES};
use canopen_loader::{seal, DeviceId, ImageHeader, LoaderConfig, LoaderNode, Request};
use canopen_slave::{Frame, FrameSink, Instant, NodeId, SinkFull};

pub const DEVICE: DeviceId = DeviceId {
    vendor_id: 0x0000_0ABC,
    product_code: 0x0000_0196,
};
pub const NODE: u8 = 0x21;
pub const SDO_RX: u16 = 0x600 + NODE as u16;
pub const SDO_TX: u16 = 0x580 + NODE as u16;
pub const HEARTBEAT: u16 = 0x700 + NODE as u16;
pub const SERIAL: u32 = 0xC0FF_EE00;
pub const LOADER_REVISION: u32 = 0x0001_0000;

/// The application slot, erased: the board's power-cut flash model (the one both images'
/// tests use) over the slot, the only region the loader's flash reaches. An erase or program
/// outside it panics in the model, so no test can pass that writes the loader's or the
/// parameter pages.
pub fn erased_slot() -> CutFlash {
    CutFlash::erased(SLOT_PAGES)
}

/// An update file for `device`: a vector table (stack in RAM, reset inside the image), then
/// seeded bytes, `length` image bytes in all, sealed.
pub fn image_for(device: DeviceId, version: u32, length: usize, seed: u64) -> Vec<u8> {
    let mut file = ImageHeader::unsealed(device.vendor_id, device.product_code, version)
        .to_slot()
        .to_vec();
    let mut s = seed;
    let mut image: Vec<u8> = (0..length).map(|_| mix(&mut s) as u8).collect();
    image[..4].copy_from_slice(&(RAM_ORIGIN + 0x4000).to_le_bytes());
    // A Thumb reset vector inside the image.
    let entry = if length > 0x100 { 0x101 } else { 1 };
    image[4..8].copy_from_slice(&(APP_ORIGIN + entry).to_le_bytes());
    file.extend_from_slice(&image);
    seal(&mut file).expect("a sealable image");
    file
}

pub fn image(version: u32, length: usize) -> Vec<u8> {
    image_for(
        DEVICE,
        version,
        length,
        u64::from(version) * 31 + length as u64,
    )
}

/// The header of a sealed file.
pub fn header_of(file: &[u8]) -> ImageHeader {
    ImageHeader::parse(file).unwrap()
}

pub struct Sink(pub Vec<Frame>);

impl FrameSink for Sink {
    fn send(&mut self, frame: Frame) -> Result<(), SinkFull> {
        self.0.push(frame);
        Ok(())
    }

    fn discard_pending(&mut self) {
        self.0.clear();
    }
}

pub fn config() -> LoaderConfig {
    LoaderConfig::new(NodeId::new(NODE).unwrap(), DEVICE, LOADER_REVISION, SERIAL)
}

/// The loader booted over a flash, with the frames it sent and the resets it asked for.
pub struct Bench {
    pub node: LoaderNode,
    pub flash: CutFlash,
    pub now_us: u64,
    pub sent: Vec<Frame>,
    pub resets: usize,
}

/// How a download goes on the wire.
#[derive(Clone, Copy, Debug)]
pub struct Transfer {
    /// Indicate the size in the initiate request (and which).
    pub size: Option<u32>,
    /// Data bytes per segment (1..=7), cycled through; seeded when `seed` is set.
    pub segment: usize,
    pub seed: Option<u64>,
}

impl Transfer {
    pub fn of(file: &[u8]) -> Self {
        Self {
            size: Some(file.len() as u32),
            segment: 7,
            seed: None,
        }
    }
}

impl Bench {
    pub fn boot(flash: CutFlash) -> Self {
        let mut node = LoaderNode::new(config(), &flash);
        let mut tx = Sink(Vec::new());
        node.start(Instant::ZERO, &mut tx);
        assert_eq!(tx.0.len(), 1);
        assert_eq!((tx.0[0].id(), tx.0[0].data()), (HEARTBEAT, &[0u8][..]));
        Self {
            node,
            flash,
            now_us: 0,
            sent: Vec::new(),
            resets: 0,
        }
    }

    pub fn now(&self) -> Instant {
        Instant::from_micros(self.now_us)
    }

    /// Delivers a frame, then polls; returns the frames sent.
    pub fn receive(&mut self, id: u16, data: &[u8]) -> Vec<Frame> {
        self.now_us += 100;
        let frame = Frame::new(id, data).unwrap();
        let mut tx = Sink(Vec::new());
        let now = self.now();
        if let Some(Request::Reset) = self.node.on_frame(now, &frame, &mut self.flash, &mut tx) {
            self.resets += 1;
        }
        self.node.poll(now, &mut tx);
        self.sent.extend(tx.0.iter().copied());
        tx.0
    }

    pub fn advance_ms(&mut self, ms: u64) -> Vec<Frame> {
        let mut out = Vec::new();
        for _ in 0..ms {
            self.now_us += 1000;
            let mut tx = Sink(Vec::new());
            self.node.poll(self.now(), &mut tx);
            out.extend(tx.0);
        }
        self.sent.extend(out.iter().copied());
        out
    }

    pub fn nmt(&mut self, command: u8) -> Vec<Frame> {
        self.receive(0x000, &[command, NODE])
    }

    /// One SDO request; its one answer.
    pub fn sdo(&mut self, request: [u8; 8]) -> [u8; 8] {
        let answers: Vec<Frame> = self
            .receive(SDO_RX, &request)
            .into_iter()
            .filter(|f| f.id() == SDO_TX)
            .collect();
        assert_eq!(answers.len(), 1, "one SDO answer to {request:02x?}");
        answers[0].data().try_into().unwrap()
    }

    fn outcome(answer: [u8; 8], index: u16, sub: u8) -> Result<[u8; 8], u32> {
        assert_eq!(
            (u16::from_le_bytes([answer[1], answer[2]]), answer[3]),
            (index, sub),
            "the answer names the object"
        );
        match answer[0] {
            0x80 => Err(u32::from_le_bytes(answer[4..8].try_into().unwrap())),
            _ => Ok(answer),
        }
    }

    /// Expedited download of 1, 2 or 4 bytes.
    pub fn write(&mut self, index: u16, sub: u8, value: &[u8]) -> Result<(), u32> {
        let cmd = 0x23 | (((4 - value.len()) as u8) << 2);
        let [i0, i1] = index.to_le_bytes();
        let mut req = [cmd, i0, i1, sub, 0, 0, 0, 0];
        req[4..4 + value.len()].copy_from_slice(value);
        let answer = self.sdo(req);
        Self::outcome(answer, index, sub).map(|a| assert_eq!(a[0], 0x60))
    }

    /// Expedited upload of a value of up to 4 bytes, as a u32.
    pub fn read(&mut self, index: u16, sub: u8) -> Result<u32, u32> {
        let [i0, i1] = index.to_le_bytes();
        let answer = self.sdo([0x40, i0, i1, sub, 0, 0, 0, 0]);
        let a = Self::outcome(answer, index, sub)?;
        assert_eq!(a[0] & 0xF3, 0x43, "expedited with size");
        let n = 4 - usize::from((a[0] >> 2) & 3);
        let mut v = [0u8; 4];
        v[..n].copy_from_slice(&a[4..4 + n]);
        Ok(u32::from_le_bytes(v))
    }

    /// (0x1F51:1, 0x1F56:1, 0x1F57:1).
    pub fn program_state(&mut self) -> (u32, u32, u32) {
        (
            self.read(0x1F51, 1).unwrap(),
            self.read(0x1F56, 1).unwrap(),
            self.read(0x1F57, 1).unwrap(),
        )
    }

    /// A segmented download of `file` to 0x1F50:1; the abort code of the initiate or of the
    /// segment that failed.
    pub fn download(&mut self, file: &[u8], how: Transfer) -> Result<(), u32> {
        let mut req = [0x21, 0x50, 0x1F, 1, 0, 0, 0, 0];
        match how.size {
            Some(size) => req[4..8].copy_from_slice(&size.to_le_bytes()),
            None => req[0] = 0x20,
        }
        let answer = self.sdo(req);
        let a = Self::outcome(answer, 0x1F50, 1)?;
        assert_eq!(a, [0x60, 0x50, 0x1F, 1, 0, 0, 0, 0]);
        let mut seed = how.seed;
        let mut toggle = 0u8;
        let mut at = 0;
        loop {
            let n = match &mut seed {
                Some(s) => 1 + (mix(s) % 7) as usize,
                None => how.segment,
            }
            .min(file.len() - at);
            let last = at + n == file.len();
            let mut seg = [0u8; 8];
            seg[0] = toggle | (((7 - n) as u8) << 1) | u8::from(last);
            seg[1..1 + n].copy_from_slice(&file[at..at + n]);
            let answer = self.sdo(seg);
            if answer[0] == 0x80 {
                assert_eq!(
                    (u16::from_le_bytes([answer[1], answer[2]]), answer[3]),
                    (0x1F50, 1)
                );
                return Err(u32::from_le_bytes(answer[4..8].try_into().unwrap()));
            }
            assert_eq!(
                answer,
                [0x20 | toggle, 0, 0, 0, 0, 0, 0, 0],
                "segment answer"
            );
            at += n;
            toggle ^= 0x10;
            if last {
                return Ok(());
            }
        }
    }

    /// Clear, download, as a master does; the abort code of the step that failed.
    pub fn update(&mut self, file: &[u8]) -> Result<(), u32> {
        self.write(0x1F51, 1, &[3])?;
        self.download(file, Transfer::of(file))
    }

    /// The application the boot decision would start.
    pub fn valid(&self) -> Option<ImageHeader> {
        canopen_loader::valid_application(&self.flash, DEVICE)
    }
}

/// The image's header slot and image as the slot holds them after a complete update.
pub fn slot_holds(flash: &CutFlash, file: &[u8]) -> bool {
    flash.bytes[..file.len()] == *file
}

const _: () = assert!(HEADER_SLOT == 512);
