"""What makes a scene's task infeasible before any solve: checks on the task's own numbers.

Each check is sufficient for infeasibility, never necessary: a task that passes them all
may still be infeasible (a duration below the shortest one its torque limit allows is
found by the planner's duration probe, `planner.ocp.shortest`), but a task that fails one cannot be
planned, so `plan()` returns at once (`Plan.infeasibility`, source "checks") and the
service answers 422 naming the field. The checks:

- **bounds**: the initial angles and rates, and the final ones that are given, within
  `task.position_bounds` and `task.velocity_bounds` (beyond `BOUND_TOL` x max(1, |bound|));
- **velocity reach**: a joint whose given final angle is farther from its initial one than
  its velocity bounds let it move in the longest duration allowed (|q_f - q_0| beyond
  [lower T, upper T] for every T of the duration);
- **coupling margin**: sigma_min(M_pa) at the initial configuration, and at the final one
  when every final angle is given, at least `task.coupling_margin` (not with wave
  co-design, whose waves are not known before the solve);
- **reach**: the tip target within the arm's reach, the sum over links of the largest
  radius l + |a| (with co-design, a up to its bound), and no nearer to the base than the
  arm folds (a link's least radius less the others' largest, `innermost`);
- **reach within bounds**: where the final angles are bounded (`task.position_bounds`, or
  given in `task.final.q`), the tip target within the tip's extent in every direction
  (`extent`: per link the largest r(q) cos(q - theta) over its interval, summed; a target
  beyond it in some direction lies outside the convex hull of what the tip reaches);
- **zero torque**: a torque limit of 0 on every active joint leaves only the free motion
  from the initial state (a state at rest without gravity stays there); the task is
  infeasible when that motion misses the given final state by more than `FREE_TOL` at
  the duration (every duration of a range);
- **energy**: under a torque limit the arm's energy changes at a bounded rate
  (`planner.energy_bound`); a final state whose energy (its potential energy alone where
  its rates are free; every final angle given) lies beyond what the longest duration lets
  the actuators reach is infeasible.

Contradictory bounds within one field (lower above upper, a duration range with min above
max, a negative torque limit) are refused by the scene's validators already.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from planner import coupling_block
from planner.dynamics import Dynamics
from planner.energy_bound import energy_reach
from planner.model import Robot
from planner.scene import Bounds, Scene

BOUND_TOL = 1e-6
"""Relative tolerance of a bound check, times max(1, |bound|) (verify's BOUND_TOL)."""
FREE_TOL = 1e-2
"""[rad, rad/s] How far the free motion must miss a given final angle or rate for a task
with zero torque to be infeasible (far above the plans' accuracy, 1e-3 rad by default)."""
FREE_SAMPLES = 400
"""Samples of the free motion over a duration range."""


@dataclass(frozen=True)
class Issue:
    """Why a task is infeasible before a solve: the field to blame (a dotted path in the
    scene, "task.final.q.1"), the check (`kind`) and what is wrong."""

    field: str
    kind: str
    message: str

    def __str__(self) -> str:
        return f"{self.field}: {self.message}"


def check(scene: Scene) -> list[Issue]:
    """Every reason the scene's task is infeasible that is known before a solve (empty:
    none is known; see the module)."""
    issues = _bounds(scene) + _velocity_reach(scene)
    issues += _margin(scene) + _reach(scene) + _zero_torque(scene) + _energy(scene)
    return issues


ENERGY_RTOL = 1e-9
"""Relative rounding allowed to an energy beyond its bound."""


def _energy(scene: Scene) -> list[Issue]:
    """The final state's energy beyond what the torque limit lets the actuators reach in
    the longest duration (`planner.energy_bound`); not with wave co-design (the waves, and
    so the initial energy, are not known before the solve)."""
    task, robot = scene.task, scene.robot
    if task.torque_limit is None or task.co_design is not None \
            or any(v is None for v in task.final.q):
        return []
    limit = np.broadcast_to(np.asarray(task.torque_limit, float), (len(robot.active),))
    if not limit.any():  # the free motion: the zero-torque check says more
        return []
    T = task.duration_span[1]
    reach = energy_reach(robot, task.initial.q, task.initial.dq, limit, T)
    rates_given = all(v is not None for v in task.final.dq)
    kinetic, potential = Dynamics(robot).energy(
        task.final.q, [0.0 if v is None else v for v in task.final.dq])
    needed = potential + (kinetic if rates_given else 0.0)
    start = reach.start
    scale = ENERGY_RTOL * max(1.0, abs(needed), abs(start))
    what = "the final state's energy" if rates_given else \
        "the final angles' potential energy (rates free: the energy is at least that)"
    if needed > reach.highest + scale:
        return [Issue("task.torque_limit", "energy",
                      f"{what} is {needed - start:.4g} J above the initial state's, and under "
                      f"this limit the actuators can add at most {reach.highest - start:.4g} J "
                      f"in {T:g} s (planner.energy_bound: power at most {reach.power:.4g} "
                      f"sqrt(2 K) W)")]
    if rates_given and needed < reach.lowest - scale:
        return [Issue("task.torque_limit", "energy",
                      f"{what} is {start - needed:.4g} J below the initial state's, and under "
                      f"this limit the actuators can take at most {start - reach.lowest:.4g} J "
                      f"in {T:g} s (planner.energy_bound: power at most {reach.power:.4g} "
                      f"sqrt(2 K) W)")]
    return []


def _lower_upper(bounds: Bounds, joint: int) -> tuple[float, float]:
    lo, hi = bounds.lower[joint], bounds.upper[joint]
    return (-math.inf if lo is None else lo), (math.inf if hi is None else hi)


def _outside(value: float, lo: float, hi: float) -> str | None:
    if value < lo - BOUND_TOL * max(1.0, abs(lo)):
        return f"{value:g} is below its lower bound {lo:g}"
    if value > hi + BOUND_TOL * max(1.0, abs(hi)):
        return f"{value:g} is above its upper bound {hi:g}"
    return None


def _bounds(scene: Scene) -> list[Issue]:
    task, issues = scene.task, []
    for name, bounds, unit in (("q", task.position_bounds, "rad"),
                               ("dq", task.velocity_bounds, "rad/s")):
        if bounds is None:
            continue
        field = "position_bounds" if name == "q" else "velocity_bounds"
        for state in ("initial", "final"):
            values = getattr(getattr(task, state), name)
            for joint, value in enumerate(values):
                if value is None:
                    continue
                why = _outside(value, *_lower_upper(bounds, joint))
                if why is not None:
                    issues.append(Issue(f"task.{state}.{name}.{joint}", "bounds",
                                        f"{why} [{unit}] (task.{field})"))
    return issues


def _velocity_reach(scene: Scene) -> list[Issue]:
    """Joints whose given displacement no duration of the task lets their velocity bounds
    cover: q_f - q_0 = integral of dq, within [lower T, upper T]."""
    task = scene.task
    issues: list[Issue] = []
    if task.velocity_bounds is None:
        return issues
    t_min, t_max = scene.task.duration_span
    for joint, (q0, qf) in enumerate(zip(task.initial.q, task.final.q, strict=True)):
        if qf is None:
            continue
        lo, hi = _lower_upper(task.velocity_bounds, joint)
        d = qf - q0
        # the durations T in [t_min, t_max] with lo T <= d <= hi T
        first, last = t_min, t_max
        for rate, above in ((hi, True), (lo, False)):
            if not math.isfinite(rate):
                continue
            if rate == 0.0:
                if (d > 0.0) if above else (d < 0.0):
                    first = math.inf
                continue
            edge = d / rate  # rate T >= d (above) or rate T <= d (below)
            if (rate > 0.0) == above:
                first = max(first, edge)
            else:
                last = min(last, edge)
        tol = BOUND_TOL * max(1.0, abs(d))
        if first > last * (1 + BOUND_TOL) + tol:
            issues.append(Issue(
                f"task.final.q.{joint}", "velocity reach",
                f"moving joint {joint} by {d:g} rad needs more than its velocity bounds "
                f"[{lo:g}, {hi:g}] rad/s allow in {t_max:g} s (task.velocity_bounds)"))
    return issues


def _margin(scene: Scene) -> list[Issue]:
    task = scene.task
    margin = task.coupling_margin
    if margin is None or task.co_design is not None or not scene.robot.passive:
        return []
    issues = []
    for state, q in (("initial", task.initial.q), ("final", task.final.q)):
        if any(v is None for v in q):
            continue
        sigma = coupling_block.at(scene.robot, q).sigma_min
        if sigma is not None and sigma < margin * (1 - BOUND_TOL):
            issues.append(Issue(
                f"task.{state}.q", "coupling margin",
                f"sigma_min(M_pa) = {sigma:.3g} kg m^2 there, below task.coupling_margin "
                f"= {margin:g}"))
    return issues


def reach(robot: Robot, amplitude_max: float | None = None) -> float:
    """[m] The farthest the arm's tip gets from its base: the sum of the largest link
    radii l + |a| (a co-designed active joint's amplitude up to `amplitude_max`)."""
    total = 0.0
    for joint, link in enumerate(robot.links):
        a = abs(link.wave.amplitude) if link.wave is not None else 0.0
        if amplitude_max is not None and joint in robot.active:
            a = max(a, min(amplitude_max, 0.95 * link.length))
        total += link.length + a
    return total


def _radii(robot: Robot, amplitude_max: float | None) -> list[tuple[float, float]]:
    """[m] The least and the largest radius l -/+ |a| of every link (a co-designed active
    joint's amplitude up to `amplitude_max`)."""
    out = []
    for joint, link in enumerate(robot.links):
        a = abs(link.wave.amplitude) if link.wave is not None else 0.0
        if amplitude_max is not None and joint in robot.active:
            a = max(a, min(amplitude_max, 0.95 * link.length))
        out.append((link.length - a, link.length + a))
    return out


def innermost(robot: Robot, amplitude_max: float | None = None) -> float:
    """[m] The nearest the arm's tip gets to its base, at least: a link of least radius
    r_k folds back at most by the other links' largest radii (0 when they can cover it)."""
    radii = _radii(robot, amplitude_max)
    total = sum(hi for _, hi in radii)
    return max(0.0, max(lo - (total - hi) for lo, hi in radii))


REACH_DIRECTIONS = 360
"""Directions in which the tip's extent within the final angles' bounds is compared with
the tip target's."""
REACH_STEP = 2e-3
"""[rad] Sample spacing of a joint's interval when its extent in a direction is bounded."""


def _final_intervals(scene: Scene) -> list[tuple[float, float]]:
    """[rad] Per joint, the interval its final angle lies in: the given final angle, else
    task.position_bounds (unbounded: a whole turn)."""
    task, out = scene.task, []
    for joint, value in enumerate(task.final.q):
        if value is not None:
            out.append((value, value))
        elif task.position_bounds is not None:
            lo, hi = _lower_upper(task.position_bounds, joint)
            out.append((lo, hi) if hi - lo < 2 * math.pi else (-math.pi, math.pi))
        else:
            out.append((-math.pi, math.pi))
    return out


def extent(scene: Scene, theta: np.ndarray) -> np.ndarray:
    """[m] An upper bound of how far the tip reaches in each direction theta (D,) [rad]
    with the final angles in their intervals (`_final_intervals`): the sum over links of
    the largest r_k(q) cos(q - theta) over the joint's interval, taken on samples REACH_STEP
    apart plus the most it can rise between them (half a step times its largest slope,
    l + |a| + |a| n). A co-designed or waveless radius counts as its largest where cos >= 0
    and its least elsewhere. Exact as REACH_STEP -> 0."""
    co = scene.task.co_design
    radii = _radii(scene.robot, co.amplitude_max if co is not None else None)
    total = np.zeros(theta.shape)
    for joint, ((lo, hi), (r_lo, r_hi)) in enumerate(zip(_final_intervals(scene), radii,
                                                         strict=True)):
        link = scene.robot.links[joint]
        q = np.linspace(lo, hi, max(2, math.ceil((hi - lo) / REACH_STEP) + 1))
        step = (hi - lo) / max(len(q) - 1, 1)
        cos = np.cos(q[None, :] - theta[:, None])
        if co is not None and joint in scene.robot.active or link.wave is None:
            r = np.where(cos >= 0.0, r_hi, r_lo)
            rate = r_hi
        else:
            w = link.wave
            r = (link.length + w.amplitude * np.sin(w.frequency * q + w.phase))[None, :]
            rate = r_hi + abs(w.amplitude) * w.frequency
        total += (r * cos).max(axis=1) + rate * step / 2
    return total


def _reach(scene: Scene) -> list[Issue]:
    target = scene.task.tip_target
    if target is None:
        return []
    co = scene.task.co_design
    amplitude_max = co.amplitude_max if co is not None else None
    farthest, nearest = reach(scene.robot, amplitude_max), innermost(scene.robot, amplitude_max)
    distance = math.hypot(target.x, target.y)
    where = f"({target.x:g}, {target.y:g}) is {distance:g} m from the base"
    if distance > farthest * (1 + BOUND_TOL):
        return [Issue("task.tip_target", "reach",
                      f"{where}, beyond the arm's reach of {farthest:g} m (the sum of its "
                      f"largest link radii)")]
    if distance < nearest * (1 - BOUND_TOL):
        return [Issue("task.tip_target", "reach",
                      f"{where}, nearer than the arm folds: at least {nearest:g} m (a "
                      f"link's least radius less the other links' largest)")]
    theta = np.append(np.linspace(-math.pi, math.pi, REACH_DIRECTIONS, endpoint=False),
                      math.atan2(target.y, target.x))
    reachable = extent(scene, theta)
    gap = target.x * np.cos(theta) + target.y * np.sin(theta) - reachable
    worst = int(np.argmax(gap))
    towards = reachable[worst] + gap[worst]
    if gap[worst] <= BOUND_TOL * max(1.0, distance):
        return []
    return [Issue("task.tip_target", "reach within bounds",
                  f"{where}, out of the tip's reach with the final angles within their "
                  f"bounds (task.position_bounds, task.final.q; a whole turn where neither "
                  f"bounds them): in the direction "
                  f"{math.degrees(theta[worst]):.1f} deg the tip's extent is at most "
                  f"{reachable[worst]:.4g} m and the target's {towards:.4g} m")]


def _zero_torque(scene: Scene) -> list[Issue]:
    """A torque limit of 0 on every active joint: the motion is the free one."""
    task = scene.task
    limits = task.torque_limit
    if limits is None:
        return []
    values = limits if isinstance(limits, list) else [limits]
    if any(v != 0.0 for v in values):
        return []
    final = np.array([np.nan if v is None else v for v in [*task.final.q, *task.final.dq]])
    given = ~np.isnan(final)
    if not given.any():
        return []
    x0 = np.array([*task.initial.q, *task.initial.dq], float)
    t_min, t_max = scene.task.duration_span
    miss = _free_miss(scene.robot, x0, final, given, t_min, t_max)
    if miss is None or miss <= FREE_TOL:
        return []
    when = f"{t_max:g} s" if t_min == t_max else f"any duration in [{t_min:g}, {t_max:g}] s"
    return [Issue("task.torque_limit", "zero torque",
                  f"a limit of 0 N m on every active joint leaves the free motion, which "
                  f"misses the final state by {miss:.3g} (rad, rad/s) at {when}")]


def _free_miss(robot: Robot, x0: np.ndarray, final: np.ndarray, given: np.ndarray,
               t_min: float, t_max: float) -> float | None:
    """The least distance (largest entry) between the free motion from x0 and the given
    final entries over [t_min, t_max]; None where the integration failed."""
    from planner.simulate import simulate  # the integrator is built only when needed

    n = robot.n
    if not robot.gravity and not np.any(x0[n:]):
        return float(np.max(np.abs(final[given] - x0[given])))  # at rest, it stays there
    samples = 1 if t_min == t_max else FREE_SAMPLES
    breaks = [0.0, t_min] if t_min == t_max else [0.0, t_min, t_max]
    coeffs = np.zeros((len(breaks) - 1, 1, len(robot.active)))
    try:
        traj = simulate(robot, breaks, coeffs, x0, samples_per_interval=samples,
                        rtol=1e-8, atol=1e-8)
    except ValueError:
        return None
    if traj.status != "completed":
        return None
    t = np.asarray(traj.t)
    states = np.hstack([np.asarray(traj.q), np.asarray(traj.dq)])[t >= t_min - 1e-12]
    miss = np.max(np.abs(states[:, given] - final[given]), axis=1)
    if len(miss) > 1:  # between samples the miss can dip by up to its change over one
        miss = miss - np.abs(np.diff(miss, append=miss[-1])).max()
    return float(miss.min())
