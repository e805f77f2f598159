"""The run-on mode (the default) and the override positions (`--axes xyzfs`) in LinuxCNC 2.9.

Run-on: Y made to do 2 mm/s and 20 mm/s^2 (the field report's axis: 2 in/s and 20 in/s^2; the
figures are the same in any unit), x100 at 0.001: one detent is 0.1. Within the 0.25 s budget a
continuous planner takes the axis 0.3 from rest (0.1 s up to 2, 0.05 s at 2, 0.1 s down);
LinuxCNC's, in 1 ms servo periods, needs 4 ms more for that, so the component plans with the
budget less 8.3 ms (`core.planner_lag`): 0.28 from rest, two detents at once, three turned at
most 200 a second.

Overrides: switch position 4 is the feed override, 5 the spindle override (the sim machine's
`handwheel.hal`); `[DISPLAY]MAX_FEED_OVERRIDE = 1.2`, spindle 0.5..1.5. The last test starts
the component again with the rapid override on position 4.
"""

import os
import signal
import time

import pytest

from canopen_handwheel import core
from conftest import SERVO_PERIOD, TOL, detent_records, last_change, moved, spin

SCALE = 0.001
V, A, BUDGET = 2.0, 20.0, 0.25
DETENT = 100 * SCALE  # at x100
# The farthest the component lets the target lead the axis at full speed: v B - v^2/2a (0.4)
# with B the budget less LinuxCNC's planner lag (8.3 ms at the sim's 1 ms servo period).
REACH_AT_SPEED = core.run_on_reach(BUDGET - core.planner_lag(V, A, SERVO_PERIOD), V, A, V)
COUNTS_Y, POS_Y, TARGET_Y = "handwheel.axis.y.jog-counts", "axis.y.pos-cmd", "axis.y.teleop-pos-cmd"
DROPPED = "handwheel.counts-dropped"
MODE_MANUAL, MODE_MDI = 1, 3  # linuxcnc.MODE_MANUAL, linuxcnc.MODE_MDI
# How much later than the budget the axis may rest after the record of the last detent: the
# component plans LinuxCNC's servo periods in (`core.planner_lag`), but neither it nor
# LinuxCNC's servo thread runs in real time on this shared machine (a few ms late under load),
# the test's listener reads the record through the hub a little before or after the
# component, and the display samples every ~0.1 ms.
STOP_SLACK = 0.005


def run_on_bound(machine, since: int) -> float:
    """How far Y can have gone on a burst whose records came after the mark `since`: full
    speed while they came (10 ms more for the listener's and the component's reads), and the
    farthest lead at full speed after the last. Ten quick detents take 24 ms on the board,
    longer in host time when its clock slips; the axis starts with the first."""
    first, last = detent_records(machine, since)
    return V * (last - first + 0.01) + REACH_AT_SPEED


def burst(machine, detents, one_by_one=False):
    """`detents` quick detents on Y (one stimulus command; `one_by_one`: a `turn` command
    each, about 30 ms apart), sampled until Y rests: (moved, run-on after the last count in
    s, run-on after the record of the last detent in s, counts sent, counts dropped)."""
    start = machine.pos()[1]
    counts = machine.pins()["axis.y.jog-counts"]
    dropped = machine.pins()["counts-dropped"]
    machine.watch(5, COUNTS_Y, POS_Y, TARGET_Y, DROPPED)
    time.sleep(0.05)
    mark = machine.frames.mark()
    if one_by_one:
        spin(machine, detents, pause=0.0)
    else:
        machine.stim.turn(detents)
    samples = machine.watched(quiet=0.4)
    stopped = last_change(samples, 2)[0]
    last_count = last_change(samples, 1)[0]
    moved_by = samples[-1][2] - start
    return (
        moved_by,
        stopped - last_count,
        stopped - detent_records(machine, mark)[1],
        samples[-1][1] - counts,
        samples[-1][4] - dropped,
    )


@pytest.fixture
def slow_y(machine):
    machine.select("y", 100)
    machine.ready_to_jog("y")
    assert not machine.pins()["axis.y.jog-vel-mode"]  # run-on: LinuxCNC's position mode
    with machine.slow_axis("y", V, A):
        yield


def test_run_on_is_the_default_mode(machine):
    p = machine.pins()
    assert not p["position-mode"] and not p["velocity-mode"]
    assert p["run-on-budget"] == pytest.approx(BUDGET)
    assert not any(p[f"axis.{L}.jog-vel-mode"] for L in "xyz")


@pytest.mark.parametrize("detents, one_by_one", [(1, False), (2, False), (-2, False), (3, True)])
def test_bursts_within_the_budget_move_exactly(machine, slow_y, detents, one_by_one):
    """One or two quick detents (2.4 ms apart), or three turned one by one (a `turn 1` each,
    about 30 ms apart): every detent moves, and Y rests within the budget of the last."""
    moved_by, run_on, after_record, sent, dropped = burst(machine, detents, one_by_one)
    print(
        f"{detents} detents: moved {moved_by:.4f}, at rest {run_on:.3f} s after the last count, "
        f"{after_record:.3f} s after its record"
    )
    assert abs(moved_by - detents * DETENT) < TOL
    assert sent == detents * 100 and dropped == 0
    assert after_record <= BUDGET + STOP_SLACK


def test_ten_quick_detents_move_as_far_as_the_budget_allows(machine, slow_y):
    moved_by, run_on, after_record, sent, dropped = burst(machine, 10)
    print(
        f"10 detents: moved {moved_by:.4f} ({sent} counts sent, {dropped} dropped), "
        f"at rest {run_on:.3f} s after the last count, {after_record:.3f} s after the record "
        "of the last detent"
    )
    # Whole detents, at least what fits from rest, never all ten, the rest dropped.
    assert sent % 100 == 0 and sent + dropped == 1000
    assert 2 * 100 <= sent < 1000
    assert abs(moved_by - sent * SCALE) < TOL
    assert after_record <= BUDGET + STOP_SLACK


def test_a_fast_spin_runs_on_at_most_the_budget(machine, slow_y):
    """60 detents at x100 (6 units) in 0.3 s on the slow Y: the axis runs at its speed while
    the wheel turns, then rests within the budget of the record of the last detent (the
    component reads it through the hub as the test's listener does); a change of mode
    afterwards releases nothing. The spin is six `turn 10` back to back: 24 ms of edges
    each, its reply 25 ms after the last (the board's time, longer in host time when its
    clock slips), about 0.3 s in all; 50 ms pauses between them made it twice as long, and
    the axis's travel while the wheel turns with it."""
    start = machine.pos()
    counts = machine.pins()["axis.y.jog-counts"]
    machine.watch(5, COUNTS_Y, POS_Y, TARGET_Y)
    mark = machine.frames.mark()
    replied = spin(machine, 60, pause=0.0, step=10)
    samples = machine.watched(quiet=0.4)
    stopped = last_change(samples, 2)
    at_last_count = last_change(samples, 1)
    first_record, last_record = detent_records(machine, mark)
    lead = max(target - pos for _, _, pos, target in samples)
    travelled = samples[-1][2] - start[1]
    print(
        f"spin: moved {travelled:.3f} of 6 (records {last_record - first_record:.3f} s); at rest "
        f"{stopped[0] - last_record:.3f} s after the "
        f"record of the last detent, {stopped[0] - at_last_count[0]:.3f} s after the last "
        f"count ({samples[-1][2] - at_last_count[2]:.3f} on), {stopped[0] - replied:.3f} s "
        f"after the last reply (its last edge at least 25 ms before); largest lead {lead:.3f}"
    )
    assert stopped[0] - last_record <= BUDGET + STOP_SLACK
    assert (samples[-1][1] - counts) % 100 == 0
    # At most full speed while the records came (0.3 s, longer when the board's clock slips)
    # and the lead then, not the 6 asked.
    assert travelled <= run_on_bound(machine, mark)
    # The reach at full speed (less the planner's lag at 2), and a servo period's motion.
    assert lead <= REACH_AT_SPEED + V * 0.002
    rest = machine.pos()
    for position, velocity in [(1, 0), (0, 1), (0, 0)]:
        machine.setp("handwheel.position-mode", position)
        machine.setp("handwheel.velocity-mode", velocity)
        machine.assert_still(rest, 0.2)
    assert machine.pins()["axis.y.jog-counts"] == samples[-1][1]


def test_turning_back_after_a_spin_rests_within_the_budget(machine, slow_y):
    """Y made to stop slower (10 mm/s^2: 0.2 s and 0.2 mm from full speed), 60 detents spun
    forward (it leads by 0.15 or so at 1.8 mm/s), then one back at once: the target would
    still lead, by less than the stopping distance, so the axis would stop past it and come
    back (0.35 s and more in all). The component lets only what the axis can rest at within
    the budget go (no detent of the turn back here), and Y rests within the budget of the
    record of the last detent."""
    with machine.slow_axis("y", V, 10.0):
        start = machine.pos()
        counts = machine.pins()["axis.y.jog-counts"]
        machine.watch(5, COUNTS_Y, POS_Y, TARGET_Y)
        mark = machine.frames.mark()
        spin(machine, 60, pause=0.0, step=10)
        machine.stim.turn(-1)
        samples = machine.watched(quiet=0.4)
        stopped = last_change(samples, 2)[0]
        _, last_record = detent_records(machine, mark)
        sent = samples[-1][1] - counts
        print(
            f"turning back: moved {samples[-1][2] - start[1]:.3f} ({sent} counts), at rest "
            f"{stopped - last_record:.3f} s after the record of the last detent"
        )
        assert stopped - last_record <= BUDGET + STOP_SLACK
        assert sent % 100 == 0 and abs(samples[-1][2] - start[1] - sent * SCALE) < TOL


@pytest.mark.parametrize("stop", ["off", "estop"])
def test_a_stop_during_a_run_on_releases_nothing(machine, slow_y, stop):
    """Ten quick detents, then at once the machine off (`off`) or E-stop (`estop`), and the
    machine on again: Y went no farther than the run-on allows (`run_on_bound`), stays, and
    nothing held or dropped comes back; the next detent moves exactly one."""
    start = machine.pos()
    mark = machine.frames.mark()
    machine.stim.turn(10)
    machine.cnc.must(stop)
    machine.cnc.must("on")
    machine.ready_to_jog("y")
    rest = machine.pos()
    assert rest[1] - start[1] <= run_on_bound(machine, mark) + TOL, (start, rest)
    machine.assert_still(rest, 0.5)
    machine.stim.turn(1)
    machine.wait_pos(moved(rest, "y", DETENT), 5)


def test_velocity_mode_during_a_run_on_releases_nothing(machine, slow_y):
    """Ten quick detents in the run-on mode, the component's `velocity-mode` pin set at once:
    Y goes no farther than the run-on allows (`run_on_bound`) and rests; in velocity mode one
    detent then moves exactly one."""
    start = machine.pos()
    mark = machine.frames.mark()
    machine.stim.turn(10)
    machine.setp("handwheel.velocity-mode", 1)
    try:
        machine.wait(lambda s: s["pins"]["axis.y.jog-vel-mode"], 5, "jog-vel-mode")
        time.sleep(BUDGET + STOP_SLACK + 0.2)
        rest = machine.pos()
        assert rest[1] - start[1] <= run_on_bound(machine, mark) + TOL, (start, rest)
        machine.assert_still(rest, 0.5)
        machine.stim.turn(1)
        machine.wait_pos(moved(rest, "y", DETENT), 5)
    finally:
        machine.setp("handwheel.velocity-mode", 0)
        machine.wait(lambda s: not s["pins"]["axis.y.jog-vel-mode"], 5, "run-on again")


def switch_mode(machine, mode: str, task_mode: int) -> None:
    """LinuxCNC to `mode` through halui's `halui.mode.<mode>` (a rising edge each try: task
    refuses a change while the axis still moves)."""
    deadline = time.monotonic() + 5
    while machine.status()["task_mode"] != task_mode:
        assert time.monotonic() < deadline, f"LinuxCNC did not switch to {mode}"
        machine.setp(f"halui.mode.{mode}", 1)
        time.sleep(0.05)
        machine.setp(f"halui.mode.{mode}", 0)


def test_mdi_and_back_releases_nothing(machine, slow_y):
    """Ten quick detents, LinuxCNC asked to switch to MDI at once (it does once the axis
    rests) and back to manual: nothing of the burst moves after the switch back; the next
    detent moves exactly one."""
    machine.stim.turn(10)
    switch_mode(machine, "mdi", MODE_MDI)
    switch_mode(machine, "manual", MODE_MANUAL)
    machine.wait(lambda s: s["teleop"], 5, "teleop")
    machine.ready_to_jog("y")
    rest = machine.pos()
    machine.assert_still(rest, 0.5)
    machine.stim.turn(1)
    machine.wait_pos(moved(rest, "y", DETENT), 5)


# Overrides -------------------------------------------------------------------------------


def override(machine, which):
    return machine.status()["overrides"][which]


def reset_overrides(machine):
    """Feed, spindle and rapid override back to 100 % through halui's reset inputs (a rising
    edge each try, until the status shows it)."""
    deadline = time.monotonic() + 10
    while any(v != 1.0 for v in machine.status()["overrides"].values()):
        assert time.monotonic() < deadline, machine.status()["overrides"]
        for pin in (
            "halui.feed-override.reset",
            "halui.spindle.0.override.reset",
            "halui.rapid-override.reset",
        ):
            machine.setp(pin, 1)
        time.sleep(0.1)
        for pin in (
            "halui.feed-override.reset",
            "halui.spindle.0.override.reset",
            "halui.rapid-override.reset",
        ):
            machine.setp(pin, 0)
        time.sleep(0.1)


# halui takes the change of an override's counts since its last look, every ~0.1 s (seen
# here), adds it times the scale to the override and clamps the sum to the limit. Turning up
# past the limit and back within one of its looks nets the two, so the tests let it look
# twice more after the override shows a turn's value before they turn again.
HALUI_SETTLE = 0.3


def wait_override(machine, which, value):
    machine.wait(
        lambda s: abs(s["overrides"][which] - value) < 1e-6, 5, f"{which} override {value}"
    )
    time.sleep(HALUI_SETTLE)


def test_feed_override_position_steps_one_percent_and_moves_no_axis(machine):
    reset_overrides(machine)
    machine.select("w", 1)  # position 4
    machine.wait(lambda s: s["pins"]["feed-override.count-enable"], 10, "count-enable")
    p = machine.pins()
    assert p["feed-override.scale"] == pytest.approx(0.01)
    assert not any(p[f"axis.{L}.jog-enable"] for L in "xyz")
    assert not p["spindle-override.count-enable"]
    rest = machine.pos()
    axis_counts = {L: p[f"axis.{L}.jog-counts"] for L in "xyz"}
    machine.stim.turn(5)
    wait_override(machine, "feed", 1.05)
    machine.stim.turn(-2)
    wait_override(machine, "feed", 1.03)
    machine.select("w", 100)  # the multiplier changes nothing: 1 % per detent
    machine.stim.turn(4)
    wait_override(machine, "feed", 1.07)
    machine.stim.turn(30)  # MAX_FEED_OVERRIDE = 1.2
    wait_override(machine, "feed", 1.2)
    machine.stim.turn(-10)
    wait_override(machine, "feed", 1.1)
    machine.assert_still(rest, 0.3)
    assert {L: machine.pins()[f"axis.{L}.jog-counts"] for L in "xyz"} == axis_counts
    assert override(machine, "spindle") == 1.0


def test_spindle_override_position_and_its_limits(machine):
    reset_overrides(machine)
    machine.select("v", 10)  # position 5
    machine.wait(lambda s: s["pins"]["spindle-override.count-enable"], 10, "count-enable")
    rest = machine.pos()
    machine.stim.turn(-5)
    wait_override(machine, "spindle", 0.95)
    machine.stim.turn(-100)  # MIN_SPINDLE_OVERRIDE = 0.5
    wait_override(machine, "spindle", 0.5)
    machine.stim.turn(3)
    wait_override(machine, "spindle", 0.53)
    machine.assert_still(rest, 0.3)
    assert override(machine, "feed") == 1.0


def test_back_on_an_axis_nothing_is_carried_over(machine):
    reset_overrides(machine)
    machine.select("w", 10)
    machine.wait(lambda s: s["pins"]["feed-override.count-enable"], 10, "count-enable")
    machine.stim.turn(7)
    wait_override(machine, "feed", 1.07)
    machine.select("y", 10)
    machine.ready_to_jog("y")
    rest = machine.pos()
    machine.assert_still(rest, 0.3)
    machine.stim.turn(2)
    machine.wait_pos(moved(rest, "y", 2 * 10 * SCALE))
    assert override(machine, "feed") == pytest.approx(1.07)


def test_machine_off_changes_no_override(machine):
    reset_overrides(machine)
    machine.select("w", 1)
    machine.wait(lambda s: s["pins"]["feed-override.count-enable"], 10, "count-enable")
    machine.cnc.must("off")
    machine.wait(lambda s: not s["pins"]["feed-override.count-enable"], 5, "count-enable off")
    machine.stim.turn(5)
    time.sleep(0.5)
    assert override(machine, "feed") == 1.0
    machine.cnc.must("on")
    machine.wait(lambda s: s["pins"]["feed-override.count-enable"], 10, "count-enable")
    time.sleep(0.3)
    assert override(machine, "feed") == 1.0
    machine.stim.turn(1)
    wait_override(machine, "feed", 1.01)


def test_rapid_override_position(machine):
    """The component started again with `--axes xyzrs`: position 4 is the rapid override,
    netted to halui's; LinuxCNC holds it to 100 % at most."""
    reset_overrides(machine)
    os.kill(machine.component_pid(), signal.SIGTERM)
    machine.wait(lambda s: s["pins"]["connected"] is None, 10, "the component gone")
    machine.spawn("--axes", "xyzrs")
    for n in ("counts", "count-enable", "scale"):
        out = machine.halcmd(
            "net", f"hw-rapid-{n}", f"handwheel.rapid-override.{n}", f"halui.rapid-override.{n}"
        )
        assert "rror" not in out, out
    machine.select("w", 1)
    machine.wait(lambda s: s["pins"]["rapid-override.count-enable"], 20, "count-enable")
    rest = machine.pos()
    machine.stim.turn(-20)
    wait_override(machine, "rapid", 0.8)
    machine.stim.turn(50)
    wait_override(machine, "rapid", 1.0)
    machine.assert_still(rest, 0.3)
    assert override(machine, "feed") == 1.0
