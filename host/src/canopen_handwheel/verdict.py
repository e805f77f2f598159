"""What the host's rule made of one feed record (`FeedVerdict`): `Core.frame` answers it for
every TPDO1 of the device, so that a shell that wants to say why (`canopen-handwheel decode`,
a log) asks the core instead of walking the rule again. Standard library only."""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import Dict, Optional

from .dating import DATE_LIMIT
from .order import ORDER_WINDOW
from .overrides import OVERRIDES

__all__ = ["FeedVerdict", "Reason", "UncreditedMotion"]


class Reason(enum.Enum):
    """Why a record credited what it did: `CREDITED`, or the one reason it credited nothing.
    In the order the rule asks (docs/ARCHITECTURE.md, "The host core's rules and why they hold")."""

    # Not judged at all: the device cannot have sent it, or it is not of the host's session.
    MALFORMED = "malformed"  # not 8 bytes
    NEVER_SENT = "never sent"  # a field the device never sends (`record_fault`)
    NO_SESSION = "no session"  # the host holds none (configuring)
    OTHER_SESSION = "other session"
    # The order rule (`order_verdict`): never the reference.
    STALE_SESSION = "stale session"  # over ORDER_WINDOW after the reference: session dropped
    DUPLICATE = "duplicate"  # the reference's bytes again: nothing at all
    SAME_NUMBER = "same number"  # the reference's number, other bytes: impossible
    COPY = "copy"  # an earlier record again
    # Taken as the reference, but it continues nothing: a baseline.
    FIRST = "first"  # the session's first record
    STALE = "stale"  # nothing of the session for longer than the staleness time
    AFTER_IMPOSSIBLE = "after impossible"  # the record before it was impossible
    LATE = "late"  # from a backlog (`BACKLOG_LIMIT`)
    OTHER_EPOCH = "other epoch"  # epochs the host did not see (`continuity`)
    UNDATED = "undated"  # no recent probe dates it (`DATE_LIMIT`)
    # Taken and continuous.
    CANNOT_FOLLOW = "cannot follow"  # impossible after the record before it (`pair_fault`)
    AT_REST = "at rest"  # no motion
    TOO_FAST = "too fast"  # beyond `--max-detents-per-s` (the allowance)
    NO_AXIS = "no axis"  # its switch position drives nothing (`--axes`)
    NO_EPOCH = "no epoch"  # no epoch shown since the configuration
    CREDITED = "credited"


# What the reasons amount to, for a summary (and the names `decode` gives them).
CREDITED = "credited"
BASELINE = "baseline"
AT_REST = "no motion"
DUPLICATE = "duplicate"
COPY = "copy"
FOREIGN = "other session"
IMPOSSIBLE = "impossible"
NOT_CREDITED = "motion not credited"
DROPPED = "session dropped"
KINDS: Dict[Reason, str] = {
    Reason.MALFORMED: IMPOSSIBLE,
    Reason.NEVER_SENT: IMPOSSIBLE,
    Reason.NO_SESSION: FOREIGN,
    Reason.OTHER_SESSION: FOREIGN,
    Reason.STALE_SESSION: DROPPED,
    Reason.DUPLICATE: DUPLICATE,
    Reason.SAME_NUMBER: IMPOSSIBLE,
    Reason.COPY: COPY,
    Reason.FIRST: BASELINE,
    Reason.STALE: BASELINE,
    Reason.AFTER_IMPOSSIBLE: BASELINE,
    Reason.LATE: BASELINE,
    Reason.OTHER_EPOCH: BASELINE,
    Reason.UNDATED: BASELINE,
    Reason.CANNOT_FOLLOW: IMPOSSIBLE,
    Reason.AT_REST: AT_REST,
    Reason.TOO_FAST: NOT_CREDITED,
    Reason.NO_AXIS: NOT_CREDITED,
    Reason.NO_EPOCH: NOT_CREDITED,
    Reason.CREDITED: CREDITED,
}

# Each reason in words; `detail` and `moved` as the verdict has them.
_WORDS: Dict[Reason, str] = {
    Reason.MALFORMED: "{detail}: a record the device cannot send",
    Reason.NEVER_SENT: "the device never sends {detail}",
    Reason.NO_SESSION: "the host has no session yet (configuring): not judged",
    Reason.OTHER_SESSION: "{detail}: not judged",
    Reason.STALE_SESSION: f"over {ORDER_WINDOW:g} s after the newest: a new session",
    Reason.DUPLICATE: "the newest record again (a duplicate): nothing",
    Reason.SAME_NUMBER: "the newest record's sequence number with other bytes",
    Reason.COPY: "a copy of an earlier record ({detail} behind the newest)",
    Reason.FIRST: "the session's first record: baseline",
    Reason.STALE: "baseline: nothing of the session for {detail}",
    Reason.AFTER_IMPOSSIBLE: "baseline: the record before it was impossible",
    Reason.LATE: "baseline: from a backlog (receive path not found empty for {detail})",
    Reason.OTHER_EPOCH: "baseline: {detail}",
    Reason.UNDATED: f"baseline: not dated within {DATE_LIMIT:g} s ({{detail}}): held on its way?",
    Reason.CANNOT_FOLLOW: "cannot follow the previous record: {detail}",
    Reason.AT_REST: "no motion",
    Reason.TOO_FAST: "moved {moved}: faster than --max-detents-per-s, counted bad",
    Reason.NO_AXIS: "moved {moved}: {detail} drives nothing (--axes)",
    Reason.NO_EPOCH: "moved {moved}: no epoch shown since the configuration",
    Reason.CREDITED: "moved {moved}",
}


@dataclass(frozen=True)
class FeedVerdict:
    """What the rule made of one feed record.

    `delta` is what it credited to `axis` (an override's detents, else counts; 0 unless
    `reason` is `CREDITED`). A record the rule took as its new reference (from `FIRST` on in
    `Reason`) has `axis`, the `--axes` letter its switch position drives (None: none), and
    `moved`, how far the position moved since the record taken before it (0 for the session's
    first). `lost`: the records counted lost before it (`records-lost`); `bad`: it was
    counted in `frames-bad`; `detail`: the particulars of the reason (a fault, the sessions, a
    time), in words."""

    reason: Reason
    axis: Optional[str] = None
    delta: int = 0
    moved: int = 0
    lost: int = 0
    bad: bool = False
    detail: str = ""

    @property
    def credited(self) -> bool:
        """The record moved an axis."""
        return self.reason is Reason.CREDITED

    @property
    def motion_uncredited(self) -> bool:
        """The device's position moved since the record taken before it and the rule credited
        none of it (a baseline after a gap, an undated record, too fast, no axis): detents the
        operator may have counted and the machine did not move."""
        return self.moved != 0 and not self.credited

    @property
    def kind(self) -> str:
        """What the reason amounts to: `CREDITED`, `BASELINE`, `COPY`, ..."""
        return KINDS[self.reason]

    @property
    def text(self) -> str:
        """The verdict in words, as `canopen-handwheel decode` prints it."""
        text = _WORDS[self.reason].format(detail=self.detail, moved=self.moved)
        if self.credited and self.axis is not None:
            name = OVERRIDES.get(self.axis, self.axis.upper())
            text = f"credited {name} {self.delta:+d} ({text})"
        elif self.kind == BASELINE and self.moved:
            text += f"; position {self.moved:+d} since the last record taken, not credited"
        if self.lost:
            text += f"; {self.lost} record{'s' if self.lost != 1 else ''} lost before it"
        if self.bad and "bad" not in text:
            text += "; counted bad"
        return text


class UncreditedMotion:
    """When to say that motion went uncredited (`FeedVerdict.motion_uncredited`): the first
    time at once, then at most once per `interval` seconds, with how many more there were in
    between, so that a bus that makes every record a baseline cannot flood the log."""

    def __init__(self, interval: float = 1.0) -> None:
        self.interval = interval
        self.told_at: Optional[float] = None
        self.untold = 0

    def line(self, verdict: FeedVerdict, now: float) -> Optional[str]:
        """The log line for `verdict` at `now`, or None (not worth a line, or too soon)."""
        if not verdict.motion_uncredited:
            return None
        if self.told_at is not None and now - self.told_at < self.interval:
            self.untold += 1
            return None
        axis = (
            "no axis" if verdict.axis is None else OVERRIDES.get(verdict.axis, verdict.axis.upper())
        )
        text = f"motion not credited ({axis}, position {verdict.moved:+d}): {verdict.text}"
        if self.untold:
            text += f" (and {self.untold} more since the last such line)"
        self.told_at, self.untold = now, 0
        return text
