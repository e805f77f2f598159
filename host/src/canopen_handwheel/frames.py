"""`Core`'s frame handlers (`FrameHandling`, a part of `Core`): the feed record (the order
rule, continuity, dating, the allowance), EMCY, heartbeat, and other masters' SDO
exchanges."""

from __future__ import annotations

import math
from typing import Optional

from .configuration import Configure, WriteFeed
from .dating import BACKLOG_LIMIT, DATE_LIMIT, PROBE_OBJECT, Probe, dated_at
from .order import AHEAD, COPY, DUPLICATE, ORDER_WINDOW, RENEW, SAME_NUMBER, order_verdict
from .overrides import OVERRIDES
from .record import (
    BOOTUP,
    EPOCH_MODULO,
    OPERATIONAL,
    PRE_OPERATIONAL,
    SEQUENCE_MODULO,
    STOPPED,
    Record,
    _link,
    record_fault,
    sequence_gap,
    wrap_s32,
)
from .sdo import (
    FOREIGN_READ_QUIET,
    FOREIGN_SDO_QUIET,
    PROGRAM_CONTROL,
    PROGRAM_OBJECTS,
    PROGRAM_STOP,
)
from .stops import (
    EMCY_MASTER_LOST,
    EMCY_TRANSMIT_BLOCKED,
    STOP_NOT_OPERATIONAL,
    STOP_REASONS,
    STOP_SESSION_ENDED,
    stop_reason,
)
from .verdict import FeedVerdict, Reason


class FrameHandling:
    """The part of `Core` that handles the device's frames (see `Core` for the state)."""

    def _holding_back(self) -> bool:
        """Another master's SDO exchange is under way (`FOREIGN_SDO_QUIET`): no request of
        the component now. Logged once per exchange that lasts (not a read answered within
        `FOREIGN_READ_QUIET`, nor the short quiet after it)."""
        if self.foreign_sdo_at is None:
            return False
        if self.now - self.foreign_sdo_at < self.foreign_quiet:
            quick = self.now - self.foreign_sdo_at < FOREIGN_READ_QUIET
            if not self.holding_logged and self.foreign_quiet == FOREIGN_SDO_QUIET and not quick:
                self.holding_logged = True
                self.log.append(
                    f"another master is exchanging SDO with node {self.cfg.node}: no request "
                    f"of the component until it has been quiet for {FOREIGN_SDO_QUIET:g} s"
                )
            return True
        self.holding_logged = False
        return False

    # Frame handlers -------------------------------------------------------------------

    def _bad(self) -> None:
        self.frames_bad = wrap_s32(self.frames_bad + 1)

    def _tpdo1(self, data: bytes, now: float) -> FeedVerdict:
        """The feed record: what it credits, and why (`FeedVerdict`)."""
        if len(data) != 8:
            self._impossible()
            return FeedVerdict(Reason.MALFORMED, bad=True, detail=f"{len(data)} bytes")
        rec = Record.decode(data)
        fault = record_fault(rec)
        if fault is not None:
            self._impossible()
            return FeedVerdict(Reason.NEVER_SENT, bad=True, detail=fault)
        if self.session is None or rec.session != self.session:
            if self.in_loader and self.config_due == math.inf:
                # A loader sends no records: an application runs (its boot-up was missed).
                self.config_due = self.now
            held = self.session
            self._foreign(rec)
            if held is None:
                return FeedVerdict(Reason.NO_SESSION)
            detail = f"session {rec.session}, not the host's {held}"
            return FeedVerdict(Reason.OTHER_SESSION, detail=detail)
        verdict, ahead = order_verdict(self.order, rec, self.now)
        if verdict == RENEW:
            self._drop_session(f"no record of it for more than {ORDER_WINDOW:g} s")
            return FeedVerdict(Reason.STALE_SESSION)
        if verdict == DUPLICATE:
            return FeedVerdict(Reason.DUPLICATE)  # the same frame twice (a known CAN effect)
        if verdict == SAME_NUMBER:
            self._impossible()  # one number, two records
            return FeedVerdict(Reason.SAME_NUMBER, bad=True)
        if verdict == COPY:
            self._bad()  # an earlier record again: never a reference, no loss
            behind = f"{SEQUENCE_MODULO - ahead} numbers"
            return FeedVerdict(Reason.COPY, bad=True, detail=behind)
        prev = self.record
        fresh = prev is not None and self.fresh
        lost = ahead - 1 if verdict == AHEAD and fresh else 0
        self.records_lost = wrap_s32(self.records_lost + lost)
        late = self.drained_at is None or self.now - self.drained_at > BACKLOG_LIMIT
        if rec.epoch != 0:
            self.epochs_shown = True
        moved = 0 if prev is None else wrap_s32(rec.position - prev.position)
        bad = False
        detail = ""
        delta: Optional[int] = None
        # Whether it continues the record before it (else it is a baseline, and why), in the
        # order the rule asks.
        if prev is None:
            reason = Reason.FIRST
        elif not fresh:
            reason = Reason.STALE
            assert self.record_time is not None
            detail = f"{self.now - self.record_time:.3f} s"
        elif self.baseline:
            reason = Reason.AFTER_IMPOSSIBLE
        elif late:
            reason = Reason.LATE
            waited = None if self.drained_at is None else self.now - self.drained_at
            detail = "ever" if waited is None else f"{waited:.3f} s"
        else:
            delta, fault = _link(prev, rec)
            reason = Reason.CREDITED if delta else Reason.AT_REST
            if fault is not None:
                self._bad()
                bad, reason, detail = True, Reason.CANNOT_FOLLOW, fault
            elif delta is None:
                reason = Reason.OTHER_EPOCH
                epochs = (rec.epoch - prev.epoch) % EPOCH_MODULO
                gap = sequence_gap(prev, rec)
                detail = f"epoch {prev.epoch} -> {rec.epoch} ({epochs} on) across a gap of {gap}"
            elif delta:
                undated = self._undated(prev)
                if undated is not None:
                    delta = None  # it may have been held on its way: a baseline
                    reason, detail = Reason.UNDATED, undated
        if delta and not self.allowance.take(abs(delta) // rec.multiplier, self.now):
            self._bad()  # faster than a wheel turns
            delta = None
            bad, reason = True, Reason.TOO_FAST
        letter = self._letter(rec.axis)
        if delta and letter is None:
            reason, detail = Reason.NO_AXIS, f"axis {rec.axis}"
        elif delta and not self.epochs_shown:
            reason = Reason.NO_EPOCH
        credited = reason is Reason.CREDITED
        if credited and delta is not None and letter is not None:
            if letter in OVERRIDES:
                delta //= rec.multiplier  # an override moves by detents, whatever the multiplier
            self.counts[letter] = wrap_s32(self.counts[letter] + delta)
        self.record = rec
        self.record_time = now
        # The earliest it can have reached the host: after the receive path was last found
        # empty (a record from a backlog may have waited there since).
        arrived = self.now if self.drained_at is None else min(self.now, self.drained_at)
        self.order = (rec, arrived)
        self.foreign_newest = False
        self.suspect = False
        self.baseline = False
        if self.state in (None, BOOTUP):
            # PDOs only flow in Operational; the heartbeat will say so too.
            self.state = OPERATIONAL
        self._watch_feed(rec)
        if credited and letter is not None:
            if self.credit_time is None:
                self.credit_time = self.now
            self.credit_last = self.now
            if self.gate(letter):
                self.credit_open[letter] = True
        credit = delta if credited and delta is not None else 0
        return FeedVerdict(reason, letter, credit, moved, lost, bad, detail)

    def _undated(self, reference: Record) -> Optional[str]:
        """None if a probe sent at most DATE_LIMIT ago found the successor of `reference`
        not yet made (`dated_at`): what a record adds to it is recent. Else why not (the
        last probe's age), counted (`undated`) and logged once until a record is dated
        again."""
        if not self.cfg.dating:
            return None
        at = dated_at(self.dates, reference)
        if at is not None and self.now - at <= DATE_LIMIT:
            self.undated_logged = False
            return None
        self.undated = wrap_s32(self.undated + 1)
        if not self.undated_logged:
            self.undated_logged = True
            self.log.append(
                "a record not dated within "
                f"{DATE_LIMIT:g} s by the sequence probe (0x2033; held on its way, or the "
                "probes unanswered): not credited"
            )
        return "no probe" if at is None else f"the last probe {self.now - at:.3f} s ago"

    def _foreign(self, rec: Record) -> None:
        """A possible record of another session (0: none; another token: another master's,
        one of the host's earlier ones, or a copy): never a reference, never credited, not
        counted bad. It closes the gates, and while the host has a session it makes the
        host check its configuration (the device may have lost it unseen: a power cycle
        whose boot-up did not arrive, another master's write). A token it shows that the
        host never used may be the device's: not written until COPY_AGE after."""
        self.foreign_newest = True
        if rec.session and rec.session not in self.superseded:
            self.busy[rec.session] = self.now
        if self.session is not None and not self.check_due:
            self.check_due = True
            if not self.check_logged:  # once a session: copies may come for a minute
                self.check_logged = True
                self.log.append(
                    f"a record of session {rec.session}, not {self.session}: checking the "
                    "device's configuration (0x2002)"
                )

    def _watch_feed(self, rec: Record) -> None:
        """A record of the session: a feed that was on and is off without the component
        having asked is a stop by the device, reported with its reason (`stop_reason`),
        after STOP_REASON_WAIT for the EMCY that tells a blocked transmit path from a lost
        master when only status bit 3 says so (also when the feed is on again by then: the
        component enables it again at once)."""
        if self.feed_on and not rec.enabled and not self.asked_off and self.stop_seen is None:
            self.stop_seen = self.now
            self.stop_master_lost = rec.master_lost
            if not rec.master_lost or self.stop_emcy is not None:
                self._stopped()
        self.feed_on = rec.enabled
        if rec.enabled and self.stop_seen is None:
            self.stop_emcy = None
            self.left_operational = False

    def _stopped(self) -> None:
        """The stop waiting for its reason, reported with what is known now."""
        self._report_stop(stop_reason(self.stop_master_lost, self.stop_emcy, self.left_operational))

    def _report_stop(self, reason: int) -> None:
        self.feed_stops = wrap_s32(self.feed_stops + 1)
        self.stop_reason = reason
        self.log.append(f"feed stopped by the device: {STOP_REASONS[reason]}")
        self.stop_seen = None
        self.stop_master_lost = False
        self.stop_emcy = None
        self.left_operational = False

    def _impossible(self) -> None:
        """A TPDO1 the device can never send: counted, and it breaks continuity; the
        last possible record stays the one the pins show, without a selected axis."""
        self._bad()
        self.baseline = True
        self.suspect = True

    def _letter(self, axis: int) -> Optional[str]:
        if 1 <= axis <= len(self.cfg.axes):
            return self.cfg.axes[axis - 1]
        return None

    def _emcy(self, data: bytes) -> None:
        if len(data) != 8:
            self._bad()
            return
        self.emcy_code = int.from_bytes(data[0:2], "little")
        if self.emcy_code in (EMCY_MASTER_LOST, EMCY_TRANSMIT_BLOCKED):
            self.stop_emcy = self.emcy_code
            if self.stop_seen is not None:
                self._stopped()

    def _foreign_sdo_request(self, data: bytes) -> None:
        """An SDO request to the device that the component did not send (the shell never
        receives its own frames): another master's exchange (`FOREIGN_SDO_QUIET`). An
        expedited write of 0x1F51:1 is remembered until the device answers it."""
        self.foreign_sdo_at = self.now
        self.foreign_quiet = FOREIGN_SDO_QUIET
        read = len(data) == 8 and data[0] & 0xE0 == 0x40  # an upload's initiate
        index = int.from_bytes(data[1:3], "little") if len(data) >= 3 else None
        self.foreign_read = bytes(data[1:4]) if read and index not in PROGRAM_OBJECTS else None
        expedited_write = len(data) == 8 and data[0] & 0xE2 == 0x22
        control = expedited_write and data[1:4] == PROGRAM_CONTROL
        self.program_request = data[4] if control else None

    def _sdo_response(self, data: bytes) -> None:
        """The device's SDO answer (to the component or another master): a confirmed write
        of 0x1F51:1 = "stop" (the component writes none) means that the boot-up following
        it is the loader's. The expedited answer (or abort) to another master's read that
        the component is not itself asking for ends the hold on its requests."""
        answered = len(data) == 8 and (data[0] & 0xE2 == 0x42 or data[0] == 0x80)
        if answered and self.foreign_read is not None and data[1:4] == self.foreign_read:
            if not self._asking_for(data[1:4]):
                self.foreign_sdo_at = self.now
                self.foreign_quiet = FOREIGN_READ_QUIET
            self.foreign_read = None
        if self.program_request is None or len(data) != 8 or data[1:4] != PROGRAM_CONTROL:
            return
        if data[0] == 0x60 and self.program_request == PROGRAM_STOP:  # confirmed
            self.program_stopped_at = self.now
        self.program_request = None

    def _asking_for(self, entry: bytes) -> bool:
        """The component's own action under way may be asking for the object `entry`
        (index, sub as an SDO frame has them): then an answer for it may be its own."""
        index, sub = int.from_bytes(entry[0:2], "little"), entry[2]
        if isinstance(self.pending, Probe):
            return (index, sub) == (PROBE_OBJECT, 0)
        if isinstance(self.pending, WriteFeed):
            return (index, sub) == (0x2000, 0)
        return self.pending is not None

    def _heartbeat(self, data: bytes, now: float) -> None:
        if len(data) != 1:
            self._bad()
            return
        state = data[0] & 0x7F
        if state != OPERATIONAL:
            self.left_operational = True
        if state == BOOTUP:
            # A (re)started device: everything it had is gone, the session too.
            if self.feed_on and not self.asked_off:
                self._report_stop(STOP_SESSION_ENDED)
            self._drop_session("the device booted")
            self.emcy_code = 0
            if isinstance(self.pending, Configure):
                # Its outcome counts only if the device answered it after this boot-up
                # (`done`); another one now would only run after it, in the same worker.
                self.booted_during = self.now
            stopped, self.program_stopped_at = self.program_stopped_at, None
            if stopped is not None and self.now - stopped <= FOREIGN_SDO_QUIET:
                # Another master stopped the program (an update): the loader booted. Asking
                # it (0x2002, 0x1000) would break that master's exchange.
                self._loader_found("another master stopped its program: 0x1F51:1 = 0")
        elif state in (PRE_OPERATIONAL, STOPPED):
            if self.feed_on and not self.asked_off:
                self._report_stop(STOP_NOT_OPERATIONAL)
                self.feed_on = False  # leaving Operational disabled it
            configuring = isinstance(self.pending, Configure) and self.pending.keep is None
            if state == PRE_OPERATIONAL and self.session is not None and not configuring:
                # Someone (or a missed boot-up) left it Pre-operational: configure and start
                # (a configuration under way ends with the start itself).
                self._drop_session("the device is Pre-operational")
        self.state = state
