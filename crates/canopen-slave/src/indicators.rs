//! CiA 303-3 indicator (LED) patterns, as a pure function of state and time.

use crate::nmt::NmtState;

/// Error indication of the ERR LED, ordered by severity so that the firmware can combine
/// its own conditions (warning limit, bus-off) with the engine's using `max`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ErrorIndication {
    /// No error: off.
    NoError,
    /// A CAN error counter reached the warning limit: single flash.
    WarningLimit,
    /// Heartbeat consumer timeout (error-control event): double flash.
    ErrorControlEvent,
    /// SYNC not received in time: triple flash.
    SyncTimeout,
    /// Bus-off: on.
    BusOff,
}

/// One CiA 303-3 blink pattern.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Pattern {
    /// Always off.
    Off,
    /// Always on.
    On,
    /// 10 Hz: 50 ms on, 50 ms off.
    Flickering,
    /// 2.5 Hz: 200 ms on, 200 ms off.
    Blinking,
    /// `n` flashes of 200 ms separated by 200 ms, then 1000 ms off (n = 1..=4).
    Flashes(u8),
}

impl Pattern {
    /// Whether the LED is lit at `now_ms` (patterns start at time 0).
    #[must_use]
    pub const fn is_on(self, now_ms: u32) -> bool {
        match self {
            Self::Off => false,
            Self::On => true,
            Self::Flickering => now_ms % 100 < 50,
            Self::Blinking => now_ms % 400 < 200,
            Self::Flashes(n) => {
                let lit = 400 * n as u32;
                let t = now_ms % (lit + 800);
                // The last "off 200" of the flashes merges into the 1000 ms pause.
                t < lit && t % 400 < 200
            }
        }
    }
}

/// The RUN (green) pattern for an NMT state.
pub const fn run_pattern(nmt: NmtState) -> Pattern {
    match nmt {
        NmtState::Initialising => Pattern::Off,
        NmtState::PreOperational => Pattern::Blinking,
        NmtState::Operational => Pattern::On,
        NmtState::Stopped => Pattern::Flashes(1),
    }
}

/// The ERR (red) pattern for an error indication.
pub const fn err_pattern(err: ErrorIndication) -> Pattern {
    match err {
        ErrorIndication::NoError => Pattern::Off,
        ErrorIndication::WarningLimit => Pattern::Flashes(1),
        ErrorIndication::ErrorControlEvent => Pattern::Flashes(2),
        ErrorIndication::SyncTimeout => Pattern::Flashes(3),
        ErrorIndication::BusOff => Pattern::On,
    }
}

/// `(RUN, ERR)` LED levels at `now_ms`.
#[must_use]
pub const fn indicators(nmt: NmtState, err: ErrorIndication, now_ms: u32) -> (bool, bool) {
    (
        run_pattern(nmt).is_on(now_ms),
        err_pattern(err).is_on(now_ms),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Times (ms, within the first period) at which the LED switches on or off.
    fn edges(p: Pattern, period: u32) -> [bool; 16] {
        let probes = [
            0, 49, 50, 99, 100, 199, 200, 399, 400, 599, 600, 799, 800, 1199, 1999, period,
        ];
        probes.map(|t| p.is_on(t))
    }

    #[test]
    fn flickering_and_blinking() {
        assert_eq!(
            [0, 49, 50, 99, 100, 149, 150].map(|t| Pattern::Flickering.is_on(t)),
            [true, true, false, false, true, true, false]
        );
        assert_eq!(
            [0, 199, 200, 399, 400, 599, 600, 800].map(|t| Pattern::Blinking.is_on(t)),
            [true, true, false, false, true, true, false, true]
        );
    }

    #[test]
    fn flashes() {
        // Single: on 0..200, off 200..1200.
        let single = [
            true, true, true, true, true, true, false, false, false, false, false, false, false,
            false, false, true,
        ];
        assert_eq!(edges(Pattern::Flashes(1), 1200), single);
        // Double: on 0..200 and 400..600, off 600..1600.
        let double = [
            true, true, true, true, true, true, false, false, true, true, false, false, false,
            false, false, true,
        ];
        assert_eq!(edges(Pattern::Flashes(2), 1600), double);
        // Triple: third flash at 800..1000, off until 2000.
        let triple = [
            true, true, true, true, true, true, false, false, true, true, false, false, true,
            false, false, true,
        ];
        assert_eq!(edges(Pattern::Flashes(3), 2000), triple);
        assert!(Pattern::Flashes(3).is_on(999));
        assert!(!Pattern::Flashes(3).is_on(1000));
        assert!(Pattern::Flashes(3).is_on(2000 + 850));
    }

    #[test]
    fn run_and_err_leds() {
        use ErrorIndication::*;
        assert_eq!(
            indicators(NmtState::Operational, NoError, 12_345),
            (true, false)
        );
        assert_eq!(
            indicators(NmtState::PreOperational, NoError, 100),
            (true, false)
        );
        assert_eq!(
            indicators(NmtState::PreOperational, NoError, 300),
            (false, false)
        );
        assert_eq!(indicators(NmtState::Stopped, BusOff, 150), (true, true));
        assert_eq!(indicators(NmtState::Stopped, BusOff, 250), (false, true));
        assert_eq!(
            indicators(NmtState::Initialising, NoError, 0),
            (false, false)
        );
        assert_eq!(
            indicators(NmtState::Operational, WarningLimit, 1250),
            (true, true)
        );
        assert_eq!(
            indicators(NmtState::Operational, WarningLimit, 1450),
            (true, false)
        );
        assert_eq!(
            indicators(NmtState::Operational, ErrorControlEvent, 1600 + 450),
            (true, true)
        );
        assert_eq!(
            indicators(NmtState::Operational, ErrorControlEvent, 1600 + 650),
            (true, false)
        );
        assert_eq!(
            indicators(NmtState::Operational, SyncTimeout, 850),
            (true, true)
        );
        assert_eq!(
            indicators(NmtState::Operational, SyncTimeout, 1050),
            (true, false)
        );
        // Wrapping of the millisecond counter never panics.
        let _ = indicators(NmtState::Stopped, SyncTimeout, u32::MAX);
        assert!(BusOff > SyncTimeout && SyncTimeout > ErrorControlEvent);
        assert!(ErrorControlEvent > WarningLimit && WarningLimit > NoError);
    }
}
