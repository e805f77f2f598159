"""`Core`'s session keeping (`SessionKeeping`, a part of `Core`): the outcomes of its
configurations and probes, a session taken, dropped or checked, and the configuration it
asks for (host/README.md, "Sessions")."""

from __future__ import annotations

import math
from typing import Dict, Optional

from .configuration import (
    EVENT_TIMER_MS_RANGE,
    YOUNG_RETRY,
    Action,
    Configure,
    Configured,
    WriteFeed,
    motion_settings,
)
from .dating import Probe, probe_date, probe_went_back
from .order import COPY_AGE
from .record import STOPPED
from .sdo import (
    ABORT_DEVICE_STATE,
    OWN_CHANNEL_DROPS_BEFORE_DEFAULT,
    PROBE_TIMEOUTS_BEFORE_CONFIGURING,
    SDO_SERVER_2,
)
from .sessions import free_tokens, next_key, token_free_at
from .stops import STOP_SESSION_ENDED


class SessionKeeping:
    """The part of `Core` that keeps its session (see `Core` for the state it works on)."""

    def done(
        self,
        action: Action,
        ok: bool,
        abort: Optional[int],
        now: float,
        result: Optional[Configured] = None,
    ) -> None:
        """The outcome of the pending action (`abort`: the SDO abort code, if any; `result`:
        what a `Configure` found and did, as far as it got)."""
        self.tick(now)
        if action is not self.pending:
            return
        self.pending = None
        if isinstance(action, Configure):
            self._configure_done(action, ok, result or Configured())
        elif isinstance(action, Probe):
            if not ok and abort == ABORT_DEVICE_STATE:
                self._probe_refused(action)
                return
            if not ok and abort is None:
                self._probe_unanswered(action)
                return
            self.probes_unanswered = 0  # the channel answers
            if action.own:
                self.own_channel_drops = 0
            date = probe_date(action, result, self.session) if ok and result else None
            if date is not None:
                self.dates.append(date)
            elif ok and result and probe_went_back(action, result, self.session):
                number = result.value >> 16  # type: ignore[operator]
                if self.feed_on and not self.asked_off:
                    self._report_stop(STOP_SESSION_ENDED)
                self._drop_session(
                    f"the device's feed sequence went back to {number} after {action.floor}: "
                    "a new power life"
                )
        elif isinstance(action, WriteFeed):
            # Success shows in the next records; give them time before trying again.
            self.feed_due = self.now + self.cfg.retry

    def _probe_refused(self, action: Probe) -> None:
        """The device refused the probe's write (abort 0x08000022): the key it carried is not
        the key of the session the device is in, so that session is not the host's, whatever
        its token (another master wrote it, in this power life or a new one whose boot-up the
        host missed). The host drops its session at once (a feed it had on stopped: the
        session ended) and configures again."""
        if self.session is None or action.key != self.session_key:
            return  # a probe of a session already dropped
        if self.feed_on and not self.asked_off:
            self._report_stop(STOP_SESSION_ENDED)
        self._drop_session(
            "the device refused the session key: its session is not this component's "
            "(another master opened it, or a new power life)"
        )

    def _probe_unanswered(self, action: Probe) -> None:
        """The probe got no answer (timed out, or the bus failed). On the component's own
        channel, the `PROBE_TIMEOUTS_BEFORE_CONFIGURING`-th in a row drops the session (a
        feed it had on stopped: the session ended, as a power cycle, a reset or another
        master's write of 0x1201 that silenced the channel ends it on the device) and the
        device is configured again, which sets up the channel again. Not while the device
        shows itself Stopped (it answers no SDO then, on any channel), nor on the default
        channel: there an unanswered probe keeps the session."""
        if self.session is None or action.key != self.session_key or not action.own:
            return  # a probe of a session already dropped, or on the default channel
        if self.state == STOPPED:
            return
        self.probes_unanswered += 1
        if self.probes_unanswered < PROBE_TIMEOUTS_BEFORE_CONFIGURING:
            return
        if self.feed_on and not self.asked_off:
            self._report_stop(STOP_SESSION_ENDED)
        self._drop_session(
            f"{self.probes_unanswered} probes unanswered on the component's own SDO channel "
            f"(0x{SDO_SERVER_2:04X})"
        )
        self.own_channel_drops += 1
        if self.own_channel_drops == OWN_CHANNEL_DROPS_BEFORE_DEFAULT:
            self.log.append(
                f"the component's own SDO channel (0x{SDO_SERVER_2:04X}) went unanswered in "
                f"{self.own_channel_drops} sessions in a row: the bus or a gateway may not "
                "carry its identifiers; configuring on the default channel from now on"
            )

    def _configure_done(self, action: Configure, ok: bool, r: Configured) -> None:
        """A configuration's outcome. It stands if every step succeeded and was read back,
        the token is one the core offered (or the kept session, still the core's), its
        session key was written after it (`Configured.keyed`), the event timer is one the
        component can judge staleness by, and the device answered it in the life the core
        knows (not before a boot-up seen meanwhile). A device found in another session than
        the core's ended it: a feed it had on stopped. A device too young for a session
        (`Configured.young`) is asked again after `YOUNG_RETRY`."""
        booted, self.booted_during = self.booted_during, None
        before_boot = booted is not None and (
            r.first_reply_at is None or r.first_reply_at <= booted
        )
        if ok and r.loader:
            if before_boot:
                self.config_due = self.now  # the device booted since: ask it again
            else:
                self._loader_found()
            return
        if r.found is not None and self.in_loader:
            # It answered 0x2002: an application runs.
            self.in_loader = False
            self.log.append("the device runs its application again (it left its loader)")
        # A token the device refused as too young was not written: it never was in it.
        for token in (r.found, None if r.young else r.tried):
            if token and token != self.session:
                self.busy[token] = self.now
        if r.tried and not r.young and r.tried in action.tokens:
            # Written when free: a new chain (a reusable token's goes on).
            self.chains[r.tried] = self.configure_asked_at
        if r.found is not None and self.session is not None and r.found != self.session:
            if self.feed_on and not self.asked_off:
                self._report_stop(STOP_SESSION_ENDED)
            self._drop_session(f"the device is in session {r.found}, not {self.session}")
        low, high = EVENT_TIMER_MS_RANGE
        if ok and r.intact and not before_boot:
            if self.session is not None and r.session == action.keep == self.session:
                self.check_due = False
                self.check_at = self.now + self.cfg.retry
                return
        elif (
            ok
            and not before_boot
            and r.session is not None
            and r.session == r.tried
            and (r.session in action.tokens or r.session in dict(action.reusable))
            and r.keyed
            and r.event_timer_ms is not None
            and low <= r.event_timer_ms <= high
        ):
            self._new_session(r.session, r.found)
            self.session_key = action.key
            self._set_event_timer(r.event_timer_ms / 1000)
            self.own_channel = action.own_sdo is not None
            return
        if self.session is None:
            # It spoke to the device's life before a boot-up seen meanwhile, or checked a
            # session dropped meanwhile, or failed while the device booted (a reset cuts a
            # transfer short): again at once; a device too young for a session: again soon;
            # another failure: after the retry time.
            again = (ok and (before_boot or r.intact)) or (not ok and booted is not None)
            if again:
                self.config_due = self.now
            elif r.young:
                self.config_due = self.now + YOUNG_RETRY
            elif r.unproven:
                # No token free, and the device may have been power cycled since each
                # reusable one was first written: wait for the first free one.
                self.config_due = token_free_at(self._last_use(), self.session)
                self.log.append(
                    "the device's uptime does not show it running since the session tokens "
                    f"in use less than {COPY_AGE:g} s ago were written (a power cycle): "
                    f"configuring in {self.config_due - self.now:.1f} s"
                )
            else:
                self.config_due = self.now + self.cfg.retry
        else:
            self.check_at = self.now + self.cfg.retry

    def _loader_found(self, how: str = '0x1000 = "BOOT"') -> None:
        """The device answered as its loader (or booted after another master stopped its
        program): no session, nothing to configure, until its boot-up (after an update, or
        `reconnected`, or a record) says an application may run. Logged once per stay."""
        if not self.in_loader:
            self.log.append(
                f"node {self.cfg.node} is in its loader ({how}), not its "
                "application: no jogging; waiting for its boot-up (`canopen-handwheel update "
                "FILE` installs an application)"
            )
        self.in_loader = True
        self.config_due = math.inf

    def _new_session(self, token: int, found: Optional[int]) -> None:
        """The configuration wrote `token` and read it back: it is the session now, with
        no order reference (its first record is a baseline). Every token the device may have
        been in until now is superseded now: its records stopped at the latest with this
        configuration's first write."""
        if self.session is not None:
            self.busy[self.session] = self.now
        if found:
            self.busy[found] = self.now
        for old in self.busy:
            if old != token:
                self.superseded[old] = self.now
        self.busy = {}
        self.session = token
        self._forget_records()
        self.check_due = False
        self.check_logged = False
        self.waiting_logged = False
        self.asked_off = False  # a feed on in this session is a master's asking
        self.feed_due = 0.0

    def _drop_session(self, why: str) -> None:
        """The host no longer holds its session: its order reference is gone (a boot-up, a
        Pre-operational device, a reference too old, a device found in another session), so
        a copy of one of its records could become a baseline that a later copy links to.
        Every record is another session's until a new token is written and read back."""
        if self.session is not None:
            self.busy[self.session] = self.now
            self.log.append(f"session {self.session} dropped ({why}); configuring the device")
        self.session = None
        self.session_key = None
        self.check_due = False
        self.config_due = self.now
        self._forget_records()

    def _forget_records(self) -> None:
        """No record of a session before: a stop still waiting for its EMCY is reported
        with what is known."""
        if self.stop_seen is not None:
            self._stopped()
        self.order = None
        self.record = None
        self.record_time = None
        self.dates.clear()
        self.probe_due = self.now
        self.own_channel = False
        self.probes_unanswered = 0
        self.baseline = True
        self.suspect = False
        self.epochs_shown = False
        self.foreign_newest = False
        self.feed_on = False
        self.stop_seen = None

    def _configure(self, keep: Optional[int]) -> Optional[Configure]:
        """A `Configure` with the tokens free now and the next session key (`next_key`:
        every configuration writes another); without any token (every one used less than
        COPY_AGE ago) a configuration waits until one is free (a check still runs: it
        writes nothing if the device is in the session)."""
        last_use = self._last_use()
        tokens = free_tokens(last_use, self.now, self.session)
        reusable = tuple(
            (t, self.chains[t])
            for t in sorted(last_use, key=lambda t: (last_use[t], t))
            if t not in tokens and t != self.session and t in self.chains
        )
        self.configure_asked_at = self.now
        if not tokens and not reusable and keep is None:
            self.config_due = token_free_at(last_use, self.session)
            if not self.waiting_logged:
                self.waiting_logged = True
                self.log.append(
                    f"no session token free (each was in use less than {COPY_AGE:g} s ago): "
                    f"configuring in {self.config_due - self.now:.1f} s"
                )
            return None
        key, self.key = self.key, next_key(self.key)
        return Configure(
            self.cfg.master,
            self.cfg.consumer_timeout_ms,
            self.cfg.event_timer_ms,
            keep,
            tokens,
            motion_settings(self.cfg),
            None
            if self.own_channel_drops >= OWN_CHANNEL_DROPS_BEFORE_DEFAULT
            else self.cfg.own_sdo,
            key,
            reusable,
        )

    def _last_use(self) -> Dict[int, float]:
        """Per token, when the host last knew the device could be in it (`superseded`,
        `busy`)."""
        last_use = dict(self.superseded)
        for token, t in self.busy.items():
            last_use[token] = max(t, last_use.get(token, -math.inf))
        return last_use
