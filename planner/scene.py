"""A planning scene: robot, task, transcription and solver settings (pydantic, SI units).

One schema serves the library and the HTTP service. Joint indices are 0-based; vectors
hold one entry per joint unless said otherwise; `null` entries of a final state are free.
"""

from __future__ import annotations

from itertools import pairwise
from typing import Literal

from pydantic import BaseModel, Field, model_validator

from planner.model import Robot
from planner.profiles import PassiveMotion
from planner.schema import DURATION_MAX, DURATION_MIN, Angle, JointState, Rate
from planner.schema import REQUEST as _STRICT


class State(BaseModel):
    """Joint angles q [rad] and rates dq [rad/s]; None entries are left free."""

    model_config = _STRICT

    q: list[Angle | None]
    dq: list[Rate | None]


MARGIN_MIN, MARGIN_MAX = 1e-6, 1e3
"""[kg m^2] The coupling margins a task may state: below 1e-6 a margin is below the
rounding of M_pa's singular values for the arms the service takes, and its rows lose their
scale (docs/planner.md, "Limits and failures")."""
TORQUE_MAX = 1e6
"""[N m] The largest torque limit a task may state."""


class DurationRange(BaseModel):
    """Bounds [s] of a free final time."""

    model_config = _STRICT

    min: float = Field(ge=DURATION_MIN, le=DURATION_MAX)
    max: float = Field(ge=DURATION_MIN, le=DURATION_MAX)

    @model_validator(mode="after")
    def _ordered(self) -> DurationRange:
        if self.min > self.max:
            raise ValueError(f"min: must not exceed max ({self.min:g} > {self.max:g})")
        return self


class Objective(BaseModel):
    """Weights of the cost terms: effort int |tau|^2 dt, time T, smoothness int |dtau/dt|^2 dt."""

    model_config = _STRICT

    effort: float = Field(default=1.0, ge=0.0)
    time: float = Field(default=0.0, ge=0.0)
    smoothness: float = Field(default=0.0, ge=0.0)


class Tracking(BaseModel):
    """Follow a prescribed passive motion exactly (equality) or in least squares (weight)."""

    model_config = _STRICT

    motion: PassiveMotion
    mode: Literal["exact", "weighted"] = "exact"
    weight: float = Field(default=100.0, gt=0.0, description="weight of int |q_p - q_ref|^2 dt")


class TipTarget(BaseModel):
    """Position [m] that the last link's tip must reach at the final time."""

    model_config = _STRICT

    x: float
    y: float


class Bounds(BaseModel):
    """Per-joint lower and upper bounds (None: unbounded)."""

    model_config = _STRICT

    lower: list[float | None]
    upper: list[float | None]

    @model_validator(mode="after")
    def _ordered(self) -> Bounds:
        for k, (lo, hi) in enumerate(zip(self.lower, self.upper, strict=False)):
            if lo is not None and hi is not None and lo > hi:
                raise ValueError(f"lower.{k}: must not exceed upper.{k} ({lo:g} > {hi:g})")
        return self


class WaveCoDesign(BaseModel):
    """Let the planner choose the active joints' wave amplitudes and phases (frequency fixed)."""

    model_config = _STRICT

    amplitude_max: float = Field(gt=0.0, description="upper bound on every amplitude [m]")
    frequency: list[float] = Field(description="fixed frequency of each active joint's wave")


class Uncertainty(BaseModel):
    """Relative errors of the robot's numbers that a plan should cope with: every link's
    mass, inertia and length and every wave's amplitude may be off by up to this share
    (docs/planner.md, "Robustness to model error")."""

    model_config = _STRICT

    mass: float = Field(default=0.0, ge=0.0, le=0.5, description="relative error of the masses")
    inertia: float = Field(default=0.0, ge=0.0, le=0.5,
                           description="relative error of the inertias")
    length: float = Field(default=0.0, ge=0.0, le=0.2,
                          description="relative error of the lengths")
    amplitude: float = Field(default=0.0, ge=0.0, le=0.5,
                             description="relative error of the wave amplitudes")


class Task(BaseModel):
    """What the motion must do and what it costs."""

    model_config = _STRICT

    duration: float | DurationRange = Field(
        description=f"fixed T [s] or bounds of a free T, each within [{DURATION_MIN:g}, "
                    f"{DURATION_MAX:g}] s")
    initial: JointState = Field(description="the state at t = 0, one entry per joint")
    final: State
    tracking: Tracking | None = None
    tip_target: TipTarget | None = None
    torque_limit: list[float] | float | None = Field(
        default=None, description=f"|tau| bound [N m] in [0, {TORQUE_MAX:g}], per active joint "
                                  "or one for all; held "
                                  "by the delivered torque polynomial on the whole of every "
                                  "interval, not only at its nodes")
    position_bounds: Bounds | None = Field(
        default=None, description="[rad] bounds on the planned angles, held on the whole of "
                                  "every interval")
    velocity_bounds: Bounds | None = Field(
        default=None, description="[rad/s] bounds on the planned rates, held on the whole of "
                                  "every interval")
    objective: Objective = Objective()
    coupling_margin: float | None = Field(
        default=None, ge=MARGIN_MIN, le=MARGIN_MAX,
        description="[kg m^2] sigma_min(M_pa) >= margin along the path")
    co_design: WaveCoDesign | None = None
    uncertainty: Uncertainty | None = Field(
        default=None, description="model errors the plan's verification replays its "
                                  "feedback under (verification.robustness)")

    @property
    def duration_span(self) -> tuple[float, float]:
        """[s] The shortest and the longest duration allowed (equal for a fixed one)."""
        d = self.duration
        return (d.min, d.max) if isinstance(d, DurationRange) else (float(d), float(d))

    @model_validator(mode="after")
    def _positive(self) -> Task:
        if isinstance(self.duration, float) and not \
                DURATION_MIN <= self.duration <= DURATION_MAX:
            raise ValueError(f"duration: must be within [{DURATION_MIN:g}, {DURATION_MAX:g}] s "
                             f"(got {self.duration:g})")
        limits = self.torque_limit if isinstance(self.torque_limit, list) else [self.torque_limit]
        for k, limit in enumerate(limits):
            where = f".{k}" if isinstance(self.torque_limit, list) else ""
            if limit is not None and limit < 0.0:
                raise ValueError(f"torque_limit{where}: must not be negative (got {limit:g} N m)")
            if limit is not None and limit > TORQUE_MAX:
                raise ValueError(f"torque_limit{where}: must be at most {TORQUE_MAX:g} N m "
                                 f"(got {limit:g} N m)")
        return self


Method = Literal["trapezoidal", "hermite-simpson", "legendre", "radau", "multiple-shooting"]


class Refinement(BaseModel):
    """Error-controlled mesh refinement: while an interval of the plan, re-integrated from
    the plan's own state with its torque, departs from it by more than
    solver.resimulation_tolerance, the intervals where the error is are cut and the NLP
    solved again, starting at the previous plan."""

    model_config = _STRICT

    enabled: bool = True
    max_passes: int = Field(default=6, ge=0, le=20, description="refined solves after the first")
    max_intervals: int = Field(default=400, ge=1, le=5000,
                               description="intervals a refined mesh may have at most")


class Transcription(BaseModel):
    """How the continuous problem becomes an NLP.

    The default, Legendre degree 3 on 50 intervals, converged on both underactuated
    benchmark scenes where degree 5 on 40 did not reach the same optimum; a fully actuated
    arm gets more accuracy per second from degree 5 (docs/planner.md, "Choosing a
    transcription").
    """

    model_config = _STRICT

    method: Method = "legendre"
    intervals: int = Field(default=50, ge=1, le=5000)
    degree: int = Field(default=3, ge=1, le=9, description="collocation degree (legendre, radau)")
    integrator: Literal["rk4", "cvodes"] = Field(
        default="rk4", description="multiple shooting's integrator")
    steps: int = Field(default=4, ge=1, le=100, description="RK4 steps per shooting interval")
    form: Literal["implicit", "explicit"] = Field(
        default="implicit", description="implicit: ddq are variables with M ddq + h = B tau")
    breaks: list[float] | None = Field(
        default=None, description="the first mesh's breakpoints as fractions of the duration, "
                                  "intervals + 1 strictly increasing values from 0 to 1 "
                                  "(default: equal intervals)")
    refinement: Refinement = Refinement()

    @model_validator(mode="after")
    def _mesh(self) -> Transcription:
        b = self.breaks
        if b is None:
            return self
        if len(b) != self.intervals + 1:
            raise ValueError(f"breaks: needs intervals + 1 = {self.intervals + 1} values "
                             f"(got {len(b)})")
        if b[0] != 0.0 or b[-1] != 1.0 or any(y <= x for x, y in pairwise(b)):
            raise ValueError("breaks: must increase strictly from 0 to 1")
        return self


class SolverSettings(BaseModel):
    """The NLP solver and its settings."""

    model_config = _STRICT

    name: Literal["ipopt", "fatrop"] = Field(
        default="ipopt",
        description="ipopt: interior point with a sparse direct linear solver (MUMPS); "
                    "fatrop: interior point that factors the KKT system stage by stage "
                    "(legendre, radau and multiple-shooting with rk4 on a fixed duration "
                    "without co-design; no progress reports or cancellation within a solve; "
                    "docs/planner.md, \"Solvers\")")
    max_iter: int = Field(default=500, ge=1, le=100000,
                          description="Ipopt iterations of one solve (a plan may run several: "
                                      "mesh passes, retries)")
    tol: float = Field(default=1e-8, ge=1e-12, le=1.0,
                       description="the NLP solver's convergence tolerance")
    max_wall_time: float = Field(default=60.0, gt=0.0,
                                 description="[s] the whole plan: every solve, mesh pass and "
                                             "retry")
    initial_guess: Literal["interpolation", "inverse-dynamics"] = Field(
        default="interpolation",
        description="interpolation: cubic from the initial to the final state, torques from "
                    "the active rows; inverse-dynamics: the classical inverse dynamics along "
                    "that passive path until it meets sigma_min(M_pa) = coupling margin (1e-3 "
                    "without one), the interpolation after")
    jit: bool = Field(default=True, description="compile the NLP's derivative kernels and the "
                                                "verification's dynamics to C (once per "
                                                "structure, cached on disk, built in the "
                                                "background: the plans before the build "
                                                "ends run interpreted)")
    warm_start: str | None = Field(
        default=None, max_length=64,
        description="the service's id of an earlier plan job to start from, or \"nearest\": "
                    "the nearest of the service's latest succeeded plans of the same joints "
                    "(docs/planner.md, \"Memory of motion\"; a cold start when none is "
                    "near). The same problem on a mesh at least as fine starts from its NLP "
                    "solution, primal and dual (a goal moved a little converges in a few "
                    "iterations); otherwise its trajectory is the initial guess. The "
                    "library's plan() takes the earlier Plan itself (warm_start=)")
    retries: int = Field(default=4, ge=0, le=4,
                         description="further attempts after one that gives no accurate plan: "
                                     "a restart from its last iterate, the inverse dynamics "
                                     "as initial guess, a first mesh of twice and of half "
                                     "the intervals (docs/planner.md, \"Retries\")")
    robustness: float | None = Field(
        default=None, gt=0.0,
        description="[rad] with task.uncertainty: the largest closed-loop tracking error "
                    "a verified plan may have on the uncertainty's corner models (none: "
                    "reported, not required)")
    resimulation_tolerance: float = Field(
        default=1e-3, ge=1e-9, le=1.0,
        description="[rad] largest error of a verified plan when each interval is "
                    "re-integrated from the plan's own state with the delivered torque: above "
                    "it the NLP's trajectory is not a motion of the robot (too coarse a mesh "
                    "for it), and the mesh refinement goes on; at least 1e-9 rad, above the "
                    "re-integration's own error (CVODES at 1e-10)")


class Scene(BaseModel):
    """A robot, a task, a transcription and solver settings."""

    model_config = _STRICT

    robot: Robot
    task: Task
    transcription: Transcription = Transcription()
    solver: SolverSettings = SolverSettings()

    @model_validator(mode="after")
    def _sizes_agree(self) -> Scene:
        n, na = self.robot.n, len(self.robot.active)
        task = self.task
        for name, state in (("initial", task.initial), ("final", task.final)):
            for field in ("q", "dq"):
                if len(getattr(state, field)) != n:
                    raise ValueError(f"task.{name}.{field}: needs {n} entries, one per joint")
        if isinstance(task.torque_limit, list) and len(task.torque_limit) != na:
            raise ValueError(f"task.torque_limit: needs {na} entries, one per active joint")
        for name in ("position_bounds", "velocity_bounds"):
            bounds = getattr(task, name)
            if bounds is not None and (len(bounds.lower) != n or len(bounds.upper) != n):
                raise ValueError(f"task.{name}: lower and upper need {n} entries each")
        if task.co_design is not None and len(task.co_design.frequency) != na:
            raise ValueError(f"task.co_design.frequency: needs {na} entries, one per active joint")
        if task.tracking is not None and isinstance(task.duration, DurationRange):
            raise ValueError("task.tracking: a prescribed motion needs a fixed duration")
        tr = self.transcription
        if self.solver.name == "fatrop" and (
                tr.method not in ("legendre", "radau", "multiple-shooting")
                or tr.method == "multiple-shooting" and tr.integrator == "cvodes"
                or isinstance(task.duration, DurationRange) or task.co_design is not None):
            raise ValueError("solver.name: 'fatrop' needs a transcription whose stages close "
                             "their gaps explicitly (legendre, radau, or multiple-shooting "
                             "with rk4), a fixed duration and no wave co-design")
        if self.solver.initial_guess == "inverse-dynamics":
            n_p = len(self.robot.passive)
            if n_p == 0 or na < n_p:
                raise ValueError("solver.initial_guess: 'inverse-dynamics' needs a robot with "
                                 "passive joints and at least as many active joints")
        return self
