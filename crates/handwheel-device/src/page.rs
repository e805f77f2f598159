//! The parameter page: the engine's [`Storage`] over one erasable page (the last 1 KiB flash
//! page on the board, a RAM page in the QEMU variant), written so that no master can wear
//! it out.
//!
//! - **Unchanged means no write.** A store whose record (node-ID, bit rate, blob) equals the
//!   stored one programs and erases nothing: a master may save as often as it likes.
//! - **A log of records, erased only when full.** A changed store appends its record (layout
//!   in [`record`]) after the last one; only a record that no longer fits erases the page and
//!   starts it again. The handwheel's full parameter set is a 154-byte record, so a page
//!   takes six changed stores per erase.
//! - **A wear budget.** Erases are rationed by a token bucket in the form of a "generic cell
//!   rate" debt: each erase adds [`ERASE_INTERVAL_MS`] (24 h) of debt, powered time pays it
//!   back, and an erase that would push the debt past [`ERASE_BURST`] (8) intervals is
//!   refused: nothing is written, [`StorageError::WearLimit`] (SDO abort 0x08000020, LSS
//!   error 255 / 1). Every record carries the debt at its writing, and a boot starts from
//!   the newest record's, so a power cycle does not refill the bucket. A fresh page (no
//!   record) has no debt.
//!
//! Arithmetic: a master storming changed stores gets 6 x (8 + 1) = 54 of them, then 6 per
//! 24 h of powered time. Erases over a life of `h` powered hours are at most 8 + h / 24:
//! 20 years of continuous power are 7 313, below the 10 000 cycles the STM32F103's
//! datasheet guarantees; the rated count would last 27 years of a master doing nothing but
//! storing. The price: once a master has spent the whole budget, the debt is only repaid
//! while the device is powered and stored again with the next record, so a device switched
//! off every few hours can refuse stores that need an erase for longer than a day.

use canopen_slave::{Instant, Storage, StorageError};

use crate::record::{self, NodeSettings, Record, RECORD_MAX};

/// Bytes in the page.
pub const PAGE_SIZE: usize = 1024;
/// Debt one erase adds, and the time that pays it back: 24 hours.
pub const ERASE_INTERVAL_MS: u64 = 24 * 60 * 60 * 1000;
/// Erases the budget allows at once (from no debt).
pub const ERASE_BURST: u64 = 8;
/// The debt in a record is in units of 2^26 us (about 67 s): a shift instead of a division.
const DEBT_UNIT_SHIFT: u32 = 26;
const INTERVAL_US: u64 = ERASE_INTERVAL_MS * 1000;
// The largest debt must fit a record's 16-bit field.
const _: () = assert!((ERASE_BURST * INTERVAL_US) >> DEBT_UNIT_SHIFT < u16::MAX as u64);
// A record must fit the page, and programming goes by half-words.
const _: () = assert!(RECORD_MAX <= PAGE_SIZE && RECORD_MAX.is_multiple_of(2));

/// A failed erase or program.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FlashError {
    /// The erase failed or did not read back as erased.
    Erase,
    /// Programming failed or did not read back as written.
    Program,
    /// The flash controller would not unlock.
    Controller,
}

/// One erasable page, as the firmware drives it.
pub trait Flash {
    /// The page as it reads now: [`PAGE_SIZE`] bytes.
    fn page(&self) -> &[u8];
    /// Erases the page: every byte reads 0xFF after success.
    fn erase(&mut self) -> Result<(), FlashError>;
    /// Programs `bytes` (even length) at the even `offset`, into erased bytes only (the page
    /// checks that they read 0xFF before asking).
    fn program(&mut self, offset: usize, bytes: &[u8]) -> Result<(), FlashError>;

    /// The engine loaded the stored parameters (at an initialisation), stored with these
    /// settings: for a board that wants to report them.
    fn on_load(&self, _settings: NodeSettings) {}
}

/// The erase budget: the instant at which the erases made so far are paid back.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct WearBudget {
    paid_at: Instant,
}

impl WearBudget {
    /// The budget at boot (engine time zero) with `debt` as stored in the newest record.
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
        // units fit 16 bits (asserted at the top).
        ((debt + (1 << DEBT_UNIT_SHIFT) - 1) >> DEBT_UNIT_SHIFT) as u16
    }
}

/// The parameter page as the engine's storage.
pub struct ParameterPage<F> {
    flash: F,
    /// Stored with every blob: the node-ID and bit rate in force, or the last LSS store's.
    settings: NodeSettings,
    budget: WearBudget,
}

impl<F: Flash> ParameterPage<F> {
    /// The page as found at boot; its budget starts from the newest record's debt. Blobs are
    /// stored with the factory settings until [`ParameterPage::set_settings`].
    pub fn new(flash: F) -> Self {
        let debt = record::scan(flash.page()).newest.map_or(0, |r| r.debt);
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
        let newest = record::scan(self.flash.page()).newest?;
        Some((newest.settings?, newest.blob))
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
    /// they are the stored state already, else a record appended, or the page erased first
    /// when it is full and the budget allows.
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
        let page = self.flash.page();
        let log = record::scan(page);
        let old = log.newest.unwrap_or(Record {
            settings: None,
            blob: &[],
            debt: 0,
        });
        let blob = blob.unwrap_or(old.blob);
        let same_settings =
            record::settings_bytes(old.settings) == record::settings_bytes(settings);
        if same_settings && same(old.blob, blob) {
            return Ok(());
        }
        let len = record::encoded_len(blob.len()).ok_or(StorageError::WriteFailed)?;
        let room = page
            .get(log.free..log.free + len)
            .is_some_and(|bytes| bytes.iter().all(|&b| b == 0xFF));
        if !room && !self.budget.take(now) {
            return Err(StorageError::WearLimit);
        }
        let debt = self.budget.stored(now);
        record::encode(settings, blob, debt, &mut buf.0).ok_or(StorageError::WriteFailed)?;
        let (at, erased) = if room {
            (log.free, Ok(()))
        } else {
            (0, self.flash.erase())
        };
        let bytes = buf.0.get(..len).unwrap_or(&[]);
        // The master learns of a failure from the answer (SDO 0x06060000, LSS error 2).
        erased
            .and_then(|()| self.flash.program(at, bytes))
            .map_err(|_| StorageError::WriteFailed)
    }
}

/// Byte-wise equality without `memcmp` (which the image does not otherwise need).
fn same(a: &[u8], b: &[u8]) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(x, y)| x == y)
}

impl<F: Flash> Storage for ParameterPage<F> {
    fn load(&mut self, buf: &mut [u8]) -> usize {
        let Some((settings, blob)) = self.stored() else {
            return 0;
        };
        self.flash.on_load(settings);
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
