"""Built-in examples: ready-to-post requests, each for the endpoint of its kind."""

from __future__ import annotations

from fastapi import APIRouter

from app.errors import ApiError
from app.openapi import problems
from planner import examples as library

router = APIRouter(prefix="/v1/examples", tags=["examples"])

ENDPOINTS = {"inverse-dynamics": "/v1/inverse-dynamics", "wave-design": "/v1/waves/design",
             "coupling": "/v1/coupling", "plan": "/v1/plans"}
"""Where to POST an example's `request`, by its kind."""


@router.get("", summary="Every built-in example (kind: inverse-dynamics -> POST "
            "/v1/inverse-dynamics, wave-design -> /v1/waves/design, coupling -> "
            "/v1/coupling, plan -> /v1/plans)")
def list_examples() -> list[library.Example]:
    return library.examples()


@router.get("/{name}", summary="One built-in example", responses=problems(404))
def get_example(name: str) -> library.Example:
    try:
        return library.example(name)
    except KeyError as exc:
        raise ApiError(404, "not-found", "No such example", str(exc.args[0])) from exc
