"""When frames left the node, on the emulator's own clock: the periods the firmware keeps
(heartbeat, event timer) are its business in emulated time, not the host's.

QEMU runs without `-icount`, so its virtual clock, which the firmware's SysTick counts, is
the host's clock: the master's receive times measure it, each late by the host's scheduling
of QEMU's CPU thread and of the recorder's thread. The emulated board keeps its own clock,
paced against the wall clock, and lets it slip behind when the host is too busy to keep up
(`tools/board-emu/server.py`, "Pacing"): measured in host time, its periods stretch with
the load (a 1 s heartbeat was seen 1.72 s apart on a loaded 2-core machine). Its frames are
timed by its clock instead: its `status` (emulated ms) read as soon as each frame is seen.
That stamp is late by the emulated time of the round trip, at most its host time (the
board's clock never runs ahead of the wall clock), so a gap between two stamps is off by
the difference of two round trips, tens of milliseconds on a busy machine.
"""

from __future__ import annotations

from typing import List

from rig import Rig


def frame_times(rig: Rig, cob_id: int, count: int, since: int, timeout: float) -> List[float]:
    """The emulator's time, in seconds, of the first `count` frames on `cob_id` received
    after the recording mark `since` (each waited for within `timeout` s of host time)."""
    if rig.qemu.task != "board":
        frames = rig.frames.wait_count(cob_id, count, timeout=timeout, since=since)
        return [f.t for f in frames[:count]]
    times = []
    for n in range(1, count + 1):
        rig.frames.wait_count(cob_id, n, timeout=timeout, since=since)
        times.append(float(rig.qemu.status()["ms"]) / 1000)
        seen = len(rig.frames.frames(cob_id, since=since))
        # A later frame before the stamp: the stamp would time that one, not frame n.
        assert seen == n, f"frame {n} of {cob_id:03X} timed only after frame {seen} arrived"
    return times


def gaps(times: List[float]) -> List[float]:
    return [round(b - a, 3) for a, b in zip(times, times[1:])]
