"""The earlier plan a job's scene starts from (solver.warm_start): which job's, decided once
per job (`resolve`: when it is submitted, `app.admission`; a batch member's "nearest", and a
job stored without an admission, when it is claimed), and that job's plan, loaded when the
job runs (`load`) with the NLP solution the store kept beside it."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict

from app import stored_plan
from app.errors import field_error, invalid
from app.store import JobStore
from planner.service import NEAREST, NlpSolution, Scene, WarmStart, nearest

MEMORY = 1000
"""How many of the latest succeeded plans solver.warm_start "nearest" looks through."""


class StartFrom(BaseModel):
    """The earlier plan job a scene starts from: its id and, when it was the nearest one,
    how far its scene is [rad] (`planner.memory.distance`)."""

    model_config = ConfigDict(frozen=True)

    job_id: str
    distance: float | None = None


def check(store: JobStore, job_id: str, loc: tuple[str, ...] = ("body",)) -> None:
    """422 at solver.warm_start (under `loc`) unless `job_id` names a job that has a plan
    of today's schema."""
    record = store.get(job_id)
    if record is None or record.plan is None:
        what = "there is no plan job" if record is None else "no plan yet in the job"
        raise invalid([field_error([*loc, "solver", "warm_start"], f"{what} {job_id!r}",
                                   "value_error")])
    if stored_plan.current(record.plan) is None:
        raise invalid([field_error([*loc, "solver", "warm_start"],
                                   f"the plan of job {job_id!r} was stored by a version of the "
                                   "service whose schema this one cannot read "
                                   "(plan_schema legacy)", "value_error")])


def resolve(store: JobStore, scene: Scene) -> StartFrom | None:
    """The earlier job the scene starts from: the one solver.warm_start names, or with
    "nearest" the nearest of the MEMORY latest succeeded ones within reach; None for a cold
    start."""
    wanted = scene.solver.warm_start
    if wanted != NEAREST:
        return None if wanted is None else StartFrom(job_id=wanted)
    found = nearest(scene, store.succeeded_scenes(MEMORY))
    return None if found is None else StartFrom(job_id=found[0], distance=found[1])


def load(store: JobStore, start: StartFrom) -> WarmStart | None:
    """The plan of the job `start` names, with the NLP solution it came from when the store
    kept one, and where it came from; None when that job has no plan (any more), or only
    one of an older schema (`app.stored_plan`)."""
    record = store.get(start.job_id)
    plan = None if record is None or record.plan is None else stored_plan.current(record.plan)
    if plan is None:
        return None
    solution = store.solution(start.job_id)
    if solution is not None:
        plan = plan.model_copy(update={"solution": NlpSolution.model_validate(solution)})
    return WarmStart(plan, start.job_id, start.distance)
