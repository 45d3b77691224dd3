"""What a plan's checks found (`Verification`), and the feedback they computed along it."""

from __future__ import annotations

from pydantic import Field

from planner.certify.decision import CouplingCertificate
from planner.ocp.output import Out
from planner.scene import Uncertainty


class Crossing(Out):
    """A configuration of the plan that is singular for the same robot without waves."""

    time: float
    q: list[float]
    sigma_min: float = Field(description="sigma_min of the waveless M_pa there")


class Feedback(Out):
    """A time-varying LQR tracking feedback along the plan, applied at the breakpoints:
    on interval k the torque is tau(t) - K_k (x(t_k) - x_plan(t_k)), x = (q, dq)."""

    gains: list[list[list[float]]] = Field(
        description="K_k for every interval k: n_active x 2n [N m/rad, N m s/rad]")
    state_weights: list[float] = Field(description="diagonal of Q, per (q, dq) entry")
    torque_weights: list[float] = Field(description="diagonal of R, per active joint")


class Robustness(Out):
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
    largest_torque: float | None = Field(
        default=None, description="[N m] the largest torque the plan with its feedback "
                                  "commands on the models (before the actuators' saturation "
                                  "at task.torque_limit, which the replays apply); None in "
                                  "plans stored before the field existed")
    saturated: bool | None = Field(
        default=None, description="the feedback asked for more than task.torque_limit on "
                                  "some model, and the actuators saturated there (None "
                                  "without a limit)")
    bound: float | None = Field(description="[rad] solver.robustness, if set")
    within: bool | None = Field(description="worst_tracking_error within bound (None "
                                            "without a bound)")


class MarginCertificate(CouplingCertificate):
    """The coupling margin proven on whole intervals of the plan (ball arithmetic on M_pa
    along each interval's polynomial; docs/planner.md, "The margin on whole intervals"):
    the target is task.coupling_margin (1 - 1e-3), undecided where an interval's bound
    stayed below it within its boxes or the budget."""

    unproven_intervals: list[int] = Field(description="the intervals without the proof")


class Verification(Out):
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
        description="the delivered plan does the task: its last solve converged "
                    "(`converged`), local_error is at most `tolerance` (the delivered torque "
                    "moves the robot along the plan, interval by interval), it keeps the "
                    "task's limits everywhere (`limit_violations` is empty) and meets every "
                    "other requirement of the task (`task_violations` is empty: states, tip "
                    "target, duration, coupling margin, prescribed motion), and, with "
                    "solver.robustness, its feedback keeps to that bound. None in plans "
                    "stored before the field existed")
    converged: bool | None = Field(
        default=None, description="the solve of the plan's iterate converged "
                                  "(solver.success); None in plans stored before the field "
                                  "existed")
    initial_error: float | None = Field(
        default=None, description="[rad, rad/s] the largest departure of the plan's "
                                  "initial angles and rates from task.initial; beyond 1e-6 x "
                                  "max(1, |value|) the plan is not verified")
    final_error: float | None = Field(
        default=None, description="[rad, rad/s] the same for the given (non-null) entries "
                                  "of task.final (None: all are free)")
    tip_error: float | None = Field(
        default=None, description="[m] the distance of the plan's final tip from "
                                  "task.tip_target (None without one); beyond 1e-6 m the "
                                  "plan is not verified")
    duration_excess: float | None = Field(
        default=None, description="[s] how far the plan's duration lies outside "
                                  "task.duration (0 within it)")
    margin_shortfall: float | None = Field(
        default=None, description="[kg m^2] how far sigma_min(M_pa) falls below "
                                  "task.coupling_margin at the dense samples (0: kept; None "
                                  "without a margin); beyond 1e-3 of the margin (relative) the "
                                  "plan is not verified")
    margin_certificate: MarginCertificate | None = Field(
        default=None, description="the coupling margin proven on every interval (None "
                                  "without a margin or passive joints, or in plans stored "
                                  "before the field existed); a plan is verified only when "
                                  "it is certified")
    tracking_error: float | None = Field(
        default=None, description="[rad] the largest departure of the passive angles from "
                                  "an exact task.tracking motion at the dense samples (None "
                                  "without one); beyond `tolerance` the plan is not verified")
    task_violations: list[str] = Field(
        default_factory=list,
        description="every requirement of the task, other than its limits, that the plan "
                    "does not meet, in words; empty when it meets them all")
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
