"""The order rule: where a record of the host's session lies against the order reference
(`order_verdict`), from the device's sequence budget (`max_ahead`, `oldest_copy_behind`;
host/README.md, "Ordering")."""

from __future__ import annotations

from typing import Optional, Tuple

from .record import SEQUENCE_MODULO, Record

# The device's sequence budget: at most SEQUENCE_BURST numbers at once, refilled by
# SEQUENCE_PER_S a second of its clock; a session ends rather than exceed it. So between two
# records of one session sent t seconds apart the sequence moved by at most
# t * SEQUENCE_PER_S + SEQUENCE_BURST (on the device's clock).
SEQUENCE_PER_S = 1000
SEQUENCE_BURST = 64
# How far the device's clock may run fast against the host's, as a fraction.
CLOCK_TOLERANCE = 0.01
_CLOCK_PPM = round(CLOCK_TOLERANCE * 1_000_000)
# The contract's age: a copy (duplicated, delayed, replayed) of a genuine record up to this
# old (s) never moves an axis. A session token is not written again for this long after the
# host replaced it, so no copy of a record of its last use can reach its next one.
COPY_AGE = 60.0
# The longest a record of the session may follow the order reference (s); a later one is
# not judged (its sequence could have run round far enough to look like a copy's or a
# copy's like it): the host starts a new session instead.
ORDER_WINDOW = 4.0
# The longest a record takes from the device to the host's receive path (s): its queue
# (a blocked transmit path is given up after 0.1 s), the bus, the adapter.
IN_TRANSIT = 0.25
_IN_TRANSIT_US = round(IN_TRANSIT * 1_000_000)


def max_ahead(dt: float) -> int:
    """The most sequence numbers a genuine record of the session can be ahead of the order
    reference when the host handles it `dt` seconds after the reference reached it: what the
    budget allows in `dt` plus the reference's time in transit, on a device clock up to
    CLOCK_TOLERANCE fast, plus the burst. Integer arithmetic on microseconds, so that the
    bound is exact at every boundary (the Rust port computes the same)."""
    us = max(0, round(dt * 1_000_000)) + _IN_TRANSIT_US
    return us * SEQUENCE_PER_S * (1_000_000 + _CLOCK_PPM) // 10**12 + SEQUENCE_BURST


def oldest_copy_behind() -> int:
    """The most sequence numbers a copy of a record of the session, at most COPY_AGE old,
    can lie behind the newest record the host took: what the budget allows in that time.
    The rule holds while this and `max_ahead(ORDER_WINDOW)` together stay below the
    modulo (a test asserts it)."""
    us = round(COPY_AGE * 1_000_000)
    return us * SEQUENCE_PER_S * (1_000_000 + _CLOCK_PPM) // 10**12 + SEQUENCE_BURST


# The verdicts of `order_verdict` on a record of the host's session.
FIRST = "first"  # no reference yet: the session's first record, a baseline
AHEAD = "ahead"  # a later record of the device
DUPLICATE = "duplicate"  # the reference's bytes again
SAME_NUMBER = "same number"  # the reference's sequence number with other bytes: impossible
COPY = "copy"  # an earlier record again (or one far beyond what the device can have sent)
RENEW = "renew"  # the reference is older than ORDER_WINDOW: start a new session


def order_verdict(ref: Optional[Tuple["Record", float]], rec: "Record", now: float):
    """(verdict, a): where `rec`, a record of the host's session handled at `now`, lies
    against the order reference `ref` (the newest record of the session the host took, and
    the earliest it can have reached the host). a = (rec's sequence - ref's) mod 65536.

    A copy at most COPY_AGE old lies at most `oldest_copy_behind()` numbers behind the
    reference, so a = 65536 minus that or more; a genuine later record is at most
    `max_ahead(dt)` ahead. While dt stays within ORDER_WINDOW the two ranges do not meet,
    so every copy reads as one, whatever its age within the contract's."""
    if ref is None:
        return FIRST, 0
    ref_rec, ref_time = ref
    dt = now - ref_time
    if dt > ORDER_WINDOW:
        return RENEW, 0
    a = (rec.sequence - ref_rec.sequence) % SEQUENCE_MODULO
    if a == 0:
        return (DUPLICATE if rec == ref_rec else SAME_NUMBER), 0
    if a <= max_ahead(dt):
        return AHEAD, a
    return COPY, a
