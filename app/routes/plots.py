"""A plan job's figure (PNG or SVG), drawn by `planner.plots` off the event loop, on a
compute thread and within the synchronous computations' memory budget
(`app.routes._compute`)."""

from __future__ import annotations

from anyio import to_thread
from fastapi import APIRouter, Request, Response

from app.deps import SettingsDep, StoreDep
from app.errors import ApiError
from app.openapi import problems
from app.routes._compute import LanesDep, running
from app.routes.plans import current_plan
from app.store import JobRecord
from app.sync_memory import PLOT_MB
from planner import plots
from planner.service import Scene

router = APIRouter(prefix="/v1/plans", tags=["plans"])

OCTETS = "application/octet-stream"
"""The figure's bytes under a generic type, for a client that asks for it (`Accept`):
generated clients (openapi-python-client) read a binary body only under this type."""
_BINARY = {"schema": {"type": "string", "format": "binary"}}


def _image(fmt: plots.Format) -> dict:
    return {200: {"content": {plots.MEDIA_TYPES[fmt]: _BINARY, OCTETS: _BINARY},
                  "description": "snapshots of the arm, joint angles, torques and "
                                 "sigma_min(M_pa) with and without waves; waveless "
                                 "singular crossings marked"},
            **problems(404, 409, 503)}


def _draw(record: JobRecord | None, job_id: str, fmt: plots.Format) -> bytes:
    if record is None:
        raise ApiError(404, "not-found", "No such plan job", f"there is no plan job {job_id!r}")
    if record.plan is None or not record.plan.get("t"):  # none, or refused before a solve
        why = f" ({record.error})" if record.error else ""
        raise ApiError(409, "no-plan", "The job has no plan yet",
                       f"plan job {job_id!r} is {record.status}{why}; a plot needs its plan")
    plan = current_plan(record, "a plot")
    scene = Scene.model_validate(record.scene)
    return plots.plan_plot(plan, scene.robot, fmt, scene.task)


def _media_type(accept: str, fmt: plots.Format) -> str:
    """The figure's own type, or application/octet-stream when the client accepts that and
    not the figure's type (nor image/*)."""
    own = plots.MEDIA_TYPES[fmt]
    accepted = {part.split(";")[0].strip().lower() for part in accept.split(",")}
    if OCTETS in accepted and not accepted & {own, "image/*", "*/*"}:
        return OCTETS
    return own


async def _plot(request: Request, job_id: str, store: StoreDep, settings: SettingsDep,
                lanes: LanesDep, fmt: plots.Format) -> Response:
    record = await to_thread.run_sync(store.get, job_id)
    async with running(settings, lanes, PLOT_MB):
        body = await to_thread.run_sync(_draw, record, job_id, fmt)
    return Response(body, media_type=_media_type(request.headers.get("accept", ""), fmt))


@router.get("/{job_id}/plot.png", summary="The plan's figure as PNG", response_class=Response,
            responses=_image("png"))
async def plan_plot_png(request: Request, job_id: str, store: StoreDep, settings: SettingsDep,
                        lanes: LanesDep) -> Response:
    return await _plot(request, job_id, store, settings, lanes, "png")


@router.get("/{job_id}/plot.svg", summary="The plan's figure as SVG", response_class=Response,
            responses=_image("svg"))
async def plan_plot_svg(request: Request, job_id: str, store: StoreDep, settings: SettingsDep,
                        lanes: LanesDep) -> Response:
    return await _plot(request, job_id, store, settings, lanes, "svg")
