//! The parameter pages over the board's NOR flash model: unchanged stores write nothing,
//! changed ones append and erase only a full page (after moving to the other one), and
//! erases are bounded per powered time, across power cycles too.

use canopen_slave::{Instant, Storage, StorageError};
use handwheel_board::flash::model::CutFlash;
use handwheel_core::BitRate;
use handwheel_storage::page::{
    Flash, ParameterPage, WearBudget, DEBT_LIMIT, ERASE_BURST, ERASE_INTERVAL_MS, PAGES, PAGE_SIZE,
    RECORDS_END, TICK_AREA,
};
use handwheel_storage::record::{self, NodeSettings};
use proptest::prelude::*;

/// The parameter pages, erased, in the board's flash model (the one of every flash test of
/// either image): NOR flash as the STM32F103's behaves, refusing (panicking on) a program
/// into a half-word that is neither erased nor set to 0x0000; no power cut in these tests.
fn erased() -> CutFlash {
    CutFlash::erased(PAGES)
}

const HOUR_MS: u64 = 60 * 60 * 1000;

fn at_ms(ms: u64) -> Instant {
    Instant::from_millis(ms)
}

/// A blob the size of the handwheel's (140 bytes: a 154-byte record, six to a page), whose
/// content is `n`.
fn blob(n: u32) -> Vec<u8> {
    let mut b = vec![0x5A; 140];
    b[..4].copy_from_slice(&n.to_le_bytes());
    b
}

fn settings(node: u8, code: u8) -> NodeSettings {
    NodeSettings::from_parts(node, code).unwrap()
}

fn stored(page: &ParameterPage<CutFlash>) -> Option<(NodeSettings, Vec<u8>)> {
    page.stored().map(|(s, b)| (s, b.to_vec()))
}

#[test]
fn unchanged_stores_write_nothing() {
    let mut page = ParameterPage::new(erased());
    // Nothing stored, and "restore defaults" asked again and again: nothing to write.
    for _ in 0..100 {
        page.store(at_ms(0), &[]).unwrap();
    }
    assert_eq!((page.flash().erases, page.flash().programs), (0, 0));
    page.store(at_ms(1), &blob(1)).unwrap();
    let programs = page.flash().programs;
    assert_eq!(programs, 77, "one 154-byte record");
    for t in 0..1000 {
        page.store(at_ms(t), &blob(1)).unwrap();
    }
    // LSS storing the settings the record holds: nothing either.
    page.store_node(at_ms(5), 16, 0).unwrap();
    assert_eq!(page.flash().erases, 0);
    assert_eq!(page.flash().programs, programs);
    assert_eq!(stored(&page), Some((NodeSettings::DEFAULT, blob(1))));
}

#[test]
fn changed_stores_append_six_records_per_erase_until_the_budget_is_spent() {
    let mut page = ParameterPage::new(erased());
    let mut accepted = 0;
    let refused = loop {
        match page.store(at_ms(accepted), &blob(accepted as u32)) {
            Ok(()) => accepted += 1,
            Err(error) => break error,
        }
        assert!(accepted < 1000, "never refused");
    };
    assert_eq!(refused, StorageError::WearLimit);
    assert_eq!(accepted, 6 * (ERASE_BURST + 1));
    assert_eq!(page.flash().erases, ERASE_BURST);
    // The refusal changed nothing: the last accepted store is the stored state.
    let before = page.flash().bytes.clone();
    assert_eq!(
        page.store(at_ms(accepted), &blob(7777)),
        Err(StorageError::WearLimit)
    );
    assert_eq!(
        page.store_node(at_ms(accepted), 5, 0),
        Err(StorageError::WearLimit)
    );
    assert_eq!(page.flash().bytes, before);
    let last = blob(accepted as u32 - 1);
    assert_eq!(stored(&page), Some((NodeSettings::DEFAULT, last.clone())));
    // What is stored may still be stored again.
    page.store(at_ms(accepted), &last).unwrap();
    let mut buf = [0u8; 256];
    assert_eq!(page.load(&mut buf), 140);
    assert_eq!(&buf[..140], &last[..]);
    // Six full records leave 4 of the page's 928 record bytes: even "nothing stored" (14
    // bytes) needs a move now, and is refused.
    assert_eq!(
        page.store(at_ms(accepted), &[]),
        Err(StorageError::WearLimit)
    );
    assert_eq!(page.flash().bytes, before);
    assert_eq!(page.flash().erases, ERASE_BURST);
}

#[test]
fn a_record_that_fits_needs_no_erase_even_with_the_budget_spent() {
    let mut page = ParameterPage::new(erased());
    let mut n = 0;
    // Spend the budget, then fill the new page with five records.
    while page.store(at_ms(0), &blob(n)).is_ok() {
        n += 1;
    }
    let erases = page.flash().erases;
    let mut page = ParameterPage::new(page.into_flash());
    // The budget spent, the newest page holds six records: restore defaults has no room.
    assert_eq!(page.store(at_ms(0), &[]), Err(StorageError::WearLimit));
    // A page with room takes it without an erase: LSS settings only (14 bytes) on a page
    // where a move just left one record.
    let mut fresh = ParameterPage::new(erased());
    for i in 0..7 {
        fresh.store(at_ms(0), &blob(i)).unwrap();
    }
    assert_eq!(fresh.flash().erases, 1);
    fresh.store(at_ms(0), &[]).unwrap();
    fresh.store_node(at_ms(0), 9, 0).unwrap();
    assert_eq!(stored(&fresh), Some((settings(9, 0), Vec::new())));
    assert_eq!((fresh.flash().erases, page.flash().erases), (1, erases));
}

#[test]
fn powered_time_pays_the_debt_back_one_erase_per_interval() {
    let mut page = ParameterPage::new(erased());
    let mut n = 0;
    while page.store(at_ms(0), &blob(n)).is_ok() {
        n += 1;
    }
    // Just before one interval has passed: still refused; at it, one erase (and the five
    // appends after it), then refused again.
    let almost = at_ms(ERASE_INTERVAL_MS - 1);
    assert_eq!(page.store(almost, &blob(n)), Err(StorageError::WearLimit));
    let day = at_ms(ERASE_INTERVAL_MS);
    for i in 0..6 {
        page.store(day, &blob(n + i)).unwrap();
    }
    assert_eq!(page.flash().erases, ERASE_BURST + 1);
    assert_eq!(page.store(day, &blob(n + 6)), Err(StorageError::WearLimit));
    // After a long quiet spell the bucket is full again, but never fuller.
    let later = at_ms(ERASE_INTERVAL_MS * 100);
    let mut more = 0;
    while page.store(later, &blob(n + 100 + more)).is_ok() {
        more += 1;
    }
    assert_eq!(page.flash().erases, 2 * ERASE_BURST + 1);
}

#[test]
fn a_power_cycle_does_not_refill_the_budget() {
    let mut page = ParameterPage::new(erased());
    let mut n = 0;
    // Four hours into the session, the budget is spent.
    let t = at_ms(4 * HOUR_MS);
    while page.store(t, &blob(n)).is_ok() {
        n += 1;
    }
    let erases = page.flash().erases;
    // Power cycle: engine time starts at zero again, the debt comes from the newest record.
    let mut page = ParameterPage::new(page.into_flash());
    assert_eq!(page.store(at_ms(0), &blob(n)), Err(StorageError::WearLimit));
    assert_eq!(
        page.store(at_ms(ERASE_INTERVAL_MS - 1), &blob(n)),
        Err(StorageError::WearLimit)
    );
    // One interval of powered time in this session pays for one erase (plus at most one
    // unit of 2^26 us: the stored debt is rounded up).
    let unit_ms = (1u64 << 26) / 1000 + 1;
    page.store(at_ms(ERASE_INTERVAL_MS + unit_ms), &blob(n))
        .unwrap();
    assert_eq!(page.flash().erases, erases + 1);
}

#[test]
fn lss_settings_and_the_blob_share_the_record() {
    let mut page = ParameterPage::new(erased());
    page.set_settings(settings(10, 0));
    page.store(at_ms(0), &blob(1)).unwrap();
    // LSS: the new settings with the stored blob.
    page.store_node(at_ms(1), 5, 2).unwrap();
    assert_eq!(stored(&page), Some((settings(5, 2), blob(1))));
    // 0x1010 afterwards keeps the LSS settings.
    page.store(at_ms(2), &blob(2)).unwrap();
    assert_eq!(stored(&page), Some((settings(5, 2), blob(2))));
    // Unconfigured (0xFF) and bit-timing index 6 (50 kbit/s, DIP code 5).
    page.store_node(at_ms(3), 0xFF, 6).unwrap();
    let unconfigured = NodeSettings::from_parts(0xFF, BitRate::Kbit50.code()).unwrap();
    assert_eq!(stored(&page), Some((unconfigured, blob(2))));
    // Index 5 (100 kbit/s) and node-ID 0 cannot be stored: "not supported", nothing written.
    let programs = page.flash().programs;
    assert_eq!(
        page.store_node(at_ms(4), 5, 5),
        Err(StorageError::Unsupported)
    );
    assert_eq!(
        page.store_node(at_ms(4), 0, 0),
        Err(StorageError::Unsupported)
    );
    assert_eq!(page.flash().programs, programs);
    // Restore defaults of everything: nothing stored, LSS settings included.
    page.store(at_ms(5), &[]).unwrap();
    assert_eq!(stored(&page), None);
    assert_eq!(page.load(&mut [0u8; 256]), 0);
    // LSS after that: the settings with no blob.
    page.store_node(at_ms(6), 7, 0).unwrap();
    assert_eq!(stored(&page), Some((settings(7, 0), Vec::new())));
    assert_eq!(page.flash().erases, 0);
}

#[test]
fn a_store_cut_off_by_a_power_loss_leaves_the_previous_record() {
    let mut page = ParameterPage::new(erased());
    page.store(at_ms(0), &blob(1)).unwrap();
    page.store(at_ms(0), &blob(2)).unwrap();
    let mut flash = page.into_flash();
    // The second record's CRC never made it: its last bytes read erased... and a bit of its
    // blob is wrong, as if programming stopped half-way.
    flash.bytes[154 + 150..154 + 154].fill(0xFF);
    let page = ParameterPage::new(flash);
    assert_eq!(stored(&page), Some((NodeSettings::DEFAULT, blob(1))));
    // The next store goes after the damaged record, without an erase.
    let mut page = page;
    page.store(at_ms(0), &blob(3)).unwrap();
    assert_eq!(stored(&page), Some((NodeSettings::DEFAULT, blob(3))));
    assert_eq!(page.flash().erases, 0);
    // Garbage where a header should be: the page is erased for the next store.
    let mut flash = page.into_flash();
    flash.bytes[3 * 154] = 0x00;
    let mut page = ParameterPage::new(flash);
    assert_eq!(stored(&page), Some((NodeSettings::DEFAULT, blob(3))));
    page.store(at_ms(0), &blob(4)).unwrap();
    assert_eq!(page.flash().erases, 1);
    assert_eq!(stored(&page), Some((NodeSettings::DEFAULT, blob(4))));
}

/// Six stores on a fresh part, then the spare page made dirty as a move cut off leaves it.
fn full_with_dirty_spare() -> CutFlash {
    let mut page = ParameterPage::new(erased());
    for n in 0..6 {
        page.store(at_ms(0), &blob(n)).unwrap();
    }
    let mut flash = page.into_flash();
    flash.bytes[PAGE_SIZE + 100] = 0x00;
    flash
}

/// The debt units of `n` erase intervals, rounded up as a stored debt is.
fn units(n: u64) -> u16 {
    (n * ERASE_INTERVAL_MS * 1000).div_ceil(1 << 26) as u16
}

#[test]
fn a_spare_page_left_dirty_is_erased_after_an_erase_tick() {
    let flash = full_with_dirty_spare();
    let mut page = ParameterPage::new(flash);
    assert_eq!(page.stored_debt(), 0);
    page.store(at_ms(0), &blob(9)).unwrap();
    // The tick (one half-word, 0x0000, first of the tick area), the spare's erase, the
    // record on the spare page, the full page's erase.
    assert_eq!(
        (page.flash().erases, page.flash().programs),
        (2, 6 * 77 + 1 + 77)
    );
    assert_eq!(stored(&page), Some((NodeSettings::DEFAULT, blob(9))));
    assert!(page.flash().page(0).iter().all(|&b| b == 0xFF));
    assert_eq!(
        ParameterPage::new(page.into_flash()).stored_debt(),
        units(2)
    );
}

#[test]
fn each_erase_tick_adds_an_interval_to_the_boot_debt_and_a_cut_one_nothing() {
    let flash = full_with_dirty_spare();
    // A tick the move wrote before the power went in the spare's erase: one interval.
    let mut ticked = flash.clone();
    ticked.bytes[RECORDS_END..RECORDS_END + 2].fill(0);
    assert_eq!(ParameterPage::new(ticked.clone()).stored_debt(), units(1));
    // A tick a cut left half done: nothing, and the next move finishes it in place.
    let mut half = flash.clone();
    half.bytes[RECORDS_END] = 0x5A;
    let mut page = ParameterPage::new(half);
    assert_eq!(page.stored_debt(), 0);
    page.store(at_ms(0), &blob(9)).unwrap();
    assert_eq!(
        (page.flash().erases, page.flash().programs),
        (2, 6 * 77 + 1 + 77)
    );
    assert_eq!(stored(&page), Some((NodeSettings::DEFAULT, blob(9))));
    // Ticks never take the boot debt past the budget's limit, and a tick area with no room
    // left reads as that limit.
    let mut many = flash.clone();
    many.bytes[RECORDS_END..RECORDS_END + 2 * 20].fill(0);
    assert_eq!(ParameterPage::new(many).stored_debt(), DEBT_LIMIT);
    // No room: an intact mark (of no debt) in every slot, a tick behind each (six in all).
    let mut crafted = flash.clone();
    let mark = record::encode_mark(record::debt_field(0, 0));
    for slot in (RECORDS_END..PAGE_SIZE).step_by(16) {
        crafted.bytes[slot..slot + mark.len()].copy_from_slice(&mark);
        crafted.bytes[slot + 14..slot + 16].fill(0);
    }
    assert_eq!(
        ParameterPage::new(crafted.clone()).stored_debt(),
        DEBT_LIMIT
    );
    // Even so, one interval of powered time (and one debt unit) gives the move its first
    // erase: the spare page's. The budget has no second one for the full page, which stays
    // as it is: the new page is the newer generation, and holds the record.
    let mut page = ParameterPage::new(crafted);
    let unit_ms = (1u64 << 26) / 1000 + 1;
    assert_eq!(
        page.store(at_ms(ERASE_INTERVAL_MS), &blob(9)),
        Err(StorageError::WearLimit)
    );
    page.store(at_ms(ERASE_INTERVAL_MS + unit_ms), &blob(9))
        .unwrap();
    assert_eq!(page.flash().erases, 1);
    let page = ParameterPage::new(page.into_flash());
    assert_eq!(stored(&page), Some((NodeSettings::DEFAULT, blob(9))));
    assert!(
        page.flash().page(0)[..154] != [0xFF; 154],
        "the full page kept"
    );
    // The move's erase is in the record's debt: the next erase needs another interval.
    assert!(page.stored_debt() > DEBT_LIMIT - units(1));
}

#[test]
fn debt_marks_of_older_firmware_still_count_and_spoilt_ones_lock_nothing() {
    let flash = full_with_dirty_spare();
    // An intact mark with two days of debt in the first slot (generation 0, as the page's
    // records): the boot starts from it, and the tick goes behind it, not over it.
    let mut marked = flash.clone();
    let mark = record::encode_mark(record::debt_field(units(2), 0));
    marked.bytes[RECORDS_END..RECORDS_END + mark.len()].copy_from_slice(&mark);
    let mut page = ParameterPage::new(marked);
    assert_eq!(page.stored_debt(), units(2));
    page.store(at_ms(0), &blob(9)).unwrap();
    // Two days, the spare's erase and the full page's.
    assert_eq!(
        ParameterPage::new(page.into_flash()).stored_debt(),
        units(4)
    );
    // Every slot spoilt by marks cut off (older firmware refused every move from here on):
    // a move now, charged for its own erases only.
    let mut spoilt = flash;
    for slot in 0..TICK_AREA / 16 {
        spoilt.bytes[RECORDS_END + 16 * slot] = 0x48;
    }
    let mut page = ParameterPage::new(spoilt);
    assert_eq!(page.stored_debt(), 0);
    page.store(at_ms(0), &blob(9)).unwrap();
    assert_eq!(stored(&page), Some((NodeSettings::DEFAULT, blob(9))));
    assert_eq!(
        ParameterPage::new(page.into_flash()).stored_debt(),
        units(2)
    );
}

#[test]
fn flash_errors_are_write_failures() {
    let mut flash = erased();
    flash.dead = true; // every operation fails, as with the controller or the power gone
    let mut page = ParameterPage::new(flash);
    assert_eq!(
        page.store(at_ms(0), &blob(1)),
        Err(StorageError::WriteFailed)
    );
    assert_eq!(
        page.store(at_ms(0), &[0; 257]),
        Err(StorageError::WriteFailed)
    );
    assert_eq!(stored(&page), None);
}

#[test]
fn the_stored_debt_rounds_up_to_whole_units() {
    let unit_us = 1u64 << 26;
    let budget = WearBudget::from_stored(3);
    assert_eq!(budget.stored(Instant::ZERO), 3);
    assert_eq!(budget.stored(Instant::from_micros(1)), 3);
    assert_eq!(budget.stored(Instant::from_micros(unit_us)), 2);
    assert_eq!(budget.stored(Instant::from_micros(3 * unit_us)), 0);
    assert_eq!(budget.stored(Instant::from_micros(99 * unit_us)), 0);
    let mut budget = WearBudget::from_stored(0);
    assert!(budget.take(Instant::ZERO));
    let day_units = (ERASE_INTERVAL_MS * 1000).div_ceil(unit_us) as u16;
    assert_eq!(budget.stored(Instant::ZERO), day_units);
    // A full bucket's debt, as stored, still refuses at boot.
    let mut full = WearBudget::from_stored(0);
    for _ in 0..ERASE_BURST {
        assert!(full.take(Instant::ZERO));
    }
    assert!(!full.take(Instant::ZERO));
    let mut booted = WearBudget::from_stored(full.stored(Instant::ZERO));
    assert!(!booted.take(Instant::ZERO));
}

#[derive(Clone, Debug)]
enum Op {
    Store(u8),
    Restore,
    Lss(u8),
    Wait(u64),
    PowerCycle,
}

fn op() -> impl Strategy<Value = Op> {
    prop_oneof![
        6 => (0u8..4).prop_map(Op::Store),
        1 => Just(Op::Restore),
        1 => (1u8..4).prop_map(Op::Lss),
        2 => (0u64..6 * HOUR_MS).prop_map(Op::Wait),
        1 => Just(Op::PowerCycle),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    /// Against a model of what is stored: every accepted store is what loads afterwards,
    /// a refused one changes nothing, what is stored already writes nothing, the flash is
    /// never programmed where it is not erased, and erases stay within the budget of the
    /// powered time.
    #[test]
    fn the_page_keeps_the_last_accepted_state_within_its_erase_budget(
        ops in proptest::collection::vec(op(), 1..200),
    ) {
        let mut page = ParameterPage::new(erased());
        let mut model: Option<(NodeSettings, Vec<u8>)> = None;
        // What 0x1010 stores with the blob: the boot's settings, or the last LSS store's.
        let mut in_force = NodeSettings::DEFAULT;
        let mut now = 0u64;
        let mut powered = 0u64;
        for op in ops {
            let before = page.flash().clone();
            let (result, target) = match op.clone() {
                Op::Store(n) => {
                    let b = blob(u32::from(n));
                    (page.store(at_ms(now), &b), Some((in_force, b)))
                }
                Op::Restore => (page.store(at_ms(now), &[]), None),
                Op::Lss(node) => {
                    let b = model.as_ref().map_or(Vec::new(), |m| m.1.clone());
                    (page.store_node(at_ms(now), node, 0), Some((settings(node, 0), b)))
                }
                Op::Wait(ms) => {
                    now += ms;
                    powered += ms;
                    continue;
                }
                Op::PowerCycle => {
                    page = ParameterPage::new(page.into_flash());
                    in_force = model.as_ref().map_or(NodeSettings::DEFAULT, |m| m.0);
                    page.set_settings(in_force);
                    now = 0;
                    continue;
                }
            };
            match result {
                Ok(()) => {
                    if let (Op::Lss(node), _) = (&op, &target) {
                        in_force = settings(*node, 0);
                    }
                    if target == model {
                        prop_assert_eq!(page.flash().programs, before.programs);
                        prop_assert_eq!(page.flash().erases, before.erases);
                    }
                    model = target;
                }
                Err(error) => {
                    prop_assert_eq!(error, StorageError::WearLimit);
                    prop_assert_eq!(&page.flash().bytes, &before.bytes);
                }
            }
            prop_assert_eq!(stored(&page), model.clone());
            let allowed = ERASE_BURST + powered / ERASE_INTERVAL_MS;
            prop_assert!(page.flash().erases <= allowed);
        }
    }
}
