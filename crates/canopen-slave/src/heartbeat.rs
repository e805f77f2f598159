//! Heartbeat producer (0x1017) and consumer (0x1016), CiA 301 7.2.8.3.2.

use crate::abort::SdoAbort;
use crate::frame::NodeId;
use crate::nmt::NmtState;
use crate::time::{earliest, Instant};

/// Number of heartbeat consumer entries (0x1016:01..).
pub const CONSUMERS: usize = 2;

/// Monitoring state of one consumer entry.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
enum Monitor {
    /// Configured (or not), but no heartbeat seen yet: CiA 301 starts monitoring only with
    /// the first heartbeat received.
    Waiting,
    /// A heartbeat was seen; the producer must be heard again before the deadline.
    Active(Instant),
    /// The deadline passed; reported once, re-armed by the next heartbeat.
    Lost,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
struct Consumer {
    /// 0x1016 entry: node-ID in bits 23..16, time in ms in bits 15..0.
    param: u32,
    monitor: Monitor,
}

impl Consumer {
    const fn node(&self) -> u8 {
        (self.param >> 16) as u8
    }

    const fn time_ms(&self) -> u16 {
        self.param as u16
    }

    /// CiA 301: a time of 0 or a node-ID outside 1..=127 disables the entry.
    const fn enabled(&self) -> bool {
        let node = self.node();
        self.time_ms() != 0 && node >= 1 && node <= 127
    }
}

/// Heartbeat producer and consumers.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub(crate) struct Heartbeat {
    producer_ms: u16,
    next_beat: Option<Instant>,
    consumers: [Consumer; CONSUMERS],
}

impl Heartbeat {
    pub(crate) const fn new() -> Self {
        Self {
            producer_ms: 0,
            next_beat: None,
            consumers: [Consumer {
                param: 0,
                monitor: Monitor::Waiting,
            }; CONSUMERS],
        }
    }

    /// Producer heartbeat time in ms (0 = off).
    pub(crate) const fn producer_ms(&self) -> u16 {
        self.producer_ms
    }

    /// Sets the producer time and restarts its timer (a write of 0x1017 does both).
    pub(crate) fn set_producer(&mut self, ms: u16, now: Instant) {
        self.producer_ms = ms;
        self.restart(now);
    }

    /// The next heartbeat is one period after `now` (after a boot-up or state change).
    pub(crate) fn restart(&mut self, now: Instant) {
        self.next_beat = (self.producer_ms != 0).then(|| now.after_ms(self.producer_ms));
    }

    /// NMT state change from `prev` to `next`: whether to announce the new state with a
    /// heartbeat now (then the period starts over). Not right after the boot-up frame: some
    /// masters miss a boot-up that is immediately followed by a heartbeat.
    pub(crate) fn on_nmt_state(&mut self, prev: NmtState, next: NmtState, now: Instant) -> bool {
        let announce = prev != NmtState::Initialising
            && next != NmtState::Initialising
            && self.producer_ms != 0;
        if announce {
            self.restart(now);
        }
        announce
    }

    /// Whether a heartbeat is due; if so, schedules the next one.
    pub(crate) fn beat_due(&mut self, now: Instant) -> bool {
        let Some(due) = self.next_beat else {
            return false;
        };
        if now < due {
            return false;
        }
        // Keep the period drift-free, but do not burst to catch up after a late poll.
        let next = due.after_ms(self.producer_ms);
        self.next_beat = Some(if next <= now {
            now.after_ms(self.producer_ms)
        } else {
            next
        });
        true
    }

    /// Raw consumer entry `sub` (1-based).
    pub(crate) fn consumer(&self, sub: u8) -> Result<u32, SdoAbort> {
        let i = usize::from(sub)
            .checked_sub(1)
            .ok_or(SdoAbort::NoSubIndex)?;
        self.consumers
            .get(i)
            .map(|c| c.param)
            .ok_or(SdoAbort::NoSubIndex)
    }

    /// Checked write of consumer entry `sub` on the node `own` (CiA 301 7.5.2.23).
    ///
    /// Refused with 0x06090030: reserved bits 31..24 set, a node-ID above 127, node-ID 0
    /// with a non-zero time (an entry is disabled by time 0, not by an unreachable node),
    /// and this node's own ID (it cannot hear its own heartbeat, so the entry would never
    /// arm). Refused with 0x06040043: a second enabled entry for a node already monitored.
    pub(crate) fn write_consumer(
        &mut self,
        sub: u8,
        param: u32,
        own: NodeId,
    ) -> Result<(), SdoAbort> {
        let i = usize::from(sub)
            .checked_sub(1)
            .filter(|&i| i < CONSUMERS)
            .ok_or(SdoAbort::NoSubIndex)?;
        let new = Consumer {
            param,
            monitor: Monitor::Waiting,
        };
        let node = new.node();
        let reserved = param & 0xFF00_0000 != 0;
        if reserved || node > 127 || (node == 0 && new.time_ms() != 0) || node == own.get() {
            return Err(SdoAbort::InvalidValue);
        }
        let clash = self
            .consumers
            .iter()
            .enumerate()
            .any(|(j, c)| j != i && new.time_ms() != 0 && c.time_ms() != 0 && c.node() == node);
        if clash {
            return Err(SdoAbort::ParameterIncompatible);
        }
        *self.consumers.get_mut(i).ok_or(SdoAbort::NoSubIndex)? = new;
        Ok(())
    }

    /// Unchecked write (defaults, stored parameters).
    pub(crate) fn set_consumer(&mut self, sub: u8, param: u32) {
        if let Some(c) = usize::from(sub)
            .checked_sub(1)
            .and_then(|i| self.consumers.get_mut(i))
        {
            *c = Consumer {
                param,
                monitor: Monitor::Waiting,
            };
        }
    }

    /// A heartbeat (or boot-up) of `node` arrived: (re)arm its entries, which also ends a
    /// loss of that node.
    pub(crate) fn on_heartbeat(&mut self, now: Instant, node: u8) {
        for c in &mut self.consumers {
            if c.enabled() && c.node() == node {
                c.monitor = Monitor::Active(now.after_ms(c.time_ms()));
            }
        }
    }

    /// The next entry whose deadline has passed, marked lost; `None` when there is none.
    pub(crate) fn take_timeout(&mut self, now: Instant) -> Option<u8> {
        let c = self
            .consumers
            .iter_mut()
            .find(|c| matches!(c.monitor, Monitor::Active(d) if now >= d))?;
        c.monitor = Monitor::Lost;
        Some(c.node())
    }

    /// Whether any monitored node is currently lost.
    pub(crate) fn any_lost(&self) -> bool {
        self.consumers.iter().any(|c| c.monitor == Monitor::Lost)
    }

    /// The earliest producer or consumer deadline.
    pub(crate) fn deadline(&self) -> Option<Instant> {
        self.consumers
            .iter()
            .filter_map(|c| match c.monitor {
                Monitor::Active(d) => Some(d),
                _ => None,
            })
            .fold(self.next_beat, |acc, d| earliest(acc, Some(d)))
    }
}
