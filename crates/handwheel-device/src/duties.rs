//! The CAN side's periodic duties and how long it may sleep: the decisions of the firmware's
//! `canopen` loop, host-tested here; the loop only reads inputs and applies outputs.
//!
//! - every [`SAMPLE_PERIOD_MS`]: the axis and multiplier switches (debounced) and the wheel's
//!   standstill (the decoder learns its rest after [`STANDSTILL_MS`](handwheel_core::STANDSTILL_MS));
//! - every [`LED_PERIOD_MS`]: the CiA 303-3 RUN and ERR patterns, the ERR LED showing the
//!   worse of the protocol's error (heartbeat loss) and the bus's (warning, passive, off);
//! - sleep until the device's next deadline or the next duty, never longer than
//!   [`MAX_SLEEP_MS`] (the loop feeds the watchdog), and while the controller is not
//!   error-active at most [`RECOVERY_POLL_MS`] (no interrupt announces its recovery).

use canopen_slave::{indicators, sleep_ms, BusState, ErrorIndication, Instant, NmtState, Periodic};
use handwheel_core::{
    Handwheel, Mutex, Selection, Selector, SelectorInput, Standstill, DEFAULT_DEBOUNCE_SAMPLES,
};

/// Switch sampling period: 4 stable samples make the 20 ms debounce; also the resolution of
/// the standstill time.
pub const SAMPLE_PERIOD_MS: u32 = 5;
/// LED update period: a quarter of the 200 ms CiA 303-3 phase.
pub const LED_PERIOD_MS: u32 = 50;
/// The longest sleep, so that the loop feeds the watchdog (500 ms) in time.
pub const MAX_SLEEP_MS: u32 = 100;
/// The longest sleep while the controller is not error-active: how soon its recovery is
/// seen.
pub const RECOVERY_POLL_MS: u32 = 10;

/// The axis and multiplier debouncer.
const SELECTOR: Selector = match Selector::new(DEFAULT_DEBOUNCE_SAMPLES) {
    Some(selector) => selector,
    None => panic!("the default debounce count is valid"),
};

/// What one switch sample found.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Sample {
    /// The debounced selection, when it changed.
    pub selection: Option<Selection>,
    /// The wheel stood still long enough and its rest was learnt anew.
    pub rest_learnt: bool,
}

/// The periodic duties' state.
#[derive(Clone, Debug, Hash)]
pub struct Duties {
    next_sample: Periodic,
    next_led: Periodic,
    standstill: Standstill,
    selector: Selector,
}

impl Duties {
    /// Both duties due at `now_ms` (a wrapping millisecond tick), then every period; a late
    /// round is not caught up in a burst (the debouncer counts samples).
    pub const fn new(now_ms: u32) -> Self {
        Self {
            next_sample: Periodic::new(now_ms, SAMPLE_PERIOD_MS),
            next_led: Periodic::new(now_ms, LED_PERIOD_MS),
            standstill: Standstill::new(),
            selector: SELECTOR,
        }
    }

    /// How many milliseconds the loop may sleep from `now_ms` (`now` on the device's clock):
    /// until the device's `deadline` or the next duty, within the caps of the module docs.
    pub fn sleep_ms(
        &self,
        now_ms: u32,
        now: Instant,
        deadline: Option<Instant>,
        bus: BusState,
    ) -> u32 {
        let cap = match bus {
            BusState::ErrorActive => MAX_SLEEP_MS,
            _ => RECOVERY_POLL_MS,
        };
        let device = deadline.map_or(cap, |t| sleep_ms(now, t, cap));
        let until = |at: u32| match at.wrapping_sub(now_ms) {
            // Already due (the tick passed it).
            ahead if ahead >= 1 << 31 => 0,
            ahead => ahead,
        };
        device
            .min(until(self.next_sample.next_ms()))
            .min(until(self.next_led.next_ms()))
    }

    /// The switch and standstill sample, when it is due at `now_ms`.
    pub fn sample(
        &mut self,
        now_ms: u32,
        switches: &mut impl SelectorInput,
        wheel: &mut impl Mutex<T = Handwheel>,
    ) -> Option<Sample> {
        if !self.next_sample.is_due(now_ms) {
            return None;
        }
        let standstill = &mut self.standstill;
        let learnt = wheel.lock(|w| w.rests_learnt());
        // At most once per standstill a settle request, which the edge applies at once if
        // the wheel has not moved since.
        let asked = wheel.lock(|w| standstill.sample(now_ms, w));
        let rest_learnt = asked && wheel.lock(|w| w.rests_learnt()) != learnt;
        Some(Sample {
            selection: self.selector.sample_input(switches),
            rest_learnt,
        })
    }

    /// The RUN and ERR LED levels, when their update is due at `now_ms`.
    pub fn leds(
        &mut self,
        now_ms: u32,
        nmt: NmtState,
        protocol: ErrorIndication,
        bus: BusState,
    ) -> Option<(bool, bool)> {
        if !self.next_led.is_due(now_ms) {
            return None;
        }
        Some(indicators(nmt, protocol.max(bus.indication()), now_ms))
    }
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use handwheel_core::{AbLevels, Axis, DecoderConfig, Intake, LinkedWheel, Multiplier, Wheel};
    use std::vec::Vec;

    struct Lines(u8, u8);

    impl SelectorInput for Lines {
        fn read_lines(&mut self) -> (u8, u8) {
            (self.0, self.1)
        }
    }

    fn at(ms: u32) -> Instant {
        Instant::from_millis(u64::from(ms))
    }

    #[test]
    fn sleeps_until_the_nearest_of_deadline_and_duties() {
        let mut d = Duties::new(1000);
        let active = BusState::ErrorActive;
        // Both duties are due at once.
        assert_eq!(d.sleep_ms(1000, at(1000), None, active), 0);
        let mut wheel = LinkedWheel::local(DecoderConfig::default(), AbLevels::from_bits(0));
        assert!(d.sample(1000, &mut Lines(0, 0), &mut wheel).is_some());
        assert!(d
            .leds(
                1000,
                NmtState::PreOperational,
                ErrorIndication::NoError,
                active
            )
            .is_some());
        // Next sample in 5 ms; a device deadline 2 ms away comes first; a far one does not.
        assert_eq!(d.sleep_ms(1000, at(1000), None, active), SAMPLE_PERIOD_MS);
        assert_eq!(d.sleep_ms(1000, at(1000), Some(at(1002)), active), 2);
        assert_eq!(d.sleep_ms(1000, at(1000), Some(at(9000)), active), 5);
        // A late loop sleeps 0, not a negative time wrapped around.
        assert_eq!(d.sleep_ms(1007, at(1007), None, active), 0);
    }

    #[test]
    fn sleep_is_capped_for_the_watchdog_and_for_bus_recovery() {
        let mut d = Duties::new(0);
        let mut wheel = LinkedWheel::local(DecoderConfig::default(), AbLevels::from_bits(0));
        let _ = d.sample(0, &mut Lines(0, 0), &mut wheel);
        let _ = d.leds(
            0,
            NmtState::PreOperational,
            ErrorIndication::NoError,
            BusState::ErrorActive,
        );
        // Without duties in the way (as if their periods were long): only the caps remain.
        let far = Duties {
            next_sample: Periodic::new(10_000, SAMPLE_PERIOD_MS),
            next_led: Periodic::new(10_000, LED_PERIOD_MS),
            ..d
        };
        assert_eq!(
            far.sleep_ms(0, at(0), None, BusState::ErrorActive),
            MAX_SLEEP_MS
        );
        assert_eq!(
            far.sleep_ms(0, at(0), Some(at(5000)), BusState::ErrorActive),
            MAX_SLEEP_MS
        );
        for bus in [BusState::Warning, BusState::ErrorPassive, BusState::BusOff] {
            assert_eq!(
                far.sleep_ms(0, at(0), None, bus),
                RECOVERY_POLL_MS,
                "{bus:?}"
            );
        }
    }

    #[test]
    fn switches_are_debounced_on_the_sample_period() {
        let mut d = Duties::new(0);
        let mut wheel = LinkedWheel::local(DecoderConfig::default(), AbLevels::from_bits(0));
        let mut z_x100 = Lines(1 << 2, 1 << 2);
        let mut changes = 0;
        for ms in 0..=30 {
            if let Some(sample) = d.sample(ms, &mut z_x100, &mut wheel) {
                if let Some(selection) = sample.selection {
                    changes += 1;
                    assert_eq!(selection.axis, Some(Axis::Z));
                    assert_eq!(selection.multiplier, Multiplier::X100);
                    // Four stable samples, 5 ms apart, from the first at 0 ms.
                    assert_eq!(ms, 15);
                }
            }
        }
        assert_eq!(changes, 1);
    }

    #[test]
    fn a_wheel_still_off_its_rest_is_settled_once() {
        let mut d = Duties::new(0);
        let mut wheel = LinkedWheel::local(DecoderConfig::default(), AbLevels::from_bits(0));
        // Half a detent forward: off the start-up rest.
        let half = AbLevels::from_bits(0).next_forward().next_forward();
        let _ = wheel.edge().on_edge(AbLevels::from_bits(0).next_forward());
        let _ = wheel.edge().on_edge(half);
        // Each sample comes after its round took the motion in, as in `Node::poll`.
        let mut sample = |ms| {
            wheel.take_motion(Intake::RoundStart);
            d.sample(ms, &mut Lines(0, 0), &mut wheel)
        };
        let learnt: Vec<u32> = (0..=1000)
            .filter_map(|ms| sample(ms).map(|s| (ms, s)))
            .filter(|(_, s)| s.rest_learnt)
            .map(|(ms, _)| ms)
            .collect();
        assert_eq!(learnt, [500]);
    }

    #[test]
    fn err_led_shows_the_worse_of_protocol_and_bus() {
        let mut d = Duties::new(0);
        // Single flash (warning limit) from the bus, nothing from the protocol: ERR on at the
        // start of its pattern.
        let (_, err) = d
            .leds(
                0,
                NmtState::Operational,
                ErrorIndication::NoError,
                BusState::ErrorPassive,
            )
            .unwrap();
        let expected = indicators(NmtState::Operational, ErrorIndication::WarningLimit, 0);
        assert_eq!(err, expected.1);
        assert!(err);
        // Not due again before its period.
        assert_eq!(
            d.leds(
                10,
                NmtState::Operational,
                ErrorIndication::NoError,
                BusState::ErrorActive
            ),
            None
        );
        let both = d
            .leds(
                50,
                NmtState::Operational,
                ErrorIndication::NoError,
                BusState::ErrorActive,
            )
            .unwrap();
        assert_eq!(
            both,
            indicators(NmtState::Operational, ErrorIndication::NoError, 50)
        );
    }
}
