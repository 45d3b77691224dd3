"""What is decided about a scene once, when its plan job is submitted, and stored with the
job (`JobRecord.admission`), so that the job's worker does not decide it again:

- the checks before a solve (`planner.service.admit`): a plan request they refuse is a 422
  with one error of type "infeasible" per field to blame; a batch member they refuse is
  stored with what they found, and its plan is refused at once when it runs;
- the earlier plan it starts from (`app.warm_start`): a job that solver.warm_start names
  must have a plan of today's schema (else a 422 there), and "nearest" is resolved to the
  nearest job and its distance. A batch member's "nearest" is resolved when the member is
  claimed, so that members start from those that finished before them (docs/api.md).

The worker gives the job's solve what was decided (`given`). A job stored without an
admission (by an earlier version) is checked and resolved when it runs, as it was then.
Retrying a job by id keeps its admission.

The admission also carries the version of the job's messages (`MESSAGE_VERSION`: how its
scene and admission are written), so that during a rolling upgrade a node of an earlier
version does not run a job it would read wrongly (`app.worker`).
"""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, Field, ValidationError

from app import warm_start
from app.errors import FieldError, field_error, invalid
from app.store import JobRecord, JobStore
from app.warm_start import StartFrom
from planner import service
from planner.service import NEAREST, Issue, Scene

MESSAGE_VERSION = 1
"""The version of what a server writes for a job's worker (its scene and admission), raised
whenever a change would make a node of an earlier version read them wrongly. A node that
claims a job of a newer version gives it back and claims nothing more (`app.worker`)."""


class Admission(BaseModel):
    """What was decided about a job's scene when it was submitted (both first fields
    required: a stored admission without them is not read as one that found nothing)."""

    issues: list[Issue] = Field(description=(
        "why its task is infeasible before a solve (planner.feasibility); empty: admitted"))
    warm_start: StartFrom | None = Field(description=(
        "the earlier plan job it starts from; None: a cold start (or one decided at claim)"))
    nearest_at_claim: bool = Field(default=False, description=(
        "solver.warm_start \"nearest\" is resolved when the job is claimed (batch members)"))
    message: int = Field(default=MESSAGE_VERSION, description=(
        "the version of the job's messages (MESSAGE_VERSION of the server that stored it)"))


def message_version(record: JobRecord) -> int:
    """The version of a job's messages: its admission's, 1 for a job stored without one;
    one this version cannot read counts as newer than MESSAGE_VERSION."""
    found = (record.admission or {}).get("message", 1)
    return found if isinstance(found, int) and not isinstance(found, bool) \
        else MESSAGE_VERSION + 1


def infeasible_errors(issues: list[Issue], loc: tuple[str, ...] = ("body",)) -> list[FieldError]:
    """A field error of type "infeasible" (under `loc`) for every issue."""
    return [field_error(loc, str(issue), "infeasible") for issue in issues]


def admit_plan(store: JobStore, scene: Scene) -> Admission:
    """A plan request's scene admitted, with the earlier plan it starts from; a 422 when
    the checks before a solve refuse it, or at solver.warm_start (`app.warm_start.check`)."""
    issues = service.admit(scene)
    if issues:
        raise invalid(infeasible_errors(issues))
    wanted = scene.solver.warm_start
    if wanted is not None and wanted != NEAREST:
        warm_start.check(store, wanted)
    return Admission(issues=[], warm_start=warm_start.resolve(store, scene))


def admit_members(store: JobStore, base: Scene, members: list[Scene]) -> list[Admission]:
    """A batch's members admitted, each with what the checks found for it; the base's
    solver.warm_start is checked once (a 422 at base.solver.warm_start), and "nearest" left
    to each member's claim."""
    wanted = base.solver.warm_start
    if wanted is not None and wanted != NEAREST:
        warm_start.check(store, wanted, ("body", "base"))
    named = None if wanted is None or wanted == NEAREST else StartFrom(job_id=wanted)
    return [Admission(issues=issues, warm_start=None if issues else named,
                      nearest_at_claim=wanted == NEAREST and not issues)
            for issues in map(service.admit, members)]


def stored(record: JobRecord) -> Admission | None:
    """The admission stored with a job; None when it has none (a job of an earlier
    version), or one this version cannot read."""
    if record.admission is None:
        return None
    try:
        return Admission.model_validate(record.admission)
    except ValidationError:
        return None


def given(store: JobStore, scene: Scene, admission: Admission | None) -> dict[str, Any]:
    """The keyword arguments of a job's solve (`planner.service.plan`): `issues`, what
    admission found (absent without an admission: the plan runs the checks), and
    `warm_start`, the earlier plan loaded (absent for a cold start, or when that job has no
    plan any more); resolved now for a job without an admission, or a "nearest" left to
    the claim."""
    if admission is None or admission.nearest_at_claim:
        start = warm_start.resolve(store, scene)
    else:
        start = admission.warm_start
    earlier = None if start is None else warm_start.load(store, start)
    return {**({} if admission is None else {"issues": admission.issues}),
            **({} if earlier is None else {"warm_start": earlier})}
