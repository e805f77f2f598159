"""Detent to motion in LinuxCNC 2.9: `cargo xtask bench`, part 4 (not part of the suite;
xtask runs this file alone, with the handwheel on the emulated board).

1. Latency, over `DETENTS` single detents at x10 on X (alternating direction, 40 ms apart),
   in the run-on mode and in velocity mode alternately, twice each:
   from the `turn 1` command to the component's `handwheel.axis.x.jog-counts` and to
   LinuxCNC's commanded position `axis.x.pos-cmd` (its first change), sampled in LinuxCNC's
   display (`watch`, every ~0.1 ms). The board's `turn 1` makes the detent's four edges 600 us
   apart from the command on and replies 25 ms (of its time) after the last one: the figures
   from the command are an upper bound (the last edge comes 1.8 ms after the first, later
   when the board's clock slips), and the reply says nothing about the motion.
2. Run-on, on Y made to do 2 mm/s with 20 mm/s^2 (the field report's axis in in/s; the
   figures are the same in any unit), x100 at 0.001 (0.1 a detent): in each of the three
   modes (run-on: budget 0.25 s) bursts of 1, 2, 3 and 10 quick detents (one `turn` command
   each): how far the axis moves and how long after the last count and after the record of
   the last detent (as the test's listener reads it through the hub) it rests; then a fast
   spin, 60 detents in about 0.3 s (6 asked; six `turn 10`), in each of the three modes:
   how far it moves in all and after the last edge, when it rests, and the largest lead of
   the planner's target over the commanded position.
3. The component's heartbeat (100 ms) over the whole run, as the test's listener receives
   it through the SLCAN hub: the spread of its periods.
"""

import statistics
import time

from conftest import COUNTS_X, POS_X, detent_records, last_change, spin

DETENTS = 120
PAUSE = 0.04
# The run-on part's axis.
RUN_ON_V, RUN_ON_A = 2.0, 20.0
COUNTS_Y, POS_Y, TARGET_Y = "handwheel.axis.y.jog-counts", "axis.y.pos-cmd", "axis.y.teleop-pos-cmd"
MODES = {"run-on": (0, 0), "velocity": (0, 1), "position": (1, 0)}  # position-, velocity-mode


def first_change_after(samples, column: int, t: float):
    """The time of the first change of `column` after time `t` (None if none)."""
    before = None
    for s in samples:
        if s[0] <= t:
            before = s[column]
            continue
        if before is not None and s[column] != before:
            return s[0]
        before = s[column]
    return None


def percentile(values, p: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(round(p / 100 * (len(ordered) - 1))))]


def figures(name: str, values_s) -> str:
    ms = [v * 1000 for v in values_s]
    return (
        f"  {name:44s} median {statistics.median(ms):6.2f}  p99 {percentile(ms, 99):6.2f}"
        f"  max {max(ms):6.2f} ms"
    )


def latency(machine, mode: str) -> None:
    """Part 1 in `mode` (`run-on`: the component reads LinuxCNC's axis before writing the
    counts; `velocity`: it does not, as before the run-on mode)."""
    position, velocity = MODES[mode]
    machine.setp("handwheel.position-mode", position)
    machine.setp("handwheel.velocity-mode", velocity)
    time.sleep(0.3)
    commands = []
    # Each `turn 1` takes about 28 ms of the board's time (edges, then its reply 25 ms after
    # the last), more when the board's clock slips (twice that on a busy machine): the
    # sampling may last four times 40 ms a detent besides the pause, and ends half a second
    # after the last change.
    machine.watch(DETENTS * (PAUSE + 0.16) + 1.0, COUNTS_X, POS_X)
    time.sleep(0.1)
    for i in range(DETENTS):
        sent = time.monotonic()
        machine.stim.turn(1 if i % 2 == 0 else -1)
        commands.append((sent, time.monotonic()))
        time.sleep(PAUSE)
    reply = machine.cnc.must("watched 0.5")
    samples = [tuple(s) for s in reply["samples"]]
    to_counts, to_pos, round_trip = [], [], []
    for sent, answered in commands:
        tc = first_change_after(samples, 1, sent)
        tp = first_change_after(samples, 2, sent)
        assert tc is not None and tp is not None, (sent, samples[-5:])
        to_counts.append(tc - sent)
        to_pos.append(tp - sent)
        round_trip.append(answered - sent)
    print(
        f"## Detent to motion, {mode} mode: {DETENTS} single detents at x10 on X, "
        f"{PAUSE * 1000:.0f} ms apart"
    )
    print(
        f"  sampling: {reply['polls']} polls in {samples[-1][0] - samples[0][0]:.1f} s, "
        f"longest gap {reply['max_gap'] * 1000:.2f} ms"
    )
    print(figures("`turn 1` to its reply (25 ms after the last edge)", round_trip))
    print(figures("command to handwheel.axis.x.jog-counts", to_counts))
    print(figures("command to axis.x.pos-cmd (motion starts)", to_pos))


def test_detent_to_motion(machine):
    beats_from = machine.frames.mark()
    machine.select("x", 10)
    machine.ready_to_jog("x")
    print()
    # Twice each, alternating, so that both modes meet the same load.
    for mode in ("run-on", "velocity", "run-on", "velocity"):
        latency(machine, mode)
    machine.setp("handwheel.velocity-mode", 0)

    print(
        f"## Run-on on Y at {RUN_ON_V:g} mm/s, {RUN_ON_A:g} mm/s^2, x100 (0.1 mm a detent), "
        "budget 0.25 s"
    )
    machine.select("y", 100)
    machine.ready_to_jog("y")
    with machine.slow_axis("y", RUN_ON_V, RUN_ON_A):
        for mode, (position, velocity) in MODES.items():
            machine.setp("handwheel.position-mode", position)
            machine.setp("handwheel.velocity-mode", velocity)
            for detents in (1, 2, 3, 10):
                start = machine.pos()[1]
                machine.watch(8.0, COUNTS_Y, POS_Y)
                time.sleep(0.05)
                mark = machine.frames.mark()
                machine.stim.turn(detents)
                samples = machine.watched(quiet=0.4)
                stopped = last_change(samples, 2)[0]
                rests = stopped - last_change(samples, 1)[0]
                after_record = stopped - detent_records(machine, mark)[1]
                print(
                    f"  {mode} mode, {detents:2d} quick detents: moved "
                    f"{samples[-1][2] - start:.3f} mm, "
                    f"rests {rests * 1000:.0f} ms after the last count, "
                    f"{after_record * 1000:.0f} ms after the record of the last detent"
                )
        for mode, (position, velocity) in MODES.items():
            machine.setp("handwheel.position-mode", position)
            machine.setp("handwheel.velocity-mode", velocity)
            machine.wait(
                lambda s, v=mode == "velocity": s["pins"]["axis.y.jog-vel-mode"] == v, 2, "mode"
            )
            start = machine.pos()[1]
            machine.watch(8.0, COUNTS_Y, POS_Y, TARGET_Y)
            mark = machine.frames.mark()
            # Six `turn 10` (24 ms of edges each, the reply 25 ms later): about 0.3 s. The
            # last edge came 25 ms of the board's time before the last reply, at least as
            # long in host time: the figures after it are lower bounds.
            last_edge = spin(machine, 60, pause=0.004, step=10) - 0.025
            samples = machine.watched(quiet=0.5)
            at_edge = [s for s in samples if s[0] <= last_edge][-1]
            rests = last_change(samples, 2)[0]
            after_count = rests - last_change(samples, 1)[0]
            first_record, last_record = detent_records(machine, mark)
            lead = max(target - pos for _, _, pos, target in samples)
            print(
                f"  {mode} mode, 60 detents in about 0.3 s (records over "
                f"{(last_record - first_record) * 1000:.0f} ms): moved "
                f"{samples[-1][2] - start:.3f} mm of 6, "
                f"after the last edge {samples[-1][2] - at_edge[2]:.3f} mm; rests "
                f"{(rests - last_edge) * 1000:.0f} ms after the last edge, "
                f"{(rests - last_record) * 1000:.0f} ms after the record of the last detent, "
                f"{after_count * 1000:.0f} ms after the last count; largest lead {lead:.3f} mm"
            )
        machine.setp("handwheel.position-mode", 0)
        machine.setp("handwheel.velocity-mode", 0)
    beats = [f.t for f in machine.frames.frames(0x701, since=beats_from)]
    periods = [(b - a) * 1000 for a, b in zip(beats, beats[1:])]
    print(
        f"## Master heartbeat (100 ms) as received through the hub: {len(periods)} periods, "
        f"min {min(periods):.1f}, median {statistics.median(periods):.1f}, "
        f"max {max(periods):.1f} ms"
    )
