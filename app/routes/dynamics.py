"""Synchronous computations: dynamics at states, coupling analysis, wave design, inverse
dynamics, forward simulation. Each runs in a worker thread within its time budget
(`app.routes._compute`)."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Body

from app.deps import SettingsDep
from app.openapi import BUDGET, problems
from app.routes._compute import LanesDep, compute
from app.schema_examples import body_examples
from planner import coupling, evaluation, inverse, simulate, waves

router = APIRouter(prefix="/v1", tags=["dynamics"], responses=problems(422, 503, s422=BUDGET))

DynamicsBody = Annotated[evaluation.DynamicsRequest,
                         Body(openapi_examples=body_examples("dynamics"))]
CouplingBody = Annotated[coupling.CouplingRequest, Body(openapi_examples=body_examples("coupling"))]
WaveBody = Annotated[waves.WaveDesignRequest, Body(openapi_examples=body_examples("wave-design"))]
InverseBody = Annotated[inverse.InverseDynamicsRequest,
                        Body(openapi_examples=body_examples("inverse-dynamics"))]
SimulationBody = Annotated[simulate.SimulationRequest,
                           Body(openapi_examples=body_examples("simulate"))]


@router.post("/dynamics", summary="M, h, gravity, energies, tips and coupling at given states")
async def dynamics(request: DynamicsBody, settings: SettingsDep,
                   lanes: LanesDep) -> evaluation.DynamicsResponse:
    return await compute(evaluation.evaluate, request, settings, lanes, quick=True)


@router.post("/coupling", summary="det, sigma_min and condition of M_pa; singular points")
async def coupling_analysis(request: CouplingBody, settings: SettingsDep,
                            lanes: LanesDep) -> coupling.CouplingReport:
    return await compute(coupling.analyse, request, settings, lanes, quick=True)


@router.post("/waves/design",
             summary="Waves that keep sigma_min(M_pa) >= margin over a region or a motion")
async def wave_design(request: WaveBody, settings: SettingsDep,
                      lanes: LanesDep) -> waves.WaveDesignResult:
    return await compute(waves.design, request, settings, lanes)


@router.post("/inverse-dynamics",
             summary="Classical inverse dynamics of a prescribed passive motion")
async def inverse_dynamics(request: InverseBody, settings: SettingsDep,
                           lanes: LanesDep) -> inverse.InverseDynamicsResult:
    return await compute(inverse.solve, request, settings, lanes)


@router.post("/simulate", summary="Forward simulation of given torques (CVODES)")
async def simulation(request: SimulationBody, settings: SettingsDep,
                     lanes: LanesDep) -> simulate.Trajectory:
    return await compute(simulate.run, request, settings, lanes)
