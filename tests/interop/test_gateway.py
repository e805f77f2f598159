"""A gateway between the device and the host that holds frames and delivers them in a burst
(a CAN-Ethernet gateway, a USB adapter's buffer): the host component (`host/src`, LinuxCNC's
`hal` replaced by host/tests/fake_hal.py) against the release image on the emulated board,
through the SLCAN relay of tools/rig/relay.py, whose `hold` keeps every frame of the device
from the component for a while and then delivers them at once.

The contract: no detent is credited later than 0.5 s after it was turned, whatever path its
record took. A hold upstream of the host is invisible to the component's receive path, so
only a date the device gives can tell: the component dates records with the sequence probe
(0x2033) and credits nothing it cannot date recent. Before that, a 1 s hold while the wheel
turned a detent every 50 ms had 12-13 detents credited more than 0.5 s after they were
turned, all of them at the hold's end.
"""

from __future__ import annotations

import time
from typing import List, Tuple

import pytest

from rig import TPDO1
from test_copies import decode, started

CONTRACT_AGE = 0.5  # s: the latest a detent may be credited after it was turned
DETENT_PERIOD = 0.05  # one detent per 50 ms, x1
BEFORE_HOLD = 0.5  # s of turning before the hold starts
# After the hold the wheel is live again this soon: a detent turned then is credited. A hold
# longer than the order window (4 s) ends the session: the component configures the device
# again first, which takes longer on a busy machine.
LIVE_AGAIN = 1.5
LIVE_AGAIN_RECONFIGURED = 3.0
ORDER_WINDOW = 4.0


def turned_times(h, since: float) -> List[Tuple[int, float]]:
    """(position, when its record left the device) for every new position of the device's
    X records since `since`: the detent was turned before its record passed the relay on
    the device's side (the relay's device recorder stamps it before any hold)."""
    seen, out = None, []
    for f in h.relay.device.frames(TPDO1):
        if f.t < since:
            continue
        position = decode(f).position
        if seen is None or position > seen:
            out.append((position, f.t))
            seen = position
    return out


def credit_ages(h, start_counts: int, since: float):
    """(X's counts credited since `since`, the age of every credit): a credit of d counts
    at time c, with the position pin then showing p (the record it took), moved positions
    p - d + 1 .. p; its age is from the device's first record of p - d + 1 (the oldest
    motion in it) leaving the device to c."""
    turns = turned_times(h, since - 1.0)
    ages = []
    before = start_counts
    for c, value in h.hal.history("axis.x.jog-counts", since):
        d = int(value) - before
        before = int(value)
        if d <= 0:
            continue
        p = int(h.hal.at("position", c + 0.002) or 0)
        oldest = p - d + 1
        turned_at = next((t for q, t in turns if q >= oldest), None)
        assert turned_at is not None, f"a credit of {d} up to position {p}, never turned"
        ages.append(c - turned_at)
    return before - start_counts, ages


@pytest.mark.parametrize(
    "hold, args",
    [
        (0.5, ()),
        (1.0, ()),
        (2.5, ("--event-timer-ms", "1000")),
        (5.0, ("--event-timer-ms", "1000")),
    ],
    ids=["0.5 s hold", "1 s hold", "2.5 s hold, 1 s event timer", "5 s hold, 1 s event timer"],
)
def test_a_held_burst_credits_nothing_late(board, tmp_path, hold, args):
    """X at x1 turns a detent every 50 ms for BEFORE_HOLD + `hold` + 1 s more than it takes
    the wheel to be live again;
    BEFORE_HOLD in, the relay holds every frame of the device for `hold` seconds and then
    delivers them at once. No detent is credited more than CONTRACT_AGE after it was turned;
    X is never credited more than the device's records say was turned; and the wheel is live
    again after the hold (a detent turned LIVE_AGAIN after it, LIVE_AGAIN_RECONFIGURED after a
    hold that ended the session, is credited)."""
    live_again = LIVE_AGAIN_RECONFIGURED if hold > ORDER_WINDOW else LIVE_AGAIN
    after_hold = live_again + 1.0  # s of turning after the hold ends
    with started(board, tmp_path, args=args) as h:
        h.must(h.caught_up, 3.0, "the component at the newest record")
        start_counts, start_position = h.counts("x"), decode(h.newest()).position
        since = time.monotonic()
        held = False
        i = 0
        while True:
            now = time.monotonic() - since
            if now > BEFORE_HOLD + hold + after_hold:
                break
            if not held and now >= BEFORE_HOLD:
                h.relay.hold(hold)
                held = True
            h.stim.turn(1)
            i += 1
            time.sleep(max(0.0, since + DETENT_PERIOD * i - time.monotonic()))
        h.wait(h.caught_up, 3.0)
        time.sleep(0.3)  # the last credits to the pins
        turned = decode(h.newest()).position - start_position
        credited, ages = credit_ages(h, start_counts, since)
        late = [a for a in ages if a > CONTRACT_AGE]
        resumed = since + BEFORE_HOLD + hold + live_again
        after = [p for p, t in turned_times(h, resumed) if t >= resumed]
        turned_after = after[-1] - after[0] + 1 if after else 0
        counts_then = int(h.hal.at("axis.x.jog-counts", resumed) or 0)
        credited_after = h.counts("x") - counts_then
        print(
            f"hold {hold} s: turned {turned}, credited {credited}, {len(late)} late "
            f"(oldest {max(ages, default=0):.3f} s); from {live_again} s after the hold: "
            f"turned {turned_after}, credited {credited_after}"
        )
        assert not late, (
            f"{len(late)} credits of motion turned more than {CONTRACT_AGE} s before "
            f"(up to {max(late):.3f} s) after a {hold} s hold"
        )
        assert 0 <= credited <= turned, f"credited {credited} of {turned} turned"
        assert turned_after >= 5 and credited_after >= turned_after, (
            f"from {live_again} s after the hold on, {credited_after} of {turned_after} "
            "detents credited: the wheel was not live again"
        )
