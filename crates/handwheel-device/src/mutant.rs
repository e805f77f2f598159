//! Plausible single bugs in the device's feed path, for the feed checker's mutation tests
//! (`crates/feed-check/tests/mutants.rs`): a checker that stops finding any of them fails
//! there. Compiled only with the hidden `mutants` feature, which the firmware never enables;
//! selected per device at run time ([`HandwheelDevice::set_mutant`](crate::HandwheelDevice::set_mutant)).

/// One bug, each where the real code would have it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Mutant {
    /// Leaving Operational (an NMT stop, pre-operational, a reset) keeps the held epochs and
    /// does not break the record sequence: what the outbox held goes out after the next start.
    NmtStopKeepsHeld,
    /// A reset of the node or of communication does not discard the frames that wait for the
    /// bus: they go out after it, and a full transmit path refuses the boot-up.
    ResetKeepsPending,
    /// TPDO1 reads its mapped objects when it is built, each after taking the wheel's new
    /// motion in (the freshest values), and the outbox takes the state at send time as sent,
    /// instead of one snapshot.
    TpdoReadAtSend,
    /// The transmit path's stall watch counts its 100 ms from the last frame that got out
    /// (the rule before the fix): a bus that takes a frame now and then never trips it.
    StallCompletions,
    /// A write of 0x2000 changes the enable without taking the motion so far in first: a
    /// detent that came before the change is taken in after it.
    EnableWithoutIntake,
    /// The session is not guarded against another master's token: it opens at once after
    /// the device started (no [`SESSION_DELAY_MS`](crate::od::SESSION_DELAY_MS)) and the
    /// sequence probe takes any key, so a session someone else opened with the host's token
    /// in a new power life answers the host's probes as its own.
    SessionUnguarded,
    /// A write of the heartbeat consumer (0x1016) keeps the master's session: another master
    /// changing whose heartbeat the device watches goes unnoticed by the host.
    ConsumerWriteKeepsSession,
    /// A write of TPDO1's communication parameters (0x1800) or mapping (0x1A00) keeps the
    /// master's session: another master changing what or when the feed record carries goes
    /// unnoticed by the host.
    TpdoWriteKeepsSession,
    /// The pace allows one number more at once than its burst.
    PaceBurstPlusOne,
    /// The pace refills one number early: a number comes back as soon as the bucket is
    /// refilled up to now, not a whole period later.
    PaceRefillEarly,
    /// The pace is not enforced: a number taken beyond it never ends the session.
    PaceNotEnforced,
}
