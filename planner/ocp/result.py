"""What a plan returns: trajectories, the delivered torque, solver report, mesh history and
independent verification (SI units)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from pydantic import Field
from pydantic.json_schema import SkipJsonSchema

from planner.coupling_block import along
from planner.dynamics import Dynamics
from planner.errors import InputError
from planner.model import Robot, Wave
from planner.ocp.evidence import Infeasibility
from planner.ocp.interpolant import PiecewisePolynomial
from planner.ocp.output import Out
from planner.ocp.transcription import Interpolant
from planner.ocp.verdict import PlanStatus
from planner.ocp.verification import Feedback, Verification
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


def waves_of(robot: Robot) -> list[WaveOut]:
    """The waves of the robot's joints, in joint order."""
    return [WaveOut(joint=j, amplitude=link.wave.amplitude, frequency=link.wave.frequency,
                    phase=link.wave.phase)
            for j, link in enumerate(robot.links) if link.wave is not None]


class DenseTrajectory(Out):
    """The transcription's interpolant sampled finely: times [s], angles [rad], torques [N m]."""

    t: list[float]
    q: list[list[float]]
    tau: list[list[float]]


class SolverReport(Out):
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
    checks_time: float | None = Field(
        default=None, description=(
            "[s] wall time from the end of the plan's last solve to the plan: that solve's "
            "interval errors and open-loop replay, the verification with the feedback, its "
            "closed-loop replays and the robustness, and assembling the plan, in the process "
            "that solved it (None: no solve ran, or a plan stored before the field existed)"))
    checks_cpu_time: float | None = Field(
        default=None, description="[s] the CPU time of that process over the same span")
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


class MeshPass(Out):
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
        description="[rad] whole-horizon open-loop replay error of this solve's plan: the "
                    "plan's reported solve only (Verification.resimulation_error), None for "
                    "the others")
    time: float = Field(description="[s] wall time of the solve and its error estimate")
    margin_reserve: float | None = Field(
        default=None, description=(
            "the relative reserve above task.coupling_margin that this solve held at its "
            "knots, after an earlier plan's margin dipped between them (docs/planner.md, "
            "\"Margin reserve\"); None: the task's margin itself"))


class WaveOut(Out):
    """A wave of the plan's robot (designed when the task asked for co-design)."""

    joint: int
    amplitude: float
    frequency: float
    phase: float


class NlpSolution(Out):
    """The NLP solution behind a plan: the problem it solved (`fingerprint`), its mesh
    (breakpoints as fractions of the duration), its variables and multipliers. A later
    plan of the same problem on the same mesh starts from it, primal and dual."""

    fingerprint: str
    breaks: list[float]
    x: list[float]
    lam_x: list[float]
    lam_g: list[float]


class StatePolynomials(Out):
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


class PlanSample(Out):
    """A plan evaluated at given times, time-major."""

    t: list[float] = Field(description="the times asked for [s]")
    q: list[list[float]] = Field(description="angles [rad]")
    dq: list[list[float]] = Field(description="rates [rad/s]")
    tau: list[list[float]] = Field(description="the delivered torque of the active joints [N m]")
    tip: list[list[float]] = Field(description="the last link's tip [x, y] [m]")
    sigma_min: list[float | None] = Field(
        description="sigma_min(M_pa) [kg m^2], the smallest singular value (as in "
                    "verification.sigma_min); null without a passive joint")


class Plan(Out):
    """A plan: nodes (time-major), dense samples, the delivered torque, objective, solver
    report, mesh history, feedback and verification."""

    status: PlanStatus | None = Field(
        default=None,
        description="what happened to the plan: verified (converged, and every check passed: "
                    "the task is done), unverified (converged, but a check failed: "
                    "`message`, `verification`), infeasible (with evidence: "
                    "`infeasibility`), out-of-budget (no converged plan within "
                    "solver.max_iter or max_wall_time), solver-failure (no converged plan "
                    "for another reason) or cancelled; `solver.status` is the last solve's "
                    "own status beneath it. None in plans stored before the field existed")
    message: str | None = Field(
        default=None, description="one sentence on the status: why a plan is not verified, "
                                  "or the infeasibility's summary")
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
