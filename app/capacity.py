"""Up-front estimate of the memory a plan's NLP needs, to refuse plans that cannot fit
in a solver worker (UNDERTOW_WORKER_MEMORY_MB) before a worker spends minutes on them.

The estimate is the address space a worker grows by to build the NLP and run Ipopt's
first iterations (the quantity the worker limit caps), fitted to `bench/capacity.py`'s
measurements (bench/results/capacity.csv). The NLP is written stage by stage: collocation,
trapezoidal and Hermite-Simpson grow with their dynamics knots (Ipopt's matrices and the
derivative blocks scattered per stage), each knot costing about n^1.4 (n links) and a
little more for a higher collocation degree; multiple shooting with RK4 expands every step of one
stage into one symbolic graph of the explicit dynamics, whatever the number of intervals,
each step costing about n^3.5. The constants are rounded so that every measured point
needs at least its estimate: the estimate refuses only plans that would certainly not fit,
and the worker limit stops the rest (a refined mesh, up to
transcription.refinement.max_intervals, can need more than the first one estimated here).
Re-fit them with `bench/capacity.py` when the planner changes.
"""

from __future__ import annotations

from app.errors import FieldError, field_error
from app.settings import Settings
from planner.service import Scene, Transcription, knot_count, node_count

FIXED_MB = 260.0
"""Ipopt and MUMPS loaded and their first allocations, whatever the plan."""
KNOT_MB = 0.0775
"""Per dynamics knot, per link count to the power KNOT_EXPONENT."""
KNOT_EXPONENT = 1.4
DEGREE_SHARE = 0.02
"""Extra share of a knot's cost per collocation degree (the denser per-interval blocks)."""
SHOOTING_MB = 0.18
"""Per RK4 step of a shooting interval, per link count to the power SHOOTING_EXPONENT."""
SHOOTING_EXPONENT = 3.5


def dynamics_knots(transcription: Transcription) -> int:
    """Points where the NLP evaluates the dynamics, as the transcription counts them: its
    knots (intervals x degree for collocation, the grid points and midpoints for trapezoidal
    and Hermite-Simpson); for multiple shooting every RK4 step of every interval (its time
    nodes, intervals x steps)."""
    if transcription.method == "multiple-shooting":
        return node_count(transcription)
    return knot_count(transcription)


def estimate_mb(scene: Scene) -> float:
    """The memory [MB] a worker needs for the scene's first NLP (at least; see the module)."""
    n, tr = scene.robot.n, scene.transcription
    if tr.method == "multiple-shooting":
        steps = tr.steps if tr.integrator == "rk4" else 0  # CVODES: one integrator call
        return FIXED_MB + SHOOTING_MB * n**SHOOTING_EXPONENT * steps
    degree = tr.degree if tr.method in ("legendre", "radau") else 1
    per_knot = KNOT_MB * n**KNOT_EXPONENT * (1 + DEGREE_SHARE * degree)
    return FIXED_MB + per_knot * dynamics_knots(tr)


def capacity_errors(scene: Scene, settings: Settings) -> list[FieldError]:
    """A field error when the scene's NLP cannot fit in a solver worker: at
    `transcription.steps` for RK4 shooting (its memory grows with the steps), else at
    `transcription.intervals`."""
    needed = estimate_mb(scene)
    if needed <= settings.worker_memory_mb:
        return []
    if scene.transcription.method == "multiple-shooting":
        field, advice = "steps", "fewer RK4 steps per interval, or fewer links"
    else:
        field, advice = "intervals", "fewer intervals, a lower degree, or fewer links"
    return [field_error(["body", "transcription", field],
                        f"this plan's NLP needs about {needed:.0f} MB, more than the "
                        f"{settings.worker_memory_mb} MB a solver worker may use on this server "
                        f"(UNDERTOW_WORKER_MEMORY_MB): use {advice}", "limit")]
