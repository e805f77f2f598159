"""When frames left the node, on the emulator's own clock: the periods the firmware keeps
(heartbeat, event timer) are its business in emulated time, not the host's.

QEMU runs without `-icount`, so its virtual clock, which drives the SysTick model, is the
host's clock: the master's receive times measure it. The firmware's own time, though, counts
SysTick interrupts (1 kHz), and a QEMU whose CPU thread the host does not run for a while
delivers one interrupt for several periods: on a busy host the firmware's time falls behind
and its frames leave late. There is no reading of that count from outside without a
stimulus command for it (the QEMU variant has none), so QEMU's periods are checked in host
time with a margin, `QEMU_LATENESS`: on a loaded 2-core machine (load 7, two more CPU hogs
beside QEMU) a 1 s heartbeat was up to 1.86 s after the one before (5 of 8 runs over 1.4 s;
with this margin 1 of 8 runs over it, at 2.2 s).

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

# How much later than meant a busy host makes QEMU's frames, in seconds of host time.
QEMU_LATENESS = 0.6


def lateness(rig: Rig) -> float:
    """How much later than the firmware meant a frame can leave on the emulator's clock:
    [`QEMU_LATENESS`] on QEMU; on the emulated board none, its clock waits for it."""
    return 0.0 if rig.qemu.task == "board" else QEMU_LATENESS


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
