//! Power cuts during stores, exhaustively: a flash model at the granularity of the chip's
//! flash controller (one operation = one half-word program or one page erase) cuts power
//! before each operation of a store and inside it (a partly erased page: a seeded choice of
//! half-words erased, the rest unchanged; a partly programmed half-word: only some of its
//! bits cleared). After each cut the device boots from what the flash holds, as the firmware
//! does (`ParameterPage::new`, `node_config::select`, the device over the pages), and must
//! find the old or the new settings and parameters, a wear debt that covers every erase begun,
//! answer SDO, and store again.

use canopen_slave::{Frame, FrameSink, Instant, SinkFull};
use handwheel_core::{AbLevels, DecoderConfig, LinkedWheel, LocalEdge};
use handwheel_device::node_config::select;
use handwheel_device::page::{
    Flash, FlashError, ParameterPage, ERASE_INTERVAL_MS, PAGES, PAGE_SIZE,
};
use handwheel_device::record::NodeSettings;
use handwheel_device::HandwheelDevice;

/// Engine time of every step: no debt is paid back during the test.
const NOW: Instant = Instant::from_millis(1);
const SERIAL: u32 = 0xC0FF_EE00;

/// Where power is cut: before flash operation `n` (it never starts), or inside it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Cut {
    Before(usize),
    Inside(usize, u64),
}

/// Two flash pages as NOR flash behaves, counting operations, with at most one power cut.
#[derive(Clone, Debug)]
struct CutFlash {
    bytes: Vec<u8>,
    /// Operations asked for so far (half-word programs and page erases).
    ops: usize,
    /// Erases that started (completed or cut inside).
    erases: u64,
    cut: Option<Cut>,
    /// Power is off: nothing more happens.
    dead: bool,
}

/// splitmix64: the seeded choices of a cut inside an operation.
fn mix(state: &mut u64) -> u64 {
    *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
    let mut z = *state;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

impl CutFlash {
    fn new() -> Self {
        Self {
            bytes: vec![0xFF; PAGES * PAGE_SIZE],
            ops: 0,
            erases: 0,
            cut: None,
            dead: false,
        }
    }

    /// The flash after the power came back: the same bytes, no cut planned, counting anew.
    fn powered_up(&self) -> Self {
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
    fn start(&mut self) -> Result<Option<u64>, FlashError> {
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
        assert!(page < PAGES && offset % 2 == 0 && offset + bytes.len() <= PAGE_SIZE);
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

struct Sink(Vec<Frame>);

impl FrameSink for Sink {
    fn send(&mut self, frame: Frame) -> Result<(), SinkFull> {
        self.0.push(frame);
        Ok(())
    }
}

/// The device as the firmware boots it over the flash.
struct Node {
    device: HandwheelDevice<ParameterPage<CutFlash>>,
    wheel: LinkedWheel<LocalEdge>,
    settings: NodeSettings,
    /// The debt the budget started from, in units of 2^26 us.
    debt: u16,
}

impl Node {
    fn boot(flash: CutFlash) -> Self {
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
        }
    }

    fn flash(&mut self) -> CutFlash {
        self.device.engine().storage().flash().clone()
    }

    fn exchange(&mut self, id: u16, data: &[u8]) -> Vec<Frame> {
        let mut tx = Sink(Vec::new());
        let frame = Frame::new(id, data).unwrap();
        self.device.on_frame(NOW, &frame, &mut self.wheel, &mut tx);
        self.device.poll(NOW, &mut self.wheel, &mut tx);
        tx.0
    }

    fn node_id(&self) -> u16 {
        u16::from(self.settings.node_id_byte())
    }

    /// An expedited SDO request; the answer's data bytes, or the abort code.
    fn sdo(&mut self, request: [u8; 8]) -> Result<[u8; 8], u32> {
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

    fn write_u16(&mut self, index: u16, sub: u8, value: u16) -> Result<(), u32> {
        let [i0, i1] = index.to_le_bytes();
        let [v0, v1] = value.to_le_bytes();
        self.sdo([0x2B, i0, i1, sub, v0, v1, 0, 0]).map(|_| ())
    }

    fn write_u32(&mut self, index: u16, sub: u8, value: u32) -> Result<(), u32> {
        let [i0, i1] = index.to_le_bytes();
        let [v0, v1, v2, v3] = value.to_le_bytes();
        self.sdo([0x23, i0, i1, sub, v0, v1, v2, v3]).map(|_| ())
    }

    fn read_u16(&mut self, index: u16, sub: u8) -> u16 {
        let [i0, i1] = index.to_le_bytes();
        let data = self
            .sdo([0x40, i0, i1, sub, 0, 0, 0, 0])
            .unwrap_or_else(|code| panic!("upload {index:#06x}:{sub} aborted {code:#010x}"));
        u16::from_le_bytes([data[4], data[5]])
    }

    /// LSS "store configuration" of `node` at bit-timing index `timing`; the LSS error code.
    fn lss_store(&mut self, node: u8, timing: u8) -> u8 {
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
    fn state(&mut self) -> State {
        State {
            node: self.settings.node_id_byte(),
            kbit: self.settings.bit_rate.kbit_per_second(),
            heartbeat: self.read_u16(0x1017, 0),
            backlog: self.read_u16(0x2040, 3),
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct State {
    node: u8,
    kbit: u32,
    heartbeat: u16,
    backlog: u16,
}

const SAVE: u32 = 0x6576_6173;
const LOAD: u32 = 0x6461_6F6C;

/// Changes the two parameters to values made of `n` and saves them (0x1010:1).
fn save(node: &mut Node, n: u16) -> Result<(), u32> {
    node.write_u16(0x1017, 0, 100 + n)?;
    node.write_u16(0x2040, 3, 1 + n)?;
    node.write_u32(0x1010, 1, SAVE)
}

/// The kinds of store under test, each from a state reached by stores without cuts.
#[derive(Clone, Copy, Debug)]
enum Kind {
    /// 0x1010 save appending to the active page.
    SaveAppend,
    /// 0x1010 save that moves to the other page (the active one is full).
    SaveMove,
    /// LSS store configuration, appending.
    LssAppend,
    /// LSS store configuration that moves.
    LssMove,
    /// 0x1011 load (everything), appending.
    LoadAppend,
    /// 0x1011 load that moves.
    LoadMove,
    /// 0x1010 save that moves over a spare page an earlier cut move left dirty: a debt mark,
    /// the spare's erase, the record, the full page's erase.
    SaveMoveDirtySpare,
}

/// The flash before the store under test: `saves` changed saves on a fresh part.
fn prepared(saves: u16) -> CutFlash {
    let mut node = Node::boot(CutFlash::new());
    for n in 0..saves {
        save(&mut node, n).unwrap();
    }
    node.flash().powered_up()
}

/// The flash before the store of `kind`.
fn setup(kind: Kind) -> CutFlash {
    match kind {
        Kind::SaveAppend | Kind::LssAppend | Kind::LoadAppend => prepared(2),
        // Six full records: the page has no room for another, not even a 14-byte one.
        Kind::SaveMove | Kind::LssMove | Kind::LoadMove => prepared(6),
        Kind::SaveMoveDirtySpare => {
            let mut flash = prepared(6);
            // The move's first half-word on the spare page, cut inside.
            flash.cut = Some(Cut::Inside(0, 99));
            run(Kind::SaveMove, flash).powered_up()
        }
    }
}

/// Runs the store of `kind` on a device booted from `flash`.
fn run(kind: Kind, flash: CutFlash) -> CutFlash {
    let mut node = Node::boot(flash);
    // With the power off the answers mean nothing: what counts is the flash.
    let _ = match kind {
        Kind::SaveAppend | Kind::SaveMove | Kind::SaveMoveDirtySpare => save(&mut node, 77),
        Kind::LssAppend | Kind::LssMove => {
            let _ = node.lss_store(42, 3);
            Ok(())
        }
        Kind::LoadAppend | Kind::LoadMove => node.write_u32(0x1011, 1, LOAD),
    };
    node.flash()
}

/// Whether a stored debt (units of 2^26 us) covers `erases` erases, each a day of debt, less
/// the millisecond of engine time at which they were taken.
fn covers(debt: u16, erases: u64) -> bool {
    (u64::from(debt) << 26) + 1000 >= erases * ERASE_INTERVAL_MS * 1000
}

/// Cuts `kind` before and inside every flash operation; returns the cut points tried.
fn cut_everywhere(kind: Kind) -> usize {
    let before = setup(kind);
    let old = Node::boot(before.powered_up()).state();
    let done = run(kind, before.powered_up());
    let ops = done.ops;
    assert!(ops > 0, "{kind:?} writes something");
    let new = Node::boot(done.powered_up()).state();
    assert_ne!(old, new, "{kind:?} changes what a boot finds");
    let mut cuts = vec![None];
    for op in 0..ops {
        cuts.push(Some(Cut::Before(op)));
        for seed in [1, 2, 3] {
            cuts.push(Some(Cut::Inside(op, seed * 7919 + op as u64)));
        }
    }
    for &cut in &cuts {
        let mut flash = before.powered_up();
        flash.cut = cut;
        let after = run(kind, flash);
        let erases = after.erases;
        let mut node = Node::boot(after.powered_up());
        let found = node.state();
        assert!(
            found == old || found == new,
            "{kind:?} cut at {cut:?}: booted with {found:?}, old {old:?}, new {new:?}"
        );
        // The budget: every erase begun (from the fresh part on) is in the debt a boot
        // starts from.
        assert!(
            covers(node.debt, erases),
            "{kind:?} cut at {cut:?}: debt {} for {erases} erases",
            node.debt
        );
        // And the device stores again (a move over a spare page the cut left dirty
        // included), and boots with what it stored.
        save(&mut node, 500).unwrap_or_else(|code| {
            panic!("{kind:?} cut at {cut:?}: the next save aborted {code:#010x}")
        });
        let erases = node.flash().erases;
        let mut again = Node::boot(node.flash().powered_up());
        let stored = again.state();
        assert_eq!(
            (stored.heartbeat, stored.backlog),
            (600, 501),
            "{kind:?} {cut:?}"
        );
        assert!(
            covers(again.debt, erases),
            "{kind:?} cut at {cut:?}: debt {} for {erases} erases after the next save",
            again.debt
        );
    }
    cuts.len()
}

#[test]
fn a_power_cut_at_any_flash_operation_of_a_store_boots_the_old_or_the_new_state() {
    let mut total = 0;
    for kind in [
        Kind::SaveAppend,
        Kind::SaveMove,
        Kind::LssAppend,
        Kind::LssMove,
        Kind::LoadAppend,
        Kind::LoadMove,
        Kind::SaveMoveDirtySpare,
    ] {
        let tried = cut_everywhere(kind);
        println!("{kind:?}: {tried} cut points");
        total += tried;
    }
    println!("{total} cut points in all");
    assert!(total > 1000, "{total}");
}

/// Moves cut off again and again (each leaving the spare page dirty) cost a debt mark each,
/// and never refill the budget; once the active page has no room for another mark, a move
/// is refused (0x08000020) rather than erasing without a record of it.
#[test]
fn repeated_cut_moves_are_charged_and_bounded() {
    let mut flash = prepared(6);
    let mut refused = false;
    let mut erases = 0;
    for round in 0..20 {
        let mut node = Node::boot(flash.powered_up());
        assert!(covers(node.debt, erases), "round {round}");
        let mut cutting = node.flash().powered_up();
        // Cut inside the first program of the new record on the spare page: the spare is
        // dirty for the next attempt. Find that operation by counting a clean run.
        let mut probe = cutting.powered_up();
        probe.cut = None;
        let ops = run(Kind::SaveMove, probe).ops;
        cutting.cut = Some(Cut::Inside(ops.saturating_sub(2), round));
        let mut node = Node::boot(cutting);
        if save(&mut node, 900 + round as u16) == Err(0x0800_0020) {
            refused = true;
            break;
        }
        flash = node.flash();
        erases = flash.erases;
    }
    assert!(refused, "a move without room for its mark is refused");
}
