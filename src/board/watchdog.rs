//! The independent watchdog, set up with fixed register values.
//!
//! The HAL's driver searches prescaler and reload at run time with 64-bit arithmetic, which
//! links a 64-bit division into the image (about 1 KiB) for a value known at build time.

use crate::pac::{DBGMCU, IWDG};

/// The watchdog's clock, the LSI RC oscillator: 40 kHz typical (30-60 kHz over temperature
/// and parts, so the real timeout lies between 0.67 and 1.33 times the nominal one).
const LSI_HZ: u32 = 40_000;
/// Prescaler /32 (PR = 3): 1.25 kHz, 0.8 ms per count, up to 3.2 s.
const PRESCALER_CODE: u8 = 3;
const PRESCALER: u32 = 32;

const KEY_ACCESS: u16 = 0x5555;
const KEY_RELOAD: u16 = 0xAAAA;
const KEY_START: u16 = 0xCCCC;

/// The reload value for a nominal timeout of `ms`, clamped to the 12-bit counter.
pub const fn reload_for_ms(ms: u32) -> u16 {
    let counts = ms * (LSI_HZ / PRESCALER) / 1000;
    if counts > 0xFFF {
        0xFFF
    } else {
        counts as u16
    }
}

/// The independent watchdog, not yet started.
pub struct Watchdog {
    iwdg: IWDG,
}

impl Watchdog {
    /// Takes the peripheral; a debugger halt stops the watchdog so debugging does not reset.
    pub fn new(iwdg: IWDG, dbgmcu: &DBGMCU) -> Self {
        dbgmcu.cr().modify(|_, w| w.dbg_iwdg_stop().set_bit());
        Self { iwdg }
    }

    /// Starts the watchdog with a nominal timeout of `ms` (at most 3276 ms). It cannot be
    /// stopped again: from now on [`Watchdog::feed`] must come in time.
    pub fn start(&mut self, ms: u32) {
        let key = |iwdg: &IWDG, key: u16| {
            // SAFETY: KR is a write-only key register; these three keys are the documented
            // ones (unlock PR/RLR, reload, start) and have no other effect.
            iwdg.kr().write(|w| unsafe { w.key().bits(key) })
        };
        key(&self.iwdg, KEY_START);
        key(&self.iwdg, KEY_ACCESS);
        // SAFETY: 3 is a valid 3-bit prescaler code (/32).
        self.iwdg
            .pr()
            .write(|w| unsafe { w.pr().bits(PRESCALER_CODE) });
        self.iwdg.rlr().write(|w| w.rl().set(reload_for_ms(ms)));
        // The new values take effect once the update flags clear (a few LSI cycles).
        while self.iwdg.sr().read().bits() != 0 {}
        key(&self.iwdg, KEY_RELOAD);
    }

    /// Restarts the countdown.
    pub fn feed(&mut self) {
        // SAFETY: the reload key, see `start`.
        self.iwdg
            .kr()
            .write(|w| unsafe { w.key().bits(KEY_RELOAD) });
    }
}
