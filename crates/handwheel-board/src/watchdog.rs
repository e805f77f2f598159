//! The independent watchdog, as both images run it: the HAL's `IndependentWatchdog`,
//! stopped while a debugger halts the core. The loader starts it before each start of the
//! application (the trial boot), and the application feeds it from then on.
//!
//! The HAL picks prescaler and reload for the timeout from the nominal 40 kHz of the LSI
//! (for 500 ms: /8 and 2500, 500.2 ms). The LSI varies from 30 to 60 kHz over temperature and
//! parts, so the real timeout lies between 0.67 and 1.33 times the nominal one.

use stm32f1xx_hal::{
    pac::{DBGMCU, IWDG},
    time::MilliSeconds,
    watchdog::IndependentWatchdog,
};

/// The independent watchdog.
pub struct Watchdog {
    iwdg: IndependentWatchdog,
}

impl Watchdog {
    /// Takes the peripheral; a debugger halt stops the watchdog so debugging does not reset.
    pub fn new(iwdg: IWDG, dbgmcu: &DBGMCU) -> Self {
        let iwdg = IndependentWatchdog::new(iwdg);
        iwdg.stop_on_debug(dbgmcu, true);
        Self { iwdg }
    }

    /// Starts the watchdog with a nominal timeout of `ms` (at most 26 s), or sets a new
    /// timeout on the running one. It cannot be stopped again: from now on
    /// [`Watchdog::feed`] must come in time.
    pub fn start(&mut self, ms: u32) {
        self.iwdg.start(MilliSeconds::millis(ms));
    }

    /// Restarts the countdown.
    pub fn feed(&mut self) {
        self.iwdg.feed();
    }
}
