"""Session tokens and keys: which token a configuration may write (`free_tokens`,
`pick_token`, `life_began_by`) and the session key its probes carry (`next_key`;
host/README.md, "Sessions")."""

from __future__ import annotations

import math
from typing import Dict, Optional, Tuple

from .order import CLOCK_TOLERANCE, COPY_AGE

# Session tokens the host writes to 0x2002 (0 means none).
TOKENS = tuple(range(1, 8))


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


def next_key(key: int) -> int:
    """The session key after `key`: 1..0xFFFF, never 0 (any int maps into the range)."""
    return key % KEY_MODULO + 1
