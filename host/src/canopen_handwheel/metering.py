"""Run-on metering and plausibility: the jog modes, the wheel's speed bound (`Allowance`),
what LinuxCNC shows of an axis (`AxisMotion`) and how many counts the run-on budget lets go
(`meter_counts`, `run_on_reach`, `planner_lag`; host/README.md, "Jog modes")."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

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


def rate_horizon(stale_after: float, consumer_timeout_ms: int) -> float:
    """How many seconds of turning at the bound one burst of records may carry: the longer
    of the staleness time and the device's heartbeat consumer timeout (see host/README.md's
    "Plausibility")."""
    return max(stale_after, consumer_timeout_ms / 1000)


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
