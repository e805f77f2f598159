//! The parameter pages: the engine's [`Storage`] over [`PAGES`] erasable flash pages (the
//! last two 1 KiB flash pages), written so that no master
//! can wear them out and no power cut loses what was stored.
//!
//! - **Unchanged means no write.** A store whose record (node-ID, bit rate, blob) equals the
//!   stored one programs and erases nothing: a master may save as often as it likes.
//! - **A log of records, erased only when full.** A changed store appends its record (layout
//!   in [`record`]) after the last one in the active page's first [`RECORDS_END`] bytes. The
//!   handwheel's full parameter set is a 154-byte record, so a page takes six changed
//!   stores. The page's last [`TICK_AREA`] bytes hold erase ticks (below).
//! - **Never erase the only copy.** A record that does not fit moves to the other (spare)
//!   page: it is programmed there first, one page generation newer, and only then is the
//!   full page erased (the classic two-page EEPROM emulation). A boot takes the page of the
//!   newer generation that holds an intact entry, so a power cut at any instant leaves the
//!   old state (the new record is incomplete) or the new one (it is complete), never an
//!   older one or none: a cut inside the erase of the old page leaves it partly erased, but
//!   older than the new page. A spare page that is not blank (a move cut off) is erased
//!   before the move.
//! - **A wear budget.** Erases are rationed by a token bucket in the form of a "generic cell
//!   rate" debt: each erase adds [`ERASE_INTERVAL_MS`] (24 h) of debt, powered time pays it
//!   back, and an erase that would push the debt past [`ERASE_BURST`] (8) intervals is
//!   refused: nothing is written, [`StorageError::WearLimit`] (SDO abort 0x08000020, LSS
//!   error 255 / 1). No erase begins before the page a boot would take carries a debt that
//!   includes it, so neither a power cycle nor a power cut refills the bucket: the full
//!   page's erase is in the debt of the moved record; the erase of a spare page left dirty
//!   is in an *erase tick* on the active page, unless the debt stored there covers it
//!   already. A tick is a half-word of the page's tick area programmed to 0x0000; a boot
//!   adds one interval per tick to the debt of the page's last entry, up to [`DEBT_LIMIT`]
//!   (the most the budget allows, so that a page needs at most [`ERASE_BURST`] ticks). A
//!   tick cut off by a power loss (a half-word neither erased nor 0x0000) counts for
//!   nothing, since its erase never began, and the next move programs 0x0000 over it (the
//!   flash controller takes 0x0000 over any half-word): a cut tick takes no room. A tick
//!   area with no room left (only a crafted page) reads as [`DEBT_LIMIT`]. Blank pages have
//!   no debt.
//! - **No lock.** The budget alone refuses a changed store, for the one erase its move needs
//!   first: the dirty spare page's, else the full page's. With a dirty spare page and no
//!   second erase in the budget, the move leaves the full page as it is (the next move
//!   erases it first). So whatever power cuts left behind, one interval of powered time in
//!   one session (plus one debt unit, 2^26 us) always gives a changed store its move.
//!
//! Arithmetic: a master storming changed stores gets 6 x (8 + 1) = 54 of them, then 6 per
//! 24 h of powered time. Erases over a life of `h` powered hours are at most 8 + h / 24 (of
//! both pages together): 20 years of continuous power are 7 313, below the 10 000 cycles
//! the STM32F103's datasheet guarantees for each page; the rated count would last 27 years
//! of a master doing nothing but storing. The price: once a master has spent the whole
//! budget, the debt is only repaid while the device is powered and stored again with the
//! next record, so a device switched off every few hours can refuse stores that need an
//! erase for longer than a day.
//!
//! Pages written before erase ticks may hold *debt marks* (a [`record`] entry of header and
//! CRC at the start of one of the tick area's six 16-byte slots, written before a spare
//! page's erase). An intact one still counts in the page's debt, and its half-words are no
//! tick positions; a mark a power cut left half written reads as ticks cut off, or as a
//! tick where one of its half-words is 0x0000 (one interval more than needed).

use canopen_slave::{Instant, Storage, StorageError};
/// The flash as both images drive it: the board's (one trait, one power-cut model).
pub use handwheel_board::flash::{Flash, FlashError, PAGE_SIZE};

use crate::record::{self, Log, NodeSettings, Record, DEBT_MAX, MARK_LEN, RECORD_MAX};

/// Bytes at the end of each page for erase ticks (one half-word each), in the six 16-byte
/// slots that held debt marks before ticks.
pub const TICK_AREA: usize = MARK_SLOTS * MARK_SLOT;
/// Slots of the tick area where a page written before ticks may hold a debt mark.
const MARK_SLOTS: usize = 6;
/// Bytes per slot: a mark and two erased bytes.
const MARK_SLOT: usize = 16;
/// Records go below this offset; the tick area follows.
pub const RECORDS_END: usize = PAGE_SIZE - TICK_AREA;
/// The value of an erase tick.
const TICK: [u8; 2] = [0, 0];
/// Erased bytes kept behind the last record, so that a walk of the records stops there.
const RECORD_GAP: usize = 4;

/// Pages the parameters take.
pub const PAGES: usize = 2;
/// Debt one erase adds, and the time that pays it back: 24 hours.
pub const ERASE_INTERVAL_MS: u64 = 24 * 60 * 60 * 1000;
/// Erases the budget allows at once (from no debt).
pub const ERASE_BURST: u64 = 8;
/// The debt in a record is in units of 2^26 us (about 67 s): a shift instead of a division.
const DEBT_UNIT_SHIFT: u32 = 26;
const INTERVAL_US: u64 = ERASE_INTERVAL_MS * 1000;
/// The largest debt the budget allows, in stored debt units rounded up: no boot starts from
/// more, and a boot that starts from this needs no tick before an erase.
pub const DEBT_LIMIT: u16 = (ERASE_BURST * INTERVAL_US).div_ceil(1 << DEBT_UNIT_SHIFT) as u16;
// The largest debt must fit a record's 14-bit debt field.
const _: () = assert!(DEBT_LIMIT < DEBT_MAX);
// Six of the handwheel's records (154 bytes) fit, a mark fits its slot, and programming
// goes by half-words.
const _: () = assert!(6 * 154 + RECORD_GAP <= RECORDS_END && MARK_LEN <= MARK_SLOT);
const _: () = assert!(RECORDS_END.is_multiple_of(2) && MARK_LEN.is_multiple_of(2));
const _: () = assert!(RECORD_MAX + RECORD_GAP <= RECORDS_END && RECORD_MAX.is_multiple_of(2));

/// The erase budget: the instant at which the erases made so far are paid back.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct WearBudget {
    paid_at: Instant,
}

impl WearBudget {
    /// The budget at boot (engine time zero) with `debt` as stored in the newest entry.
    pub const fn from_stored(debt: u16) -> Self {
        Self {
            paid_at: Instant::from_micros((debt as u64) << DEBT_UNIT_SHIFT),
        }
    }

    /// Takes one erase at `now`, if the debt stays within [`ERASE_BURST`] intervals.
    pub fn take(&mut self, now: Instant) -> bool {
        // Microseconds since boot: no sum here comes near 2^64.
        let now = now.as_micros();
        let paid_at = self.paid_at.as_micros().max(now) + INTERVAL_US;
        let allowed = paid_at - now <= ERASE_BURST * INTERVAL_US;
        if allowed {
            self.paid_at = Instant::from_micros(paid_at);
        }
        allowed
    }

    /// The debt at `now` as a record stores it (rounded up: a boot never finds less).
    pub fn stored(&self, now: Instant) -> u16 {
        let debt = self.paid_at.as_micros().saturating_sub(now.as_micros());
        // At most ERASE_BURST intervals (`take`) or what a record held (`from_stored`): the
        // units fit 14 bits (asserted at the top).
        ((debt + (1 << DEBT_UNIT_SHIFT) - 1) >> DEBT_UNIT_SHIFT) as u16
    }
}

/// The pages as a boot reads them: which one is active (holds the stored state), its log,
/// its newest debt mark, its erase ticks and where the next one goes.
struct View<'a> {
    active: usize,
    log: Log<'a>,
    /// The debt and generation of the active page's newest intact debt mark (written by
    /// firmware before erase ticks).
    mark: Option<(u16, u8)>,
    /// The active page's complete erase ticks: tick positions that read 0x0000.
    ticks: u16,
    /// The offset of the active page's first tick position that is not a complete tick:
    /// erased, or a tick a power cut left half done.
    next_tick: Option<usize>,
}

impl View<'_> {
    /// The debt a boot starts from: the larger of the last entry's and the newest mark's,
    /// one interval more per tick, at most [`DEBT_LIMIT`] (which a full tick area reads as).
    fn debt(&self) -> u16 {
        let mark = self.mark.map_or(0, |(debt, _)| debt);
        let base = self.log.debt.unwrap_or(0).max(mark);
        match self.next_tick {
            Some(_) => {
                // At most 48 ticks: no sum here comes near 2^64.
                let ticks = (u64::from(self.ticks) * INTERVAL_US).div_ceil(1 << DEBT_UNIT_SHIFT);
                // At most DEBT_LIMIT, a u16.
                (u64::from(base) + ticks).min(u64::from(DEBT_LIMIT)) as u16
            }
            None => DEBT_LIMIT,
        }
    }

    /// The active page's generation (0 for a page without entries).
    fn generation(&self) -> u8 {
        self.log
            .generation
            .or(self.mark.map(|(_, generation)| generation))
            .unwrap_or(0)
    }
}

/// One page as a boot reads it.
fn read(page: &[u8]) -> View<'_> {
    let mut view = View {
        active: 0,
        log: record::scan(page),
        mark: None,
        ticks: 0,
        next_tick: None,
    };
    for slot in (RECORDS_END..PAGE_SIZE).step_by(MARK_SLOT) {
        let mut positions = slot;
        if let Some(mark) = page.get(slot..).and_then(record::decode_mark) {
            view.mark = Some(mark);
            positions += MARK_LEN;
        }
        for at in (positions..slot + MARK_SLOT).step_by(2) {
            match page.get(at..at + 2) {
                Some(half) if half == TICK => view.ticks += 1,
                Some(_) => view.next_tick = view.next_tick.or(Some(at)),
                None => {}
            }
        }
    }
    view
}

/// The active page: of two pages with intact entries, the one a generation newer (the other
/// is the page a move left, erased or not); else the one with entries; else page 0.
fn view<F: Flash>(flash: &F) -> View<'_> {
    let first = read(flash.page(0));
    let mut second = read(flash.page(1));
    let entries = |v: &View<'_>| v.log.generation.is_some() || v.mark.is_some();
    let newer = match (entries(&first), entries(&second)) {
        (true, true) => {
            second.generation().wrapping_sub(first.generation()) % record::GENERATIONS == 1
        }
        (false, true) => true,
        _ => false,
    };
    if newer {
        second.active = 1;
        second
    } else {
        first
    }
}

/// Whether `len` bytes from `at` of `page` read erased.
fn blank(page: &[u8], at: usize, len: usize) -> bool {
    page.get(at..at + len)
        .is_some_and(|bytes| bytes.iter().all(|&b| b == 0xFF))
}

/// The parameter pages as the engine's storage.
pub struct ParameterPage<F> {
    flash: F,
    /// Stored with every blob: the node-ID and bit rate in force, or the last LSS store's.
    settings: NodeSettings,
    budget: WearBudget,
}

impl<F: Flash> ParameterPage<F> {
    /// The pages as found at boot; the budget starts from the active page's last entry's
    /// debt. Blobs are stored with the factory settings until
    /// [`ParameterPage::set_settings`].
    pub fn new(flash: F) -> Self {
        let debt = view(&flash).debt();
        Self {
            flash,
            settings: NodeSettings::DEFAULT,
            budget: WearBudget::from_stored(debt),
        }
    }

    /// The node-ID and bit rate in force, which 0x1010 stores with the blob.
    pub fn set_settings(&mut self, settings: NodeSettings) {
        self.settings = settings;
    }

    /// The stored state: settings and blob, or `None` when nothing is stored.
    pub fn stored(&self) -> Option<(NodeSettings, &[u8])> {
        let newest = view(&self.flash).log.newest?;
        Some((newest.settings?, newest.blob))
    }

    /// The wear debt a boot would start from now, in units of 2^26 us.
    pub fn stored_debt(&self) -> u16 {
        view(&self.flash).debt()
    }

    /// The flash, e.g. for tests that damage it.
    pub fn flash(&self) -> &F {
        &self.flash
    }

    /// Gives the flash back.
    pub fn into_flash(self) -> F {
        self.flash
    }

    /// Makes `settings` and `blob` (`None`: the stored blob) the stored state: nothing when
    /// they are the stored state already, else a record appended to the active page, or
    /// moved to the spare page when it does not fit and the budget allows.
    fn write(
        &mut self,
        now: Instant,
        settings: Option<NodeSettings>,
        blob: Option<&[u8]>,
    ) -> Result<(), StorageError> {
        // Word-aligned, so that filling it uses the word-wise `memset` the image already has.
        #[repr(align(4))]
        struct Aligned([u8; RECORD_MAX]);
        let mut buf = Aligned([0; RECORD_MAX]);
        let view = view(&self.flash);
        let (active, log) = (view.active, view.log);
        let old = log.newest.unwrap_or(Record {
            settings: None,
            blob: &[],
            debt: 0,
            generation: 0,
        });
        let blob = blob.unwrap_or(old.blob);
        let same_settings =
            record::settings_bytes(old.settings) == record::settings_bytes(settings);
        if same_settings && same(old.blob, blob) {
            return Ok(());
        }
        let len = record::encoded_len(blob.len()).ok_or(StorageError::WriteFailed)?;
        let generation = view.generation();
        let page = self.flash.page(active);
        // Room for the record and a gap behind it, below the mark slots.
        if log.free + len + RECORD_GAP <= RECORDS_END && blank(page, log.free, len) {
            let debt = record::debt_field(self.budget.stored(now), generation);
            record::encode(settings, blob, debt, &mut buf.0).ok_or(StorageError::WriteFailed)?;
            return self.program(active, log.free, &buf.0, len);
        }
        // The move. A spare page that is not blank (a move cut off, or one that left the
        // full page as it was) is erased first, with its erase in the budget and, before it
        // begins, in the debt a boot would start from (a tick, unless that debt covers it
        // already). The full page is erased once the record is on the spare page; when the
        // spare page needed an erase and the budget has no second one, the full page stays
        // as it is, the dirty spare page of the next move.
        let spare = 1 - active;
        let spare_blank = blank(self.flash.page(spare), 0, PAGE_SIZE);
        let mut budget = self.budget;
        if !spare_blank && !budget.take(now) {
            return Err(StorageError::WearLimit);
        }
        let tick = !spare_blank && budget.stored(now) > view.debt();
        let erase_full = budget.take(now);
        if spare_blank && !erase_full {
            return Err(StorageError::WearLimit);
        }
        // Never refused here: with no tick position left the page's debt is DEBT_LIMIT,
        // which no debt the budget allows exceeds, so no tick is needed.
        let tick_at = match (tick, view.next_tick) {
            (false, _) => None,
            (true, Some(at)) => Some(at),
            (true, None) => return Err(StorageError::WearLimit),
        };
        self.budget = budget;
        let next = (generation + 1) % record::GENERATIONS;
        let debt = record::debt_field(budget.stored(now), next);
        record::encode(settings, blob, debt, &mut buf.0).ok_or(StorageError::WriteFailed)?;
        if !spare_blank {
            if let Some(at) = tick_at {
                // Over an erased half-word, or over a tick a power cut left half done.
                self.program(active, at, &TICK, TICK.len())?;
            }
            self.erase(spare)?;
        }
        self.program(spare, 0, &buf.0, len)?;
        if erase_full {
            self.erase(active)?;
        }
        Ok(())
    }

    fn erase(&mut self, page: usize) -> Result<(), StorageError> {
        self.flash
            .erase(page)
            .map_err(|_| StorageError::WriteFailed)
    }

    /// Programs the first `len` bytes of `bytes` at `offset` of `page`. The master learns
    /// of a failure from the answer (SDO 0x06060000, LSS error 2).
    fn program(
        &mut self,
        page: usize,
        offset: usize,
        bytes: &[u8],
        len: usize,
    ) -> Result<(), StorageError> {
        let bytes = bytes.get(..len).ok_or(StorageError::WriteFailed)?;
        self.flash
            .program(page, offset, bytes)
            .map_err(|_| StorageError::WriteFailed)
    }
}
/// Byte-wise equality without `memcmp` (which the image does not otherwise need).
fn same(a: &[u8], b: &[u8]) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(x, y)| x == y)
}

impl<F: Flash> Storage for ParameterPage<F> {
    fn load(&mut self, buf: &mut [u8]) -> usize {
        let Some((_, blob)) = self.stored() else {
            return 0;
        };
        match buf.get_mut(..blob.len()) {
            Some(dst) => {
                dst.copy_from_slice(blob);
                blob.len()
            }
            // A blob the engine cannot take is as good as none: defaults apply.
            None => 0,
        }
    }

    /// 0x1010 and 0x1011: the blob with the settings in force; an empty blob (0x1011 of
    /// everything) stores "nothing stored", LSS settings included.
    fn store(&mut self, now: Instant, blob: &[u8]) -> Result<(), StorageError> {
        let settings = (!blob.is_empty()).then_some(self.settings);
        self.write(now, settings, Some(blob))
    }

    /// LSS "store configuration": the new node-ID and bit rate with the blob stored now (if
    /// any), so that 0x1010 and LSS share one record; a later 0x1010 store keeps them.
    fn store_node(
        &mut self,
        now: Instant,
        node_id: u8,
        bit_timing: u8,
    ) -> Result<(), StorageError> {
        let settings =
            NodeSettings::from_lss(node_id, bit_timing).ok_or(StorageError::Unsupported)?;
        self.write(now, Some(settings), None)?;
        self.settings = settings;
        #[cfg(feature = "defmt")]
        defmt::info!("LSS stored {}", settings);
        Ok(())
    }
}
