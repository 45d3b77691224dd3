"""How a plan with its feedback copes with an arm that is not the one it was planned for.

A scene may state an uncertainty (`task.uncertainty`): relative errors of the links'
masses, inertias and lengths and of the waves' amplitudes. The perturbed models are the
corners of that box with every link changed alike: each stated kind scaled by 1 - e or
1 + e, all 2^k combinations of the k stated kinds (at most 16 models; a scaled length or
amplitude keeps every wave inside its link, a < l). Each model replays the plan's torque
with its LQR feedback (`planner.ocp.feedback`) from the planned initial state, and the
report keeps the worst tracking error (largest |q_sim - q_plan| along the horizon) and
the worst final-state error (|q - q_goal| and |dq - dq_goal| at the end, rad and rad/s),
beside the worst final-state error of the torque alone (the same models, open loop): what
the feedback is worth. With `solver.robustness` set, a plan is verified only when the
worst tracking error is within it.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from planner.model import Robot, Structure
from planner.ocp.feedback import REPLAY_TOL
from planner.ocp.flow import inputs
from planner.ocp.replays import Lane, Replayed, planned_state, reference, replays
from planner.ocp.transcription import Interpolant
from planner.ocp.verification import Robustness
from planner.scene import Uncertainty

KINDS = ("mass", "inertia", "length", "amplitude")
"""The stated kinds, in the order their signs are named in a model's label."""
MAX_AMPLITUDE_SHARE = 0.95
"""A scaled wave amplitude is kept below this share of its (scaled) link's length."""


def models(robot: Robot, uncertainty: Uncertainty) -> list[tuple[str, Robot]]:
    """The corner models of the uncertainty box, each with a label such as "mass+ length-"."""
    kinds = [k for k in KINDS if getattr(uncertainty, k) > 0]
    out = []
    for signs in itertools.product((-1.0, 1.0), repeat=len(kinds)):
        scale = {k: 1.0 + s * getattr(uncertainty, k) for k, s in zip(kinds, signs, strict=True)}
        label = " ".join(f"{k}{'+' if s > 0 else '-'}" for k, s in zip(kinds, signs, strict=True))
        out.append((label, _scaled(robot, scale)))
    return out


def _scaled(robot: Robot, scale: dict[str, float]) -> Robot:
    links = []
    for link in robot.links:
        length = link.length * scale.get("length", 1.0)
        update: dict[str, object] = {"mass": link.mass * scale.get("mass", 1.0),
                                     "inertia": link.inertia * scale.get("inertia", 1.0),
                                     "length": length}
        if link.wave is not None:
            amplitude = min(link.wave.amplitude * scale.get("amplitude", 1.0),
                            MAX_AMPLITUDE_SHARE * length)
            update["wave"] = link.wave.model_copy(update={"amplitude": amplitude})
        links.append(link.model_copy(update=update))
    return robot.model_copy(update={"links": links})


@dataclass(frozen=True)
class Corners:
    """The replays of a plan on the corner models of an uncertainty: each model's label, its
    two lanes (with the feedback, and the torque alone) one after the other, and the plan's
    final state (2n,)."""

    uncertainty: Uncertainty
    labels: list[str]
    lanes: list[Lane]
    goal: np.ndarray


def corners(robot: Robot, interp: Interpolant, K: np.ndarray, uncertainty: Uncertainty,
            limit: np.ndarray | None = None) -> Corners:
    """The lanes that replay the plan `interp` of `robot` with gains K (N, na, 2n), and
    without them, on every corner model of `uncertainty` from the planned initial state,
    the actuators saturating at `limit` (na,) [N m] where given."""
    breaks = interp.q.breaks
    start = planned_state(interp, breaks[0])
    labels, lanes = [], []
    for label, model in models(robot, uncertainty):
        params = inputs(model, interp, limit)[1]
        labels.append(label)
        lanes += [Lane(start, params, K), Lane(start, params, None)]
    return Corners(uncertainty, labels, lanes, planned_state(interp, breaks[-1]))


def report(made: Corners, done: list[Replayed], bound: float | None,
           limit: np.ndarray | None = None) -> Robustness:
    """What the replays `done` of the lanes of `made` say; `bound` [rad]: the largest worst
    tracking error the plan may have (a replay that stopped or failed counts as one that
    diverged)."""
    closed, alone = done[0::2], done[1::2]
    peak = max(r.peak for r in closed)
    tracking = [np.inf if r.error is None else r.error for r in closed]
    final = [np.inf if r.end is None else float(np.abs(r.end - made.goal).max())
             for r in closed]
    drift = [np.inf if r.end is None else float(np.abs(r.end - made.goal).max())
             for r in alone]
    worst = int(np.argmax(tracking))
    worst_tracking = tracking[worst]
    return Robustness(
        uncertainty=made.uncertainty, models=len(made.labels),
        worst_tracking_error=worst_tracking if np.isfinite(worst_tracking) else None,
        worst_final_error=max(final) if np.isfinite(max(final)) else None,
        open_loop_final_error=max(drift) if np.isfinite(max(drift)) else None,
        worst_model=made.labels[worst], bound=bound, largest_torque=peak,
        saturated=None if limit is None else bool(np.any(peak > limit)),
        within=None if bound is None else bool(worst_tracking <= bound))


def robustness(robot: Robot, interp: Interpolant, K: np.ndarray, uncertainty: Uncertainty,
               bound: float | None, compiled: bool = False,
               deadline: float | None = None, limit: np.ndarray | None = None) -> Robustness:
    """The plan `interp` of `robot` with gains K (N, na, 2n) replayed on every corner model
    of `uncertainty`, the actuators saturating at `limit` (na,) [N m] where given; `bound`
    [rad]: the largest worst tracking error it may have; a replay still running past
    `deadline` (time.perf_counter() seconds) stops (as one diverged)."""
    made = corners(robot, interp, K, uncertainty, limit)
    done = replays(Structure.of(robot), reference(interp), made.lanes, REPLAY_TOL, compiled,
                   deadline)
    return report(made, done, bound, limit)
