"""The component's decisions, free of HAL and CAN: what a frame means, what the pins show,
what to tell the device next.

`Core` is fed events and answers with pin snapshots and at most one `Action` at a time. The
shell (`component.py`) carries out actions over python-canopen and writes the pins to HAL;
it makes no decision of its own. Everything here is plain Python (standard library only)
and deterministic in the times it is given, so it is tested without a bus or LinuxCNC
(`host/tests`), and the interop suite checks the device's records with the same functions
(`Record`, `record_fault`, `continuity`, `pair_fault`).

The event API (stable; `replay` runs a list of these events through a `Core`):

- `frame(cob_id, data, now)`: a frame the shell read at `now` (identifiers other than the
  device's TPDO1, EMCY and heartbeat are ignored);
- `drained(now)`: the shell's receive path was found empty at a moment not before `now`,
  so every frame that reached the host before `now` has been handed to `frame`;
- `tick(now)`: time passes (staleness);
- `set_enable(bool)`, `set_position_mode(bool)`, `set_velocity_mode(bool)`,
  `set_run_on_budget(s)`: the input pins; `set_motion_known(bool)`: LinuxCNC shows its axes'
  motion (teleop mode);
- `reconnected(now)`: the shell opened the bus again (what the device did meanwhile is
  unknown);
- `next_action(now)` -> the `Action` to carry out (`Configure`, `WriteFeed`, `Probe`) or
  None, and `done(action, ok, abort, now, result)`: its outcome (a `Configure`'s: a
  `Configured`; a `Probe`'s: a `Probed`, and its write refused with abort 0x08000022 ends
  the core's session, as do `PROBE_TIMEOUTS_BEFORE_CONFIGURING` probes in a row on the
  component's own SDO channel without an answer: `done(probe, False, None, ...)`);
- `take_log()` -> the lines the core wants logged (a feed stop and its reason, a session
  dropped, a configuration waiting for a token), for the shell to print;
- `publish(now, motion)` -> the list of `Pins` snapshots to write now, in order, at least
  `GATE_HOLD` apart (`motion(letter)`: LinuxCNC's `AxisMotion` of an axis, asked in the
  run-on mode for an axis with new counts); `pins()` is the state they end in;
  `shutdown_action()`.

The rules the core keeps, and the argument that motion is never credited to another axis,
twice or backwards: host/README.md, "The core's rules and why they hold" (its section "What
it does" states them for machine builders); the docstrings below name the rule where one
implements it.
"""

from __future__ import annotations

import collections
import math
from dataclasses import dataclass, field, replace
from typing import Callable, Deque, Dict, List, Optional, Tuple

# Device heartbeat states.
BOOTUP = 0x00
STOPPED = 0x04
OPERATIONAL = 0x05
PRE_OPERATIONAL = 0x7F

# The feed record (TPDO1, version 2), byte 4 (0x2011 "Feed selection"): bits 0-2 the axis
# (0 none, 1..5 these letters; 6 and 7 never sent), bits 3-4 the multiplier code (an index
# into MULTIPLIERS; 3 never sent), bits 5-7 the low three bits of the selection epoch (0x2010:3).
DEVICE_AXES = "xyzwv"
MULTIPLIERS = (1, 10, 100)
AXIS_MASK = 0x07
MULTIPLIER_SHIFT = 3
EPOCH_SHIFT = 5
EPOCH_MODULO = 8
# Byte 5 (0x2030 "Feed status"): bits 0-4 these flags, bits 5-7 the session (0 none, 1..7 the
# token a master wrote to 0x2002).
STATUS_ENABLED = 0x01
STATUS_ENCODER_ERROR = 0x02
STATUS_STEPS_DROPPED = 0x04
STATUS_MASTER_LOST = 0x08
STATUS_IGNORED_MOTION = 0x10
FLAGS_MASK = 0x1F
SESSION_SHIFT = 5
# Bytes 6-7 (0x2031 "Feed sequence", U16): +1 per record and per loss, +8 at a break.
SEQUENCE_MODULO = 65536

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
# Session tokens the host writes to 0x2002 (0 means none).
TOKENS = tuple(range(1, 8))


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


def free_tokens(last_use: Dict[int, float], now: float, own: Optional[int] = None):
    """The tokens the host may write now, best first (a tuple): not `own` (its session), and
    none whose records may have been sent less than COPY_AGE ago (`last_use`: when the host
    superseded it, or last knew the device could be in it); never used ones first (lowest
    first), then the least recently used. Every copy of a record of a token's last use is
    then older than COPY_AGE when it is written again."""
    free = [t for t in TOKENS if t != own and now - last_use.get(t, -math.inf) >= COPY_AGE]
    return tuple(sorted(free, key=lambda t: (last_use.get(t, -math.inf), t)))


def token_free_at(last_use: Dict[int, float], own: Optional[int] = None) -> float:
    """When the first token other than `own` becomes free (`free_tokens`)."""
    return min(last_use.get(t, -math.inf) + COPY_AGE for t in TOKENS if t != own)


# The device's uptime (0x2035, U32 ms since the device started; reset node and reset
# communication keep it counting). A token the host wrote less than COPY_AGE ago may be
# written again at once if the device's uptime shows that it has run since before the host
# first wrote that token, after the token was last free (its `chain` start): every record of
# the token within the contract's age is then of the device's present power life, whose
# sequence never goes back, so that a copy of one is older than every number the new
# session's probes answer and dates nothing (a reset storm no longer uses up the tokens).
UPTIME_OBJECT = 0x2035


def life_began_by(uptime_ms: int, answered_at: float) -> float:
    """The latest time (the host's clock) at which the device's present power life can have
    begun, from its uptime `uptime_ms` in an answer the host handled at `answered_at`: the
    device's clock may run up to CLOCK_TOLERANCE fast. (A wrapped uptime, after 49.7 days,
    reads as a young life: the proof fails safe.)"""
    return answered_at - uptime_ms / 1000 / (1 + CLOCK_TOLERANCE)


def pick_token(
    candidates: Tuple[int, ...],
    device_session: int,
    reusable: Tuple[Tuple[int, float], ...] = (),
    began_by: Optional[float] = None,
) -> Optional[int]:
    """The token a configuration writes: the first of `candidates` (`free_tokens`) that is
    not the session the device holds (another master's, or one the host may have written
    without seeing it read back); else the first of `reusable` ((token, chain start), see
    `UPTIME_OBJECT`) that is not either and whose chain began after the device's present
    life began (`began_by`, `life_began_by`; None: no uptime read, nothing reusable).
    None: no candidate; the configuration fails."""
    for token in candidates:
        if token != device_session:
            return token
    if began_by is None:
        return None
    for token, chain_start in reusable:
        if token != device_session and began_by < chain_start:
            return token
    return None


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


# Feed stops the component did not ask for (`stop-reason`): why the device stopped the feed.
STOP_NONE = 0
STOP_MASTER_LOST = 1
STOP_TRANSMIT_BLOCKED = 2
STOP_MASTER_WRITE = 3
STOP_NOT_OPERATIONAL = 4
STOP_SESSION_ENDED = 5
STOP_REASONS = {
    STOP_MASTER_LOST: "master heartbeat lost (EMCY 0x8130)",
    STOP_TRANSMIT_BLOCKED: "transmit path blocked (EMCY 0x8100)",
    STOP_MASTER_WRITE: "disabled by a master write (0x2000 = 0)",
    STOP_NOT_OPERATIONAL: "the device left Operational",
    STOP_SESSION_ENDED: (
        "the session ended (a reset, a power cycle, another master's write, or the record "
        "sequence outran its pace)"
    ),
}
EMCY_MASTER_LOST = 0x8130
EMCY_TRANSMIT_BLOCKED = 0x8100
# Status bit 3 is set by both a lost master and a blocked transmit path; the EMCY that tells
# them apart may reach the host after the record (s to wait for it).
STOP_REASON_WAIT = 0.05
# The core's log lines not yet taken by the shell (`Core.take_log`): a bounded queue, so that
# nothing on the bus can make it grow.
LOG_LINES = 32


def stop_reason(master_lost: bool, emcy: Optional[int], left_operational: bool) -> int:
    """Why the device stopped the feed, from what the host saw since the feed was last on:
    the record's status bit 3 (a loss of communication), the last EMCY 0x8100 or 0x8130, a
    heartbeat other than Operational. Bit 3 without either EMCY: the master was lost (the
    device's own watch, whose EMCY a blocked path may have discarded). No bit 3: a master
    wrote 0x2000 = 0, unless the device left Operational, which disables the feed too."""
    if emcy == EMCY_TRANSMIT_BLOCKED:
        return STOP_TRANSMIT_BLOCKED
    if master_lost or emcy == EMCY_MASTER_LOST:
        return STOP_MASTER_LOST
    if left_operational:
        return STOP_NOT_OPERATIONAL
    return STOP_MASTER_WRITE


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

# The session key (0x2034, U16, write-only): a configuration writes a key of its own
# (`Configure.key`, 1..0xFFFF, a new one per configuration from a random start per run) right
# after its token, and every probe carries it in bits 16-31 of the value written to 0x2033
# (`Probe.key`). The device keeps a key only with the session it was written in (0 again at
# every change or end of the session, and at power-on) and refuses a probe whose key bits are
# neither 0 nor its session's key (abort 0x08000022, nothing changed). The token and the
# nonce alone cannot tell the host's session from one another master opened with the same
# token (every fresh component writes token 1 first), say after a power cycle whose boot-up
# the host missed: that session's device would answer the host's probes as its own and date
# records of a session the host never configured. Its refusal of the key tells: the host
# drops its session (`Core.done`) and configures again.
SESSION_KEY_OBJECT = 0x2034
SESSION_KEY_SHIFT = 16  # the key's place in the probe's value
KEY_MODULO = 0xFFFF  # keys 1..0xFFFF (0 is no key): the next key is key % KEY_MODULO + 1
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


def next_key(key: int) -> int:
    """The session key after `key`: 1..0xFFFF, never 0 (any int maps into the range)."""
    return key % KEY_MODULO + 1


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


# Pin steps (`Core.publish`): consecutive steps are written at least this far apart, so that
# every servo period of LinuxCNC (1 ms by default; up to 5 ms covered) that sees the counts
# of a step also sees its gates.
GATE_HOLD = 0.005

# The largest sequence gap still read as "the same epoch": each epoch takes at least one
# sequence number, so 6 missing numbers hide at most 6 epochs and the record after them is
# at most 7 epochs on, never the 8 that would bring the 3-bit epoch round.
SAME_EPOCH_MAX_GAP = 6

# Default bound of the wheel's speed (`--max-detents-per-s`). A 100-detent MPG flicked as
# fast as a hand can peaks around 10 revolutions, 1000 detents, per second; twice that is
# never reached by turning, while the jumps of a random 32-bit position are far above it.
DEFAULT_MAX_DETENTS_PER_S = 2000
MAX_DETENTS_PER_S_RANGE = (10, 100_000)

# Jog modes (`Core.mode`): the run-on budget (default), LinuxCNC's velocity mode, or
# LinuxCNC's position mode.
RUN_ON = "run-on"
VELOCITY = "velocity"
POSITION = "position"

# The run-on budget (s, `--run-on-budget` and the `run-on-budget` pin): how long an axis may
# still be on its way to its target after the last detent, at its own limits.
DEFAULT_RUN_ON_BUDGET = 0.25
RUN_ON_BUDGET_RANGE = (0.02, 10.0)

# One detent at an override position changes the override by this many percent
# (`--override-step`), whatever the multiplier.
DEFAULT_OVERRIDE_STEP = 1.0
OVERRIDE_STEP_RANGE = (0.01, 100.0)

# SDO abort: "data cannot be transferred because of the present device state".
ABORT_DEVICE_STATE = 0x08000022

# The resident loader's device type 0x1000, "BOOT" (docs/FIRMWARE-UPDATE.md): a device that
# answers with it runs no application and sends no feed records.
LOADER_DEVICE_TYPE = 0x544F_4F42

# Another master's SDO exchange with the device (`canopen-handwheel update`, a configuration
# tool): CiA 301's default SDO channel (0x600 + node, 0x580 + node) serves one client at a
# time, and either client takes the other's answer for its own, so the component sends no
# SDO request until that master has sent none for this long. Longer than the gaps inside a
# program download (0x1F57 polled every 0.05 s; the boot-up after "start" comes within
# milliseconds on the board), short against a person's pause.
FOREIGN_SDO_QUIET = 2.0
# Except after another master's expedited read (an HMI polling, say 0x1001 once a second),
# which is over with its answer: the hold then ends FOREIGN_READ_QUIET after the answer, or
# the component, whose probes date every record, would credit nothing while the HMI polls.
# The short quiet keeps a master that reads and goes on at once (an update's first steps)
# undisturbed; a read of the program download objects (0x1F50..0x1F5F: an update under way)
# keeps the long one. At most PROBE_PERIOD + FOREIGN_READ_QUIET between two probes stays
# within DATE_LIMIT. Either client's python-canopen refuses an answer for another object
# than it asked for, so a collision costs a retry.
FOREIGN_READ_QUIET = 0.15
PROGRAM_OBJECTS = range(0x1F50, 0x1F60)
# The component's own SDO channel: the device's second SDO server (0x1201), set up by every
# configuration, so that its probes (ten a second) and feed writes never share the default
# channel with another master, whose python-canopen would take an answer to a write of the
# component's for its own (it checks no index in a download's answer). COB-IDs from a range
# the pre-defined connection set leaves free (0x680..0x6DF): the master node-ID m (1..127)
# picks 0x680 + (m - 1) mod 48 to the device and 0x6B0 + the same from it; `--sdo-channel`
# sets others or none (then everything goes on the default channel, held back as above).
OWN_SDO_RANGE = range(0x680, 0x6E0)
OWN_SDO_PAIRS = 48
SDO_SERVER_2 = 0x1201
# The device does not store 0x1201: a power cycle or a reset of communication the host did not
# see, or another master's write of it, leaves the component's own channel unanswered, so that
# every probe on it times out. Nothing is then credited (no probe dates a record), but
# unanswered probes alone would keep the session (and the wheel dead) for good when the
# device's records still carry the component's token. So after this many probes in a row on
# the own channel without any answer (no reply at all; an abort is an answer) the host drops
# its session and configures the device again on the default channel, which sets 0x1201 up
# again. Three: one or two can be lost to a busy bus without costing the session, and at
# PROBE_PERIOD plus python-canopen's SDO timeout (0.3 s) each, the wheel is dead about 1 s at
# most before the configuration starts. (Not a check that keeps an intact session: the
# configuration writes 0x1201 by construction, whatever else made the channel silent.)
PROBE_TIMEOUTS_BEFORE_CONFIGURING = 3
# Sessions in a row dropped that way, no probe on the own channel answered in between, before
# the core configures without it (the default channel): the first drop sets the channel up
# again (a power cycle or another master's write silenced it); a second says the bus or a
# gateway does not carry the channel's identifiers, and configuring it again would only burn
# a session token a second (each kept out for `COPY_AGE` after).
OWN_CHANNEL_DROPS_BEFORE_DEFAULT = 2


def own_sdo_ids(master: int) -> Tuple[int, int]:
    """(to the device, from it): the component's own SDO channel for master node-ID `master`."""
    m = (master - 1) % OWN_SDO_PAIRS
    return OWN_SDO_RANGE.start + m, OWN_SDO_RANGE.start + OWN_SDO_PAIRS + m


def parse_sdo_channel(text: str, master: int) -> Optional[Tuple[int, int]]:
    """`--sdo-channel`: "auto" (`own_sdo_ids`), "none", or two COB-IDs "RX,TX" (hex or
    decimal, distinct, in 0x680..0x6DF); `ValueError` otherwise."""
    if text == "auto":
        return own_sdo_ids(master)
    if text == "none":
        return None
    try:
        rx, tx = (int(part, 0) for part in text.split(","))
    except ValueError:
        raise ValueError(f"--sdo-channel {text!r}: auto, none or RX,TX") from None
    if rx == tx or rx not in OWN_SDO_RANGE or tx not in OWN_SDO_RANGE:
        raise ValueError(f"--sdo-channel {text!r}: two distinct COB-IDs in 0x680..0x6DF")
    return rx, tx


# Program control 0x1F51:1 (CiA 302-3): "stop" resets the application into its loader.
PROGRAM_CONTROL = b"\x51\x1f\x01"
PROGRAM_STOP = 0

# The event timer written when the device has none (0x1800:5 = 0) or one outside the range,
# and assumed until the first configuration when `--event-timer-ms` is not given (the
# device's default, too). At most 1 s: three periods of silence (staleness) then stay within
# ORDER_WINDOW, so a device at rest never makes the host start a new session.
DEFAULT_EVENT_TIMER_MS = 100
EVENT_TIMER_MS_RANGE = (10, 1000)


def wrap_s32(value: int) -> int:
    """`value` wrapped into the signed 32-bit range."""
    return ((value + 0x8000_0000) & 0xFFFF_FFFF) - 0x8000_0000


# Switch positions that drive one of LinuxCNC's overrides instead of an axis (`--axes`): the
# letter and the name its pins carry (`N.feed-override.counts`, ...).
OVERRIDES = {"f": "feed-override", "s": "spindle-override", "r": "rapid-override"}
LINUXCNC_AXES = "xyzabcuvw"


def parse_axes(letters: str) -> str:
    """The `--axes` option checked: in switch order, at least one and at most five of the
    LinuxCNC axis letters `xyzabcuvw` and the override letters `f` (feed), `s` (spindle),
    `r` (rapid), each at most once.

    Position n of the switch (1..5) drives the n-th letter, so `xyzfs` puts X, Y, Z on
    positions 1..3 and the feed and spindle overrides on 4 and 5.
    """
    letters = letters.strip().lower()
    if not 1 <= len(letters) <= 5:
        raise ValueError("--axes needs 1 to 5 letters (axes, or f, s, r for the overrides)")
    twice = sorted({c for c in letters if letters.count(c) > 1})
    if twice:
        raise ValueError(f"--axes {letters!r} names {''.join(twice)!r} twice")
    bad = [c for c in letters if c not in LINUXCNC_AXES and c not in OVERRIDES]
    if bad:
        raise ValueError(
            f"--axes {letters!r}: {''.join(bad)!r} is neither a LinuxCNC axis letter "
            "(xyzabcuvw) nor an override (f feed, s spindle, r rapid)"
        )
    return letters


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


def rate_horizon(stale_after: float, consumer_timeout_ms: int) -> float:
    """How many seconds of turning at the bound one burst of records may carry: the longer
    of the staleness time and the device's heartbeat consumer timeout (see host/README.md's
    "Plausibility")."""
    return max(stale_after, consumer_timeout_ms / 1000)


@dataclass(frozen=True)
class Record:
    """A feed record (TPDO1, 8 bytes, version 2) field by field: the one place the layout
    is written down in Python (README "Feed record"). `multiplier` is the factor (1, 10, 100;
    0 for code 3, which the device never sends), `flags` status bits 0-4, `session` the
    session the device was in, `sequence` the 16-bit feed sequence. Every 8 bytes decode,
    and `encode` gives them back."""

    position: int
    axis: int
    multiplier: int
    epoch: int
    flags: int
    session: int
    sequence: int

    @staticmethod
    def decode(data: bytes) -> "Record":
        """The record in `data`, which must be 8 bytes (`ValueError` otherwise)."""
        if len(data) != 8:
            raise ValueError(f"a feed record is 8 bytes, not {len(data)}")
        selection, status = data[4], data[5]
        code = (selection >> MULTIPLIER_SHIFT) & 0x03
        return Record(
            position=int.from_bytes(data[0:4], "little", signed=True),
            axis=selection & AXIS_MASK,
            multiplier=MULTIPLIERS[code] if code < len(MULTIPLIERS) else 0,
            epoch=selection >> EPOCH_SHIFT,
            flags=status & FLAGS_MASK,
            session=status >> SESSION_SHIFT,
            sequence=int.from_bytes(data[6:8], "little"),
        )

    def encode(self) -> bytes:
        """The 8 bytes. The position and the sequence wrap, the epoch is taken mod 8 (the
        record carries their low bits); another field out of its range is a mistake of the
        caller (`ValueError`), not something to wrap into a different record."""
        if not 0 <= self.axis <= AXIS_MASK:
            raise ValueError(f"axis {self.axis} does not fit 3 bits")
        if self.multiplier not in MULTIPLIERS + (0,):
            raise ValueError(f"multiplier {self.multiplier}: 1, 10, 100 (or 0 for code 3)")
        if not 0 <= self.flags <= FLAGS_MASK:
            raise ValueError(f"flags 0x{self.flags:X} do not fit 5 bits")
        if not 0 <= self.session <= 7:
            raise ValueError(f"session {self.session} does not fit 3 bits")
        code = MULTIPLIERS.index(self.multiplier) if self.multiplier else 3
        selection = (
            self.axis | code << MULTIPLIER_SHIFT | (self.epoch % EPOCH_MODULO) << EPOCH_SHIFT
        )
        status = self.flags | self.session << SESSION_SHIFT
        return (
            (self.position & 0xFFFF_FFFF).to_bytes(4, "little")
            + bytes([selection, status])
            + (self.sequence % SEQUENCE_MODULO).to_bytes(2, "little")
        )

    @property
    def enabled(self) -> bool:
        return bool(self.flags & STATUS_ENABLED)

    @property
    def master_lost(self) -> bool:
        return bool(self.flags & STATUS_MASTER_LOST)


def record_fault(rec: Record) -> Optional[str]:
    """Why the device can never send `rec` on its own, or None if it can."""
    if rec.axis > len(DEVICE_AXES):
        return f"axis {rec.axis}"
    if rec.multiplier not in MULTIPLIERS:
        return "multiplier code 3"
    if rec.enabled and rec.master_lost:
        return "feed enabled with master lost"
    return None


def sequence_gap(prev: Record, rec: Record) -> int:
    """The sequence numbers between `prev` and `rec` (records lost or dropped), mod 65536."""
    return (rec.sequence - prev.sequence - 1) % SEQUENCE_MODULO


def _link(prev: Record, rec: Record) -> Tuple[Optional[int], Optional[str]]:
    """(delta, fault): the delta `continuity` gives, and why the pair is impossible."""
    if record_fault(prev) is not None or record_fault(rec) is not None:
        return None, None
    gap = sequence_gap(prev, rec)
    epochs = (rec.epoch - prev.epoch) % EPOCH_MODULO
    delta = wrap_s32(rec.position - prev.position)
    if epochs == 0 and gap <= SAME_EPOCH_MAX_GAP:
        if (rec.axis, rec.multiplier, rec.enabled) != (prev.axis, prev.multiplier, prev.enabled):
            return None, "axis, multiplier or enable changed within an epoch"
    elif not (epochs == 1 and gap == 0):
        return None, None  # epochs the host did not see: a new baseline
    if delta != 0:
        if not rec.enabled:
            return None, "moved while disabled"
        if rec.axis == 0:
            return None, "moved without an axis"
        if delta % rec.multiplier != 0:
            return None, f"moved {delta}, no multiple of the multiplier {rec.multiplier}"
    return delta, None


def continuity(prev: Record, rec: Record) -> Optional[int]:
    """The motion `rec` adds to its axis after `prev` (the record received before it), or
    None: `rec` is a new baseline (it continues nothing). host/README.md's "Feed bookkeeping"
    gives the rule and why it never credits motion to another axis. 0 for a record that
    continues without motion (disabled, no axis, the wheel at rest). Records the device
    cannot send (`record_fault`, `pair_fault`) give None."""
    return _link(prev, rec)[0]


def pair_fault(prev: Record, rec: Record) -> Optional[str]:
    """Why `rec` cannot follow `prev` from the same device, or None. Only for records that
    each could be sent (`record_fault` is None for both)."""
    return _link(prev, rec)[1]


@dataclass
class Allowance:
    """The detents a wheel can have turned: a token bucket that refills at `rate` per
    second up to `cap` (host/README.md's "Plausibility")."""

    rate: float
    cap: float
    level: Optional[float] = None  # None: full
    time: Optional[float] = None

    def level_at(self, now: float) -> float:
        if self.level is None or self.time is None:
            return self.cap
        return min(self.cap, self.level + self.rate * max(0.0, now - self.time))

    def take(self, detents: int, now: float) -> bool:
        """Spends `detents` if the bucket holds them; False (spending nothing) if not."""
        level = self.level_at(now)
        ok = detents <= level
        self.level = level - detents if ok else level
        self.time = now
        return ok


# LinuxCNC's servo period where its INI file does not say ([EMCMOT]SERVO_PERIOD; its sample
# configurations' 1 ms), s.
SERVO_PERIOD = 0.001


def servo_period_of_ini(text: str) -> Optional[float]:
    """LinuxCNC's servo period (s) as its INI file `text` sets it: [EMCMOT]SERVO_PERIOD, in
    nanoseconds. None when it is not there or not a positive number (`SERVO_PERIOD` then)."""
    section = None
    for line in text.splitlines():
        line = line.strip()
        if not line or line[0] in "#;":
            continue
        if line.startswith("[") and "]" in line:
            section = line[1 : line.index("]")].strip()
        elif section == "EMCMOT" and "=" in line:
            key, value = (part.strip() for part in line.split("=", 1))
            if key == "SERVO_PERIOD":
                try:
                    ns = float(value)
                except ValueError:
                    return None
                return ns * 1e-9 if math.isfinite(ns) and ns > 0 else None
    return None


@dataclass(frozen=True)
class AxisMotion:
    """What LinuxCNC shows of one axis in teleop mode, in machine units: how far the target
    of its jog planner leads its commanded position (`axis.L.teleop-pos-cmd` minus
    `axis.L.pos-cmd`), the planner's velocity (`axis.L.teleop-vel-cmd`, signed), the
    limits it plans with (`ini.L.max_velocity`, and `ini.L.max_acceleration` times
    `axis.L.jog-accel-fraction`) and the servo period it plans in."""

    lead: float
    velocity: float
    max_velocity: float
    max_acceleration: float
    target: Optional[float] = None  # `axis.L.teleop-pos-cmd` itself, when known
    servo_period: float = SERVO_PERIOD  # s: LinuxCNC's planner moves in these steps


# How long after the component wrote an axis's counts it takes the target it then expected
# rather than LinuxCNC's as the lead's end (s): LinuxCNC takes counts on its next servo cycle,
# and a read in between (a servo thread running late, records 2 ms apart) would show the
# target without them and let the next counts lead by that much more.
IN_FLIGHT = 0.02


def run_on_reach(budget: float, max_velocity: float, max_acceleration: float, velocity=0.0):
    """The farthest an axis can go from where it is now and be at rest there within `budget`
    seconds, moving at `velocity` now (positive: towards the target), at its limits: it
    speeds up to at most `max_velocity`, keeps that, and brakes. 0 when the limits are not
    positive and finite (nothing can be promised). An axis that cannot even stop within the
    budget reaches its stopping distance: no less than that can be asked of it."""
    v, a = max_velocity, max_acceleration
    if not (math.isfinite(v) and math.isfinite(a) and v > 0 and a > 0 and budget > 0):
        return 0.0
    v0 = min(max(velocity, -v), v) if math.isfinite(velocity) else 0.0
    peak = min(v, (a * budget + v0) / 2)  # speed up to `peak`, brake from it
    if peak < v0:
        return v0 * v0 / (2 * a)  # braking at once takes longer than the budget
    ramps = (peak - v0) / a + peak / a
    cruise = max(0.0, budget - ramps)
    return (peak * peak - v0 * v0) / (2 * a) + peak * cruise + peak * peak / (2 * a)


# `planner_lag`: the servo periods LinuxCNC's jog planner may come to rest later than the
# continuous profile of `run_on_reach`, besides the half log of its periods of braking.
PLANNER_LAG_PERIODS = 6.0


def planner_lag(max_velocity: float, max_acceleration: float, servo_period: float) -> float:
    """How much later (s) than the profile `run_on_reach` plans LinuxCNC can bring the axis to
    rest at its target. Its jog planner moves in servo periods: each period it asks for the
    speed from which braking by one period's worth of acceleration a period ends on the
    target, which is below the continuous braking curve by that much and so brakes early
    and creeps in; that costs half the natural log of m periods, m = v / (a T) (the periods it
    takes to stop from full speed), plus a few periods at the ends of the braking. Counts
    also wait for the next servo cycle, and the axis LinuxCNC showed may be a cycle old by
    then: a cycle on towards the old target. `PLANNER_LAG_PERIODS` covers these; the host
    tests check the sum against a step-by-step model of the planner (host/README.md, "Jog
    modes"). 0 for a period that is not positive and finite."""
    t = servo_period
    if not (math.isfinite(t) and t > 0):
        return 0.0
    periods = max_velocity / (max_acceleration * t)
    braking = math.log(periods) / 2 if math.isfinite(periods) and periods > 1 else 0.0
    return t * (braking + PLANNER_LAG_PERIODS)


# Rounding room when dividing what the budget allows into detents: a millionth of a detent
# (LinuxCNC's positions are doubles; 0.3 / 0.1 is 2.9999999999999996).
METER_EPSILON = 1e-6


def meter_counts(pending: int, step: int, scale: float, motion: AxisMotion, budget: float) -> int:
    """How many of `pending` counts (signed; a multiple of `step`, the counts of one detent)
    may go to the axis now so that, if the wheel stops, it comes to rest at its target within
    `budget` seconds in LinuxCNC (`run_on_reach` within the budget less `planner_lag`, from
    its lead and velocity as `motion` shows them): whole detents, the first ones of `pending`;
    the rest is dropped by the caller, never held. Counts that bring the target back towards
    the axis (turning back) are no exception: where the axis must stop and come back to the
    new target, that can take longer than going on to the old one. An axis that stops from
    full speed within (budget less `planner_lag`) / 2.414 (v / a; 1 + sqrt(2): stopping and
    coming back over its stopping distance) lets every such count go that keeps the target
    ahead of it."""
    if pending == 0:
        return 0
    step = abs(step) or 1
    detents = abs(pending) // step
    unit = abs(step * scale)  # machine units per detent
    direction = 1 if pending * scale > 0 else -1
    ahead = motion.lead * direction  # the target's lead in the direction of the new counts
    v, a = motion.max_velocity, motion.max_acceleration
    planned = budget - planner_lag(v, a, motion.servo_period)
    reach = run_on_reach(planned, v, a, motion.velocity * direction)
    allowed = math.floor((reach - ahead) / unit + METER_EPSILON) if unit > 0 else 0
    allowed = max(0, min(detents, allowed))
    return (1 if pending > 0 else -1) * allowed * step


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


Action = object  # Configure | WriteFeed | Probe


@dataclass
class Pins:
    jog_counts: Dict[str, int]
    jog_enable: Dict[str, bool]
    select: Dict[str, bool]
    connected: bool = False
    feed_enabled: bool = False
    encoder_error: bool = False
    axis: int = 0
    multiplier: int = 1
    position: int = 0
    emcy_code: int = 0
    records_lost: int = 0
    frames_bad: int = 0
    state: int = -1  # last heartbeat state byte, -1 before any
    jog_vel_mode: bool = False  # LinuxCNC's velocity mode for every axis
    counts_dropped: int = 0  # counts the run-on budget dropped (wrapping)
    feed_stops: int = 0  # feed stops by the device the component did not ask for (wrapping)
    stop_reason: int = STOP_NONE  # the last one's reason (`STOP_REASONS`)
    in_loader: bool = False  # the device answered as its loader at the last configuration


def _with(pins: Pins, counts: Dict[str, int], gates: Dict[str, bool]) -> Pins:
    """`pins` with these counts and gates."""
    return replace(pins, jog_counts=dict(counts), jog_enable=dict(gates))


@dataclass
class Core:
    cfg: Config
    enable: bool = False
    # What the device showed.
    state: Optional[int] = None  # last heartbeat state byte
    record: Optional[Record] = None  # last accepted record (of the session)
    record_time: Optional[float] = None
    # The order reference: the newest record of the session taken, and the earliest it can
    # have reached the host (`order_verdict`).
    order: Optional[Tuple[Record, float]] = None
    foreign_newest: bool = False  # the newest possible record was of another session
    emcy_code: int = 0
    # Bookkeeping.
    counts: Dict[str, int] = field(default_factory=dict)
    baseline: bool = True  # the next record is a baseline
    records_lost: int = 0
    frames_bad: int = 0
    suspect: bool = False  # the last TPDO1 was impossible: no axis until a possible one
    epochs_shown: bool = False  # a non-zero epoch since the last configuration
    drained_at: Optional[float] = None  # the shell's receive path last found empty
    # Publishing (`publish`): the pins last handed to the shell, and the credits since.
    published: Optional[Pins] = None
    credit_time: Optional[float] = None  # the earliest credit not yet published
    credit_last: Optional[float] = None  # the latest credit not yet published
    credit_open: Dict[str, bool] = field(default_factory=dict)  # credited with the gate open
    withdrawn: int = 0  # credits withdrawn because they were not published in time
    allowance: Allowance = field(init=False)
    event_timer: float = field(init=False)  # s: the device's, once configured
    position_mode: bool = field(init=False)  # the `position-mode` input
    velocity_mode: bool = field(init=False)  # the `velocity-mode` input
    run_on_budget: float = field(init=False)  # the `run-on-budget` input, s
    motion_known: bool = False  # LinuxCNC shows its axes' motion (teleop mode)
    counts_dropped: int = 0  # counts the run-on budget dropped
    # Per axis: the jog target LinuxCNC has after the component's last metered counts, and
    # when they were written (`IN_FLIGHT`).
    sent_target: Dict[str, Tuple[float, float]] = field(default_factory=dict)
    # The session (`Configure`): the token the host wrote and read back, None without one,
    # and the key it wrote after it (`SESSION_KEY_OBJECT`; its probes carry it).
    session: Optional[int] = None
    session_key: Optional[int] = None
    key: int = field(init=False)  # the next configuration's key
    superseded: Dict[int, float] = field(default_factory=dict)  # token -> when replaced
    # Tokens the device may have been in since the last successful configuration, and when
    # that was last known: the host's session once it dropped it, a token written without
    # its read-back, a session the device reported or showed that the host never used. The
    # next successful configuration ends them all: it supersedes them.
    busy: Dict[int, float] = field(default_factory=dict)
    # Per token the host wrote: when the configuration that first wrote it after it was last
    # free (`free_tokens`) was asked for (`UPTIME_OBJECT`); the core's clock.
    chains: Dict[int, float] = field(default_factory=dict)
    configure_asked_at: float = 0.0  # when the configuration under way was asked for
    check_due: bool = False  # a record of another session came: check the configuration
    check_at: float = 0.0  # not before this (one check per `retry` at most)
    check_logged: bool = False  # a check was logged in this session
    waiting_logged: bool = False  # the wait for a free token was logged
    # Feed stops (`feed-stops`, `stop-reason`): the component asked for the feed off (its
    # 0x2000 = 0 since it last asked for it on), a stop waiting for its EMCY (when it was
    # seen, and whether status bit 3 was set), what the device showed since the feed was
    # last on: the last EMCY 0x8100 or 0x8130, a heartbeat other than Operational.
    asked_off: bool = False
    stop_seen: Optional[float] = None
    stop_master_lost: bool = False
    stop_emcy: Optional[int] = None
    left_operational: bool = False
    feed_stops: int = 0
    stop_reason: int = STOP_NONE
    feed_on: bool = False  # the last record of the session showed the feed on
    # The last configuration found the device in its loader (`Configured.loader`): no
    # configuration until something shows that an application may run (its boot-up, a
    # record, the bus opened again); none on a timer, since SDO requests of the component
    # would break a program download under way.
    in_loader: bool = False
    # Another master's SDO requests (`FOREIGN_SDO_QUIET`): when the last one was seen, and
    # its expedited write of 0x1F51:1 waiting for the device's answer; when the device
    # confirmed a "stop": a boot-up soon after it is its loader's.
    foreign_sdo_at: Optional[float] = None
    foreign_read: Optional[bytes] = None  # index and sub of another master's read under way
    foreign_quiet: float = FOREIGN_SDO_QUIET  # the hold after `foreign_sdo_at`
    holding_logged: bool = False
    program_request: Optional[int] = None
    program_stopped_at: Optional[float] = None
    log: Deque[str] = field(default_factory=lambda: collections.deque(maxlen=LOG_LINES))
    # Actions.
    config_due: float = 0.0  # configure at this time (without a session)
    feed_due: float = 0.0  # earliest time for the next 0x2000 write
    pending: Optional[Action] = None
    booted_during: Optional[float] = None  # a boot-up while a `Configure` was pending
    # Dating (`DATE_LIMIT`): the probes' dates (n, sent_at), oldest first, for the session;
    # the next probe's nonce and time; records not credited for want of a date.
    dates: Deque[Tuple[int, float]] = field(
        default_factory=lambda: collections.deque(maxlen=PROBE_DATES)
    )
    nonce: int = field(init=False)
    probe_due: float = 0.0
    # The session's configuration set up the component's own SDO channel (`Config.own_sdo`):
    # probes and feed writes go there, never held back by another master's exchanges.
    own_channel: bool = False
    # Probes of the session on the own channel in a row that got no answer at all
    # (`PROBE_TIMEOUTS_BEFORE_CONFIGURING`).
    probes_unanswered: int = 0
    # Sessions dropped in a row for unanswered probes on the own channel
    # (`OWN_CHANNEL_DROPS_BEFORE_DEFAULT`); at the limit the core stays on the default channel
    # for the rest of the run.
    own_channel_drops: int = 0
    undated: int = 0
    undated_logged: bool = False
    now: float = 0.0

    def __post_init__(self) -> None:
        self.nonce = self.cfg.first_nonce & NONCE_MASK
        self.key = next_key(self.cfg.first_key - 1)
        self.counts = {letter: 0 for letter in self.cfg.axes}
        self.event_timer = self.cfg.event_timer
        self.position_mode = self.cfg.position_mode
        self.velocity_mode = self.cfg.velocity_mode
        self.run_on_budget = self.cfg.run_on_budget
        rate = self.cfg.max_detents_per_s
        self.allowance = Allowance(rate=rate, cap=rate * self.rate_horizon)

    # Events ---------------------------------------------------------------------------

    def frame(self, cob_id: int, data: bytes, now: float) -> None:
        """A frame from the bus (any identifier; others than the device's are ignored)."""
        self.tick(now)
        node = self.cfg.node
        if cob_id == 0x180 + node:
            self._tpdo1(bytes(data), now)
        elif cob_id == 0x080 + node:
            self._emcy(bytes(data))
        elif cob_id == 0x700 + node:
            self._heartbeat(bytes(data), now)
        elif cob_id == 0x600 + node:
            self._foreign_sdo_request(bytes(data))
        elif cob_id == 0x580 + node:
            self._sdo_response(bytes(data))

    def drained(self, now: float) -> None:
        """The shell found its receive path empty at a moment not before `now`: every frame
        that reached the host before `now` has been handed to `frame`. The shell calls it
        whenever a read (waiting or not) finds nothing, `now` being the time taken before that
        read. A feed record handled more than `BACKLOG_LIMIT` after the last such report
        may have waited that long in a buffer: it is only a baseline."""
        if self.drained_at is None or now > self.drained_at:
            self.drained_at = now
        self.tick(now)

    def reconnected(self, now: float) -> None:
        """The shell opened the bus again: a boot-up may have come while it was closed, so
        a device held in its loader is asked again."""
        self.tick(now)
        if self.in_loader and self.session is None and self.config_due == math.inf:
            self.config_due = self.now

    def set_enable(self, enable: bool) -> None:
        if enable != self.enable:
            self.feed_due = 0.0  # act at once
        self.enable = enable

    def set_position_mode(self, position_mode: bool) -> None:
        """The `position-mode` input. It changes the mode and nothing else."""
        self.position_mode = position_mode

    def set_velocity_mode(self, velocity_mode: bool) -> None:
        """The `velocity-mode` input. It changes the mode and nothing else."""
        self.velocity_mode = velocity_mode

    def set_run_on_budget(self, budget: float) -> None:
        """The `run-on-budget` input (s), held to `RUN_ON_BUDGET_RANGE` (a value outside it:
        the nearest end; not a number: the option's value)."""
        low, high = RUN_ON_BUDGET_RANGE
        self.run_on_budget = (
            min(high, max(low, budget)) if math.isfinite(budget) else self.cfg.run_on_budget
        )

    def set_motion_known(self, known: bool) -> None:
        """Whether LinuxCNC shows its axes' motion (`AxisMotion`; it does in teleop mode).
        Without it the run-on mode cannot meter: the axes are left in LinuxCNC's velocity
        mode, which bounds their run-on by their stopping distance."""
        self.motion_known = known

    @property
    def mode(self) -> str:
        """`POSITION` while the `position-mode` input is true, else `VELOCITY` while
        `velocity-mode` is, else `RUN_ON`."""
        if self.position_mode:
            return POSITION
        return VELOCITY if self.velocity_mode else RUN_ON

    @property
    def metering(self) -> bool:
        """Counts go to the axes through `meter_counts` (the run-on mode, LinuxCNC showing
        the axes' motion)."""
        return self.mode == RUN_ON and self.motion_known

    def tick(self, now: float) -> None:
        """Time passes: staleness; a feed stop whose EMCY did not come is reported."""
        self.now = max(self.now, now)
        if self.record_time is not None and not self.fresh:
            self.baseline = True
        if self.stop_seen is not None and self.now - self.stop_seen >= STOP_REASON_WAIT:
            self._stopped()

    def take_log(self) -> List[str]:
        """The log lines the core made since the last call, for the shell to print."""
        lines = list(self.log)
        self.log.clear()
        return lines

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

    # Decisions ------------------------------------------------------------------------

    def _set_event_timer(self, period: float) -> None:
        self.event_timer = period
        self.allowance.cap = self.cfg.max_detents_per_s * self.rate_horizon
        if self.allowance.level is not None:
            self.allowance.level = min(self.allowance.level, self.allowance.cap)

    @property
    def configured(self) -> bool:
        """The host holds a session: a configuration wrote its token and read it back, and
        nothing since showed the device lost it."""
        return self.session is not None

    @property
    def stale_after(self) -> float:
        """Three periods of the device's event timer (the assumed one until configured)."""
        return 3 * self.event_timer

    @property
    def rate_horizon(self) -> float:
        return rate_horizon(self.stale_after, self.cfg.consumer_timeout_ms)

    @property
    def fresh(self) -> bool:
        return self.record_time is not None and self.now - self.record_time <= self.stale_after

    @property
    def operational(self) -> bool:
        return self.fresh and self.state in (None, OPERATIONAL)

    @property
    def feed_enabled(self) -> bool:
        """The newest record is of the host's session, fresh, and shows the feed on."""
        return (
            self.fresh
            and self.record is not None
            and self.record.enabled
            and not self.foreign_newest
        )

    def selected(self) -> Optional[str]:
        """The configured letter the device's switch selects, if any."""
        if self.record is None or self.suspect:
            return None
        axis = self.record.axis
        if 1 <= axis <= len(self.cfg.axes):
            return self.cfg.axes[axis - 1]
        return None

    def next_action(self, now: float) -> Optional[Action]:
        """The action to carry out now, if any (none while one is pending). Without a
        session: a configuration; after a record of another session: a check (a
        configuration that keeps the session if the device still has it); else the feed
        enable. 0x2000 = 1 only while the newest record is of the host's session and shows
        the feed off. Another master's SDO exchange holds everything back
        (`_holding_back`), but the feed writes and probes of a session whose configuration set
        up the component's own SDO channel (`own_channel`): those go there."""
        self.tick(now)
        if self.pending is not None:
            return None
        own = self.own_channel
        if not own and self._holding_back():
            return None
        # On the default channel, configurations wait for another master's exchange still.
        held = (
            own
            and self.foreign_sdo_at is not None
            and self.now - self.foreign_sdo_at < self.foreign_quiet
        )
        action: Optional[Action] = None
        if self.session is None:
            if self.now >= self.config_due and not held:
                action = self._configure(keep=None)
        elif self.check_due:
            if self.now >= self.check_at and not held:
                action = self._configure(keep=self.session)
        elif self.operational and self.record is not None and self.now >= self.feed_due:
            if self.enable and not self.record.enabled and not self.foreign_newest:
                action = WriteFeed(1, own)
                self.asked_off = False
            elif not self.enable and self.record.enabled:
                action = WriteFeed(0, own)
                self.asked_off = True
        probing = self.cfg.dating and self.session is not None
        if action is None and probing and self.now >= self.probe_due:
            floor = self.order[0].sequence if self.order is not None else None
            action = Probe(self.nonce, floor, own, self.session_key or 0)
            self.nonce = (self.nonce + 1) & NONCE_MASK
            self.probe_due = self.now + PROBE_PERIOD
        self.pending = action
        return action

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

    def shutdown_action(self) -> Optional[Action]:
        """What to do before the component exits: disable the feed, whatever the last
        record showed. A write of 0x2000 = 1 may have been accepted without a record
        showing it yet, and a device that has been silent for a while may be back; one SDO
        exchange too many costs nothing. Except to a device held in its loader (None): it
        has no feed, and a request could break a program download under way."""
        self.asked_off = True
        return None if self.in_loader else WriteFeed(0)

    def gate(self, letter: str) -> bool:
        """`jog-enable` of axis `letter` as the core sees it now."""
        selected = self.selected() if self.fresh else None
        return self.enable and self.operational and self.feed_enabled and letter == selected

    def publish(
        self, now: float, motion: Optional[Callable[[str], Optional[AxisMotion]]] = None
    ) -> List[Pins]:
        """What the shell writes to the pins now: a list of snapshots, to be written in
        order, each completely, consecutive ones at least `GATE_HOLD` apart (the last one is
        `pins()`). The steps keep every servo period from seeing counts without their gate:
        first the gates that must be open for the new counts are opened and those of axes
        whose new counts were credited with their gate closed are closed, then the counts
        change, then (a hold later) the gates take their final values. So counts credited
        while the gate was open reach LinuxCNC with the gate open even when the same round
        closes it (a boot-up, staleness, another axis selected), and counts credited while
        it was closed never find it open (an axis's credits of one round go out together,
        with the gate open if any of them was made with it open: `enable` is read between
        rounds, so within one only a heartbeat can close the gate between two credits, and
        those were turned while Operational). Credits older than `BACKLOG_LIMIT` that were not
        yet published (the component stalled between handling a frame and writing the
        pins) are withdrawn: the counts go back to what was published.

        In the run-on mode (`metering`), an axis's new counts pass `meter_counts` first, with
        `motion(letter)`, what LinuxCNC shows of that axis now (asked only for an axis with
        new counts): what the run-on budget does not allow is dropped (`counts_dropped`),
        and all of them when LinuxCNC does not tell (None, or no `motion`)."""
        self.tick(now)
        target = self.pins()
        last = self.published
        if last is None:
            self._published(target)
            return [target]
        if self.credit_time is not None and self.now - self.credit_time > BACKLOG_LIMIT:
            self.withdrawn += 1
            self.counts = dict(last.jog_counts)
            self.credit_open = {}
            target = self.pins()
        if self.metering:
            self._meter(last, motion)
            target = self.pins()
        axes = self.cfg.axes
        changed = {L for L in axes if target.jog_counts[L] != last.jog_counts[L]}
        gates = {
            L: bool(self.credit_open.get(L)) if L in changed else last.jog_enable[L] for L in axes
        }
        steps: List[Pins] = []
        if gates != last.jog_enable:
            steps.append(_with(target, last.jog_counts, gates))
        if changed:
            steps.append(_with(target, target.jog_counts, gates))
        if not steps or gates != target.jog_enable:
            steps.append(target)
        self._published(steps[-1])
        return steps

    def _meter(self, last: Pins, motion) -> None:
        """The run-on budget applied to every axis's counts not yet published. The budget
        runs from when the component read the record of the last detent: the time the counts
        waited here since, and the hold before them when a gate opens first (`publish`), is
        spent."""
        multiplier = self.record.multiplier if self.record else 1
        unpublished = {
            L: wrap_s32(self.counts[L] - last.jog_counts[L]) for L in self.cfg.axis_letters
        }
        waited = self.now - self.credit_last if self.credit_last is not None else 0.0
        gates = {L: bool(self.credit_open.get(L)) for L, n in unpublished.items() if n}
        if any(gate != last.jog_enable[L] for L, gate in gates.items()):
            waited += GATE_HOLD  # `publish` writes the gates first, the counts a hold later
        budget = self.run_on_budget - max(0.0, waited)
        for L, counts in unpublished.items():
            if counts == 0:
                continue
            state = motion(L) if motion is not None else None
            step = multiplier if counts % multiplier == 0 else 1
            released = 0
            if state is not None:
                state = self._with_counts_in_flight(L, state)
                released = meter_counts(counts, step, self.cfg.scale, state, budget)
                if released and state.target is not None:
                    target = state.target + released * self.cfg.scale
                    self.sent_target[L] = (target, self.now)
            if released != counts:
                self.counts[L] = wrap_s32(last.jog_counts[L] + released)
                self.counts_dropped = wrap_s32(self.counts_dropped + abs(counts - released))

    def _with_counts_in_flight(self, letter: str, state: AxisMotion) -> AxisMotion:
        """`state` with the target the component's own last counts give, if it wrote them
        less than `IN_FLIGHT` ago: LinuxCNC may not have taken them yet (if it has, the two
        agree; if it dropped them, the lead is overstated for a moment: fewer counts go)."""
        sent = self.sent_target.get(letter)
        if state.target is None or sent is None or self.now - sent[1] > IN_FLIGHT:
            return state
        position = state.target - state.lead
        return replace(state, lead=sent[0] - position, target=sent[0])

    def _published(self, pins: Pins) -> None:
        self.published = pins
        self.credit_time = None
        self.credit_last = None
        self.credit_open = {}

    def pins(self) -> Pins:
        selected = self.selected() if self.fresh else None
        jog = self.enable and self.operational and self.feed_enabled
        rec = self.record if self.fresh else None
        return Pins(
            jog_counts=dict(self.counts),
            jog_enable={L: jog and L == selected for L in self.cfg.axes},
            select={L: L == selected for L in self.cfg.axis_letters},
            connected=self.fresh,
            feed_enabled=self.feed_enabled,
            encoder_error=bool(rec and rec.flags & STATUS_ENCODER_ERROR),
            axis=0 if rec is None or self.suspect else rec.axis,
            multiplier=self.record.multiplier if self.record else 1,
            position=self.record.position if self.record else 0,
            emcy_code=self.emcy_code,
            records_lost=self.records_lost,
            frames_bad=self.frames_bad,
            state=-1 if self.state is None else self.state,
            jog_vel_mode=self.mode == VELOCITY or (self.mode == RUN_ON and not self.motion_known),
            counts_dropped=self.counts_dropped,
            feed_stops=self.feed_stops,
            stop_reason=self.stop_reason,
            in_loader=self.in_loader,
        )

    # Frame handlers -------------------------------------------------------------------

    def _bad(self) -> None:
        self.frames_bad = wrap_s32(self.frames_bad + 1)

    def _tpdo1(self, data: bytes, now: float) -> None:
        if len(data) != 8:
            self._impossible()
            return
        rec = Record.decode(data)
        if record_fault(rec) is not None:
            self._impossible()
            return
        if self.session is None or rec.session != self.session:
            if self.in_loader and self.config_due == math.inf:
                # A loader sends no records: an application runs (its boot-up was missed).
                self.config_due = self.now
            self._foreign(rec)
            return
        verdict, ahead = order_verdict(self.order, rec, self.now)
        if verdict == RENEW:
            self._drop_session(f"no record of it for more than {ORDER_WINDOW:g} s")
            return
        if verdict == DUPLICATE:
            return  # the same frame twice (a known CAN effect): nothing at all
        if verdict == SAME_NUMBER:
            self._impossible()  # one number, two records
            return
        if verdict == COPY:
            self._bad()  # an earlier record again: never a reference, no loss
            return
        prev = self.record
        fresh = prev is not None and self.fresh
        if verdict == AHEAD and fresh:
            self.records_lost = wrap_s32(self.records_lost + ahead - 1)
        late = self.drained_at is None or self.now - self.drained_at > BACKLOG_LIMIT
        continuous = fresh and not self.baseline and not late
        if rec.epoch != 0:
            self.epochs_shown = True
        delta: Optional[int] = None
        if continuous and prev is not None:
            delta, fault = _link(prev, rec)
            if fault is not None:
                self._bad()
            if delta and not self._dated(prev):
                delta = None  # it may have been held on its way: a baseline
        if delta and not self.allowance.take(abs(delta) // rec.multiplier, self.now):
            self._bad()  # faster than a wheel turns
            delta = None
        letter = self._letter(rec.axis)
        credited = bool(delta and self.epochs_shown and letter is not None)
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

    def _dated(self, reference: Record) -> bool:
        """A probe sent at most DATE_LIMIT ago found the successor of `reference` not yet
        made (`dated_at`): what a record adds to it is recent. Else counted (`undated`) and
        logged once until a record is dated again."""
        if not self.cfg.dating:
            return True
        at = dated_at(self.dates, reference)
        if at is not None and self.now - at <= DATE_LIMIT:
            self.undated_logged = False
            return True
        self.undated = wrap_s32(self.undated + 1)
        if not self.undated_logged:
            self.undated_logged = True
            self.log.append(
                "a record not dated within "
                f"{DATE_LIMIT:g} s by the sequence probe (0x2033; held on its way, or the "
                "probes unanswered): not credited"
            )
        return False

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


# The HAL interface: (name without the prefix, type, direction, meaning). The shell creates
# exactly these pins; host/README.md's pin table lists them.
AXIS_PINS = [
    (
        "axis.{L}.jog-counts",
        "s32",
        "out",
        "wrapping sum of the position deltas of the feed records that named this axis",
    ),
    (
        "axis.{L}.jog-enable",
        "bit",
        "out",
        "true only for the selected axis while connected, Operational, feed enabled and `enable`",
    ),
    ("axis.{L}.jog-scale", "float", "out", "`--scale`: machine units per multiplied unit"),
    (
        "axis.{L}.jog-vel-mode",
        "bit",
        "out",
        "true in LinuxCNC's velocity mode (`velocity-mode`, or the run-on mode outside "
        "teleop); false in the run-on and position modes",
    ),
    ("halui.axis.{L}.select", "bit", "out", "the device's switch selects this axis"),
]
# Pins of an override position, `{O}` its name in `OVERRIDES`; they go to halui's
# `halui.feed-override.*`, `halui.spindle.0.override.*`, `halui.rapid-override.*`.
OVERRIDE_PINS = [
    (
        "{O}.counts",
        "s32",
        "out",
        "wrapping sum of the detents turned at this position (any multiplier)",
    ),
    (
        "{O}.count-enable",
        "bit",
        "out",
        "true only while this position is selected, connected, Operational, feed enabled and "
        "`enable` (as `jog-enable`)",
    ),
    ("{O}.scale", "float", "out", "`--override-step` / 100: the override's change per detent"),
]
COMPONENT_PINS = [
    ("enable", "bit", "in", "feed allowed (e.g. machine on); the component writes 0x2000 = 1 / 0"),
    (
        "position-mode",
        "bit",
        "in",
        "true: LinuxCNC's position mode (every count moved, however long it takes); starts "
        "as `--position-mode` sets it",
    ),
    (
        "velocity-mode",
        "bit",
        "in",
        "true (and `position-mode` false): LinuxCNC's velocity mode; starts as "
        "`--velocity-mode` sets it; both false: the run-on mode",
    ),
    (
        "run-on-budget",
        "float",
        "in",
        "s, the run-on mode's budget (0.02..10); starts as `--run-on-budget` sets it",
    ),
    (
        "counts-dropped",
        "s32",
        "out",
        "counts the run-on mode dropped because the axis could not move them within the budget",
    ),
    (
        "connected",
        "bit",
        "out",
        "feed records of the component's session arrive (none for three event-timer periods: "
        "false)",
    ),
    (
        "feed-enabled",
        "bit",
        "out",
        "the newest record is of the component's session and shows feed enabled (status bit 0)",
    ),
    ("encoder-error", "bit", "out", "illegal quadrature transition in this epoch (status bit 1)"),
    ("axis", "s32", "out", "the device's axis switch: 0 none, 1..5 = X, Y, Z, W, V"),
    ("multiplier", "s32", "out", "1, 10 or 100"),
    ("position", "s32", "out", "the last feed record's position (multiplied units)"),
    ("emcy-code", "u32", "out", "the last active EMCY code, 0 once cleared"),
    (
        "records-lost",
        "s32",
        "out",
        "feed records missed or dropped by the device (gaps in the feed sequence)",
    ),
    (
        "frames-bad",
        "s32",
        "out",
        "frames the device cannot send (wrong DLC, impossible record, motion beyond "
        "`--max-detents-per-s`) and copies of earlier records; no motion from them",
    ),
    ("state", "s32", "out", "the device's last heartbeat state (5 Operational), -1 before any"),
    (
        "feed-stops",
        "s32",
        "out",
        "feed stops by the device the component did not ask for (each also logged with its reason)",
    ),
    (
        "stop-reason",
        "s32",
        "out",
        "the last such stop's reason: 0 none yet, 1 master heartbeat lost, 2 transmit path "
        "blocked, 3 disabled by a master write, 4 the device left Operational, 5 session ended",
    ),
    (
        "in-loader",
        "bit",
        "out",
        "the device answered as its resident loader (0x1000 = BOOT), or booted right after "
        "another master stopped its program: no application, no jogging; false once it "
        "answers as its application",
    ),
]


def pin_table(axes: str) -> List[Tuple[str, str, str]]:
    """(name without the prefix, type, direction) of every pin for these switch letters
    (`--axes`: axes and overrides)."""
    table = [
        (n.format(L=L), t, d) for L in axes if L not in OVERRIDES for (n, t, d, _) in AXIS_PINS
    ]
    table += [
        (n.format(O=OVERRIDES[L]), t, d)
        for L in axes
        if L in OVERRIDES
        for (n, t, d, _) in OVERRIDE_PINS
    ]
    table += [(n, t, d) for (n, t, d, _) in COMPONENT_PINS]
    return table


# Replaying events ----------------------------------------------------------------------------


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


Event = tuple  # ("frame", cob_id, data, t) | ("drained", t) | ("tick", t) | ("enable", bool)


def replay_core(events, cfg: Optional[Config] = None) -> Core:
    """A `Core` (of `cfg`, default `Config()`) after `events`, each handled as the shell
    does in a round of its own: the event, then `publish` at its time. Events:
    ("frame", cob_id, data, t), ("drained", t), ("tick", t), ("enable", bool),
    ("position-mode", bool), ("velocity-mode", bool), and ("configure", found, t),
    ("configure", found, t, uptime_ms) or ("configure", found, t, uptime_ms, "refused"): the
    configuration the core asks for at `t` carried out at once on a device whose 0x2002 reads
    `found` and whose uptime 0x2035 reads `uptime_ms` (None: not read) (`configure_outcome`:
    the session kept if it is the core's, else the token `pick_token` gives written), so
    that the records after it can carry the core's session; "refused": the device refused
    the token as too young (`Configured.young`).
    With `Config.dating`, a sequence probe in two events, as the shell carries it out:
    ("probe", value, floor, t): the `Probe` the core asks for at `t` (`next_action`; its
    nonce must be `value`'s bits 0-12 and its floor `floor`, None for no floor; `value`'s
    key bits are the writer's own, not the core's draw), its write sent at `t`; then
    ("probed", value, t): its answer (0x2033 as read, None: not read) reached the core at
    `t` (`done` with a `Probed` of the send time), or ("probe_refused", t): the device
    refused the write (abort 0x08000022: `done` with that abort). A `WriteFeed` the core asks
    for first is reported not carried out (the vectors' host writes no 0x2000: their masters
    do). Nothing else is asked of the core between the two. Times never go backwards in a
    real run; the core takes the latest time it was given. A malformed event, a "configure"
    or "probe" when the core asks for another action, or a "probed" or "probe_refused" with
    no probe under way raises `ValueError` (a vector's mistake, not the bus's)."""
    c = Core(cfg or Config())
    probe_sent: Optional[float] = None  # the probe under way: when its write was sent
    for event in events:
        kind = event[0] if isinstance(event, (tuple, list)) and event else None
        if kind == "configure" and len(event) in (3, 4, 5):
            _, found, t, *more = event
            action = c.next_action(float(t))
            if not isinstance(action, Configure):
                raise ValueError(f"no configuration due at {t}: {action!r}")
            uptime = (int(more[0]), float(t)) if more and more[0] is not None else None
            ok, result = configure_outcome(action, int(found), c.event_timer, uptime)
            abort = None
            if more[1:] == ["refused"] and result.tried is not None:
                # The device refused the token: too young for a session.
                ok, abort = False, ABORT_DEVICE_STATE
                result = Configured(found=int(found), tried=result.tried, young=True)
            elif more[1:]:
                raise ValueError(f"not a configure event: {event!r}")
            c.done(action, ok, abort, float(t), result)
            c.publish(float(t))
        elif kind == "probe" and len(event) == 4:
            _, value, floor, t = event
            action = c.next_action(float(t))
            while isinstance(action, WriteFeed):
                c.done(action, False, None, float(t))
                action = c.next_action(float(t))
            nonce, floor = int(value) & NONCE_MASK, None if floor is None else int(floor)
            if not (isinstance(action, Probe) and (action.nonce, action.floor) == (nonce, floor)):
                raise ValueError(f"no probe of nonce {nonce}, floor {floor} due at {t}: {action!r}")
            probe_sent = float(t)
            c.publish(float(t))
        elif kind == "probe_refused" and len(event) == 2:
            t = event[1]
            action = c.pending
            if not isinstance(action, Probe) or probe_sent is None:
                raise ValueError(f"no probe under way at {t}: {action!r}")
            c.done(action, False, ABORT_DEVICE_STATE, float(t))
            probe_sent = None
            c.publish(float(t))
        elif kind == "probed" and len(event) == 3:
            _, value, t = event
            action = c.pending
            if not isinstance(action, Probe) or probe_sent is None:
                raise ValueError(f"no probe under way at {t}: {action!r}")
            read = None if value is None else int(value)
            c.done(action, read is not None, None, float(t), Probed(probe_sent, read))
            probe_sent = None
            c.publish(float(t))
        elif kind == "frame" and len(event) == 4:
            _, cob_id, data, t = event
            c.frame(int(cob_id), bytes(data), float(t))
            c.publish(float(t))
        elif kind == "drained" and len(event) == 2:
            c.drained(float(event[1]))
            c.publish(float(event[1]))
        elif kind == "tick" and len(event) == 2:
            c.tick(float(event[1]))
            c.publish(float(event[1]))
        elif kind == "enable" and len(event) == 2:
            c.set_enable(bool(event[1]))
        elif kind == "position-mode" and len(event) == 2:
            c.set_position_mode(bool(event[1]))
        elif kind == "velocity-mode" and len(event) == 2:
            c.set_velocity_mode(bool(event[1]))
        else:
            raise ValueError(f"not an event: {event!r}")
    return c


def replay(events, cfg: Optional[Config] = None) -> Dict[str, int]:
    """The per-axis counts (`jog-counts` as published) after `events` (see `replay_core`):
    the entry point for test vectors, e.g. every delivered record stream of a model checker
    with the truth per axis to compare against."""
    c = replay_core(events, cfg)
    assert c.published is not None
    return dict(c.published.jog_counts)
