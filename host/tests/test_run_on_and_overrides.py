"""The run-on mode's metering (`run_on_reach`, `meter_counts`, `Core.publish` with LinuxCNC's
axis motion) and the override positions of the selector (`--axes xyzfs`)."""

import math
from dataclasses import replace

import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from canopen_handwheel import core
from canopen_handwheel.core import AxisMotion, Config, Core
from records import EN, configured
from test_core import Run

# The slow axis of the field report: 2 units/s, 20 units/s^2 (in/s or mm/s alike), 0.25 s.
V, A, BUDGET = 2.0, 20.0, 0.25
AT_REST = AxisMotion(lead=0.0, velocity=0.0, max_velocity=V, max_acceleration=A)


def time_to_rest(distance, v, a, v0=0.0, dt=1e-5):
    """How long a planner that speeds up to `v` at `a` and brakes as late as it can takes to
    come to rest `distance` ahead, starting at `v0`: a step-by-step simulation, independent
    of `run_on_reach`'s closed form."""
    x, vel, t = 0.0, v0, 0.0
    while True:
        left = distance - x
        if left <= 1e-9 and abs(vel) <= a * dt:
            return t
        if vel > 0 and vel * vel / (2 * a) >= left:
            vel = max(0.0, vel - a * dt)  # brake
        else:
            vel = min(v, vel + a * dt)
        x += vel * dt
        t += dt
        if t > 100:
            raise AssertionError("never came to rest")


def linuxcnc_step(pos, vel, aim, v, a, period):
    """One servo period of LinuxCNC's jog planner (2.9) heading for `aim`, from position `pos`
    at velocity `vel`: (position, velocity) after it. A step-by-step model: it asks for the
    speed from which braking by a * period every period ends on the target,
    sqrt(2 a e + (a period)^2) - a period for a distance e to go (in e's direction; none
    within a thousandth of a period's worth of motion at that step), held to +-v; moves its
    velocity towards that by at most a * period; then moves by velocity * period."""
    step_v = a * period
    to_go = aim - pos
    if abs(to_go) > step_v * period * 1e-3:
        ask = math.copysign(math.sqrt(2 * a * abs(to_go) + step_v * step_v) - step_v, to_go)
    else:
        ask = 0.0
    ask = min(max(ask, -v), v)
    vel = min(max(ask, vel - step_v), vel + step_v)
    return pos + vel * period, vel


def linuxcnc_rest(target, velocity, v, a, period, old_target=None, late=0):
    """When (s from now, whole servo periods) the model of LinuxCNC's planner last moves an
    axis that is at 0 with `velocity` and heads for `target`, the first `late` periods still
    heading for `old_target` (counts it has not taken yet)."""
    pos, vel = 0.0, velocity
    n = last = 0
    while n < 10**6:
        pos, vel = linuxcnc_step(pos, vel, old_target if n < late else target, v, a, period)
        n += 1
        if vel != 0.0:
            last = n
        if n >= late and vel == 0.0 and abs(target - pos) <= a * period * period * 1e-3:
            return last * period
    raise AssertionError("never came to rest")


def test_reach_of_the_field_reports_axis():
    # From rest: 0.1 s up to 2, 0.05 s at 2, 0.1 s down: 0.1 + 0.1 + 0.1.
    assert core.run_on_reach(BUDGET, V, A) == pytest.approx(0.3)
    # Too short to reach full speed: up for B/2, down for B/2.
    assert core.run_on_reach(0.1, V, A) == pytest.approx(A * 0.1**2 / 4)
    # Already at full speed: 0.15 s at 2, then 0.1 s down.
    assert core.run_on_reach(BUDGET, V, A, velocity=V) == pytest.approx(0.4)
    # Moving away from the target: it must stop and come back first.
    assert core.run_on_reach(BUDGET, V, A, velocity=-1.0) < 0.3
    # Cannot stop within the budget at all: its stopping distance.
    assert core.run_on_reach(0.05, V, A, velocity=V) == pytest.approx(0.1)
    for v, a in [(0, A), (V, 0), (float("nan"), A), (V, float("inf")), (-1, A)]:
        assert core.run_on_reach(BUDGET, v, a) == 0.0


@settings(max_examples=60, deadline=None)
@given(
    v=st.floats(0.5, 20),
    a=st.floats(5, 500),
    budget=st.floats(0.05, 1.0),
    fraction=st.floats(0, 1),
)
def test_reach_is_what_a_planner_does_in_the_budget(v, a, budget, fraction):
    """The reach ends at rest within the budget, and 5 % more does not."""
    v0 = fraction * v
    reach = core.run_on_reach(budget, v, a, v0)
    if v0 / a > budget:
        assert reach == pytest.approx(v0 * v0 / (2 * a))
        return
    assert time_to_rest(reach, v, a, v0) <= budget + 1e-3
    assert time_to_rest(reach * 1.05 + 1e-6, v, a, v0) > budget


def test_servo_period_of_an_ini_file():
    ini = (
        "[EMC]\nMACHINE = m\n# SERVO_PERIOD = 5\n[EMCMOT]\nEMCMOT = motmod\nSERVO_PERIOD = 500000\n"
    )
    assert core.servo_period_of_ini(ini) == pytest.approx(0.0005)
    assert core.servo_period_of_ini("[EMCMOT]\n  SERVO_PERIOD=1000000  \n") == pytest.approx(0.001)
    for text in [
        "",
        "[TASK]\nSERVO_PERIOD = 1000000\n",  # another section's
        "[EMCMOT]\n; SERVO_PERIOD = 1000000\n",
        "[EMCMOT]\nSERVO_PERIOD = fast\n",
        "[EMCMOT]\nSERVO_PERIOD = 0\n",
        "[EMCMOT]\nSERVO_PERIOD = -1000000\n",
        "[EMCMOT]\nSERVO_PERIOD = nan\n",
    ]:
        assert core.servo_period_of_ini(text) is None, text


def test_linuxcncs_planner_rests_a_few_periods_after_the_continuous_profile():
    """What the lag is for: the field report's axis from rest to 0.3 (0.25 s continuous) and
    from full speed to 0.4 (0.25 s) takes LinuxCNC's planner 4 periods longer at 1 ms; the
    model rests by the continuous profile's time plus the lag, one period late included."""
    for lead, velocity in [(0.3, 0.0), (0.4, V)]:
        rest = linuxcnc_rest(lead, velocity, V, A, 0.001)
        assert rest == pytest.approx(0.254)
        late = linuxcnc_rest(lead, velocity, V, A, 0.001, old_target=0.0, late=1)
        assert max(rest, late) <= BUDGET + core.planner_lag(V, A, 0.001)
    # m = v / (a T) = 100 periods to stop: T (ln(100) / 2 + 6) = 8.3 ms.
    assert core.planner_lag(V, A, 0.001) == pytest.approx(0.001 * (math.log(100) / 2 + 6))
    assert core.planner_lag(V, A, 0.002) > core.planner_lag(V, A, 0.001)
    assert core.planner_lag(1.0, 1e6, 0.001) == pytest.approx(0.006)  # stops within a period
    for period in (0.0, -0.001, float("nan"), float("inf")):
        assert core.planner_lag(V, A, period) == 0.0


@settings(max_examples=150, deadline=None)
@given(
    v=st.floats(0.5, 200),
    a=st.floats(5, 5000),
    period=st.sampled_from([0.0005, 0.001, 0.002]),
    budget=st.floats(0.02, 0.6),
    detent=st.floats(0.001, 0.3),
    bursts=st.lists(
        st.tuples(st.integers(0, 400), st.integers(-30, 30).filter(bool), st.booleans()),
        min_size=1,
        max_size=6,
    ),
)
def test_linuxcnc_rests_within_the_budget_after_metered_counts(
    v, a, period, budget, detent, bursts
):
    """Bursts of detents either way (`detent` a fraction of what the budget reaches from
    rest) metered from the state the step model of LinuxCNC's planner is in after the
    bursts before, some taken a servo period late: after each, the model rests within the
    budget."""
    unit = detent * core.run_on_reach(budget, v, a)
    assume(unit > 0)
    pos = vel = target = 0.0
    for periods, detents, late in bursts:
        for _ in range(periods):  # time passes: the planner runs on towards `target`
            pos, vel = linuxcnc_step(pos, vel, target, v, a, period)
        motion = AxisMotion(target - pos, vel, v, a, servo_period=period)
        out = core.meter_counts(detents, 1, unit, motion, budget)
        if out == 0:
            continue
        new = target + out * unit
        rest = linuxcnc_rest(new - pos, vel, v, a, period, target - pos, int(late))
        assert rest <= budget + 1e-9, (rest, motion, out)
        if late:
            pos, vel = linuxcnc_step(pos, vel, target, v, a, period)
        target = new


def test_meter_the_field_reports_bursts():
    """x100 at 0.001: one detent is 0.1. LinuxCNC's planner at 1 ms needs 0.254 s for 0.3
    from rest: bursts of 1 and 2 go whole, 3 and 10 go as 2 (a continuous planner, servo
    period 0, would take 3)."""
    for detents in (1, 2):
        assert core.meter_counts(detents * 100, 100, 0.001, AT_REST, BUDGET) == detents * 100
    assert core.meter_counts(300, 100, 0.001, AT_REST, BUDGET) == 200
    continuous = replace(AT_REST, servo_period=0.0)
    assert core.meter_counts(300, 100, 0.001, continuous, BUDGET) == 300
    assert core.meter_counts(1000, 100, 0.001, AT_REST, BUDGET) == 200
    assert core.meter_counts(-1000, 100, 0.001, AT_REST, BUDGET) == -200
    assert core.meter_counts(1000, 100, -0.001, AT_REST, BUDGET) == 200  # the scale's sign
    # The axis already 0.25 ahead at rest: half a detent fits, so none.
    ahead = AxisMotion(0.25, 0.0, V, A)
    assert core.meter_counts(100, 100, 0.001, ahead, BUDGET) == 0
    # At full speed: 0.4 in 0.25 s, less the planner's 2 x 8.3 ms at 2: a lead of 0.2 takes
    # one detent more, not two.
    assert core.meter_counts(300, 100, 0.001, AxisMotion(0.2, V, V, A), BUDGET) == 100
    assert (
        core.meter_counts(300, 100, 0.001, replace(continuous, lead=0.2, velocity=V), BUDGET) == 200
    )
    # Turning back while the target stays ahead: this axis stops from full speed in 0.1 s,
    # and stopping and coming back over its stopping distance (0.241 s) fits the 0.242 s
    # the planner is given: all of it goes, even back to the axis itself.
    assert core.meter_counts(-200, 100, 0.001, AxisMotion(0.3, 2.0, V, A), BUDGET) == -200
    assert core.meter_counts(-280, 10, 0.001, AxisMotion(0.28, 2.0, V, A), BUDGET) == -280
    # An axis that needs 0.2 s to stop (a = 10), 0.28 ahead at full speed: back to the axis
    # it would stop 0.2 on and come back, 0.48 s; what goes leaves the target 0.2 ahead,
    # which it reaches braking (0.2 s), and 0.196 is as close as the budget allows.
    slow_to_stop = AxisMotion(0.28, 2.0, V, 10.0)
    assert core.meter_counts(-280, 10, 0.001, slow_to_stop, BUDGET) == -80
    # Past the axis, against its motion at 2: it brakes for 0.1 (0.1 on), and has 0.14 s
    # left of the 0.242 s the planner is given to come back: to 0.0 fits (0.141 s), to -0.1
    # does not.
    assert core.meter_counts(-500, 100, 0.001, AxisMotion(0.3, 2.0, V, A), BUDGET) == -300
    # Back past the axis at rest by more than the budget allows the other way: what fits.
    assert core.meter_counts(-1000, 100, 0.001, AxisMotion(0.3, 0.0, V, A), BUDGET) == -500
    assert core.meter_counts(0, 100, 0.001, AT_REST, BUDGET) == 0
    # No limits known: nothing can be promised, nothing goes.
    assert core.meter_counts(100, 100, 0.001, AxisMotion(0, 0, 0, A), BUDGET) == 0
    # A budget the planner's lag alone uses up: nothing goes from rest.
    assert core.meter_counts(100, 100, 0.001, AT_REST, core.planner_lag(V, A, 0.001)) == 0


@settings(max_examples=300, deadline=None)
@given(
    detents=st.integers(-200, 200).filter(bool),
    step=st.sampled_from([1, 10, 100]),
    scale=st.sampled_from([0.001, -0.001, 0.0001, 0.01]),
    lead=st.floats(-1, 1),
    velocity=st.floats(-2, 2),
    budget=st.floats(0.02, 1),
)
def test_meter_sends_whole_detents_within_the_budget_and_no_fewer(
    detents, step, scale, lead, velocity, budget
):
    motion = AxisMotion(lead, velocity, V, A)
    pending = detents * step
    out = core.meter_counts(pending, step, scale, motion, budget)
    assert out % step == 0 and abs(out) <= abs(pending)
    assert out == 0 or (out > 0) == (pending > 0)
    direction = 1 if pending * scale > 0 else -1
    planned = budget - core.planner_lag(V, A, motion.servo_period)
    reach = core.run_on_reach(planned, V, A, velocity * direction)
    lead_after = (lead + out * scale) * direction
    if out != 0 and lead_after > 0:  # what went leads by no more than the reach
        assert lead_after <= reach + 1e-6 * abs(step * scale)
    if out != pending:  # one detent more would have led beyond the reach
        assert (lead + (out + math.copysign(step, pending)) * scale) * direction > reach


def slow_axis(lead=0.0, velocity=0.0):
    return AxisMotion(lead, velocity, V, A)


class Metered(Run):
    """A `Run` in the run-on mode with LinuxCNC showing the axes' motion (`motion`)."""

    def __init__(self, **kw):
        super().__init__(axes="xyz", **kw)
        self.c.set_motion_known(True)
        self.asked = []
        self.motion = {L: slow_axis() for L in "xyz"}

    def publish(self):
        def tell(letter):
            self.asked.append(letter)
            return self.motion[letter]

        return self.c.publish(self.at(), tell)

    def enabled(self, axis=2, mult=100):
        self.c.set_enable(True)
        self.record(0, axis=axis, mult=mult)
        self.record(0, axis=axis, mult=mult)
        self.publish()
        self.asked.clear()


def test_run_on_mode_meters_the_selected_axis():
    r = Metered()
    r.enabled()
    pins = r.c.pins()
    assert not pins.jog_vel_mode and r.c.mode == core.RUN_ON
    assert pins.jog_enable["y"]
    r.record(1000, axis=2, mult=100)  # 10 quick detents at x100
    steps = r.publish()
    assert steps[-1].jog_counts["y"] == 200 and r.c.counts_dropped == 800
    assert r.asked == ["y"]  # only the axis with new counts
    # The axis on its way (0.2 ahead, at speed): what still fits goes, the rest is dropped.
    r.motion["y"] = slow_axis(lead=0.2, velocity=2.0)
    r.record(1300, axis=2, mult=100)
    r.publish()
    assert r.c.pins().jog_counts["y"] == 300 and r.c.counts_dropped == 1000
    # Nothing was held: a quiet round asks for nothing and moves nothing.
    r.asked.clear()
    r.publish()
    assert r.asked == [] and r.c.pins().jog_counts["y"] == 300


def test_run_on_mode_without_linuxcncs_answer_drops_the_counts():
    r = Metered()
    r.enabled()
    r.motion["y"] = None  # a read that failed
    r.record(200, axis=2, mult=100)
    r.publish()
    assert r.c.pins().jog_counts["y"] == 0 and r.c.counts_dropped == 200


def test_modes_and_their_vel_mode_pins():
    c = Core(Config(axes="xy"))
    assert c.mode == core.RUN_ON and c.pins().jog_vel_mode  # outside teleop: LinuxCNC's bound
    c.set_motion_known(True)
    assert not c.pins().jog_vel_mode
    c.set_velocity_mode(True)
    assert c.mode == core.VELOCITY and c.pins().jog_vel_mode and not c.metering
    c.set_position_mode(True)  # wins over velocity-mode
    assert c.mode == core.POSITION and not c.pins().jog_vel_mode and not c.metering
    assert Core(Config(velocity_mode=True)).mode == core.VELOCITY


def test_velocity_and_position_mode_pass_every_count():
    for setter in ("set_velocity_mode", "set_position_mode"):
        r = Metered()
        getattr(r.c, setter)(True)
        r.enabled()
        r.record(1000, axis=2, mult=100)
        r.publish()
        assert r.c.pins().jog_counts["y"] == 1000 and r.asked == []


def test_a_change_of_mode_releases_nothing():
    """Switching between the three modes at rest, with motion dropped before: no count."""
    r = Metered()
    r.enabled()
    r.record(1000, axis=2, mult=100)
    r.publish()
    assert r.c.pins().jog_counts["y"] == 200
    for position, velocity in [(1, 0), (0, 1), (0, 0), (1, 1), (0, 0)]:
        r.c.set_position_mode(bool(position))
        r.c.set_velocity_mode(bool(velocity))
        r.publish()
        assert r.c.pins().jog_counts == {"x": 0, "y": 200, "z": 0}


def test_run_on_budget_pin_is_held_to_its_range():
    c = Core(Config())
    assert c.run_on_budget == core.DEFAULT_RUN_ON_BUDGET
    c.set_run_on_budget(0.5)
    assert c.run_on_budget == 0.5
    c.set_run_on_budget(0.0)
    assert c.run_on_budget == core.RUN_ON_BUDGET_RANGE[0]
    c.set_run_on_budget(1e9)
    assert c.run_on_budget == core.RUN_ON_BUDGET_RANGE[1]
    c.set_run_on_budget(float("nan"))
    assert c.run_on_budget == core.DEFAULT_RUN_ON_BUDGET


def test_a_longer_budget_lets_more_through():
    r = Metered()
    r.c.set_run_on_budget(0.5)  # 0.1 + 0.3 at 2 + 0.1 = 0.8, less 2 x 8.3 ms at 2
    r.enabled()
    r.record(1000, axis=2, mult=100)
    r.publish()
    assert r.c.pins().jog_counts["y"] == 700


def test_the_budget_runs_from_the_record():
    """The run-on budget starts when the component read the record of the last detent: the
    time its counts wait for the pins, and the gate's hold before them, is spent. On the
    field report's axis a budget of 0.2 s plus the planner's lag and 2 ms lets two detents
    go from rest when the pins are written at once, one when they wait 5 ms."""
    budget = 0.2 + core.planner_lag(V, A, core.SERVO_PERIOD) + 0.002
    for wait, moved in [(0.0, 200), (0.005, 100)]:
        r = Metered()
        r.c.set_run_on_budget(budget)
        r.enabled()
        r.record(200, axis=2, mult=100)
        r.at(wait)
        r.publish()
        assert r.c.pins().jog_counts["y"] == moved, wait
    # Counts from records read 4 ms apart: the budget runs from the later one.
    r = Metered()
    r.c.set_run_on_budget(budget)
    r.enabled()
    r.record(100, axis=2, mult=100)
    r.record(200, axis=2, mult=100, dt=0.004)
    r.publish()
    assert r.c.pins().jog_counts["y"] == 200
    # The gate opens with the counts (the machine was off a moment): they follow the gate
    # `GATE_HOLD` later, so that much less budget.
    for hold, moved in [(False, 200), (True, 100)]:
        r = Metered()
        r.c.set_run_on_budget(budget)
        r.enabled()
        if hold:
            r.c.set_enable(False)
            r.publish()
            r.c.set_enable(True)
        r.record(200, axis=2, mult=100)
        steps = r.publish()
        assert steps[-1].jog_counts["y"] == moved and len(steps) == (2 if hold else 1), hold
        assert steps[0].jog_enable["y"]


# Overrides --------------------------------------------------------------------------------


def test_axes_option_takes_override_letters_once_each():
    assert core.parse_axes("XYZFS") == "xyzfs"
    assert core.parse_axes("frs") == "frs"
    cfg = Config(axes="xyzfs")
    assert (cfg.axis_letters, cfg.override_letters) == ("xyz", "fs")
    with pytest.raises(ValueError, match="'f' twice"):
        core.parse_axes("xyzff")
    with pytest.raises(ValueError, match="neither"):
        core.parse_axes("xyzq")
    with pytest.raises(ValueError, match="1 to 5"):
        core.parse_axes("xyzfsr")
    names = [n for n, _, _ in core.pin_table("xyzfs")]
    assert "feed-override.counts" in names and "spindle-override.count-enable" in names
    assert "spindle-override.scale" in names and "rapid-override.counts" not in names
    assert "axis.f.jog-counts" not in names and "halui.axis.f.select" not in names


def test_override_positions_count_detents_and_move_no_axis():
    r = Run(axes="xyzfs")
    r.c.set_enable(True)
    r.record(0, axis=4, mult=100)
    r.record(0, axis=4, mult=100)
    assert r.c.pins().jog_enable["f"] and not any(r.c.pins().jog_enable[L] for L in "xyzs")
    assert r.c.pins().select == {"x": False, "y": False, "z": False}
    r.record(300, axis=4, mult=100)  # 3 detents at x100: 3 steps
    r.record(200, axis=4, mult=100)
    assert r.counts() == {"x": 0, "y": 0, "z": 0, "f": 2, "s": 0}
    r.record(200, axis=5, mult=10)  # spindle position, x10
    r.record(250, axis=5, mult=10)
    assert r.counts()["s"] == 5 and r.counts()["f"] == 2
    r.record(250, axis=1, mult=10)  # back on X: nothing carried over
    assert r.counts() == {"x": 0, "y": 0, "z": 0, "f": 2, "s": 5}
    r.record(260, axis=1, mult=10)
    assert r.counts() == {"x": 10, "y": 0, "z": 0, "f": 2, "s": 5}


def test_override_count_enable_is_gated_like_jog_enable():
    r = Run(axes="xf")
    r.record(0, axis=2, mult=1)
    r.record(0, axis=2, mult=1)
    assert not r.c.pins().jog_enable["f"]  # `enable` false
    r.c.set_enable(True)
    assert r.c.pins().jog_enable["f"]
    r.record(0, axis=2, mult=1, flags=0)  # the device reports the feed off
    assert not r.c.pins().jog_enable["f"]
    r.record(5, axis=2, mult=1, flags=0)  # motion while disabled: impossible, nothing
    assert r.counts()["f"] == 0


def test_overrides_are_not_metered():
    r = Metered()
    r.c = configured(Config(axes="xyzfs"))
    r.c.set_motion_known(True)
    r.motion.update({"f": None, "s": None})
    r.enabled(axis=4)
    r.record(5000, axis=4, mult=100)
    r.publish()
    assert r.c.pins().jog_counts["f"] == 50 and r.asked == [] and r.c.counts_dropped == 0


def test_override_records_pass_the_record_rules():
    """An override after an outage moves by nothing: the first record is a baseline."""
    r = Run(axes="xyzfs")
    r.c.set_enable(True)
    r.record(0, axis=4)
    r.record(3, axis=4)
    assert r.counts()["f"] == 3
    r.c.tick(r.at(1.0))  # silent for longer than three event-timer periods
    r.record(40, axis=4)
    assert r.counts()["f"] == 3
    r.record(41, axis=4)
    assert r.counts()["f"] == 4
    r.record(41 + 10**6, axis=4)  # faster than a wheel turns: bad, nothing
    assert r.counts()["f"] == 4 and r.bad() == 1


def test_status_bits_follow_the_override_position():
    r = Run(axes="xyzfs")
    r.c.set_enable(True)
    r.record(0, axis=5, mult=1, flags=EN)
    assert r.c.pins().axis == 5


def test_counts_linuxcnc_has_not_taken_yet_count_as_lead():
    """LinuxCNC reads counts on its next servo cycle: a read of its target before that (the
    same target as before the write) must not let the next counts lead further."""
    r = Metered()
    r.enabled()
    r.motion["y"] = AxisMotion(0.0, 0.0, V, A, target=5.0)
    r.record(200, axis=2, mult=100)
    r.publish()
    assert r.c.pins().jog_counts["y"] == 200
    r.record(300, axis=2, mult=100)  # 10 ms later LinuxCNC still shows the old target
    r.publish()
    assert r.c.pins().jog_counts["y"] == 200  # 0.2 in flight + 0.1: beyond the reach (0.28)
    # Once LinuxCNC shows it (or the window is over), its own figures count again: the axis
    # 0.1 on its way, 0.1 to go, and one more detent fits.
    r.motion["y"] = AxisMotion(0.1, 0.0, V, A, target=5.2)
    r.at(core.IN_FLIGHT)
    r.record(400, axis=2, mult=100)
    r.publish()
    assert r.c.pins().jog_counts["y"] == 300
