"""Plans as the job store holds them, read against today's `Plan` schema.

A stored plan is the JSON the version of the service that solved it wrote. One that
validates against today's `Plan` is `current` and served as today. One that does not is
`legacy`: a plan of a version whose schema differs in a way this one cannot read (a field
it requires is missing, an object it holds strictly has a field it does not know: a newer
server sharing the database, or a change without a default). It is served as stored,
without validation, never a 500 (its non-finite numbers, which an old SQLite file may
hold, leave as null like those of every response: the response model's JSON
serialisation writes them so); what needs the plan's meaning (figures, samples, warm
starts) refuses it instead.

Mechanical changes of the schema would be upgraded here before validating; there have been
none: every field added since the first plans has a default (null, [] or "not recorded"),
and the one removed (`verification.perturbed_open_loop_error`) is ignored when read.
`tests/test_stored_plan.py` holds a plan of the first schema to being `current`.
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import RootModel, ValidationError

from planner.service import Plan

PlanSchema = Literal["current", "legacy"]


class StoredPlan(RootModel[dict[str, Any]]):
    """A plan of another schema, as the job store holds it (not validated; non-finite
    numbers as null). Its fields are those of `Plan` at the version that solved it."""


def current(stored: dict[str, Any]) -> Plan | None:
    """The stored plan under today's schema; None when it does not validate."""
    try:
        return Plan.model_validate(stored)
    except ValidationError:
        return None


def read(stored: dict[str, Any]) -> Plan | StoredPlan:
    """The stored plan as today's `Plan` when it validates, else as stored (`StoredPlan`)."""
    plan = current(stored)
    return plan if plan is not None else StoredPlan(stored)


def schema_of(plan: Plan | StoredPlan | None) -> PlanSchema | None:
    """Which schema a plan `read` returned follows (None without a plan)."""
    if plan is None:
        return None
    return "current" if isinstance(plan, Plan) else "legacy"

