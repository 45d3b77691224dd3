"""Replanning sessions: POST /v1/sessions keeps a finished plan's replanner hot for one
client (`app.sessions`), POST /v1/sessions/{id}/updates replans the rest of the motion from
a measured state, GET reads a session and DELETE frees it. Updates run on a compute thread
within the synchronous computations' memory budget and wall time (`app.routes._compute`)."""

from __future__ import annotations

import time
from typing import Annotated

from anyio import to_thread
from fastapi import APIRouter, Body, Depends, Request, Response
from pydantic import BaseModel, Field

from app import stored_plan
from app.deps import SettingsDep, StoreDep
from app.errors import ApiError, field_error, invalid
from app.openapi import problems
from app.routes._compute import LanesDep, running
from app.sessions import Full, Session, Sessions
from app.settings import Settings
from app.store import JobRecord
from app.sync_memory import SESSION_UPDATE_MB
from planner.errors import InputError
from planner.schema import REQUEST
from planner.service import Plan, Replanner, ReplanReport, Scene, StateUpdate, node_count

router = APIRouter(prefix="/v1/sessions", tags=["sessions"])


def _sessions(request: Request) -> Sessions:
    return request.app.state.sessions


SessionsDep = Annotated[Sessions, Depends(_sessions)]


class SessionRequest(BaseModel):
    """The finished plan to replan, and how."""

    model_config = REQUEST

    plan: str = Field(description="id of a plan job that has its plan")
    intervals: int | None = Field(default=None, ge=2, description=(
        "intervals of every update's motion (default: the plan's scene's)"))
    final_stretch: float | None = Field(default=None, ge=0.0, description=(
        "[s] the last part of the motion in which updates hold the last plan without a "
        "solve (default: 5 % of the plan's duration)"))


class SessionInfo(BaseModel):
    """A live session."""

    id: str
    plan: str = Field(description="the plan job it replans")
    duration: float = Field(description="[s] the plan's duration: updates' times lie before it")
    intervals: int = Field(description="intervals of every update's motion")
    final_stretch: float = Field(description="[s] the final stretch, where updates hold")
    updates: int = Field(description="updates made so far")
    expires_in: float = Field(description="[s] until it is freed unless a request touches it")
    warm_up: ReplanReport | None = Field(default=None, description=(
        "the converged update from the plan's own initial state at t = 0 that built the "
        "session's NLP (only in the answer that opened it)"))

    @classmethod
    def of(cls, session: Session, sessions: Sessions,
           warm_up: ReplanReport | None = None) -> SessionInfo:
        r = session.replanner
        return cls(id=session.id, plan=session.plan_id, duration=r.end, intervals=r.intervals,
                   final_stretch=r.final_stretch, updates=session.updates,
                   expires_in=sessions.expires_in(session), warm_up=warm_up)


def _plan_of(record: JobRecord | None, job_id: str) -> tuple[Scene, Plan]:
    """The scene and plan of the job, or a 422 at `plan` saying why there is none."""
    plan = None if record is None or record.plan is None else stored_plan.current(record.plan)
    if record is None or plan is None:
        why = ("there is no plan job" if record is None else "no plan yet in the job"
               if record.plan is None else "a plan of another schema (plan_schema legacy) in")
        raise invalid([field_error(["body", "plan"], f"{why} {job_id!r}")])
    return Scene.model_validate(record.scene), plan


def _replanner(scene: Scene, plan: Plan, body: SessionRequest,
               settings: Settings) -> Replanner:
    """The replanner of a session, or a 422 at the field that refuses it."""
    nodes = None if body.intervals is None else node_count(scene.transcription, body.intervals)
    if nodes is not None and nodes > settings.max_nodes:
        raise invalid([field_error(["body", "intervals"], (
            f"{body.intervals} intervals hold {nodes} time nodes; this server takes at most "
            f"{settings.max_nodes} (UNDERTOW_MAX_NODES)"))])
    try:
        return Replanner(scene, plan, body.intervals, body.final_stretch)
    except InputError as exc:  # "final_stretch: ..." is the body's field, the rest the plan's
        loc = ["body"] if str(exc).startswith("final_stretch") else ["body", "plan"]
        raise invalid([field_error(loc, str(exc))]) from exc


def _wall(settings: Settings, asked: float | None) -> float:
    """[s] each solve of an update: as asked, within half the synchronous budget (an
    update runs at most two solves)."""
    share = settings.sync_wall_time / 2
    return share if asked is None else min(asked, share)


def _update(session: Session, update: StateUpdate, wall: float) -> ReplanReport:
    """One update on the session (a 409 while another runs), its InputError a 422 at the
    field it names."""
    if not session.lock.acquire(blocking=False):
        raise ApiError(409, "session-busy", "The session is running another update",
                       f"session {session.id!r} runs one update at a time; send the next "
                       "when the last has answered")
    try:
        replan = session.replanner.update(update.t, update.q, update.dq, mode=update.mode,
                                          iterations=update.iterations, goal=update.goal,
                                          verify=update.verify, wall_time=wall)
    except InputError as exc:
        raise invalid([field_error(["body"], str(exc))]) from exc
    finally:
        session.touched = time.monotonic()  # idle from its answer on, not its request
        session.lock.release()
    session.updates += 1
    return ReplanReport.of(replan)


def _warm_up(session: Session, plan: Plan, wall: float) -> ReplanReport:
    """The session's first, converged update from the plan's initial state at t = 0."""
    with session.lock:
        replan = session.replanner.update(0.0, plan.q[0], plan.dq[0], mode="converged",
                                          wall_time=wall)
        session.touched = time.monotonic()
    return ReplanReport.of(replan)


def _found(sessions: Sessions, session_id: str) -> Session:
    session = sessions.get(session_id)
    if session is None:
        raise ApiError(404, "not-found", "No such session",
                       f"there is no session {session_id!r} (it may have expired after "
                       f"{sessions.idle:g} s without a request, UNDERTOW_SESSION_IDLE)")
    return session


@router.post("", status_code=201, summary="Open a replanning session on a finished plan",
             responses=problems(422, 503))
async def open_session(body: Annotated[SessionRequest, Body()], response: Response,
                       store: StoreDep, settings: SettingsDep, lanes: LanesDep,
                       sessions: SessionsDep) -> SessionInfo:
    record = await to_thread.run_sync(store.get, body.plan)
    scene, plan = _plan_of(record, body.plan)
    replanner = _replanner(scene, plan, body, settings)
    try:
        session = sessions.open(body.plan, replanner)
    except Full:
        raise ApiError(503, "sessions-full", "Every session place is taken",
                       f"this server keeps {sessions.limit} sessions at once "
                       f"(UNDERTOW_MAX_SESSIONS); delete one, or retry in "
                       f"{settings.retry_after} s", headers={
                           "Retry-After": str(settings.retry_after)}) from None
    try:
        async with running(settings, lanes, SESSION_UPDATE_MB):
            warm = await to_thread.run_sync(_warm_up, session, plan,
                                            _wall(settings, None))
    except BaseException:
        sessions.close(session.id)
        raise
    response.headers["Location"] = f"/v1/sessions/{session.id}"
    return SessionInfo.of(session, sessions, warm)


@router.post("/{session_id}/updates", summary="Replan the rest of the motion from a measured "
             "state", responses=problems(404, 409, 422, 503))
async def update_session(session_id: str, update: Annotated[StateUpdate, Body()],
                         settings: SettingsDep, lanes: LanesDep,
                         sessions: SessionsDep) -> ReplanReport:
    session = _found(sessions, session_id)
    async with running(settings, lanes, SESSION_UPDATE_MB):
        return await to_thread.run_sync(_update, session, update,
                                        _wall(settings, update.wall_time))


@router.get("/{session_id}", summary="A replanning session", responses=problems(404))
async def get_session(session_id: str, sessions: SessionsDep) -> SessionInfo:
    return SessionInfo.of(_found(sessions, session_id), sessions)


@router.delete("/{session_id}", status_code=204, summary="Close a replanning session",
               responses=problems(404))
async def close_session(session_id: str, sessions: SessionsDep) -> Response:
    if not sessions.close(session_id):
        _found(sessions, session_id)
    return Response(status_code=204)
