"""The JSON text of the store's columns (scenes, progress, plans, NLP solutions,
histories), written and read by pydantic-core rather than the standard library: a plan's
JSON, hundreds of kilobytes of numbers, is the bulk of every verdict's write and of every
read of a finished job (docs/bench-service.md, "Plan jobs through the service: submit to
answer"). A number that is not finite, which no validated value holds, is written as null,
as the API serves it; text an earlier version wrote with NaN or Infinity still reads."""

from __future__ import annotations

from typing import Any

import pydantic_core


def dumps(value: Any) -> bytes:
    """`value` (dicts, lists, strings, numbers, booleans, None) as compact JSON, UTF-8."""
    return pydantic_core.to_json(value, inf_nan_mode="null")


def loads(text: str | bytes) -> Any:
    """The value of JSON text."""
    return pydantic_core.from_json(text)
