"""The earlier plan a job's scene starts from (solver.warm_start): the one of the job it
names, or with "nearest" the nearest of the latest succeeded plans within reach; its NLP
solution comes with it when the store kept one."""

from __future__ import annotations

from app.store import JobStore
from app.stored_plan import current
from planner.service import NEAREST, NlpSolution, Plan, Scene, nearest

MEMORY = 1000
"""How many of the latest succeeded plans solver.warm_start "nearest" looks through."""


def warm_start(store: JobStore, scene: Scene) -> tuple[Plan, str, float | None] | None:
    """The earlier plan the scene starts from, its job's id and distance [rad] (None but
    for "nearest"); None for a cold start, or when that job has no plan (any more)."""
    start_from = _start_from(store, scene)
    if start_from is None:
        return None
    earlier = _earlier(store, start_from[0])
    return None if earlier is None else (earlier, *start_from)


def started_from(plan: Plan, job_id: str, distance: float | None) -> Plan:
    """The plan with the job it started from in its solver report."""
    report = plan.solver.model_copy(update={"warm_start": job_id,
                                            "warm_start_distance": distance})
    return plan.model_copy(update={"solver": report})


def _start_from(store: JobStore, scene: Scene) -> tuple[str, float | None] | None:
    """The id of the earlier job the scene starts from (solver.warm_start: its own, or
    with "nearest" the nearest of the MEMORY latest succeeded ones within reach, with its
    distance [rad]); None for a cold start."""
    wanted = scene.solver.warm_start
    if wanted != NEAREST:
        return (wanted, None) if wanted else None
    return nearest(scene, store.succeeded_scenes(MEMORY))


def _earlier(store: JobStore, job_id: str) -> Plan | None:
    """The plan of an earlier job with the NLP solution it came from, to warm-start from
    (None when there is none, or only one of an older schema: `app.stored_plan`)."""
    record = store.get(job_id)
    plan = None if record is None or record.plan is None else current(record.plan)
    if plan is None:
        return None
    solution = store.solution(job_id)
    if solution is None:
        return plan
    return plan.model_copy(update={"solution": NlpSolution.model_validate(solution)})
