//! The CAN controller's bit-rate switch after LSS "activate bit timing", as steps of the
//! firmware's loop, none of which waits for the bus.
//!
//! The controller leaves the bus (initialisation mode), takes the new timing and rejoins by
//! itself once it has seen 11 consecutive recessive bits: at once on an idle bus, after the
//! frame under way on a busy one, never on a dominant one (shorted lines, a babbling node).
//! So the firmware asks the controller for one short step per loop round
//! (`CanPort::switch_bit_rate`, a few register accesses under the CAN port's lock) and
//! [`RateSwitch`] keeps the time: a switch not done within [`SYNC_LIMIT_MS`] makes the node
//! off the bus, reported as bus-off is (log, ERR LED on, EMCY 0x8140 once back); the
//! controller still rejoins by itself as soon as the bus is free, which ends it.

use handwheel_core::BitRate;

/// How long a switch may take before the node counts as off the bus. A healthy bus needs at
/// most two frames: the one under way when initialisation is requested, then one before the
/// 11 recessive bits of its end; at 10 kbit/s, the slowest table rate, a frame with stuffing
/// is at most about 16 ms.
pub const SYNC_LIMIT_MS: u32 = 50;

/// The loop's longest sleep while a switch is under way and within [`SYNC_LIMIT_MS`]: a
/// healthy switch takes a few rounds. Past the limit the node is off the bus, and the loop
/// looks as often as for any state that is not error-active
/// ([`crate::duties::RECOVERY_POLL_MS`]).
pub const SWITCH_POLL_MS: u32 = 1;

/// A bit-rate switch under way, if any.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct RateSwitch {
    /// The rate and when its switch began (loop ticks, ms).
    pending: Option<(BitRate, u32)>,
    /// The switch passed [`SYNC_LIMIT_MS`] and has not ended yet.
    off_bus: bool,
}

impl RateSwitch {
    /// No switch under way.
    pub const fn new() -> Self {
        Self {
            pending: None,
            off_bus: false,
        }
    }

    /// Begins a switch to `rate` at `now_ms`; it replaces one under way (the controller
    /// steps towards the rate asked last).
    pub fn start(&mut self, rate: BitRate, now_ms: u32) {
        self.pending = Some((rate, now_ms));
    }

    /// One round's step: `step(rate)` is the controller's (never a wait; `true` once it is
    /// on the bus at `rate`). Returns the rate when the switch has just passed
    /// [`SYNC_LIMIT_MS`] without its controller on the bus (once per switch, for the log).
    pub fn poll(&mut self, now_ms: u32, step: impl FnOnce(BitRate) -> bool) -> Option<BitRate> {
        let (rate, since) = self.pending?;
        if step(rate) {
            self.pending = None;
            self.off_bus = false;
            return None;
        }
        let late = now_ms.wrapping_sub(since) >= SYNC_LIMIT_MS;
        let newly = late && !self.off_bus;
        self.off_bus |= late;
        newly.then_some(rate)
    }

    /// A switch is under way: its controller is not on the bus at the rate yet.
    pub const fn under_way(&self) -> bool {
        self.pending.is_some()
    }

    /// The node is off the bus: a switch has not found 11 recessive bits within
    /// [`SYNC_LIMIT_MS`]. The firmware reports this as bus-off.
    pub const fn off_bus(&self) -> bool {
        self.off_bus
    }

    /// The longest the loop may sleep before the next [`RateSwitch::poll`]:
    /// [`SWITCH_POLL_MS`] while a switch is under way within its limit, otherwise no limit
    /// of its own (`u32::MAX`).
    pub const fn sleep_cap_ms(&self) -> u32 {
        match self.pending {
            Some(_) if !self.off_bus => SWITCH_POLL_MS,
            _ => u32::MAX,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const RATE: BitRate = BitRate::ALL[3];

    #[test]
    fn a_healthy_switch_polls_every_ms_and_ends_when_the_controller_is_on_the_bus() {
        let mut s = RateSwitch::new();
        assert_eq!(s.sleep_cap_ms(), u32::MAX, "nothing to do");
        assert_eq!(s.poll(0, |_| panic!("no switch, no step")), None);
        assert!(!s.under_way());
        s.start(RATE, 100);
        assert!(s.under_way());
        assert_eq!(s.sleep_cap_ms(), SWITCH_POLL_MS);
        let mut asked = None;
        assert_eq!(
            s.poll(100, |r| {
                asked = Some(r);
                false
            }),
            None
        );
        assert_eq!(asked, Some(RATE));
        assert_eq!(s.poll(101, |_| false), None);
        assert!(s.under_way());
        assert_eq!(s.poll(102, |_| true), None);
        assert!(!s.under_way(), "on the bus: done");
        assert_eq!(s.sleep_cap_ms(), u32::MAX);
        assert!(!s.off_bus());
        assert_eq!(s.poll(103, |_| panic!("done, no more steps")), None);
    }

    #[test]
    fn a_switch_that_never_synchronises_is_off_the_bus_once_until_it_joins() {
        let mut s = RateSwitch::new();
        s.start(RATE, u32::MAX - 10); // the tick count wraps during the switch
        let start = u32::MAX - 10;
        assert_eq!(
            s.poll(start.wrapping_add(SYNC_LIMIT_MS - 1), |_| false),
            None
        );
        assert!(!s.off_bus());
        assert_eq!(
            s.poll(start.wrapping_add(SYNC_LIMIT_MS), |_| false),
            Some(RATE)
        );
        assert!(s.off_bus());
        assert_eq!(
            s.sleep_cap_ms(),
            u32::MAX,
            "the bus state's own polling now"
        );
        assert_eq!(s.poll(start.wrapping_add(5000), |_| false), None, "once");
        assert!(s.off_bus());
        assert_eq!(s.poll(start.wrapping_add(5010), |_| true), None);
        assert!(!s.off_bus(), "back on the bus by itself once it is free");
    }

    #[test]
    fn a_new_switch_replaces_the_one_under_way() {
        let mut s = RateSwitch::new();
        s.start(BitRate::ALL[3], 0);
        s.start(BitRate::ALL[7], 1);
        let mut asked = None;
        s.poll(2, |r| {
            asked = Some(r);
            false
        });
        assert_eq!(asked, Some(BitRate::ALL[7]));
    }
}
