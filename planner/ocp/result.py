"""What a plan returns: trajectories, the delivered torque, solver report, mesh history and
independent verification (SI units)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from pydantic.json_schema import SkipJsonSchema

from planner.coupling_block import along
from planner.dynamics import Dynamics
from planner.errors import InputError
from planner.model import Robot, Wave
from planner.ocp.interpolant import PiecewisePolynomial
from planner.ocp.transcription import Interpolant
from planner.scene import Uncertainty
from planner.torque import TorquePolynomial

MAX_SAMPLE_TIMES = 1000
"""The most times one `Plan.sample` call evaluates."""


@dataclass(frozen=True)
class Progress:
    """One Ipopt iteration: the plan's iteration count so far (Ipopt's own count, summed
    over the plan's solves), objective, primal and dual infeasibility (None: not reported),
    wall time since the plan started [s], and the mesh pass the solve belongs to (0: the
    first mesh)."""

    iteration: int
    objective: float
    inf_pr: float
    inf_du: float | None
    elapsed: float
    mesh_pass: int = 0


class _Out(BaseModel):
    model_config = ConfigDict(frozen=True)


class DenseTrajectory(_Out):
    """The transcription's interpolant sampled finely: times [s], angles [rad], torques [N m]."""

    t: list[float]
    q: list[list[float]]
    tau: list[list[float]]


class SolverReport(_Out):
    """Ipopt's verdict and the cost of getting it."""

    status: str = Field(description="Ipopt's return status of the last solve, e.g. "
                                    "Solve_Succeeded")
    success: bool
    message: str
    iterations: int = Field(description="Ipopt iterations, summed over the plan's solves")
    build_time: float = Field(description="[s] building NLPs; 0 when all came from the cache")
    solve_time: float = Field(description="[s] Ipopt wall time, summed over the plan's solves")
    total_time: float | None = Field(
        default=None, description="[s] the whole plan: building, solves, error estimates, "
                                  "verification (None in plans stored before the field existed)")
    cache_hit: bool = Field(description="the NLP of the first mesh was already built")
    compiled: bool = Field(default=False, description=(
        "the first solve's derivative kernels ran compiled to C (solver.jit, once the "
        "structure's library is built: the first plans of a structure run interpreted while "
        "it is built in the background)"))
    initial_guess: str = Field(
        default="not recorded",
        description="where Ipopt started: interpolation, inverse-dynamics or warm start; "
                    "an inverse dynamics that could not be computed says why, and the "
                    "interpolation was used instead ('not recorded' in plans stored before "
                    "the field existed)")
    warm_start: str | None = Field(
        default=None,
        description="the service's id of the plan job it was given to start from "
                    "(solver.warm_start, or the nearest one found for \"nearest\"); None "
                    "for a cold start")
    warm_start_distance: float | None = Field(
        default=None,
        description="[rad] with solver.warm_start \"nearest\": how far that plan's scene is "
                    "from this one (planner.memory.distance)")
    strategy: str = Field(
        default="not recorded",
        description="what produced the plan: 'direct' (one solve), 'refined' (mesh "
                    "refinement after the first solve), or a retry named after what it "
                    "changed ('not recorded' in plans stored before the field existed)")


class MeshPass(_Out):
    """One solve of the plan on one mesh."""

    strategy: str = Field(default="direct", description="the attempt it belongs to (see "
                                                        "SolverReport.strategy)")
    intervals: int
    iterations: int = Field(description="Ipopt iterations of this solve")
    status: str = Field(description="Ipopt's return status")
    objective: float | None = Field(description="the objective of this solve's plan")
    max_local_error: float | None = Field(
        description="[rad] largest interval error of this solve's plan (see "
                    "Verification.local_error); None where it could not be computed")
    resimulation_error: float | None = Field(
        description="[rad] whole-horizon open-loop replay error of this solve's plan")
    time: float = Field(description="[s] wall time of the solve and its error estimate")


class Crossing(_Out):
    """A configuration of the plan that is singular for the same robot without waves."""

    time: float
    q: list[float]
    sigma_min: float = Field(description="sigma_min of the waveless M_pa there")


class Feedback(_Out):
    """A time-varying LQR tracking feedback along the plan, applied at the breakpoints:
    on interval k the torque is tau(t) - K_k (x(t_k) - x_plan(t_k)), x = (q, dq)."""

    gains: list[list[list[float]]] = Field(
        description="K_k for every interval k: n_active x 2n [N m/rad, N m s/rad]")
    state_weights: list[float] = Field(description="diagonal of Q, per (q, dq) entry")
    torque_weights: list[float] = Field(description="diagonal of R, per active joint")


class Robustness(_Out):
    """The plan with its feedback replayed on perturbed models of the robot (the corners of
    task.uncertainty; docs/planner.md, "Robustness to model error")."""

    uncertainty: Uncertainty
    models: int = Field(description="perturbed models replayed")
    worst_tracking_error: float | None = Field(
        description="[rad] the largest |q_sim - q_plan| along the horizon over the models, "
                    "closed loop from the planned initial state (None: a replay diverged)")
    worst_final_error: float | None = Field(
        description="[rad, rad/s] the largest |q - q_goal|, |dq - dq_goal| at the end over "
                    "the models (None: a replay diverged)")
    open_loop_final_error: float | None = Field(
        default=None, description="[rad, rad/s] the same for the delivered torque alone, "
                                  "without the feedback (None: a replay diverged, or a plan "
                                  "stored before the field existed)")
    worst_model: str = Field(description="the model of the worst tracking error, e.g. "
                                         "\"mass+ length-\"")
    bound: float | None = Field(description="[rad] solver.robustness, if set")
    within: bool | None = Field(description="worst_tracking_error within bound (None "
                                            "without a bound)")


class Verification(_Out):
    """Checks computed independently of the NLP."""

    local_error: float | None = Field(
        default=None,
        description="[rad] accuracy: every interval re-integrated by CVODES (rtol 1e-10) "
                    "from the plan's own state at its start with the delivered torque; the "
                    "largest departure from the plan, max(|q_sim - q_plan|, h |dq_sim - "
                    "dq_plan|) over the interval (h its length). None in plans stored "
                    "before the field existed")
    interval_errors: list[float | None] = Field(
        default_factory=list,
        description="[rad] that error on every interval (None where CVODES failed)")
    local_status: str = Field(
        default="not recorded",
        description='"completed", or on which intervals CVODES failed')
    verified: bool | None = Field(
        default=None,
        description="local_error is at most `tolerance` (the delivered torque moves the "
                    "robot along the plan, interval by interval) and the plan keeps the "
                    "task's limits everywhere (`limit_violations` is empty). None in plans "
                    "stored before the field existed")
    tolerance: float | None = Field(
        default=None, description="[rad] the scene's solver.resimulation_tolerance")
    resimulation_error: float | None = Field(
        description="[rad] open-loop behaviour: max |q_sim - q_plan| with the delivered "
                    "torque fed to CVODES (rtol 1e-10) from the plan's initial state over "
                    "the whole horizon, at the breakpoints and 3 points between each two "
                    "(a simulation with samples_per_interval 4 gives the same)")
    resimulation_status: str
    growth_factor: float | None = Field(
        default=None,
        description="open-loop sensitivity: the largest ||Phi(t, s)||_2 over breakpoints "
                    "s <= t, Phi the state transition matrix of the dynamics linearised "
                    "along the plan; an error of e at time s grows up to about this factor "
                    "times e (None where Phi overflows)")
    closed_loop_error: float | None = Field(
        default=None,
        description="[rad] replay error with the plan's feedback from the planned initial "
                    "state")
    perturbed_closed_loop_error: float | None = Field(
        default=None,
        description="[rad] the same from the initial state perturbed by `perturbation` "
                    "(every angle and rate)")
    perturbation: float | None = Field(
        default=None, description="[rad, rad/s] the perturbation of every initial angle "
                                  "and rate")
    robustness: Robustness | None = Field(
        default=None, description="the closed loop on perturbed models, where the task "
                                  "states an uncertainty (None: it states none, or the "
                                  "plan has no feedback)")
    skipped: list[str] = Field(
        default_factory=list,
        description="checks that were not run, and why: the closed-loop replays (optional, "
                    "not needed for `verified`) when the plan's wall-time budget had run out "
                    "before them")
    defect: float | None = Field(
        description="integral of |M ddq + h - B tau| [N m s] along the plan's interpolant")
    torque_excess: float | None = Field(
        default=None,
        description="[N m] how far the delivered torque exceeds task.torque_limit anywhere: "
                    "the largest of the dense samples and every interval's exact extrema "
                    "(0 within it; None without a limit). Beyond 1e-6 of the limit (relative) "
                    "the plan is not verified")
    position_excess: float | None = Field(
        default=None,
        description="[rad] how far the planned angles go beyond task.position_bounds "
                    "anywhere, as torque_excess (None without bounds). Beyond 1e-6 x max(1, "
                    "|bound|) the plan is not verified")
    velocity_excess: float | None = Field(
        default=None,
        description="[rad/s] the same for the planned rates and task.velocity_bounds")
    limit_violations: list[str] = Field(
        default_factory=list,
        description="every limit or bound the plan leaves beyond its tolerance: which joint, "
                    "how far, and when; empty when it keeps them all")
    min_sigma: float | None = Field(description="min sigma_min(M_pa) along the plan")
    waveless_min_sigma: float | None = Field(
        description="min sigma_min(M_pa) along the plan for the robot without waves")
    waveless_singular_crossings: list[Crossing]
    sigma_min: list[float | None] = Field(
        default_factory=list,
        description="[kg m^2] sigma_min(M_pa) at every time of dense.t (the smallest "
                    "singular value, which task.coupling_margin bounds); null where it is "
                    "undefined (no passive joint). Empty in plans that could not be "
                    "verified or were stored before the field existed")
    waveless_sigma_min: list[float | None] = Field(
        default_factory=list,
        description="[kg m^2] the same for the robot without waves")


class WaveOut(_Out):
    """A wave of the plan's robot (designed when the task asked for co-design)."""

    joint: int
    amplitude: float
    frequency: float
    phase: float


class ViolatedRows(_Out):
    """The NLP's constraint rows of one kind that the reported iterate violates."""

    kind: str = Field(description="dynamics (collocation and M ddq + h - B tau), continuity "
                                  "(between intervals), torque limit, position bound, "
                                  "velocity bound, coupling margin or tip target")
    rows: int = Field(description="rows of this kind violated beyond 1e-6")
    largest: float = Field(description="the largest violation, in the rows' own units "
                                       "(N m for dynamics and limits, rad, rad/s, kg m^2, m)")
    time: float = Field(description="[s] where the largest violation is: the start of its "
                                    "interval, or the final time for a row of the final node")


class InfeasibleField(_Out):
    """A field of the task that makes it infeasible, found before any solve."""

    field: str = Field(description='the field, a dotted path in the scene ("task.final.q.1")')
    kind: str = Field(description="the check: bounds, velocity reach, coupling margin, reach, "
                                  "zero torque")
    message: str


class Infeasibility(_Out):
    """Why the planner holds the task infeasible, with its evidence (docs/planner.md,
    "Limits and failures")."""

    source: Literal["checks", "solver", "duration"] = Field(
        description="checks: a check before any solve failed (`fields`; no solve ran); "
                    "solver: two different starts ended with a status saying that the "
                    "constraints cannot all hold; duration: the task's attempts gave no "
                    "converged plan and a time-optimal solve under its limits found a "
                    "verified plan only at a longer duration (`shortest_duration`)")
    summary: str = Field(description="one sentence: what cannot hold, and the evidence")
    fields: list[InfeasibleField] = Field(default_factory=list)
    attempts: list[str] = Field(
        default_factory=list, description="the starts that reported infeasibility, with "
                                          "their status")
    attempt: str | None = Field(
        default=None, description="the most informative of them (the least largest "
                                  "violation), whose iterate the plan is")
    violations: list[ViolatedRows] = Field(
        default_factory=list, description="the violated rows of that iterate by kind, the "
                                          "largest violation first")
    durations: list[float] = Field(
        default_factory=list, description="[s] the durations it covers: [T] for a fixed "
                                          "duration, [min, max] for a duration range")
    shortest_duration: float | None = Field(
        default=None, description="[s] the duration of the verified plan a time-optimal "
                                  "solve under the task's torque limit and velocity bounds "
                                  "found (docs/planner.md, \"Infeasible tasks\"); null when "
                                  "none was found or tried")


class NlpSolution(_Out):
    """The NLP solution behind a plan: the problem it solved (`fingerprint`), its mesh
    (breakpoints as fractions of the duration), its variables and multipliers. A later
    plan of the same problem on the same mesh starts from it, primal and dual."""

    fingerprint: str
    breaks: list[float]
    x: list[float]
    lam_x: list[float]
    lam_g: list[float]


class StatePolynomials(_Out):
    """The plan's angles and rates between its breakpoints, as the transcription
    interpolates them (what the verification re-integrates against): on interval k, with
    s = (t - breaks[k]) / (breaks[k + 1] - breaks[k]) in [0, 1],
    q(t) = sum_m q[k][m] s^m [rad] and dq(t) = sum_m dq[k][m] s^m [rad/s]; at a
    breakpoint the interval starting there applies."""

    breaks: list[float] = Field(description="the mesh's breakpoints [s]")
    q: list[list[list[float]]] = Field(description="K x powers x n: angle coefficients [rad]")
    dq: list[list[list[float]]] = Field(description="K x powers x n: rate coefficients [rad/s]")

    def polynomials(self) -> tuple[PiecewisePolynomial, PiecewisePolynomial]:
        """q and dq as piecewise polynomials."""
        breaks = np.asarray(self.breaks, float)
        return (PiecewisePolynomial(breaks, np.asarray(self.q, float)),
                PiecewisePolynomial(breaks, np.asarray(self.dq, float)))


class PlanSample(_Out):
    """A plan evaluated at given times, time-major."""

    t: list[float] = Field(description="the times asked for [s]")
    q: list[list[float]] = Field(description="angles [rad]")
    dq: list[list[float]] = Field(description="rates [rad/s]")
    tau: list[list[float]] = Field(description="the delivered torque of the active joints [N m]")
    tip: list[list[float]] = Field(description="the last link's tip [x, y] [m]")
    sigma_min: list[float | None] = Field(
        description="sigma_min(M_pa) [kg m^2], the smallest singular value (as in "
                    "verification.sigma_min); null without a passive joint")


class Plan(_Out):
    """A plan: nodes (time-major), dense samples, the delivered torque, objective, solver
    report, mesh history, feedback and verification."""

    t: list[float] = Field(description="the mesh's breakpoints [s]")
    q: list[list[float]]
    dq: list[list[float]]
    ddq: list[list[float]]
    tau: list[list[float]] = Field(description="active joints' torques at each node [N m]")
    dense: DenseTrajectory
    torque: TorquePolynomial | None = Field(
        default=None, description="the delivered torque (None in plans stored before the "
                                  "field existed)")
    states: StatePolynomials | None = Field(
        default=None, description="the angles and rates between the breakpoints (None in "
                                   "plans stored before the field existed)")
    duration: float
    objective: float | None = Field(
        description="the objective at the returned iterate (None where it is not finite)")
    waves: list[WaveOut]
    solver: SolverReport
    mesh_passes: list[MeshPass] = Field(default_factory=list)
    feedback: Feedback | None = None
    verification: Verification
    infeasibility: Infeasibility | None = Field(
        default=None, description="set when the task is infeasible (then the plan is not "
                                  "succeeded): found by the checks before a solve, or by two "
                                  "starts of the solver; null otherwise")
    solution: SkipJsonSchema[NlpSolution | None] = Field(
        default=None, exclude=True,
        description="the NLP solution to warm-start a later plan from; kept apart from the "
                    "plan's JSON")

    def robot_of(self, robot: Robot) -> Robot:
        """The scene's robot carrying the plan's waves (they differ after wave co-design)."""
        waves = {w.joint: Wave(amplitude=w.amplitude, frequency=w.frequency, phase=w.phase)
                 for w in self.waves}
        return robot.with_waves(waves) if waves else robot

    def interpolant(self) -> Interpolant:
        """The plan's angles, rates and delivered torque as piecewise polynomials, exactly
        those its checks ran on; ValueError for a plan without them (refused before a
        solve, or stored before they were)."""
        if self.states is None or self.torque is None:
            raise ValueError("the plan holds no polynomials: no solve ran, or it was stored "
                             "before they were")
        q, dq = self.states.polynomials()
        tau = PiecewisePolynomial(np.asarray(self.torque.breaks, float),
                                  np.asarray(self.torque.coefficients, float))
        return Interpolant(q, dq, tau)

    def sample(self, robot: Robot, times: Sequence[float]) -> PlanSample:
        """The plan at `times` [s] (at most MAX_SAMPLE_TIMES, each within [0, duration]):
        angles and rates from `states`, the delivered torque from `torque`, the last tip
        and sigma_min(M_pa) of `robot` (the scene's; the plan's waves are applied).
        InputError ("t.K: ...") for a time out of range or too many times; ValueError for
        a plan stored before its states were."""
        t = _sample_times(times, self.duration)
        if self.states is None or self.torque is None:
            raise ValueError("the plan was stored before its states were: it cannot be sampled")
        q_of, dq_of = self.states.polynomials()
        q, dq = q_of(t), dq_of(t)
        arm = self.robot_of(robot)
        dynamics = Dynamics(arm)
        tips = [dynamics.tips(row)[-1] for row in q]
        sigma = along(arm, q).least if len(t) else np.zeros(0)
        return PlanSample(t=t.tolist(), q=q.tolist(), dq=dq.tolist(),
                          tau=self.torque.evaluate(t).reshape(len(t), -1).tolist(),
                          tip=np.reshape(tips, (len(t), 2)).tolist(),
                          sigma_min=[None if np.isnan(v) else float(v) for v in sigma])


def _sample_times(times: Sequence[float], duration: float) -> np.ndarray:
    """The times as an array, or InputError naming the first that is out of range."""
    if len(times) > MAX_SAMPLE_TIMES:
        raise InputError(f"t: {len(times)} times exceed the limit of {MAX_SAMPLE_TIMES}")
    t = np.asarray(times, dtype=float).reshape(-1)
    for k, value in enumerate(t):
        if not 0.0 <= value <= duration:
            raise InputError(f"t.{k}: {value:g} s is outside the plan, [0, {duration:g}] s")
    return t
