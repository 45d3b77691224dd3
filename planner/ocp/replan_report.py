"""A replanning update as a client sends it (`StateUpdate`) and its answer as the service
returns it (`ReplanReport`): the rest of the motion's delivered torque, the motion it
plans and the LQR gains along it, with what was checked."""

from __future__ import annotations

import numpy as np
from pydantic import BaseModel, Field

from planner.ocp.outcome import finite_or_none
from planner.ocp.output import Out
from planner.ocp.replan import HELD, REALTIME_ITERATIONS, Mode, Replan
from planner.ocp.result import StatePolynomials
from planner.scene import State
from planner.schema import REQUEST, Angle, Rate
from planner.torque import TorquePolynomial

MAX_ITERATIONS = 50
"""The most Ipopt iterations a real-time update may ask for."""


class StateUpdate(BaseModel):
    """The arm's measured state at time t along the plan, and how to replan from it."""

    model_config = REQUEST

    t: float = Field(ge=0.0, description="[s] the time along the plan the state was measured "
                                         "at, before its end")
    q: list[Angle] = Field(description="measured joint angles [rad], one per joint")
    dq: list[Rate] = Field(description="measured joint rates [rad/s], one per joint")
    mode: Mode = Field(default="real-time", description=(
        "real-time: `iterations` Ipopt iterations from the last update's primal and dual "
        "point, a converged solve only where they end beyond the accepted violation; "
        "converged: solved to the scene's tolerance"))
    iterations: int = Field(default=REALTIME_ITERATIONS, ge=1, le=MAX_ITERATIONS,
                            description="Ipopt iterations of a real-time update")
    goal: State | None = Field(default=None, description=(
        "a moved goal, kept from then on (default: the plan's, or the last one moved)"))
    verify: bool = Field(default=False, description=(
        "also re-integrate every interval of the update's motion with its delivered torque"))
    wall_time: float | None = Field(default=None, gt=0.0, description=(
        "[s] the most each solve of the update may take (default and at most: the "
        "server's share of a synchronous computation)"))


class ReplanReport(Out):
    """One update: the rest of the motion from `start` to `end` [s] along the plan, or the
    last plan kept (`fallback`)."""

    start: float = Field(description="[s] the time along the plan the update starts at")
    end: float = Field(description="[s] the plan's end")
    status: str = Field(description=f"the solve's status (Ipopt's; a real-time update ends "
                                    f"Maximum_Iterations_Exceeded by design; {HELD}: in the "
                                    f"final stretch, no solve)")
    success: bool
    iterations: int
    violation: float | None = Field(description=(
        "the largest violation of the NLP's rows and bounds at the returned point [their "
        "units: rad, rad/s, N m]; null when no solve ran, or its point was not finite"))
    checked: list[str] = Field(description="what was checked, in words")
    interval_error: float | None = Field(description=(
        "[rad] the largest interval error when verified, else null"))
    within: bool = Field(description="every check passed")
    escalated: bool = Field(description=(
        "the real-time iterations ended beyond the accepted violation and a converged "
        "solve followed"))
    fallback: bool = Field(description=(
        "nothing replaced the last plan: keep following the last update's torque and gains"))
    torque: TorquePolynomial | None = Field(description=(
        "the delivered torque of the rest of the motion, breakpoints in time along the plan "
        "[s]; null with a fallback"))
    states: StatePolynomials | None = Field(description=(
        "the planned angles and rates of the rest of the motion, on the torque's breakpoints"))
    gains: list[list[list[float]]] | None = Field(description=(
        "LQR gains K_k per interval of the torque, n_active x 2n [N m/rad, N m s/rad]: apply "
        "tau(t) - K_k (x - x_plan(t)) with x = (q, dq) measured, x_plan from `states`"))
    wall_time: float = Field(description="[s] the update's wall time in the library")
    cpu_time: float = Field(description="[s] the update's CPU time in the library")

    @classmethod
    def of(cls, replan: Replan) -> ReplanReport:
        """The report of a library update."""
        torque = states = None
        if replan.interp is not None:
            interp = replan.interp
            breaks = (replan.start + interp.tau.breaks).tolist()
            torque = TorquePolynomial(breaks=breaks,
                                      coefficients=np.asarray(interp.tau.coeffs).tolist())
            states = StatePolynomials(breaks=breaks, q=np.asarray(interp.q.coeffs).tolist(),
                                      dq=np.asarray(interp.dq.coeffs).tolist())
        return cls(start=replan.start, end=replan.end, status=replan.status,
                   success=replan.success, iterations=replan.iterations,
                   violation=None if replan.violation is None else finite_or_none(replan.violation),
                   checked=list(replan.checked),
                   interval_error=replan.interval_error, within=replan.within,
                   escalated=replan.escalated, fallback=replan.fallback, torque=torque,
                   states=states,
                   gains=None if replan.gains is None else replan.gains.tolist(),
                   wall_time=replan.wall, cpu_time=replan.cpu)
