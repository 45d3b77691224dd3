"""The key of an NLP: everything that decides its symbolic form, and nothing numeric.

One NLP serves every scene of its key (`planner.ocp.problem`): robot numbers, duration,
mesh, references, bounds and weights enter it as parameters or bounds.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass, replace
from functools import lru_cache

from planner.model import Structure
from planner.ocp import methods
from planner.ocp.formulation import formulation_hash
from planner.ocp.solvers import SOLVERS
from planner.ocp.transcription import AnyTranscription
from planner.scene import Bounds, DurationRange, Scene


@dataclass(frozen=True)
class ProblemKey:
    """Everything that decides the NLP's symbolic form; numbers are not part of it.

    torque_limit, position_bounds, velocity_bounds (the joints bounded below and above): the
    bounds that need rows beyond their variables' bounds to hold on whole intervals
    (`Transcription.hulls`); a bound whose polynomials the variables bound alone is not
    part of the key."""

    structure: Structure
    method: str
    intervals: int
    degree: int
    integrator: str
    steps: int
    form: str
    free_time: bool
    weighted_tracking: bool
    tip: bool
    margin: bool
    codesign: bool
    effort: bool
    time: bool
    smoothness: bool
    torque_limit: bool
    position_bounds: tuple[tuple[int, ...], tuple[int, ...]]
    velocity_bounds: tuple[tuple[int, ...], tuple[int, ...]]
    tol: float
    jit: bool
    solver: str = "ipopt"
    max_iter: int = 0  # fixed when the solver is built: one that calls no iteration callback
    idle: bool = False
    """One variable that no row or cost reads (`Solver.idle_variable`), after the others."""
    relaxed: bool = False
    """Virtual torques on the passive joints too (the relaxed dynamics of a continuation,
    `planner.ocp.continuation`): the torque vector holds the active joints' torques, then
    the passive joints' virtual ones; implicit form only."""
    exact_tracking: bool = False
    """The passive joints follow a prescribed motion exactly by rows at the knots
    (`planner.ocp.terms.ExactTracking`): where the transcription has no angle variables
    at its knots to bound (`Transcription.knot_blocks`)."""

    @classmethod
    def of(cls, scene: Scene, intervals: int | None = None) -> ProblemKey:
        """The key of a scene's NLP on `intervals` intervals (default: the scene's)."""
        task, tr, settings = scene.task, scene.transcription, scene.solver
        robot = scene.robot
        wavy = None
        if task.co_design is not None:
            wavy = tuple(link.wavy or link.joint == "active" for link in robot.links)
        shooting = tr.method == "multiple-shooting"
        key = cls(
            structure=Structure.of(robot, wavy),
            method=tr.method,
            intervals=tr.intervals if intervals is None else intervals,
            degree=tr.degree if tr.method in ("legendre", "radau") else 0,
            integrator=tr.integrator if shooting else "",
            steps=tr.steps if shooting and tr.integrator == "rk4" else 0,
            form="explicit" if shooting else tr.form,
            free_time=isinstance(task.duration, DurationRange),
            weighted_tracking=task.tracking is not None and task.tracking.mode == "weighted",
            tip=task.tip_target is not None,
            margin=task.coupling_margin is not None,
            codesign=task.co_design is not None,
            effort=task.objective.effort > 0,
            time=task.objective.time > 0,
            smoothness=task.objective.smoothness > 0,
            torque_limit=task.torque_limit is not None,
            position_bounds=_bounded(task.position_bounds),
            velocity_bounds=_bounded(task.velocity_bounds),
            tol=settings.tol,
            jit=settings.jit,
            solver=settings.name,
            max_iter=0 if SOLVERS[settings.name].monitored else settings.max_iter,
            idle=SOLVERS[settings.name].idle_variable,
        )
        hulls = _hulls(key.method, key.degree, key.integrator, key.steps, key.form)
        exact = task.tracking is not None and task.tracking.mode == "exact"
        return replace(key, exact_tracking=exact and not _knot_blocks(key.method),
                       torque_limit=key.torque_limit and "tau" in hulls,
                       position_bounds=key.position_bounds if "q" in hulls else ((), ()),
                       velocity_bounds=key.velocity_bounds if "dq" in hulls else ((), ()))

    def transcription(self) -> AnyTranscription:
        """The transcription method of this key."""
        return methods.create(self.method, self.intervals, self.degree, self.integrator,
                              self.steps, self.form == "implicit")

    def torque_count(self) -> int:
        """Rows of the torque variables: the active joints (and the passive ones, relaxed)."""
        return self.structure.n if self.relaxed else len(self.structure.active_idx)

    def global_variables(self) -> tuple[tuple[str, int], ...]:
        """The variables of no stage (name, size): the duration T when it is free, the
        wave (amplitude, phase) of every active joint when they are co-designed, the idle
        variable last."""
        out: tuple[tuple[str, int], ...] = (("T", 1),) if self.free_time else ()
        out += (("wave", 2 * len(self.structure.active_idx)),) if self.codesign else ()
        return out + ((("idle", 1),) if self.idle else ())

    def stage_key(self) -> ProblemKey:
        """What the key's stages depend on (`planner.ocp.stages`): the key without its
        number of intervals and without the solver's settings (its tolerance, iteration
        limit and name), which change how the NLP is solved, not its functions; `idle` (one
        variable more) and `jit` (whether to compile) stay."""
        return replace(self, intervals=0, tol=0.0, max_iter=0, solver="")

    def fingerprint(self) -> str:
        """A stable hash of the whole key (its number of intervals too) and of the code that
        builds its NLP: two problems with the same fingerprint have the same variables and
        constraints."""
        return hashlib.sha256((repr(self) + formulation_hash()).encode()).hexdigest()[:20]

    def digest(self) -> str:
        """A stable hash of the key's `stage_key` and of the code that builds its NLP: names
        compiled stages in the disk cache, so that keys that differ only in their number of
        intervals or their solver's settings share them, and code compiled from other
        sources is never loaded."""
        text = repr(self.stage_key()) + formulation_hash()
        return hashlib.sha256(text.encode()).hexdigest()[:20]


def _bounded(bounds: Bounds | None) -> tuple[tuple[int, ...], tuple[int, ...]]:
    """The joints with a (finite) lower bound and those with an upper bound."""
    if bounds is None:
        return (), ()
    def finite(values: list[float | None]) -> tuple[int, ...]:
        return tuple(j for j, v in enumerate(values) if v is not None and math.isfinite(v))
    return finite(bounds.lower), finite(bounds.upper)


@lru_cache(maxsize=64)
def _knot_blocks(method: str) -> tuple[str, ...]:
    """`Transcription.knot_blocks` of a key's method."""
    return methods.create(method, 1).knot_blocks


@lru_cache(maxsize=64)
def _hulls(method: str, degree: int, integrator: str, steps: int, form: str) -> tuple[str, ...]:
    """`Transcription.hulls` of a key's method."""
    return methods.create(method, 1, degree, integrator, steps, form == "implicit").hulls
