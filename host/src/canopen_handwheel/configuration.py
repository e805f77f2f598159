"""The component's settings (`Config`, `make_config`) and the device's configuration: what
it writes (`consumer_plan`, `event_timer_plan`, `inhibit_plan`, `motion_settings`, ...),
the actions the shell carries out (`Configure`, `Configured`, `WriteFeed`) and the
component's heartbeat timing (`beat_allowed`, `next_beat`)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Dict, Optional, Tuple

from .dating import DATE_LIMIT
from .metering import (
    DEFAULT_MAX_DETENTS_PER_S,
    DEFAULT_RUN_ON_BUDGET,
    MAX_DETENTS_PER_S_RANGE,
    RUN_ON_BUDGET_RANGE,
    rate_horizon,
)
from .outputs import DEFAULT_OUTPUT_PERIOD_MS, output_period
from .overrides import DEFAULT_OVERRIDE_STEP, OVERRIDE_STEP_RANGE, OVERRIDES, parse_axes
from .record import DEVICE_AXES
from .sdo import parse_sdo_channel
from .sessions import life_began_by, pick_token

# TPDO1's mapping 0x1A00 as the feed record needs it (README "Feed record"): position 0x6004,
# selection 0x2011, status 0x2030, sequence 0x2031 (16 bits). A configuration that finds
# another mapping fails (it is logged and retried; the feed is never enabled): another master
# remapped the PDO, and what it carries would not be the record the rule reads.
FEED_RECORD_MAPPING = (0x6004_0020, 0x2011_0008, 0x2030_0008, 0x2031_0010)


def tpdo1_cob_id_fault(cob_id: int, node: int) -> Optional[str]:
    """Why TPDO1's COB-ID entry 0x1800:1 (read back after the configuration) does not carry
    the feed record where the component reads it, or None: valid, on 0x180 + node-ID."""
    if cob_id & 0x8000_0000:
        return "TPDO1 is invalid (0x1800:1 bit 31)"
    if cob_id & 0x7FF != 0x180 + node or cob_id & 0x2000_0000:
        return f"TPDO1 is on 0x{cob_id & 0x1FFF_FFFF:X}, not 0x{0x180 + node:X}"
    return None


# TPDO1 inhibit time 0x1800:3 (100 us units): below INHIBIT_MIN (1 ms) the device's records
# could come faster than its sequence budget refills, ending the session; configuration then
# sets INHIBIT_SET (2 ms, the default).
INHIBIT_MIN = 10
INHIBIT_SET = 20
# Above INHIBIT_MAX (20 ms) a detent's record could follow it by more than the dating of
# records allows for (`RECORD_DELAY`): configuration sets INHIBIT_SET too.
INHIBIT_MAX = 200


def inhibit_plan(device: int) -> Optional[int]:
    """What to write to 0x1800:3 at configuration, or None to keep the device's value."""
    return INHIBIT_SET if not INHIBIT_MIN <= device <= INHIBIT_MAX else None


# TPDO1's transmission type 0x1800:2: the feed record is event-driven (254 or 255: on
# change, after the inhibit time, and at the event timer). Any other type (synchronous)
# would send records only at a SYNC, so that neither staleness nor the record's timing would
# mean what the rule assumes; configuration then sets TRANSMISSION_TYPE_SET.
EVENT_DRIVEN = (254, 255)
TRANSMISSION_TYPE_SET = 254


def transmission_type_plan(device: int) -> Optional[int]:
    """What to write to 0x1800:2 at configuration, or None to keep the device's value."""
    return None if device in EVENT_DRIVEN else TRANSMISSION_TYPE_SET


# The wheel's parameters 0x2020:3 (counts per detent) and 0x2020:4 (invert direction)
# decide the scale and the sign of every detent: the component sets them to its own
# `--counts-per-detent` and `--invert-direction` at every configuration, whatever the device
# stored or another master wrote, and reads them back.
WHEEL = 0x2020
COUNTS_PER_DETENT_SUB = 3
INVERT_SUB = 4
COUNTS_PER_DETENT = (1, 2, 4)
DEFAULT_COUNTS_PER_DETENT = 4


def motion_settings(cfg: "Config") -> Tuple[Tuple[int, int, int], ...]:
    """(index, sub, value) of the settings a configuration writes that shape motion and do
    not depend on what the device holds: the wheel's parameters and the feed format
    (0x2001 = 0, the feed record). With the feed record's mapping, TPDO1's parameters and
    the 0x1016 entry (which depend on what is read first) they are read back once more
    after the session is written (`Configure`)."""
    return (
        (WHEEL, COUNTS_PER_DETENT_SUB, cfg.counts_per_detent),
        (WHEEL, INVERT_SUB, int(cfg.invert_direction)),
        (0x2001, 0, 0),
    )


# The device's session open delay (s): a write of 0x2002 = 1..7 less than this after the
# device started (power-on, any reset of its MCU; not NMT's reset node or communication) is
# refused with abort 0x08000022. Longer than DATE_LIMIT: a probe answered before a power cycle
# dates records for DATE_LIMIT at most, and no record of the new power life carries a session
# before SESSION_DELAY, so no date of the old life ever dates a record of the new one.
SESSION_DELAY = 0.5
assert DATE_LIMIT < SESSION_DELAY, "a probe's date must run out before a new life's session"
# A configuration refused because the device is younger than SESSION_DELAY
# (`Configured.young`) is asked for again this soon (not `Config.retry` later), so that the
# host has its session within about a second of the device's boot-up.
YOUNG_RETRY = 0.1


# The event timer written when the device has none (0x1800:5 = 0) or one outside the range,
# and assumed until the first configuration when `--event-timer-ms` is not given (the
# device's default, too). At most 1 s: three periods of silence (staleness) then stay within
# ORDER_WINDOW, so a device at rest never makes the host start a new session.
DEFAULT_EVENT_TIMER_MS = 100
EVENT_TIMER_MS_RANGE = (10, 1000)


def resolve_master(node: int, master: Optional[int]) -> int:
    """The master node-ID: `master` if given (1..127, not `node`), else 1, or 2 when the
    device itself is node 1."""
    if not 1 <= node <= 127:
        raise ValueError(f"--node {node}: node-IDs are 1..127")
    if master is None:
        return 2 if node == 1 else 1
    if not 1 <= master <= 127:
        raise ValueError(f"--master-node {master}: node-IDs are 1..127")
    if master == node:
        raise ValueError(f"--master-node {master} is the device's own node-ID")
    return master


def consumer_plan(entries: Dict[int, int], master: int, timeout_ms: int) -> Tuple[int, int]:
    """Which 0x1016 sub-index to write and the value: the sub that already watches
    `master`, else the first unused one (time 0), else sub 1."""
    value = (master << 16) | timeout_ms
    for sub in sorted(entries):
        if (entries[sub] >> 16) & 0xFF == master:
            return sub, value
    for sub in sorted(entries):
        if entries[sub] & 0xFFFF == 0:
            return sub, value
    return 1, value


def make_config(
    node: int,
    master: Optional[int],
    axes: str,
    scale: float,
    event_timer_ms: Optional[int],
    heartbeat_ms: int,
    max_detents_per_s: int = DEFAULT_MAX_DETENTS_PER_S,
    position_mode: bool = False,
    velocity_mode: bool = False,
    run_on_budget: float = DEFAULT_RUN_ON_BUDGET,
    override_step: float = DEFAULT_OVERRIDE_STEP,
    counts_per_detent: int = DEFAULT_COUNTS_PER_DETENT,
    invert_direction: bool = False,
    sdo_channel: str = "auto",
    output_period_ms: int = DEFAULT_OUTPUT_PERIOD_MS,
) -> "Config":
    """The component's settings from its options, every one checked (`ValueError` says
    which is wrong). The device is told to allow five of the component's heartbeat periods
    (0x1016), so one late beat never stops the wheel. `event_timer_ms` None: the device's
    own (read at configuration)."""
    low, high = MAX_DETENTS_PER_S_RANGE
    if not low <= max_detents_per_s <= high:
        raise ValueError(f"--max-detents-per-s must be {low}..{high}")
    if not (math.isfinite(scale) and scale != 0):
        raise ValueError(f"--scale {scale}: a finite, non-zero number of machine units")
    if not 10 <= heartbeat_ms <= 10000:
        raise ValueError("--heartbeat-ms must be 10..10000")
    low, high = EVENT_TIMER_MS_RANGE
    if event_timer_ms is not None and not low <= event_timer_ms <= high:
        raise ValueError(f"--event-timer-ms must be {low}..{high}")
    if position_mode and velocity_mode:
        raise ValueError("--position-mode and --velocity-mode exclude each other")
    low, high = RUN_ON_BUDGET_RANGE
    if not (math.isfinite(run_on_budget) and low <= run_on_budget <= high):
        raise ValueError(f"--run-on-budget must be {low}..{high} s")
    low, high = OVERRIDE_STEP_RANGE
    if not (math.isfinite(override_step) and low <= override_step <= high):
        raise ValueError(f"--override-step must be {low}..{high} %")
    if counts_per_detent not in COUNTS_PER_DETENT:
        raise ValueError(f"--counts-per-detent must be one of {COUNTS_PER_DETENT}")
    period = output_period(output_period_ms)
    master_node = resolve_master(node, master)
    return Config(
        node=node,
        master=master_node,
        axes=parse_axes(axes),
        scale=scale,
        event_timer=(event_timer_ms or DEFAULT_EVENT_TIMER_MS) / 1000,
        event_timer_ms=event_timer_ms,
        heartbeat_period=heartbeat_ms / 1000,
        consumer_timeout_ms=5 * heartbeat_ms,
        max_detents_per_s=max_detents_per_s,
        position_mode=position_mode,
        velocity_mode=velocity_mode,
        run_on_budget=run_on_budget,
        override_step=override_step,
        counts_per_detent=counts_per_detent,
        invert_direction=invert_direction,
        dating=True,
        own_sdo=parse_sdo_channel(sdo_channel, master_node),
        output_period=period,
    )


def event_timer_plan(device_ms: int, wanted_ms: Optional[int]) -> Optional[int]:
    """What to write to the device's event timer 0x1800:5 at configuration, or None to
    keep its value: `wanted_ms` (`--event-timer-ms`) when given and different, else
    `DEFAULT_EVENT_TIMER_MS` when the device has none (0: records only on change, so that
    silence would not tell that it is gone) or one outside `EVENT_TIMER_MS_RANGE`."""
    if wanted_ms is not None:
        return wanted_ms if wanted_ms != device_ms else None
    low, high = EVENT_TIMER_MS_RANGE
    return None if low <= device_ms <= high else DEFAULT_EVENT_TIMER_MS


# How long the component's main loop may go without progress before its heartbeat stops
# (at least this, or two heartbeat periods if longer): the heartbeat has a thread of its
# own, but it must not keep the device feeding a component that no longer reads its frames.
LOOP_STALL_LIMIT = 0.25


def beat_allowed(loop_seen: float, now: float, period: float) -> bool:
    """Whether the heartbeat may go out at `now`, the main loop having last made progress
    at `loop_seen`: not once the loop has stalled for longer than `LOOP_STALL_LIMIT` or two
    periods. The device then stops the feed after its consumer timeout (five periods)."""
    return now - loop_seen <= max(LOOP_STALL_LIMIT, 2 * period)


def next_beat(due: float, now: float, period: float) -> float:
    """When the component's heartbeat is next due, after the beat due at `due` went out at
    `now`: the next point of the grid `due + k * period` after `now`. On time, that is one
    period on (no drift from the time sending took); a sender held up for longer than a
    period skips the beats it missed rather than sending them in a burst."""
    if period <= 0:
        raise ValueError("the heartbeat period must be positive")
    late = max(0.0, now - due)
    return due + (math.floor(late / period) + 1) * period


@dataclass(frozen=True)
class Config:
    node: int = 16
    master: int = 1
    axes: str = DEVICE_AXES
    scale: float = 0.001
    # s, the device's TPDO1 event timer (0x1800:5) as assumed until the device tells.
    event_timer: float = DEFAULT_EVENT_TIMER_MS / 1000
    event_timer_ms: Optional[int] = None  # `--event-timer-ms`: written at configuration
    heartbeat_period: float = 0.1  # s, the component's own heartbeat
    consumer_timeout_ms: int = 500  # what the device is told to allow (0x1016)
    retry: float = 0.5  # s between attempts of a failed or unconfirmed action
    max_detents_per_s: float = DEFAULT_MAX_DETENTS_PER_S  # the wheel's speed bound
    position_mode: bool = False  # `--position-mode`: the `position-mode` pin's start value
    velocity_mode: bool = False  # `--velocity-mode`: the `velocity-mode` pin's start value
    run_on_budget: float = (
        DEFAULT_RUN_ON_BUDGET  # s, `--run-on-budget`: the `run-on-budget` pin's start value
    )
    override_step: float = (
        DEFAULT_OVERRIDE_STEP  # %, `--override-step`: one detent at an override position
    )
    counts_per_detent: int = DEFAULT_COUNTS_PER_DETENT  # 0x2020:3, `--counts-per-detent`
    invert_direction: bool = False  # 0x2020:4, `--invert-direction`
    first_nonce: int = 0  # the sequence probe's first nonce (the component draws it)
    # The first configuration's session key (`next_key` after it for each further one; the
    # component draws it, 1..0xFFFF), so that no run's keys follow another's.
    first_key: int = 1
    # Records dated by the sequence probe (`DATE_LIMIT`): the component's (`make_config`).
    # Off, the core credits what its rule links without dating it: the rule as
    # `crates/feed-check` checks it (its model has no path that holds frames upstream of the
    # host), and a capture of a component from before the probe.
    dating: bool = False
    # The component's own SDO channel (`own_sdo_ids`): (to the device, from it), or None.
    own_sdo: Optional[Tuple[int, int]] = None
    # s, the outputs' repeat period (`--output-period-ms`, `OutputSchedule`); None: no
    # outputs (a capture of a component from before them replays without).
    output_period: Optional[float] = None

    @property
    def axis_letters(self) -> str:
        """The LinuxCNC axes among the switch positions (`axes`), in switch order."""
        return "".join(c for c in self.axes if c not in OVERRIDES)

    @property
    def override_letters(self) -> str:
        """The overrides (`f`, `s`, `r`) among the switch positions, in switch order."""
        return "".join(c for c in self.axes if c in OVERRIDES)

    @property
    def stale_after(self) -> float:
        """Three event-timer periods, of the assumed event timer (`Core.stale_after` uses
        the device's once it is known)."""
        return 3 * self.event_timer

    @property
    def rate_horizon(self) -> float:
        """`Core.rate_horizon` for the assumed event timer."""
        return rate_horizon(self.stale_after, self.consumer_timeout_ms)


# Actions the shell carries out, one at a time; it reports back with `Core.done`.
@dataclass(frozen=True)
class Configure:
    """The configuration, in this order, every write read back (a difference fails it):
    read 0x2002; if that is refused (an SDO abort), read 0x1000: a device that answers the
    loader's "BOOT" (`LOADER_DEVICE_TYPE`) is in its loader, reported as `Configured.loader`,
    and nothing else is read or written. If 0x2002 is `keep` (the host's session, on a check
    after records of another session) the configuration is intact and nothing is written.
    Otherwise: the 0x1016 entry `consumer_plan` gives; the event timer 0x1800:5 as
    `event_timer_plan` says; the inhibit time 0x1800:3 as `inhibit_plan` says (TPDO1 made
    invalid for the write, valid again after); the transmission type 0x1800:2 as
    `transmission_type_plan` says; the second SDO server 0x1201 on `own_sdo` (subs 1, 2, and
    3 the master's node-ID; made invalid first when it serves another channel); `settings`
    (`motion_settings`: the wheel's parameters,
    0x2001 = 0), each written where it differs; TPDO1's mapping and COB-ID checked; 0x2000 =
    0 (feed off); 0x2002 = `pick_token(tokens, found)` (the session, last: every write
    before it ends a session; a device younger than `SESSION_DELAY` refuses it with abort
    0x08000022: `Configured.young`, nothing further); 0x2034 = `key` (the session key,
    `Configured.keyed`; the device keeps it with this session only); then everything that
    shapes motion read back once more (the 0x1016 entry, TPDO1's COB-ID, type, inhibit time,
    event timer and mapping, `settings`) and 0x2002 last: a change of any of them by
    another master after it was first read back and before the session was written would
    otherwise be in force in the new session (a change after the session was written ends
    it, and 0x2002 then reads 0); then NMT start. Its outcome (`Core.done`) carries a
    `Configured`, also when it failed part way."""

    master: int
    timeout_ms: int
    event_timer_ms: Optional[int] = None  # `--event-timer-ms`, if given
    keep: Optional[int] = None  # the session that counts as intact (a check), if any
    tokens: Tuple[int, ...] = ()  # `free_tokens`, best first
    settings: Tuple[Tuple[int, int, int], ...] = ()  # `motion_settings`: (index, sub, value)
    own_sdo: Optional[Tuple[int, int]] = None  # 0x1201 set to this channel, read back
    key: int = 1  # the session key written to 0x2034 after the token (1..0xFFFF)
    # Tokens in use less than COPY_AGE ago that the host wrote itself, with their chain
    # start, least recently used first: written only when no token is free and the device's
    # uptime (read before and after the session is written) proves them (`pick_token`).
    reusable: Tuple[Tuple[int, float], ...] = ()


@dataclass
class Configured:
    """What a `Configure` found and did, filled in by the shell as it goes (so a failed one
    tells how far it got): `found`, 0x2002 as read first; `intact`, it was `keep` and nothing
    was written; `tried`, the token written to 0x2002; `session`, that token read back (or
    the kept one); `event_timer_ms`, 0x1800:5 as read back; `first_reply_at`, when (the
    core's clock) the shell handled the device's answer to its first transfer: a
    configuration answered only after a boot-up the core saw while it ran was made in the
    device's new life and stands; `loader`, the device refused 0x2002 and its 0x1000 is the
    loader's (nothing else was done); `keyed`, the session key 0x2034 was written after the
    token (a configuration counts only with it); `young`, the device refused the token with
    abort 0x08000022 (started less than `SESSION_DELAY` ago: the device is in no session of
    it); `uptime`, the device's uptime (ms) and when the host handled its answer, read when
    only a reusable token was left (`UPTIME_OBJECT`); `unproven`, it did not show the device
    running since the chain of any (nothing was written)."""

    event_timer_ms: Optional[int] = None
    first_reply_at: Optional[float] = None
    found: Optional[int] = None
    intact: bool = False
    tried: Optional[int] = None
    session: Optional[int] = None
    loader: bool = False
    keyed: bool = False
    young: bool = False
    uptime: Optional[Tuple[int, float]] = None
    unproven: bool = False


@dataclass(frozen=True)
class WriteFeed:
    """0x2000 = value (`own`: on the component's own SDO channel)."""

    value: int
    own: bool = False


Action = object  # Configure | WriteFeed | Probe


def configure_outcome(
    action: Configure,
    found: int,
    event_timer: float,
    uptime: Optional[Tuple[int, float]] = None,
):
    """(ok, `Configured`): what carrying out `action` on a device whose 0x2002 reads `found`
    and whose every write succeeds reports: intact when `found` is the session to keep,
    else the token `pick_token` gives written and read back (none: failed) with the session
    key after it, the event timer `event_timer` (s) read back. `uptime`: the device's
    uptime (ms) and when its answer was handled, both times it is read (`UPTIME_OBJECT`;
    None: the device has no 0x2035, as a device before it: nothing reusable is written)."""
    if action.keep is not None and found == action.keep:
        return True, Configured(found=found, intact=True, session=found)
    token = pick_token(action.tokens, found)
    unproven = False
    if token is None and action.reusable and uptime is not None:
        token = pick_token((), found, action.reusable, life_began_by(*uptime))
        unproven = token is None
    if token is None:
        return False, Configured(found=found, uptime=uptime, unproven=unproven)
    ms = round(event_timer * 1000)
    return True, Configured(
        event_timer_ms=ms, found=found, tried=token, session=token, keyed=True, uptime=uptime
    )
