//! The truth the host's credits are judged against: what the operator turned on each axis
//! while the feed was enabled, taken from the stimulus, never from the device's position.
//!
//! Per axis the truth is the list of detents, in the order they were turned, each with its
//! signed size in multiplied units (the multiplier the switch stood at, negative when turned
//! backwards), when it was turned, and whether it is *owed*: turned while no record was
//! missing (see [`crate::model`]: the host had a record made since the last loss, reset,
//! power cycle, NMT command, stall or device-side stop, and none came since).
//!
//! The contract says every credit is motion turned on that axis while enabled, with its
//! sign, at most once, and not later than the bound; and exactly that when no record is
//! missing. So the credits of an axis, in order, must be sums of consecutive, disjoint runs
//! of its detents, runs in the order they were turned (the host can skip motion, never
//! reorder or repeat it), each detent at most `late_ms` old when its run is credited; runs
//! may leave detents out (motion lost), but never an owed one, which must be credited within
//! `late_ms`. Which run a credit stands for is not always unique (+1 and +1 can be either
//! detent), so the truth keeps every *cursor* (how many detents are used up) that some
//! consistent reading of the credits so far leaves: `sound` for the contract's bound, and
//! `exact`, the readings that skipped no owed detent. A credit no reading explains is a
//! breach; so is an owed detent that every exact reading leaves uncredited past `late_ms`.

/// One detent.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Detent {
    /// Multiplied units, signed (x1, x10, x100; negative backwards).
    pub units: i32,
    /// When it was turned, model ms.
    pub at: u64,
    /// Turned while no record was missing: it must be credited, in time.
    pub owed: bool,
}

/// Detents too old to be credited that are kept for messages.
const EXPIRED_KEPT: usize = 4;

/// Bit `c` set: `c` detents used up is a consistent reading.
type Cursors = u64;

/// The truth of one axis.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub struct AxisTruth {
    /// Detents not older than the bound (older ones can no longer be credited).
    detents: Vec<Detent>,
    /// The last few older ones, for messages only.
    expired: Vec<Detent>,
    sound: Cursors,
    exact: Cursors,
}

impl Default for AxisTruth {
    fn default() -> Self {
        Self {
            detents: Vec::new(),
            expired: Vec::new(),
            sound: 1,
            exact: 1,
        }
    }
}

/// Why a credit breaches the contract.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Miss {
    /// No reading explains it.
    Unsound,
    /// Only readings that skip an owed detent (this one) explain it.
    Skipped(Detent),
}

fn cursors(set: Cursors) -> impl Iterator<Item = usize> {
    (0..64).filter(move |c| set & (1 << c) != 0)
}

impl AxisTruth {
    /// Detents kept (for messages).
    pub fn detents(&self) -> &[Detent] {
        &self.detents
    }

    /// A detent was turned while enabled.
    pub fn turned(&mut self, detent: Detent) {
        assert!(
            self.detents.len() < 63,
            "the truth keeps at most 63 detents"
        );
        self.detents.push(detent);
    }

    /// Whether `detents[a..j]` can be one credit of `delta` at `now`.
    fn run(&self, a: usize, j: usize, delta: i32, now: u64, late_ms: u64) -> bool {
        let run = &self.detents[a..j];
        run.iter().map(|d| d.units).sum::<i32>() == delta
            && run.iter().all(|d| now.saturating_sub(d.at) <= late_ms)
    }

    /// The cursors after a credit of `delta` read from `from`; skipping owed detents only if
    /// `skip_owed`.
    fn after(
        &self,
        from: Cursors,
        skip_owed: bool,
        mut ok: impl FnMut(usize, usize) -> bool,
    ) -> Cursors {
        let n = self.detents.len();
        let mut next = 0;
        for c in cursors(from) {
            let mut a = c;
            loop {
                for j in a + 1..=n {
                    if ok(a, j) {
                        next |= 1 << j;
                    }
                }
                if a == n || (!skip_owed && self.detents[a].owed) {
                    break;
                }
                a += 1;
            }
        }
        next
    }

    /// The host credited `delta` to this axis at `now`.
    pub fn credit(&mut self, delta: i32, now: u64, late_ms: u64) -> Result<(), Miss> {
        let ok = |a, j| self.run(a, j, delta, now, late_ms);
        let sound = self.after(self.sound, true, ok);
        if sound == 0 {
            return Err(Miss::Unsound);
        }
        let exact = self.after(self.exact, false, ok);
        if exact == 0 {
            let first = self.exact.trailing_zeros() as usize;
            let skipped = self.detents[first..]
                .iter()
                .find(|d| d.owed)
                .copied()
                .expect("an exact reading fails only by skipping an owed detent");
            return Err(Miss::Skipped(skipped));
        }
        self.sound = sound;
        self.exact = exact;
        Ok(())
    }

    /// Whether some reading, ignoring what was credited before (from no detent used up),
    /// explains `delta`, with (`in_time`) or without the bound.
    pub fn explains_from_start(&self, delta: i32, now: u64, late_ms: u64, in_time: bool) -> bool {
        let late = if in_time { late_ms } else { u64::MAX };
        self.after(1, true, |a, j| self.run(a, j, delta, now, late)) != 0
    }

    /// Whether a run of detents, those too old to be credited among them, explains `delta`;
    /// the age of its oldest detent then (the youngest such run).
    pub fn explains_late(&self, delta: i32, now: u64) -> Option<u64> {
        let all: Vec<Detent> = self.expired.iter().chain(&self.detents).copied().collect();
        let mut youngest = None;
        for a in 0..all.len() {
            for j in a + 1..=all.len() {
                if all[a..j].iter().map(|d| d.units).sum::<i32>() == delta {
                    let age = now.saturating_sub(all[a].at);
                    youngest = Some(youngest.map_or(age, |y: u64| y.min(age)));
                }
            }
        }
        youngest
    }

    /// Forgets the detents every reading has used up (after a warm-up: what was credited).
    pub fn forget_credited(&mut self) {
        let used = self.sound.trailing_zeros() as usize;
        self.detents.drain(..used);
        self.sound >>= used;
        self.exact >>= used;
        self.expired.clear();
    }

    /// A record went missing (or what stands for it): no detent turned so far is owed.
    pub fn excuse(&mut self) {
        for d in &mut self.detents {
            d.owed = false;
        }
        self.exact = self.sound;
    }

    /// The oldest owed detent that every exact reading leaves uncredited.
    pub fn owed(&self) -> Option<Detent> {
        let credited = 63 - self.exact.leading_zeros() as usize;
        self.detents[credited..].iter().find(|d| d.owed).copied()
    }

    /// Time passed to `now`: detents older than the bound can no longer be credited; they
    /// are dropped, and every reading moves past them (an owed one among them is a breach
    /// the caller finds first with [`AxisTruth::owed`]).
    pub fn age(&mut self, now: u64, late_ms: u64) {
        let old = self
            .detents
            .iter()
            .take_while(|d| now.saturating_sub(d.at) > late_ms)
            .count();
        if old == 0 {
            return;
        }
        let past = |set: Cursors| {
            let below = set & ((1 << old) - 1);
            ((set & !((1 << old) - 1)) | if below != 0 { 1 << old } else { 0 }) >> old
        };
        // An exact reading that left an owed detent among them uncredited is no longer one.
        let owed_upto = self.detents[..old]
            .iter()
            .rposition(|d| d.owed)
            .map_or(0, |i| i + 1);
        let exact = self.exact & !((1 << owed_upto) - 1);
        self.sound = past(self.sound);
        self.exact = if exact == 0 { self.sound } else { past(exact) };
        self.expired.extend(self.detents.drain(..old));
        let keep = self.expired.len().saturating_sub(EXPIRED_KEPT);
        self.expired.drain(..keep);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn d(units: i32, at: u64, owed: bool) -> Detent {
        Detent { units, at, owed }
    }

    #[test]
    fn credits_are_runs_in_order_each_once() {
        let mut t = AxisTruth::default();
        t.turned(d(1, 0, false));
        t.turned(d(1, 1, false));
        assert_eq!(t.credit(2, 2, 500), Ok(()));
        assert_eq!(t.credit(1, 3, 500), Err(Miss::Unsound), "again");
        t.turned(d(-10, 4, false));
        assert_eq!(t.credit(-10, 5, 500), Ok(()));
    }

    #[test]
    fn skipped_motion_is_allowed_unless_owed() {
        let mut t = AxisTruth::default();
        t.turned(d(1, 0, false));
        t.turned(d(100, 1, true));
        assert_eq!(t.credit(100, 2, 500), Ok(()), "the first was not owed");
        let mut t = AxisTruth::default();
        t.turned(d(100, 1, true));
        t.turned(d(1, 2, true));
        assert_eq!(t.credit(1, 3, 500), Err(Miss::Skipped(d(100, 1, true))));
        t.excuse();
        assert_eq!(t.credit(1, 3, 500), Ok(()));
    }

    #[test]
    fn an_ambiguous_credit_keeps_every_reading() {
        let mut t = AxisTruth::default();
        t.turned(d(1, 0, false));
        t.turned(d(1, 1, true));
        assert_eq!(t.credit(1, 2, 500), Ok(()));
        assert_eq!(t.owed(), None, "the credit may have been the owed one");
        assert_eq!(
            t.credit(1, 3, 500),
            Ok(()),
            "or the first: both readings stay"
        );
        assert_eq!(t.credit(1, 4, 500), Err(Miss::Unsound));
    }

    #[test]
    fn forgetting_what_was_credited_keeps_what_was_not() {
        let mut t = AxisTruth::default();
        t.turned(d(1, 0, false));
        t.turned(d(1, 1, true));
        t.turned(d(1, 2, true));
        assert_eq!(t.credit(1, 3, 500), Ok(()));
        t.forget_credited();
        assert_eq!(
            t.detents().len(),
            2,
            "the credit may have been either of the first two"
        );
        assert_eq!(t.credit(1, 4, 500), Ok(()));
        assert_eq!(t.owed(), None);
    }

    #[test]
    fn late_motion_is_no_credit_and_owed_motion_is_due() {
        let mut t = AxisTruth::default();
        t.turned(d(1, 0, true));
        assert_eq!(t.owed(), Some(d(1, 0, true)));
        assert_eq!(t.credit(1, 501, 500), Err(Miss::Unsound));
        assert_eq!(t.explains_late(1, 501), Some(501));
        t.age(501, 500);
        assert_eq!(t.explains_late(1, 502), Some(502), "kept for messages");
        assert!(t.detents().is_empty());
        assert_eq!(t.owed(), None);
        t.turned(d(1, 600, true));
        assert_eq!(t.credit(1, 601, 500), Ok(()));
    }
}
