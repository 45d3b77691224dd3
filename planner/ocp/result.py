"""What a plan returns: trajectories, solver report and independent verification (SI units)."""

from __future__ import annotations

from dataclasses import dataclass

from pydantic import BaseModel, ConfigDict, Field


@dataclass(frozen=True)
class Progress:
    """One Ipopt iteration: its number (counting restoration-phase iterations, which
    `SolverReport.iterations` leaves out), objective, primal infeasibility, dual
    infeasibility (None: the interface does not report it), wall time since the start [s]."""

    iteration: int
    objective: float
    inf_pr: float
    inf_du: float | None
    elapsed: float


class _Out(BaseModel):
    model_config = ConfigDict(frozen=True)


class DenseTrajectory(_Out):
    """The transcription's own interpolant sampled finely: times [s], angles [rad], torques [N m]."""

    t: list[float]
    q: list[list[float]]
    tau: list[list[float]]


class SolverReport(_Out):
    """Ipopt's verdict and the cost of getting it."""

    status: str = Field(description="Ipopt's return status, e.g. Solve_Succeeded")
    success: bool
    message: str
    iterations: int
    build_time: float = Field(description="[s] building the NLP; 0 when reused from the cache")
    solve_time: float = Field(description="[s] Ipopt wall time")
    cache_hit: bool = Field(description="the NLP of this scene structure was already built")
    initial_guess: str = Field(
        default="not recorded",
        description="where Ipopt started: interpolation, inverse-dynamics or warm start; "
                    "an inverse dynamics that could not be computed says why, and the "
                    "interpolation was used instead ('not recorded' in plans stored before "
                    "the field existed)")


class Crossing(_Out):
    """A configuration of the plan that is singular for the same robot without waves."""

    time: float
    q: list[float]
    sigma_min: float = Field(description="sigma_min of the waveless M_pa there")


class Verification(_Out):
    """Checks computed independently of the NLP."""

    resimulation_error: float | None = Field(
        description="max |q_sim - q_plan| [rad] with the planned torque fed to CVODES (rtol 1e-10)")
    resimulation_status: str
    defect: float | None = Field(
        description="integral of |M ddq + h - B tau| [N m s] along the plan's interpolant")
    verified: bool | None = Field(
        default=None,
        description="the re-simulation completed with an error of at most `tolerance`: the "
                    "planned torque moves the robot along the plan (None in plans stored "
                    "before the field existed)")
    tolerance: float | None = Field(
        default=None, description="[rad] the scene's solver.resimulation_tolerance")
    min_sigma: float | None = Field(description="min sigma_min(M_pa) along the plan")
    waveless_min_sigma: float | None = Field(
        description="min sigma_min(M_pa) along the plan for the robot without waves")
    waveless_singular_crossings: list[Crossing]


class WaveOut(_Out):
    """A wave of the plan's robot (designed when the task asked for co-design)."""

    joint: int
    amplitude: float
    frequency: float
    phase: float


class Plan(_Out):
    """A plan: nodes (time-major), dense samples, objective, solver report, verification."""

    t: list[float]
    q: list[list[float]]
    dq: list[list[float]]
    ddq: list[list[float]]
    tau: list[list[float]] = Field(description="active joints' torques at each node [N m]")
    dense: DenseTrajectory
    duration: float
    objective: float
    waves: list[WaveOut]
    solver: SolverReport
    verification: Verification
