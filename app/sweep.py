"""Batch sweeps: a base scene and its members, each the base with a few named parameters
set, given as a list of overrides or as a grid (every combination of the axes' values).

A parameter is named by a path into the scene:

| name | sets |
|---|---|
| `duration` | `task.duration` [s] (a fixed duration) |
| `initial.q.J` | `task.initial.q[J]` [rad] |
| `final.q.J` | `task.final.q[J]` [rad] |
| `wave.I.amplitude`, `wave.I.frequency`, `wave.I.phase` | the wave of link I (it must have one) |

Values are JSON numbers, as everywhere in a request (`planner.schema`): a string ("2") or
a boolean (true) is refused at its field, not read as 2.0 or 1.0. Each member is
validated as a scene of its own and held to the server's limits; an error names the
member (`overrides.K` or `grid` with the member's values) and the field.
"""

from __future__ import annotations

import copy
import itertools
import math
import re
from typing import Annotated, Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from app.capacity import capacity_errors
from app.errors import ApiError, FieldError, field_error, invalid
from app.limits import check_scene
from app.settings import Settings
from planner.service import Scene

_NAME = re.compile(r"^(duration|(initial|final)\.q\.(\d+)"
                   r"|wave\.(\d+)\.(amplitude|frequency|phase))$")
MAX_PARAMETERS = 16  # names one override or one grid may set
MAX_MEMBERS = 1000  # hard cap; UNDERTOW_MAX_BATCH_MEMBERS is the server's own
MAX_ERRORS = 20  # member errors one 422 lists

Parameters = Annotated[dict[str, float], Field(max_length=MAX_PARAMETERS, description=(
    "parameter name -> value: duration, initial.q.J, final.q.J, wave.I.amplitude, "
    "wave.I.frequency, wave.I.phase"))]


class BatchRequest(BaseModel):
    """A sweep: the base scene and either `overrides` (one member each) or `grid` (one
    member per combination of the axes' values, the last axis varying fastest)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, strict=True)

    base: Scene = Field(description="the scene every member starts from")
    overrides: list[Parameters] | None = Field(
        default=None, min_length=1, max_length=MAX_MEMBERS,
        description="one member per entry: the parameters it sets on the base scene")
    grid: dict[str, Annotated[list[float], Field(min_length=1, max_length=MAX_MEMBERS)]] | None = (
        Field(default=None, min_length=1, max_length=MAX_PARAMETERS,
              description="parameter name -> the values of its axis"))

    @model_validator(mode="after")
    def _one_way(self) -> BatchRequest:
        if (self.overrides is None) == (self.grid is None):
            raise ValueError("give either overrides or grid")
        return self


def members(request: BatchRequest, settings: Settings) -> list[dict[str, float]]:
    """The members' parameters, in order; 422 when there are more than the server allows."""
    overrides, grid = request.overrides, request.grid or {}  # the validator gives one
    where = "overrides" if overrides is not None else "grid"
    if overrides is not None:
        count = len(overrides)
    else:
        count = math.prod(len(values) for values in grid.values())
    if count > settings.max_batch_members:
        raise invalid([field_error(["body", where], f"{count} members exceed this server's "
                                   f"limit of {settings.max_batch_members} "
                                   "(UNDERTOW_MAX_BATCH_MEMBERS)", "limit")])
    if overrides is not None:
        return [dict(item) for item in overrides]
    names = list(grid)
    return [dict(zip(names, values, strict=True))
            for values in itertools.product(*grid.values())]


def _set(scene: dict[str, Any], name: str, value: float) -> str | None:
    """Set parameter `name` in the scene's JSON; why it cannot be set, or None."""
    match = _NAME.match(name)
    if match is None:
        return ("unknown parameter; expected duration, initial.q.J, final.q.J or "
                "wave.I.amplitude|frequency|phase")
    task, links = scene["task"], scene["robot"]["links"]
    if match[1] == "duration":
        task["duration"] = value
    elif match[2] is not None:
        joint, q = int(match[3]), task[match[2]]["q"]
        if joint >= len(q):
            return f"joint {joint} does not exist: the robot has {len(q)} joints"
        q[joint] = value
    else:
        link = int(match[4])
        if link >= len(links) or links[link].get("wave") is None:
            return f"link {link} has no wave in the base scene"
        links[link]["wave"][match[5]] = value
    return None


def _prefixed(error: FieldError, loc: list[str | int], what: str) -> FieldError:
    """`error` (located from "body") moved under `loc`, its message naming the member."""
    rest = error.loc[1:] if error.loc[:1] == ["body"] else error.loc
    return FieldError(loc=[*loc, *rest], msg=f"{what}{error.msg}", type=error.type)


def _member_scene(base: dict[str, Any], parameters: dict[str, float],
                  settings: Settings) -> tuple[Scene | None, list[FieldError]]:
    """The member's scene, checked against the server's limits, or its field errors
    (located from "body")."""
    scene = copy.deepcopy(base)
    errors = [field_error(["body", name], why) for name, value in parameters.items()
              if (why := _set(scene, name, value)) is not None]
    if errors:
        return None, errors
    try:
        checked = check_scene(Scene.model_validate(scene), settings)
    except ValidationError as exc:
        return None, [field_error(["body", *e["loc"]], e["msg"], e["type"])
                      for e in exc.errors()]
    except ApiError as exc:
        return None, list(exc.errors or [])
    return checked, capacity_errors(checked, settings)


def scenes(request: BatchRequest, parameters: list[dict[str, float]],
           settings: Settings) -> list[Scene]:
    """Every member's scene; 422 listing the members that are not valid."""
    try:
        base = check_scene(request.base, settings)
    except ApiError as exc:
        raise invalid([_prefixed(e, ["body", "base"], "") for e in exc.errors or []]) from exc
    base_json = base.model_dump(mode="json", exclude_unset=True)
    out: list[Scene] = []
    errors: list[FieldError] = []
    for k, member in enumerate(parameters):
        scene, found = _member_scene(base_json, member, settings)
        loc: list[str | int]
        if request.overrides is not None:
            loc, what = ["body", "overrides", k], ""
        else:
            values = ", ".join(f"{name}={value:g}" for name, value in member.items())
            loc, what = ["body", "grid"], f"member {k} ({values}): "
        errors += [_prefixed(e, loc, what) for e in found]
        if scene is not None and not found:
            out.append(scene)
        if len(errors) >= MAX_ERRORS:
            break
    if errors:
        raise invalid(errors[:MAX_ERRORS])
    return out
