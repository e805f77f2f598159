"""Dating by the sequence probe (0x2033): the probe (`Probe`, `Probed`), the date its answer
gives (`probe_date`) and the date of a record (`dated_at`; host/README.md, "Dating")."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Tuple

from .record import SEQUENCE_MODULO, Record
from .sessions import SESSION_KEY_SHIFT

# Backlog: a feed record handled longer than this after the shell last found its receive
# path empty (`Core.drained`) may have waited in a buffer that long (a frozen, starved or
# flooded component): it is only a baseline. Credits not published to the pins within it
# (the component stalled between handling a frame and writing the pins) are withdrawn.
BACKLOG_LIMIT = 0.1


# Dating (README "The contract"): a gateway or an adapter between the device and the host can
# hold the device's frames and deliver them in a burst, which the host's receive path never
# sees. The sequence probe 0x2033 dates records instead: the component writes a nonce of its
# own (`Probe`), reads the object back and notes when it sent the write (`Probed`). An answer
# that carries the nonce and the host's session, with the number n, says that the device had
# made no record numbered n or later when the write was sent. The motion a record adds to its
# reference was turned after the device made the reference's successor, at most
# RECORD_DELAY before that successor was made (a detent's record waits for the inhibit
# time, at most INHIBIT_MAX, and the device's round). So a record is credited only while a
# probe sent at most DATE_LIMIT ago found the reference's successor not yet made: then its
# motion is at most DATE_LIMIT + RECORD_DELAY old when credited, and a credit reaches the
# pins within BACKLOG_LIMIT or is withdrawn; with a margin for the host's own delays, within
# CONTRACT_AGE. What cannot be dated so (a hold of the device's frames, answers that do not
# come) is a baseline: it moves nothing.
PROBE_OBJECT = 0x2033
PROBE_PERIOD = 0.1  # s between probes while the host holds a session
NONCE_BITS = 13  # bits 0-12 of the probe's value; bits 13-15 the session, 16-31 the number
NONCE_MASK = (1 << NONCE_BITS) - 1
CONTRACT_AGE = 0.5  # s: no motion credited later than this after it was turned
RECORD_DELAY = 0.03  # s: from a detent to its record's making at the longest
DATE_MARGIN = 0.02  # s: the host's own delays between handling a record and writing pins
DATE_LIMIT = CONTRACT_AGE - BACKLOG_LIMIT - RECORD_DELAY - DATE_MARGIN
PROBE_DATES = 32  # dates kept (the newest; at PROBE_PERIOD, more than DATE_LIMIT's worth)


def probe_date(
    action: "Probe", result: "Probed", session: Optional[int]
) -> Optional[Tuple[int, float]]:
    """(n, sent_at): the date a probe's answer gives, or None if it gives none: no answer,
    another nonce (another master's probe, an answer to an earlier probe of the host), not
    the host's `session`, or a number not beyond what the host had already received when it
    sent the probe (`Probe.floor`: an answer the device gave before it; only a stale one)."""
    if result.value is None or result.sent_at is None or session is None:
        return None
    value = result.value
    number = value >> 16
    if value & NONCE_MASK != action.nonce or (value >> NONCE_BITS) & 0x07 != session:
        return None
    if action.floor is not None and not _at_or_after(number, action.floor + 1):
        return None
    return number, result.sent_at


def probe_went_back(action: "Probe", result: "Probed", session: Optional[int]) -> bool:
    """The answer to the host's own probe (its nonce, its session) shows a number not beyond
    what the host had already received (`Probe.floor`): the device's sequence went back,
    which only a new power life does (reset node and reset communication keep it going). Its
    session then is the host's token written again by another master after a power cycle
    whose boot-up the host missed; records of the new life must not link to the old one."""
    if result.value is None or session is None or action.floor is None:
        return False
    value = result.value
    ours = value & NONCE_MASK == action.nonce and (value >> NONCE_BITS) & 0x07 == session
    return ours and not _at_or_after(value >> 16, action.floor + 1)


def _at_or_after(number: int, other: int) -> bool:
    """`number` is `other` or later in the sequence's order (within half its range)."""
    return (number - other) % SEQUENCE_MODULO < SEQUENCE_MODULO // 2


def dated_at(dates, reference: "Record") -> Optional[float]:
    """The latest time the device had not yet made the successor of `reference` (by the
    probe dates (n, sent_at), oldest first), or None if no date tells."""
    successor = (reference.sequence + 1) % SEQUENCE_MODULO
    for number, sent_at in reversed(dates):
        if _at_or_after(successor, number):
            return sent_at
    return None


@dataclass(frozen=True)
class Probe:
    """The sequence probe: 0x2033 = `value` (the session key `key` in bits 16-31, `nonce`
    in bits 0-12; the time the write is sent noted), then 0x2033 read back (`Probed`).
    `floor`: the newest record number of the session the host had received when it asked for
    the probe (an answer must lie beyond it). A device whose session has another key refuses
    the write (abort 0x08000022): the host's session is gone (`Core.done`)."""

    nonce: int
    floor: Optional[int] = None
    own: bool = False  # on the component's own SDO channel
    key: int = 0  # the host's session key (0: none)

    @property
    def value(self) -> int:
        """What the shell writes to 0x2033."""
        return (self.key & 0xFFFF) << SESSION_KEY_SHIFT | self.nonce & NONCE_MASK


@dataclass
class Probed:
    """What a `Probe` found: when the write was sent (the core's clock) and the value read
    back (None: not read)."""

    sent_at: Optional[float] = None
    value: Optional[int] = None
