//! The host's rule, as `host/src/canopen_handwheel/core.py` runs it (`Core._tpdo1`,
//! `order_verdict`, `max_ahead`, `free_tokens`), for the model: sessions, which feed records
//! link, what they credit, what starts afresh, what is a copy.
//!
//! The widths and the pace are parameters: the model lowers the sequence's width, and the
//! device's pace with it, so that the wrap is reached in a few dozen records. What the rule
//! depends on is differences modulo the width and the pace's bound on how many numbers the
//! device can take in a given time; both scale together (`RuleConfig::holds`). At the shipped
//! values this is the component's rule, and `cargo xtask test` replays the streams the model
//! reaches through `core.py` itself (the vectors of [`crate::vectors`]).

/// Device axis numbers the host maps to its letters: 1 = X, 2 = Y (`--axes xy`).
pub const AXES: usize = 2;

/// Feed record status bits the rule reads.
const STATUS_ENABLED: u8 = 0x01;
const STATUS_MASTER_LOST: u8 = 0x08;

/// Session tokens the host writes (0 means none).
pub const TOKENS: u8 = 7;

/// Bits of the sequence probe's value (0x2033) that carry the nonce (`core.py`'s
/// `NONCE_BITS`); bits 13-15 the session, 16-31 the number the next record carries.
const NONCE_BITS: u32 = 13;
const NONCE_MASK: u32 = (1 << NONCE_BITS) - 1;
/// Probe dates kept, the newest (`core.py`'s `PROBE_DATES`).
const PROBE_DATES: usize = 32;
/// The key the host writes to 0x2034 after its token and carries in its probes (bits
/// 16-31). `core.py` draws one at random per session; only its being another than 0 (the
/// key of a session someone else opened) matters to the rule, so the model's is one value.
pub const SESSION_KEY: u16 = 0x5EC5;

/// A change of the host's dating that the checker must notice (`tests/mutants.rs`): each a
/// plausible slip in porting or changing `core.py`'s dating.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum HostMutant {
    /// `DATE_LIMIT` ten times too generous.
    DateLimitTenfold,
    /// An answer whose number is not beyond the floor still gives a date (and never drops
    /// the session).
    NoFloorCheck,
    /// The record itself dated (`rec.sequence`) instead of its reference's successor.
    DateTheRecord,
    /// A probe's `sent_at` taken when its answer arrives instead of when it was sent.
    SentAtArrival,
    /// `max_ahead` ten times too generous: a record that far ahead of the reference is taken
    /// as the session's (an old copy read as a new record).
    MaxAheadTenfold,
    /// A record two epochs on with one number missing links too (as if the missing number
    /// were the epoch in between's, with no motion).
    LinkEpochStepTwo,
    /// A token in use less than the copy age ago written again without the device's uptime
    /// proving no power cycle since its chain began.
    ReuseUnproven,
}

/// The rule's settings.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct RuleConfig {
    /// Bits of the sequence the host sees (16 on the wire).
    pub sequence_bits: u8,
    /// Bits of the epoch the host sees (3 on the wire).
    pub epoch_bits: u8,
    /// No record for longer than this: the next one is a baseline (3 event-timer periods).
    pub stale_after_ms: u64,
    /// A record handled longer than this after the host last found its receive path empty
    /// may have waited in a backlog: it is only a baseline.
    pub backlog_limit_ms: u64,
    /// The device's pace: numbers at once.
    pub burst: u64,
    /// The device's pace: microseconds per number.
    pub us_per_number: u64,
    /// How long a record may take to reach the host, µs.
    pub in_transit_us: u64,
    /// How far the device's clock may run fast, parts per million.
    pub clock_ppm: u64,
    /// The longest a record of the session may follow the order reference, µs.
    pub order_window_us: u64,
    /// The contract's age of copies, µs; a token is written again only this long after the
    /// host replaced it.
    pub copy_age_us: u64,
    /// Records dated by the sequence probe (`core.py`'s `Config.dating`): credited only while
    /// a probe sent at most `date_limit_ms` ago found the reference's successor not yet made.
    pub dating: bool,
    /// `DATE_LIMIT`, ms (0.35 s shipped).
    pub date_limit_ms: u64,
    /// `PROBE_PERIOD`, ms (0.1 s shipped): a probe this long after the last one.
    pub probe_period_ms: u64,
    /// The session tokens the host uses, 1..=`tokens` (7 shipped: all the 3-bit field
    /// has); fewer run out in fewer configurations.
    pub tokens: u8,
    /// A dating mutant (`tests/mutants.rs`); `None`: the rule as `core.py` has it.
    pub mutant: Option<HostMutant>,
}

impl RuleConfig {
    /// The component's rule for a device whose event timer is `event_timer_ms`.
    pub const fn shipped(event_timer_ms: u64) -> Self {
        Self {
            sequence_bits: 16,
            epoch_bits: 3,
            stale_after_ms: 3 * event_timer_ms,
            backlog_limit_ms: 100,
            burst: 64,
            us_per_number: 1000,
            in_transit_us: 250_000,
            clock_ppm: 10_000,
            order_window_us: 4_000_000,
            copy_age_us: 60_000_000,
            dating: false,
            date_limit_ms: 350,
            probe_period_ms: 100,
            tokens: TOKENS,
            mutant: None,
        }
    }

    /// `core.py`'s `_at_or_after`: `number` is `other` or later in the sequence's order
    /// (within half its range).
    const fn at_or_after(&self, number: u64, other: u64) -> bool {
        let m = self.sequence_modulo();
        (number + m - other % m) % m < m / 2
    }

    /// The sequence's modulo as the host sees it.
    pub const fn sequence_modulo(&self) -> u64 {
        1 << self.sequence_bits
    }

    const fn epoch_modulo(&self) -> u8 {
        1 << self.epoch_bits
    }

    /// The largest gap still read as "the same epoch": each epoch takes at least one
    /// sequence number, so this many missing numbers hide at most this many epochs, one
    /// fewer than the epoch field needs to come round.
    pub const fn same_epoch_max_gap(&self) -> u64 {
        self.epoch_modulo() as u64 - 2
    }

    /// Numbers the device can take in `us` on a clock up to `clock_ppm` fast, plus a burst
    /// (`core.py`'s `max_ahead` and `oldest_copy_behind`).
    const fn numbers_in(&self, us: u64) -> u64 {
        us * (1_000_000 + self.clock_ppm) / (self.us_per_number * 1_000_000) + self.burst
    }

    /// The most numbers a genuine record of the session can be ahead of the reference, `dt_us`
    /// after the reference reached the host.
    pub const fn max_ahead(&self, dt_us: u64) -> u64 {
        self.numbers_in(dt_us + self.in_transit_us)
    }

    /// The most numbers a copy up to the contract's age lies behind the newest record.
    pub const fn oldest_copy_behind(&self) -> u64 {
        self.numbers_in(self.copy_age_us)
    }

    /// Whether the rule's ranges do not meet: every copy within the age reads as one.
    pub const fn holds(&self) -> bool {
        self.max_ahead(self.order_window_us) + self.oldest_copy_behind() < self.sequence_modulo()
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
    /// Session, 0..7.
    pub session: u8,
    /// Sequence, low `sequence_bits`.
    pub sequence: u64,
}

impl Record {
    /// The wire bytes read with the lowered widths; `None` for a record the device can
    /// never send (counted bad, a baseline).
    pub fn decode(bytes: [u8; 8], config: &RuleConfig) -> Option<Self> {
        let flags = bytes[5] & 0x1F;
        let axis = bytes[4] & 0x07;
        let multiplier = match (bytes[4] >> 3) & 0x03 {
            0 => 1,
            1 => 10,
            2 => 100,
            _ => return None,
        };
        let valid = axis <= 5
            && flags & (STATUS_ENABLED | STATUS_MASTER_LOST) != STATUS_ENABLED | STATUS_MASTER_LOST;
        valid.then(|| Self {
            position: i32::from_le_bytes([bytes[0], bytes[1], bytes[2], bytes[3]]),
            axis,
            multiplier,
            flags,
            epoch: (bytes[4] >> 5) % config.epoch_modulo(),
            session: bytes[5] >> 5,
            sequence: u64::from(u16::from_le_bytes([bytes[6], bytes[7]]))
                % config.sequence_modulo(),
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
    /// The host's session token, once a configuration wrote it and read it back.
    session: Option<u8>,
    /// The newest accepted record of the session, its bytes, its tag, when it was handled
    /// and the earliest it can have reached the host (µs).
    reference: Option<(Record, [u8; 8], T, u64, u64)>,
    /// The next record is a baseline.
    baseline: bool,
    /// The device showed a non-zero epoch since it (re)booted.
    epochs_shown: bool,
    last_drained: u64,
    /// A record of another session came: check the configuration (not before `check_at`).
    check_due: bool,
    check_at: u64,
    /// Per token, when the host replaced it (ms) (`core.py`'s `superseded`).
    superseded: [Option<u64>; TOKENS as usize],
    /// Per token, when the host last knew the device could be in it without having replaced
    /// it (`core.py`'s `busy`).
    busy: [Option<u64>; TOKENS as usize],
    /// Per token the host wrote, when the configuration that first wrote it after it was
    /// last free did (ms; `core.py`'s `chains`).
    chains: [Option<u64>; TOKENS as usize],
    /// No configuration without a session before this (ms; `core.py`'s `config_due` after a
    /// token refused as too young, or a reuse not proven).
    configure_at: u64,
    /// Per axis, wrapping sums of the credited deltas (`jog-counts`).
    pub counts: [i32; AXES],
    /// Records the host missed (sequence gaps).
    pub records_lost: i32,
    /// Frames that cannot be the device's (impossible, copies).
    pub frames_bad: i32,
    /// Dating: the probes' dates (n, sent_at ms), oldest first, for the session (`core.py`'s
    /// `dates`).
    dates: std::collections::VecDeque<(u64, u64)>,
    /// The next probe's nonce.
    nonce: u32,
    /// When the last probe of the session was sent (ms): the next is due a period after it
    /// (`core.py`'s `probe_due`); `None`: due now.
    probed_at: Option<u64>,
    /// The probe under way (`core.py`'s `pending`): nonce, floor, sent at (ms). No other
    /// action (a configuration) while it is.
    probe: Option<(u32, Option<u64>, u64)>,
}

/// Seconds as `core.py` has them (a vector's time in ms, as the float it reads): the dating's
/// limits are compared in the same floating point, so that a date exactly at a limit reads
/// the same in both rules.
fn seconds(ms: u64) -> f64 {
    ms as f64 / 1000.0
}

/// A check runs again at most this long after the last one (ms; `core.py`'s `retry`).
const CHECK_RETRY_MS: u64 = 500;
/// A token refused as too young is written again this long after (ms; `core.py`'s
/// `YOUNG_RETRY`).
const YOUNG_RETRY_MS: u64 = 100;

fn slot(token: u8) -> usize {
    usize::from(token - 1)
}

impl<T: Clone> HostRule<T> {
    /// A host that has seen nothing yet.
    pub fn new(config: RuleConfig) -> Self {
        Self {
            config,
            session: None,
            reference: None,
            baseline: true,
            epochs_shown: false,
            last_drained: 0,
            check_due: false,
            check_at: 0,
            superseded: [None; TOKENS as usize],
            busy: [None; TOKENS as usize],
            chains: [None; TOKENS as usize],
            configure_at: 0,
            counts: [0; AXES],
            records_lost: 0,
            frames_bad: 0,
            dates: std::collections::VecDeque::new(),
            nonce: 0,
            probed_at: None,
            probe: None,
        }
    }

    /// The host's session, if it has one.
    pub const fn session(&self) -> Option<u8> {
        self.session
    }

    /// Whether the host asks for a configuration at `now_ms` (`core.py`'s `next_action`
    /// giving a `Configure`): without a session when a token is free, or a check.
    pub fn configure_due(&self, now_ms: u64) -> bool {
        if self.probe.is_some() {
            return false;
        }
        match self.session {
            None => {
                now_ms >= self.configure_at
                    && (1..=self.config.tokens).any(|t| self.free(t, now_ms) || self.reusable(t))
            }
            Some(_) => self.check_due && now_ms >= self.check_at,
        }
    }

    fn last_use(&self, token: u8) -> Option<u64> {
        self.superseded[slot(token)].max(self.busy[slot(token)])
    }

    fn free(&self, token: u8, now_ms: u64) -> bool {
        Some(token) != self.session
            && self
                .last_use(token)
                .is_none_or(|at| now_ms >= at + self.config.copy_age_us / 1000)
    }

    /// A token the host wrote itself and does not hold now: written again before it is free
    /// if the device's uptime proves it (`core.py`'s `Configure.reusable`).
    fn reusable(&self, token: u8) -> bool {
        Some(token) != self.session && self.chains[slot(token)].is_some()
    }

    /// The token a configuration writes at `now_ms` on a device whose 0x2002 reads
    /// `device` (`core.py`'s `free_tokens` and `pick_token`): not the host's own, none the
    /// host or the device used less than the contract's age ago, never used ones first,
    /// lowest first, then the least recently used; never the device's. Else, with the
    /// device's uptime `uptime_ms` (0x2035) read at `now_ms`, the least recently used token
    /// the host wrote whose chain began after the device's present life began at the latest
    /// (`core.py`'s `life_began_by`, in its floating point). `None`: none.
    pub fn next_token(&self, now_ms: u64, device: u8, uptime_ms: Option<u32>) -> Option<u8> {
        let tokens = 1..=self.config.tokens;
        let mut free: Vec<u8> = tokens.clone().filter(|&t| self.free(t, now_ms)).collect();
        free.sort_by_key(|&t| (self.last_use(t), t));
        if let Some(t) = free.into_iter().find(|&t| t != device) {
            return Some(t);
        }
        let uptime = f64::from(uptime_ms?);
        let tolerance = 1.0 + self.config.clock_ppm as f64 / 1e6;
        let began_by = seconds(now_ms) - uptime / 1000.0 / tolerance;
        let mut reusable: Vec<u8> = tokens
            .filter(|&t| !self.free(t, now_ms) && self.reusable(t))
            .collect();
        reusable.sort_by_key(|&t| (self.last_use(t), t));
        reusable.into_iter().find(|&t| {
            let chain = self.chains[slot(t)].map_or(f64::NEG_INFINITY, seconds);
            t != device
                && (self.config.mutant == Some(HostMutant::ReuseUnproven) || began_by < chain)
        })
    }

    /// The device refused the token as too young for a session (`core.py`'s
    /// `Configured.young`): the next configuration `YOUNG_RETRY` (100 ms) later.
    pub fn young(&mut self, now_ms: u64) {
        self.configure_at = now_ms + YOUNG_RETRY_MS;
    }

    /// The device's uptime did not prove any reusable token (`core.py`'s
    /// `Configured.unproven`): the next configuration when the first token is free.
    pub fn unproven(&mut self, now_ms: u64) {
        let copy_age_ms = self.config.copy_age_us / 1000;
        self.configure_at = (1..=self.config.tokens)
            .filter(|&t| Some(t) != self.session)
            .map(|t| self.last_use(t).map_or(now_ms, |at| at + copy_age_ms))
            .min()
            .unwrap_or(now_ms);
    }

    /// Whether a configuration at `now_ms` on a device in `device` needs the device's uptime
    /// to pick a token: none is free, one the host wrote may be reused.
    pub fn needs_uptime(&self, now_ms: u64, device: u8) -> bool {
        self.next_token(now_ms, device, None).is_none()
            && (1..=self.config.tokens).any(|t| t != device && self.reusable(t))
    }

    /// A configuration at `now_ms` found the device in `found`: still the host's session
    /// (nothing written), or the host wrote and read back `token`.
    pub fn configured(&mut self, found: u8, token: Option<u8>, now_ms: u64) {
        if let Some(t) = token.filter(|&t| self.free(t, now_ms)) {
            // Written when free: a new chain (a reused token's goes on).
            self.chains[slot(t)] = Some(now_ms);
        }
        for t in [Some(found), token].into_iter().flatten() {
            if t != 0 && Some(t) != self.session {
                self.busy[slot(t)] = Some(now_ms);
            }
        }
        if self.session.is_some() && Some(found) == self.session && token.is_none() {
            self.check_due = false;
            self.check_at = now_ms + CHECK_RETRY_MS;
            return;
        }
        if self.session.is_some() && Some(found) != self.session {
            self.drop_session(now_ms);
        }
        let Some(token) = token else {
            return;
        };
        if let Some(old) = self.session {
            self.busy[slot(old)] = Some(now_ms);
        }
        if found != 0 {
            self.busy[slot(found)] = Some(now_ms);
        }
        for t in 1..=TOKENS {
            if t != token && self.busy[slot(t)].is_some() {
                self.superseded[slot(t)] = Some(now_ms);
            }
        }
        self.busy = [None; TOKENS as usize];
        self.session = Some(token);
        self.forget_records();
        self.check_due = false;
    }

    /// `core.py`'s `_forget_records`, as far as the rule goes: no reference, no dates, a
    /// probe due at once.
    fn forget_records(&mut self) {
        self.reference = None;
        self.baseline = true;
        self.dates.clear();
        self.probed_at = None;
    }

    /// Whether the host asks for a probe at `now_ms` (`core.py`'s `next_action` giving a
    /// `Probe`): dating, a session, nothing under way, no configuration due, a period after
    /// the last probe of the session.
    pub fn probe_due(&self, now_ms: u64) -> bool {
        self.config.dating
            && self.session.is_some()
            && self.probe.is_none()
            && !self.configure_due(now_ms)
            && self.probed_at.is_none_or(|at| {
                seconds(now_ms) >= seconds(at) + seconds(self.config.probe_period_ms)
            })
    }

    /// The host sends a probe at `now_ms`: (the value it writes to 0x2033: its session key
    /// in bits 16-31, the nonce below; the floor: the newest record number of the session it
    /// received).
    pub fn probe(&mut self, now_ms: u64) -> (u32, Option<u64>) {
        let nonce = u32::from(SESSION_KEY) << 16 | self.nonce;
        let floor = self.reference.as_ref().map(|r| r.0.sequence);
        self.nonce = (self.nonce + 1) & NONCE_MASK;
        self.probed_at = Some(now_ms);
        self.probe = Some((nonce, floor, now_ms));
        (nonce, floor)
    }

    /// The answer to the probe under way (0x2033 read back, `None`: not read) reaches the
    /// host at `now_ms` (`core.py`'s `done` of a `Probe`, `probe_date` and
    /// `probe_went_back`).
    pub fn probed(&mut self, value: Option<u32>, now_ms: u64) {
        let Some((nonce, floor, sent_at)) = self.probe.take() else {
            return;
        };
        let nonce = nonce & NONCE_MASK;
        let (Some(value), Some(session)) = (value, self.session) else {
            return;
        };
        let number = u64::from(value >> 16) % self.config.sequence_modulo();
        let ours =
            value & NONCE_MASK == nonce && (value >> NONCE_BITS) & 0x07 == u32::from(session);
        if !ours {
            return;
        }
        let m = self.config.sequence_modulo();
        let beyond = |f: u64| self.config.at_or_after(number, (f + 1) % m);
        let floor_checked = self.config.mutant != Some(HostMutant::NoFloorCheck);
        if floor_checked && floor.is_some_and(|f| !beyond(f)) {
            // The device's sequence went back: a new power life.
            self.drop_session(now_ms);
            return;
        }
        let sent_at = if self.config.mutant == Some(HostMutant::SentAtArrival) {
            now_ms
        } else {
            sent_at
        };
        if self.dates.len() == PROBE_DATES {
            self.dates.pop_front();
        }
        self.dates.push_back((number, sent_at));
    }

    /// The device refused the probe's write (abort 0x08000022: the key is not the session's):
    /// the session the device has is not the host's, whatever its token (`core.py`'s
    /// `probe_refused`). It is dropped; a configuration follows.
    pub fn probe_refused(&mut self, now_ms: u64) {
        if self.probe.take().is_some() && self.session.is_some() {
            self.drop_session(now_ms);
        }
    }

    /// `frames.py`'s `_undated` (inverted): a probe sent at most the date limit ago found the successor of
    /// `reference` not yet made (`dated_at`). Always, without dating.
    fn dated(&self, reference: &Record, rec: &Record, now_ms: u64) -> bool {
        if !self.config.dating {
            return true;
        }
        let m = self.config.sequence_modulo();
        let successor = if self.config.mutant == Some(HostMutant::DateTheRecord) {
            rec.sequence
        } else {
            (reference.sequence + 1) % m
        };
        let at = self
            .dates
            .iter()
            .rev()
            .find(|&&(number, _)| self.config.at_or_after(successor, number))
            .map(|&(_, sent_at)| sent_at);
        let limit = if self.config.mutant == Some(HostMutant::DateLimitTenfold) {
            10 * self.config.date_limit_ms
        } else {
            self.config.date_limit_ms
        };
        at.is_some_and(|at| seconds(now_ms) - seconds(at) <= seconds(limit))
    }

    /// The receive path was found empty at `now` (ms).
    pub fn drained(&mut self, now: u64) {
        self.last_drained = self.last_drained.max(now);
    }

    /// The device's heartbeat at `now` (ms): a boot-up ends the session (it configures
    /// again), and so does Pre-operational while it has one.
    pub fn heartbeat(&mut self, state: u8, now: u64) {
        let state = state & 0x7F;
        if state == 0 {
            self.baseline = true;
            self.epochs_shown = false;
        }
        if state == 0 || (state == 0x7F && self.session.is_some()) {
            self.drop_session(now);
        }
    }

    fn drop_session(&mut self, now: u64) {
        if let Some(old) = self.session.take() {
            self.busy[slot(old)] = Some(now);
        }
        self.check_due = false;
        self.forget_records();
    }

    /// A TPDO1 of 8 bytes, handled at `now` (ms). Returns the motion it credits, if any.
    pub fn record(&mut self, bytes: [u8; 8], tag: T, now: u64) -> Option<Credit<T>> {
        let Some(rec) = Record::decode(bytes, &self.config) else {
            self.frames_bad += 1;
            self.baseline = true;
            return None;
        };
        if self.session != Some(rec.session) {
            // Another session's (or none): never a reference, never credited; check. A
            // token the host never replaced may be the device's: kept out for the age.
            if rec.session != 0 && self.superseded[slot(rec.session)].is_none() {
                self.busy[slot(rec.session)] = Some(now);
            }
            if self.session.is_some() {
                self.check_due = true;
            }
            return None;
        }
        let fresh = self
            .reference
            .as_ref()
            .is_some_and(|r| now.saturating_sub(r.3) <= self.config.stale_after_ms);
        if !fresh {
            self.baseline = true;
        }
        let now_us = now * 1000;
        if let Some((prev, prev_bytes, _, _, arrived_us)) = &self.reference {
            let dt = now_us.saturating_sub(*arrived_us);
            if dt > self.config.order_window_us {
                self.drop_session(now);
                return None;
            }
            let m = self.config.sequence_modulo();
            let ahead = (rec.sequence + m - prev.sequence) % m;
            if ahead == 0 {
                if *prev_bytes != bytes {
                    self.frames_bad += 1;
                    self.baseline = true;
                }
                return None;
            }
            let max_ahead = if self.config.mutant == Some(HostMutant::MaxAheadTenfold) {
                10 * self.config.max_ahead(dt)
            } else {
                self.config.max_ahead(dt)
            };
            if ahead > max_ahead {
                self.frames_bad += 1;
                return None;
            }
            if fresh {
                self.records_lost += (ahead - 1) as i32;
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
            .map(|(prev, _, tag, _, _)| (*prev, tag.clone()));
        if let Some((prev, prev_tag)) = linked {
            let delta = self.link(&prev, &rec);
            let letter = usize::from(rec.axis).checked_sub(1).filter(|&a| a < AXES);
            let late = now.saturating_sub(self.last_drained) > self.config.backlog_limit_ms;
            // Dated only what `core.py` dates: a link's motion, not late.
            let delta = delta.filter(|&d| d != 0 && (late || self.dated(&prev, &rec, now)));
            if let (Some(delta), Some(axis), true, false) = (delta, letter, self.epochs_shown, late)
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
        let arrived_us = now.min(self.last_drained) * 1000;
        self.reference = Some((rec, bytes, tag, now, arrived_us));
        self.baseline = false;
        credit
    }

    /// The motion of `rec`'s epoch between the two records, when they link (`core.py`'s
    /// `continuity` and `_link`); `None` when `rec` starts afresh. A link that contradicts
    /// itself counts as bad.
    fn link(&mut self, prev: &Record, rec: &Record) -> Option<i32> {
        let m = self.config.sequence_modulo();
        let gap = (rec.sequence + 2 * m - prev.sequence - 1) % m;
        let d = (rec.epoch + self.config.epoch_modulo() - prev.epoch) % self.config.epoch_modulo();
        let delta = rec.position.wrapping_sub(prev.position);
        let same = d == 0 && gap <= self.config.same_epoch_max_gap();
        let next = (d == 1 && gap == 0)
            || (d == 2 && gap <= 1 && self.config.mutant == Some(HostMutant::LinkEpochStepTwo));
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_shipped_rule_keeps_copies_and_new_records_apart() {
        let c = RuleConfig::shipped(100);
        assert_eq!(c.max_ahead(c.order_window_us), 4356);
        assert_eq!(c.oldest_copy_behind(), 60_664);
        assert!(c.holds());
    }

    #[test]
    fn tokens_wait_the_copy_age_after_their_last_use() {
        let mut h: HostRule<()> = HostRule::new(RuleConfig::shipped(100));
        assert_eq!(h.next_token(0, 0, None), Some(1));
        assert_eq!(h.next_token(0, 1, None), Some(2), "never the device's");
        h.configured(0, Some(1), 0);
        assert_eq!(h.next_token(10, 0, None), Some(2));
        h.configured(1, Some(2), 10);
        assert_eq!(
            h.next_token(20, 0, None),
            Some(3),
            "1 was replaced 10 ms ago"
        );
        for t in 3..=7 {
            h.configured(t - 1, Some(t), 20);
        }
        assert_eq!(
            h.next_token(30, 0, None),
            None,
            "every other token replaced within 60 s"
        );
        assert!(h.needs_uptime(30, 0));
        assert_eq!(h.next_token(60_010, 0, None), Some(1));
    }

    #[test]
    fn a_token_is_reused_early_only_when_the_uptime_proves_it() {
        let mut h: HostRule<()> = HostRule::new(RuleConfig::shipped(100));
        h.configured(0, Some(1), 1_000);
        for t in 2..=7 {
            h.configured(t - 1, Some(t), 1_000 + u64::from(t));
        }
        // Up since before t = 1 s (on a clock up to 1 % fast): token 1's chain, the least
        // recently used.
        assert_eq!(h.next_token(3_000, 0, Some(2_100)), Some(1));
        assert_eq!(
            h.next_token(3_000, 1, Some(2_100)),
            Some(2),
            "never the device's"
        );
        // Up 1.5 s: begun at 3 - 1.5 / 1.01 = 1.51 s at the latest, after every chain.
        assert_eq!(h.next_token(3_000, 0, Some(1_500)), None);
        assert_eq!(h.next_token(3_000, 0, None), None, "no uptime, no reuse");
        h.configured(7, h.next_token(3_000, 0, Some(2_100)), 3_000);
        assert_eq!(h.session(), Some(1));
        assert_eq!(h.chains[0], Some(1_000), "a reused token's chain goes on");
    }
}
