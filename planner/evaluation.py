"""Dynamics at given states: M, h, gravity term, energies, tips and coupling measures.

Every number in a result is finite; a measure that is undefined at a state (det of a
non-square M_pa, the condition number where sigma_min = 0, sigma_min when there is no
passive joint) is None.
"""

from __future__ import annotations

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from planner import budget
from planner.coupling_block import at
from planner.dynamics import Dynamics
from planner.errors import InputError
from planner.model import Robot
from planner.schema import REQUEST as _STRICT
from planner.schema import JointState

MAX_STATES = 10_000


class StateQuery(JointState):
    """Joint angles q [rad], rates dq [rad/s] and, optionally, accelerations ddq [rad/s^2]."""

    ddq: list[float] | None = None


class DynamicsRequest(BaseModel):
    """A robot and the states at which to evaluate its dynamics."""

    model_config = _STRICT

    robot: Robot
    states: list[StateQuery] = Field(min_length=1, max_length=MAX_STATES)

    @model_validator(mode="after")
    def _sizes(self) -> DynamicsRequest:
        n = self.robot.n
        for k, state in enumerate(self.states):
            for name in ("q", "dq", "ddq"):
                values = getattr(state, name)
                if values is not None and len(values) != n:
                    raise ValueError(f"states.{k}.{name}: needs {n} entries, one per joint")
        return self


class CouplingMeasures(BaseModel):
    """Measures of M_pa: det (square M_pa only), smallest singular value, condition number."""

    model_config = ConfigDict(frozen=True)

    det: float | None
    sigma_min: float | None
    condition: float | None


class DynamicsResult(BaseModel):
    """The dynamics at one state (SI units; vectors per joint, tips per link as [x, y])."""

    model_config = ConfigDict(frozen=True)

    M: list[list[float]] = Field(description="mass matrix [kg m^2], n x n")
    h: list[float] = Field(description="Coriolis, centrifugal and gravity terms [N m]")
    gravity: list[float] = Field(description="gravity term dV/dq [N m]")
    kinetic_energy: float = Field(description="[J]")
    potential_energy: float = Field(description="[J]")
    tips: list[list[float]] = Field(description="tip position [x, y] of every link [m]")
    coupling: CouplingMeasures
    generalized_forces: list[float] | None = Field(
        default=None, description="M ddq + h [N m], when ddq was given")


class DynamicsResponse(BaseModel):
    """One result per requested state, in order."""

    model_config = ConfigDict(frozen=True)

    results: list[DynamicsResult]


def _result(dyn: Dynamics, k: int, state: StateQuery) -> DynamicsResult:
    q, dq = np.asarray(state.q), np.asarray(state.dq)
    M, h, gravity = dyn.mass_matrix(q), dyn.bias(q, dq), dyn.gravity(q)
    T, V = dyn.energy(q, dq)
    tips = dyn.tips(q)
    forces = None if state.ddq is None else dyn.inverse(q, dq, np.asarray(state.ddq))
    arrays = [M, h, gravity, np.array([T, V]), tips] + ([forces] if forces is not None else [])
    if not all(np.all(np.isfinite(a)) for a in arrays):
        raise InputError(f"states.{k}: the dynamics overflow at this state (values too large)")
    c = at(dyn.robot, q, dyn.structure)
    return DynamicsResult(
        M=M.tolist(), h=h.tolist(), gravity=gravity.tolist(), kinetic_energy=T,
        potential_energy=V, tips=tips.tolist(),
        coupling=CouplingMeasures(det=c.det, sigma_min=c.sigma_min, condition=c.condition),
        generalized_forces=None if forces is None else forces.tolist())


def evaluate(request: DynamicsRequest, *, deadline: float | None = None) -> DynamicsResponse:
    """Evaluate the dynamics at every state of a request.

    Raises InputError ("states.k: ...") where a state is so large that a value overflows,
    BudgetExceeded past `deadline` (a `time.monotonic()` value).
    """
    dyn = Dynamics(request.robot)
    results = []
    for k, state in enumerate(request.states):
        budget.check(deadline, f"the dynamics (at state {k} of {len(request.states)})")
        results.append(_result(dyn, k, state))
    return DynamicsResponse(results=results)
