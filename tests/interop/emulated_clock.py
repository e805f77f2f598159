"""When frames left the node, on the emulator's own clock: the periods the firmware keeps
(heartbeat, event timer) are its business in emulated time, not the host's.

The emulated board keeps a clock of its own, paced against the wall clock, which slips
behind when the host is too busy to keep up (`tools/board-emu/server.py`, "Pacing"):
measured in host time, its periods stretch with the load (a 1 s heartbeat was seen 1.72 s
apart on a loaded 2-core machine). Its frames are timed by its clock instead: its `status`
(emulated ms) read as soon as each frame is seen. That stamp is late by the emulated time
of the round trip, at most its host time (the board's clock never runs ahead of the wall
clock), so a gap between two stamps is off by the difference of two round trips, tens of
milliseconds on a busy machine.
"""

from __future__ import annotations

from typing import List

from rig import Rig

# How much later than meant a busy host makes the board's frames arrive, in seconds of host
# time, for the few checks that time frames on the host's clock (a mean over many periods,
# too short for a `status` round trip per frame): the board's clock slips behind the wall
# clock when the host cannot keep up.
HOST_LATENESS = 0.6


def frame_times(rig: Rig, cob_id: int, count: int, since: int, timeout: float) -> List[float]:
    """The emulator's time, in seconds, of the first `count` frames on `cob_id` received
    after the recording mark `since` (each waited for within `timeout` s of host time)."""
    times = []
    for n in range(1, count + 1):
        rig.frames.wait_count(cob_id, n, timeout=timeout, since=since)
        times.append(float(rig.board.status()["ms"]) / 1000)
        seen = len(rig.frames.frames(cob_id, since=since))
        # A later frame before the stamp: the stamp would time that one, not frame n.
        assert seen == n, f"frame {n} of {cob_id:03X} timed only after frame {seen} arrived"
    return times


def gaps(times: List[float]) -> List[float]:
    return [round(b - a, 3) for a, b in zip(times, times[1:])]
