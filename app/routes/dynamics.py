"""Synchronous computations: dynamics at states, forward simulation."""

from __future__ import annotations

from fastapi import APIRouter

from app.deps import LimiterDep, SettingsDep
from app.routes._compute import compute
from planner import evaluation, simulate

router = APIRouter(prefix="/v1", tags=["dynamics"])


@router.post("/dynamics", summary="M, h, gravity, energies, tips and coupling at given states")
async def dynamics(request: evaluation.DynamicsRequest, settings: SettingsDep,
                   limiter: LimiterDep) -> evaluation.DynamicsResponse:
    return await compute(evaluation.evaluate, request, settings, limiter)


@router.post("/simulate", summary="Forward simulation of given torques (CVODES)")
async def simulation(request: simulate.SimulationRequest, settings: SettingsDep,
                     limiter: LimiterDep) -> simulate.Trajectory:
    return await compute(simulate.run, request, settings, limiter)
