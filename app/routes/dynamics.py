"""Synchronous computations: dynamics at states, coupling analysis, wave design, inverse
dynamics, forward simulation. Each runs in a worker thread, bounded by the compute limiter."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Body

from app.deps import LimiterDep, SettingsDep
from app.routes._compute import compute
from app.schema_examples import body_examples
from planner import coupling, evaluation, inverse, simulate, waves

router = APIRouter(prefix="/v1", tags=["dynamics"])

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
                   limiter: LimiterDep) -> evaluation.DynamicsResponse:
    return await compute(evaluation.evaluate, request, settings, limiter)


@router.post("/coupling", summary="det, sigma_min and condition of M_pa; singular points")
async def coupling_analysis(request: CouplingBody, settings: SettingsDep,
                            limiter: LimiterDep) -> coupling.CouplingReport:
    return await compute(coupling.analyse, request, settings, limiter)


@router.post("/waves/design",
             summary="Waves that keep sigma_min(M_pa) >= margin over a region or a motion")
async def wave_design(request: WaveBody, settings: SettingsDep,
                      limiter: LimiterDep) -> waves.WaveDesignResult:
    return await compute(waves.design, request, settings, limiter)


@router.post("/inverse-dynamics",
             summary="Classical inverse dynamics of a prescribed passive motion")
async def inverse_dynamics(request: InverseBody, settings: SettingsDep,
                           limiter: LimiterDep) -> inverse.InverseDynamicsResult:
    return await compute(inverse.solve, request, settings, limiter)


@router.post("/simulate", summary="Forward simulation of given torques (CVODES)")
async def simulation(request: SimulationBody, settings: SettingsDep,
                     limiter: LimiterDep) -> simulate.Trajectory:
    return await compute(simulate.run, request, settings, limiter)
