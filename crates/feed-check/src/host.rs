//! The host's rule, as `host/src/canopen_handwheel/core.py` runs it (`Core._tpdo1`), for the
//! model: which feed records link, what they credit, what starts afresh.
//!
//! The sequence and epoch widths are parameters: the model lowers them so that wrap-around
//! is reached in a few steps. At the shipped widths (8 and 3 bits) this is the component's
//! rule, and `cargo xtask test` replays the streams the model reaches through `core.py`
//! itself (the vectors of [`crate::vectors`]), so the two cannot drift apart.

/// Device axis numbers the host maps to its letters: 1 = X, 2 = Y (`--axes xy`).
pub const AXES: usize = 2;

/// Feed record status bits the rule reads.
const STATUS_ENABLED: u8 = 0x01;
const STATUS_MASTER_LOST: u8 = 0x08;

/// The rule's settings.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct RuleConfig {
    /// Bits of the sequence byte the host sees (8 on the wire).
    pub sequence_bits: u8,
    /// Bits of the epoch the host sees (3 on the wire).
    pub epoch_bits: u8,
    /// No record for longer than this: the next one is a baseline (3 event-timer periods).
    pub stale_after_ms: u64,
    /// A record handled longer than this after the host last found its receive path empty
    /// may have waited in a backlog: it is only a baseline.
    pub backlog_limit_ms: u64,
    /// The newest record stays the reference for "behind" this long after it came.
    pub order_expiry_ms: u64,
}

impl RuleConfig {
    /// The component's rule for a device whose event timer is `event_timer_ms`.
    pub const fn shipped(event_timer_ms: u64) -> Self {
        Self {
            sequence_bits: 8,
            epoch_bits: 3,
            stale_after_ms: 3 * event_timer_ms,
            backlog_limit_ms: 100,
            order_expiry_ms: 2000,
        }
    }

    const fn sequence_modulo(&self) -> u16 {
        1 << self.sequence_bits
    }

    const fn epoch_modulo(&self) -> u8 {
        1 << self.epoch_bits
    }

    /// The largest gap still read as "the same epoch": each epoch takes at least one
    /// sequence number, so this many missing numbers hide at most this many epochs, one
    /// fewer than the epoch field needs to come round.
    pub const fn same_epoch_max_gap(&self) -> u16 {
        self.epoch_modulo() as u16 - 2
    }
}

/// One feed record as the host reads it (widths already lowered).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Record {
    /// Position, multiplied units.
    pub position: i32,
    /// 0 none, 1..5.
    pub axis: u8,
    /// 1, 10 or 100.
    pub multiplier: u8,
    /// Status flags, bits 0-4.
    pub flags: u8,
    /// Epoch, low `epoch_bits`.
    pub epoch: u8,
    /// Sequence, low `sequence_bits`.
    pub sequence: u8,
}

impl Record {
    /// The wire bytes read with the lowered widths; `None` for a record the device can
    /// never send (counted bad, a baseline).
    pub fn decode(bytes: [u8; 8], config: &RuleConfig) -> Option<Self> {
        let flags = bytes[6] & 0x1F;
        let valid = bytes[4] <= 5
            && matches!(bytes[5], 1 | 10 | 100)
            && flags & (STATUS_ENABLED | STATUS_MASTER_LOST) != STATUS_ENABLED | STATUS_MASTER_LOST;
        valid.then(|| Self {
            position: i32::from_le_bytes([bytes[0], bytes[1], bytes[2], bytes[3]]),
            axis: bytes[4],
            multiplier: bytes[5],
            flags,
            epoch: (bytes[6] >> 5) % config.epoch_modulo(),
            sequence: (u16::from(bytes[7]) % config.sequence_modulo()) as u8,
        })
    }

    fn enabled(&self) -> bool {
        self.flags & STATUS_ENABLED != 0
    }
}

/// Motion the rule gives an axis: the difference between two records, and the tags (the
/// model's knowledge of where each record came from) of both.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Credit<T> {
    /// Index into the axes (0 = X, 1 = Y).
    pub axis: usize,
    /// Multiplied units.
    pub delta: i32,
    /// The record the difference is taken from.
    pub from: (Record, T),
    /// The record that credits it.
    pub to: (Record, T),
}

/// The host's bookkeeping of one device.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub struct HostRule<T> {
    config: RuleConfig,
    /// The last accepted record, its tag, and when it came.
    reference: Option<(Record, [u8; 8], T, u64)>,
    /// The next record is a baseline.
    baseline: bool,
    /// The device showed a non-zero epoch since it (re)booted.
    epochs_shown: bool,
    last_drained: u64,
    /// Per axis, wrapping sums of the credited deltas (`jog-counts`).
    pub counts: [i32; AXES],
    /// Records the host missed (sequence gaps).
    pub records_lost: i32,
    /// Frames that cannot be the device's (impossible, behind).
    pub frames_bad: i32,
}

impl<T: Clone> HostRule<T> {
    /// A host that has seen nothing yet.
    pub fn new(config: RuleConfig) -> Self {
        Self {
            config,
            reference: None,
            baseline: true,
            epochs_shown: false,
            last_drained: 0,
            counts: [0; AXES],
            records_lost: 0,
            frames_bad: 0,
        }
    }

    /// The receive path was found empty at `now`.
    pub fn drained(&mut self, now: u64) {
        self.last_drained = self.last_drained.max(now);
    }

    /// The device's heartbeat: after a boot-up nothing links to what came before, but the
    /// newest record stays the reference for "behind" (a reset keeps the sequence going, so
    /// only copies of older records fall behind it).
    pub fn heartbeat(&mut self, state: u8) {
        if state & 0x7F == 0 {
            self.baseline = true;
            self.epochs_shown = false;
        }
    }

    /// A TPDO1 of 8 bytes, handled at `now`. Returns the motion it credits, if any.
    pub fn record(&mut self, bytes: [u8; 8], tag: T, now: u64) -> Option<Credit<T>> {
        let Some(rec) = Record::decode(bytes, &self.config) else {
            self.frames_bad += 1;
            self.baseline = true;
            return None;
        };
        let fresh = self
            .reference
            .as_ref()
            .is_some_and(|r| now.saturating_sub(r.3) <= self.config.stale_after_ms);
        if !fresh {
            self.baseline = true;
        }
        if let Some((prev, prev_bytes, _, at)) = &self.reference {
            if now.saturating_sub(*at) <= self.config.order_expiry_ms {
                let ahead = (u16::from(rec.sequence) + self.config.sequence_modulo()
                    - u16::from(prev.sequence))
                    % self.config.sequence_modulo();
                if ahead == 0 {
                    if *prev_bytes != bytes {
                        self.frames_bad += 1;
                        self.baseline = true;
                    }
                    return None;
                }
                if ahead >= self.config.sequence_modulo() / 2 {
                    self.frames_bad += 1;
                    return None;
                }
                if fresh {
                    self.records_lost += i32::from(ahead - 1);
                }
            }
        }
        if rec.epoch != 0 {
            self.epochs_shown = true;
        }
        let mut credit = None;
        let linked = self
            .reference
            .as_ref()
            .filter(|_| !self.baseline)
            .map(|(prev, _, tag, _)| (*prev, tag.clone()));
        if let Some((prev, prev_tag)) = linked {
            let delta = self.link(&prev, &rec);
            let letter = usize::from(rec.axis).checked_sub(1).filter(|&a| a < AXES);
            let late = now.saturating_sub(self.last_drained) > self.config.backlog_limit_ms;
            if let (Some(delta), Some(axis), true, false) =
                (delta.filter(|&d| d != 0), letter, self.epochs_shown, late)
            {
                self.counts[axis] = self.counts[axis].wrapping_add(delta);
                credit = Some(Credit {
                    axis,
                    delta,
                    from: (prev, prev_tag),
                    to: (rec, tag.clone()),
                });
            }
        }
        self.reference = Some((rec, bytes, tag, now));
        self.baseline = false;
        credit
    }

    /// The motion of `rec`'s epoch between the two records, when they link (`core.py`'s
    /// `continuity` and `_link`); `None` when `rec` starts afresh. A link that contradicts
    /// itself counts as bad.
    fn link(&mut self, prev: &Record, rec: &Record) -> Option<i32> {
        let m = self.config.sequence_modulo();
        let gap = (u16::from(rec.sequence) + 2 * m - u16::from(prev.sequence) - 1) % m;
        let d = (rec.epoch + self.config.epoch_modulo() - prev.epoch) % self.config.epoch_modulo();
        let delta = rec.position.wrapping_sub(prev.position);
        let same = d == 0 && gap <= self.config.same_epoch_max_gap();
        let next = d == 1 && gap == 0;
        if !same && !next {
            return None;
        }
        let changed = (rec.axis, rec.multiplier, rec.enabled())
            != (prev.axis, prev.multiplier, prev.enabled());
        let impossible = (same && changed)
            || (delta != 0
                && (!rec.enabled() || rec.axis == 0 || delta % i32::from(rec.multiplier) != 0));
        if impossible {
            self.frames_bad += 1;
            return None;
        }
        Some(delta)
    }
}
