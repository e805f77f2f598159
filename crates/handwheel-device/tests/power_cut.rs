//! Power cuts during stores, exhaustively: a flash model at the granularity of the chip's
//! flash controller (one operation = one half-word program or one page erase) cuts power
//! before each operation of a store and inside it (a partly erased page: a seeded choice of
//! half-words erased, the rest unchanged; a partly programmed half-word: only some of its
//! bits cleared). After each cut the device boots from what the flash holds, as the firmware
//! does (`ParameterPage::new`, `node_config::select`, the device over the pages), and must
//! find the old or the new settings and parameters, a wear debt that covers every erase begun,
//! answer SDO, and store again. Then runs of up to 20 stores in a row, each cut (with the debt
//! marks before erase ticks, seven moves cut inside their first operation locked the store for
//! good): after any run, stores and restore defaults are accepted again, at once or, when the
//! budget has no erase left, after a day of powered time.

mod flash_bench;

use canopen_slave::Instant;
use flash_bench::{Cut, CutFlash, Node, LOAD, SAVE};
use handwheel_storage::page::{ERASE_BURST, ERASE_INTERVAL_MS};
use proptest::prelude::*;

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
    /// 0x1010 save that moves over a spare page an earlier cut move left dirty: an erase tick,
    /// the spare's erase, the record, the full page's erase.
    SaveMoveDirtySpare,
}

/// The flash before the store under test: `saves` changed saves on a fresh part.
fn prepared(saves: u16) -> CutFlash {
    let mut node = Node::boot(flash_bench::erased_pages());
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

/// Moves cut off one after the other, each inside the last half-word of the record on the
/// spare page (which is then not blank): every later move writes an erase tick and erases
/// the spare page first, so each such erase is in the stored debt before it starts, and the
/// budget runs out: the first cut move begins no erase, each later one one (the spare's;
/// the full page's never begins), and the ninth is refused with 0x08000020 (an eighth
/// erase at once, but seven ticks' debt rounded up to whole units is a minute more than
/// seven intervals), with the stored state as it was. One interval of powered time later the
/// save is accepted.
#[test]
fn repeated_cut_moves_are_charged_and_bounded() {
    let mut flash = prepared(6);
    let mut moves = 0;
    loop {
        let node = Node::boot(flash.powered_up());
        assert!(covers(node.debt, flash.erases), "after {moves} cut moves");
        // Count a clean run's operations to cut inside the record's last half-word.
        let done = run(Kind::SaveMove, flash.powered_up());
        if done.ops == 0 {
            // Refused before writing anything: see below.
            let mut node = Node::boot(flash.powered_up());
            assert_eq!(save(&mut node, 900), Err(0x0800_0020));
            break;
        }
        // The clean run's last operation is the full page's erase if the budget had it
        // (besides the spare page's, from the second move on), else the record's last
        // half-word.
        let spare_erased = moves > 0;
        let full_erased = done.erases - flash.erases > u64::from(spare_erased);
        let record_end = done.ops - usize::from(full_erased);
        let mut cutting = flash.powered_up();
        cutting.cut = Some(Cut::Inside(record_end - 1, moves as u64));
        let mut node = Node::boot(cutting);
        let _ = save(&mut node, 900);
        moves += 1;
        assert!(moves <= 20, "never refused");
        flash = node.flash();
    }
    assert_eq!((moves, flash.erases), (8, 7));
    let mut node = Node::boot(flash.powered_up());
    assert_eq!(node.state().heartbeat, 105, "the sixth save's");
    assert!(covers(node.debt, flash.erases));
    node.now = Instant::from_millis(ERASE_INTERVAL_MS);
    save(&mut node, 900).unwrap();
    let mut node = Node::boot(node.flash().powered_up());
    assert_eq!(node.state().heartbeat, 1000, "the save after a day");
}

/// How a device waits after a run of cut moves before it stores again.
#[derive(Clone, Copy, Debug)]
enum Then {
    /// Stores right after the power-on.
    PowerOn,
    /// Stores after an NMT reset node.
    ResetNode,
    /// Stores after nine days of powered time: every erase of the budget paid back.
    NineDays,
}

/// The run of cut moves that locked the store for good before erase ticks: the page full,
/// seven moves in a row each cut inside their first flash operation (the first inside the
/// record's first half-word on the spare page, each later one inside what it writes before
/// the spare page's erase). No erase ever began, so nothing of the budget is spent: after a
/// power-on, a reset node or nine powered days, a changed save and a restore defaults are
/// accepted and stored.
#[test]
fn seven_moves_cut_inside_their_first_flash_operation_leave_the_store_usable() {
    let mut flash = prepared(6);
    for run in 0..7u64 {
        let mut cutting = flash.powered_up();
        cutting.cut = Some(Cut::Inside(0, run * 7919 + 1));
        let mut node = Node::boot(cutting);
        let _ = save(&mut node, 900 + run as u16);
        flash = node.flash();
        assert!(flash.dead, "move {run} was cut");
    }
    assert_eq!(flash.erases, 0, "no erase began");
    let mut refused = Vec::new();
    for then in [Then::PowerOn, Then::ResetNode, Then::NineDays] {
        // A few power cycles first: none of them may change what the store does.
        let mut booted = flash.powered_up();
        for _ in 0..3 {
            let mut node = Node::boot(booted.powered_up());
            assert_eq!(node.state().heartbeat, 105, "{then:?}: the sixth save's");
            booted = node.flash();
        }
        let mut node = Node::boot(booted.powered_up());
        match then {
            Then::PowerOn => {}
            Then::ResetNode => {
                let id = node.node_id() as u8;
                node.exchange(0x000, &[0x81, id]);
            }
            Then::NineDays => {
                node.now = Instant::from_millis(9 * ERASE_INTERVAL_MS);
            }
        }
        // The changed save, then (whether or not it was accepted) restore defaults.
        match save(&mut node, 400) {
            Ok(()) => {
                let mut again = Node::boot(node.flash().powered_up());
                assert_eq!(again.state().heartbeat, 500, "{then:?}: the changed save's");
                again.now = node.now;
                node = again;
            }
            Err(code) => refused.push((then, "changed save", code)),
        }
        match node.write_u32(0x1011, 1, LOAD) {
            Ok(()) => {
                let mut restored = Node::boot(node.flash().powered_up());
                let defaults = restored.state();
                assert_eq!(
                    (defaults.node, defaults.heartbeat),
                    (16, 1000),
                    "{then:?}: the defaults"
                );
            }
            Err(code) => refused.push((then, "restore defaults", code)),
        }
    }
    assert!(
        refused.is_empty(),
        "refused after seven cut moves: {refused:#x?}"
    );
}

/// One interval of debt in microseconds.
const DAY_US: u64 = ERASE_INTERVAL_MS * 1000;
/// One unit of stored debt (2^26 us), rounded up to milliseconds.
const UNIT_MS: u64 = (1 << 26) / 1000 + 1;
/// The most operations a store takes: a tick, the spare page's erase, a 154-byte record, the
/// full page's erase.
const MOST_OPS: usize = 80;

/// A store of a run.
#[derive(Clone, Copy, Debug)]
enum Store {
    /// 0x1010 save of the two parameters made of `n`.
    Save(u16),
    /// 0x1011 restore defaults (everything).
    Load,
}

fn apply(node: &mut Node, store: Store) -> Result<(), u32> {
    match store {
        Store::Save(n) => save(node, n),
        Store::Load => node.write_u32(0x1011, 1, LOAD),
    }
}

/// `cut` inside a store of `ops` operations: an operation past its last is its last.
fn clamped(cut: Cut, ops: usize) -> Cut {
    match cut {
        Cut::Before(op) => Cut::Before(op.min(ops - 1)),
        Cut::Inside(op, seed) => Cut::Inside(op.min(ops - 1), seed),
    }
}

/// A device's life over the cut flash, one session per store: what its flash holds, the
/// powered time of its sessions so far and what a boot finds.
#[derive(Clone)]
struct Life {
    flash: CutFlash,
    powered_ms: u64,
    state: flash_bench::State,
    /// Stores the budget refused.
    refused: usize,
}

impl Life {
    /// `saves` changed saves on a fresh part.
    fn prepared(saves: u16) -> Self {
        let flash = prepared(saves);
        let state = Node::boot(flash.powered_up()).state();
        Self {
            flash,
            powered_ms: 0,
            state,
            refused: 0,
        }
    }

    /// A boot from the flash as it is, `wait_ms` of powered time after the boot's.
    fn boot(&self, flash: CutFlash, wait_ms: u64) -> Node {
        let mut node = Node::boot(flash);
        node.now = Instant::from_millis(1 + wait_ms);
        node
    }

    /// One session: a boot, `wait_ms` of powered time, `store` cut at `cut` (an operation
    /// past the store's last is its last; `None`: not cut). Checks the boot (the state and
    /// the budget's promises) and what a boot finds after the store (the old state or the
    /// new one), and that a refusal is the budget's: the debt the boot started from, less
    /// the powered time, leaves no erase. `Ok(true)`: the store was cut; `Ok(false)`: it
    /// completed or wrote nothing; `Err`: it was refused with this abort code.
    fn session(&mut self, wait_ms: u64, store: Store, cut: Option<Cut>) -> Result<bool, u32> {
        let mut node = self.boot(self.flash.powered_up(), wait_ms);
        assert_eq!(node.state(), self.state, "the boot before {store:?}");
        let debt_us = u64::from(node.debt) << 26;
        let erases = self.flash.erases;
        assert!(
            debt_us + self.powered_ms * 1000 >= erases * DAY_US,
            "debt {} for {erases} erases in {} ms of powered time",
            node.debt,
            self.powered_ms
        );
        assert!(
            erases <= ERASE_BURST + self.powered_ms / ERASE_INTERVAL_MS,
            "{erases} erases in {} ms of powered time",
            self.powered_ms
        );
        self.powered_ms += 1 + wait_ms;
        // The store uncut: its operations and what a boot finds after it.
        let result = apply(&mut node, store);
        let done = node.flash();
        if let Err(code) = result {
            assert_eq!(code, 0x0800_0020, "{store:?}");
            assert_eq!(done.ops, 0, "{store:?} refused before writing");
            assert!(
                debt_us > 7 * DAY_US + (1 + wait_ms) * 1000,
                "{store:?} refused with debt {} after {wait_ms} ms powered",
                node.debt
            );
            self.refused += 1;
            return Err(code);
        }
        let new = Node::boot(done.powered_up()).state();
        let Some(cut) = cut.filter(|_| done.ops > 0) else {
            self.flash = done;
            self.state = new;
            return Ok(false);
        };
        let mut cutting = self.flash.powered_up();
        cutting.cut = Some(clamped(cut, done.ops));
        let mut node = self.boot(cutting, wait_ms);
        let _ = apply(&mut node, store);
        let after = node.flash();
        assert!(after.dead, "{store:?} cut at {cut:?}");
        let found = Node::boot(after.powered_up()).state();
        assert!(
            found == self.state || found == new,
            "{store:?} cut at {cut:?}: {found:?}, old {:?}, new {new:?}",
            self.state
        );
        self.flash = after;
        self.state = found;
        Ok(true)
    }

    /// `store` uncut: accepted in a session at once, or (refused by the budget) in one
    /// after one interval of powered time and one debt unit.
    fn stores(&mut self, store: Store) {
        if self.session(0, store, None).is_err() {
            self.session(ERASE_INTERVAL_MS + UNIT_MS, store, None)
                .unwrap_or_else(|code| {
                    panic!("{store:?} refused {code:#010x} after a day of powered time")
                });
        }
    }

    /// After whatever came before: a changed save, restore defaults and a changed save are
    /// accepted (each at once, or a day later when the budget has no erase left) and boot.
    fn recovers(mut self, what: &str) {
        self.stores(Store::Save(300));
        assert_eq!(
            (self.state.heartbeat, self.state.backlog),
            (400, 301),
            "{what}"
        );
        self.stores(Store::Load);
        assert_eq!(
            (self.state.node, self.state.heartbeat),
            (16, 1000),
            "{what}"
        );
        self.stores(Store::Save(301));
        assert_eq!(self.state.heartbeat, 401, "{what}");
    }
}

/// Every cut point of a store (before and inside each operation, up to the most a store
/// takes), in runs of 1 to 20 consecutive changed saves each cut at that point (the page
/// full at the start; a save the budget refuses is tried again a day later, and must then
/// be accepted and cut): after each run the device boots with the old or the new state, its
/// debt covers every erase begun, and saves and restore defaults are accepted again.
#[test]
fn runs_of_up_to_twenty_cut_saves_at_every_cut_point_leave_the_store_usable() {
    let start = Life::prepared(6);
    let (mut runs, mut refused, mut erases) = (0, 0, 0);
    for op in 0..MOST_OPS {
        for kind in 0..3u64 {
            let mut life = start.clone();
            for n in 0..20u16 {
                let cut = match kind {
                    0 => Cut::Before(op),
                    _ => Cut::Inside(op, kind * 7919 + u64::from(n)),
                };
                let store = Store::Save(600 + n);
                let cut_off = match life.session(0, store, Some(cut)) {
                    Ok(cut_off) => cut_off,
                    Err(_) => life
                        .session(ERASE_INTERVAL_MS + UNIT_MS, store, Some(cut))
                        .unwrap_or_else(|code| {
                            panic!("{cut:?}, store {n}: refused {code:#010x} a day later")
                        }),
                };
                assert!(cut_off, "{cut:?}: store {n} was cut");
                life.clone()
                    .recovers(&format!("{} cut saves at {cut:?}", n + 1));
                runs += 1;
            }
            refused += life.refused;
            erases += life.flash.erases;
        }
    }
    println!("{runs} runs; the budget refused {refused} cut saves first; {erases} erases");
    assert_eq!(runs, MOST_OPS * 3 * 20);
}

/// A cut point of one store of a random run.
#[derive(Clone, Copy, Debug)]
struct RandomCut {
    op: usize,
    inside: bool,
    seed: u64,
    /// Powered time before the store, in hours.
    hours: u64,
    /// Restore defaults instead of a changed save.
    load: bool,
}

fn random_cut() -> impl Strategy<Value = RandomCut> {
    (
        0..MOST_OPS,
        any::<bool>(),
        any::<u64>(),
        prop_oneof![4 => Just(0u64), 1 => 1u64..40],
        prop::bool::weighted(0.2),
    )
        .prop_map(|(op, inside, seed, hours, load)| RandomCut {
            op,
            inside,
            seed,
            hours,
            load,
        })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    /// Runs of 1 to 20 consecutive stores (changed saves, some restore defaults), each cut
    /// at its own random point, some after hours of powered time, from a full page or a
    /// page with room: the same promises as above.
    #[test]
    fn random_runs_of_cut_stores_leave_the_store_usable(
        saves in 1u16..=6,
        run in proptest::collection::vec(random_cut(), 1..=20),
    ) {
        let mut life = Life::prepared(saves);
        for (n, at) in run.iter().enumerate() {
            let cut = if at.inside {
                Cut::Inside(at.op, at.seed)
            } else {
                Cut::Before(at.op)
            };
            let store = if at.load { Store::Load } else { Store::Save(600 + n as u16) };
            let wait_ms = at.hours * 60 * 60 * 1000;
            if life.session(wait_ms, store, Some(cut)).is_err() {
                // Refused by the budget (checked): a day of powered time gives an erase.
                life.session(wait_ms + ERASE_INTERVAL_MS + UNIT_MS, store, Some(cut))
                    .unwrap_or_else(|code| panic!("{n}: refused {code:#010x} a day later"));
            }
        }
        life.recovers(&format!("{run:?}"));
    }
}
