"""Up-front estimate of the memory a plan's NLP needs, to refuse plans that cannot fit
in a solver worker (UNDERTOW_WORKER_MEMORY_MB) before a worker spends minutes building them.

The estimate is the address space a worker grows by to build the NLP and run Ipopt's
first iterations (the quantity the worker limit caps), fitted to
`bench/capacity.py`'s measurements (bench/results/capacity.csv). Building the NLP expands
the robot's dynamics at every dynamics knot into one symbolic graph, so memory grows with
the knots times the size of one evaluation of the dynamics: about n^2 nodes for the
implicit form (M(q) ddq + h = B tau, n links), about n^3 for the explicit one (solving M
ddq = ...). Multiple shooting keeps one integrator function for every interval and grows
with the links alone. The constants are rounded so that every measured point needs at
least its estimate: the estimate refuses only plans that would certainly not fit, and the
worker limit stops the rest. Re-fit them with `bench/capacity.py` when the planner changes.
"""

from __future__ import annotations

from app.errors import FieldError, field_error
from app.settings import Settings
from planner.scene import Scene, Transcription

FIXED_MB = 280.0
"""Ipopt and MUMPS loaded and first allocations, whatever the plan."""
IMPLICIT_MB = 0.11
"""Per dynamics knot and per squared link count, implicit form."""
EXPLICIT_MB = 0.05
"""Per dynamics knot and per cubed link count, explicit form."""
SHOOTING_MB = 0.25
"""Per cubed link count, multiple shooting (any number of intervals and steps)."""


def dynamics_knots(transcription: Transcription) -> int:
    """Points where the NLP evaluates the dynamics: intervals x degree for collocation,
    the grid points (and midpoints) for trapezoidal and Hermite-Simpson, intervals x steps
    for multiple shooting."""
    k = transcription.intervals
    return {
        "legendre": k * transcription.degree,
        "radau": k * transcription.degree,
        "hermite-simpson": 2 * k + 1,
        "trapezoidal": k + 1,
        "multiple-shooting": k * transcription.steps,
    }[transcription.method]


def estimate_mb(scene: Scene) -> float:
    """The memory [MB] a worker needs for the scene's NLP (at least; see the module)."""
    n, transcription = scene.robot.n, scene.transcription
    if transcription.method == "multiple-shooting":
        return FIXED_MB + SHOOTING_MB * n**3
    per_knot = IMPLICIT_MB * n**2 if transcription.form == "implicit" else EXPLICIT_MB * n**3
    return FIXED_MB + per_knot * dynamics_knots(transcription)


def capacity_errors(scene: Scene, settings: Settings) -> list[FieldError]:
    """A field error at `transcription.intervals` when the scene's NLP cannot fit in a
    solver worker."""
    needed = estimate_mb(scene)
    if needed <= settings.worker_memory_mb:
        return []
    return [field_error(["body", "transcription", "intervals"],
                        f"this plan's NLP needs about {needed:.0f} MB, more than the "
                        f"{settings.worker_memory_mb} MB a solver worker may use on this server "
                        "(UNDERTOW_WORKER_MEMORY_MB): use fewer intervals, a lower degree or "
                        "fewer links", "limit")]
