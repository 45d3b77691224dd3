"""Request examples shown in the OpenAPI document, taken from `planner.examples`.

Dynamics and simulation have no library example of their own: theirs use the robot of
the two-link example at a plain state and a small torque pulse; the batch example sweeps
the two-link plan over durations and wave amplitudes.
"""

from __future__ import annotations

from functools import cache
from typing import Any

from planner import examples as library


@cache
def _by_kind() -> dict[str, dict[str, dict[str, Any]]]:
    out: dict[str, dict[str, dict[str, Any]]] = {}
    for item in library.examples():
        out.setdefault(item.kind, {})[item.name] = {
            "summary": item.title, "description": item.description, "value": item.request}
    robot = library.example("two-link-waves").request["robot"]
    out["dynamics"] = {"two-link": {
        "summary": "Two-link arm at rest and in motion",
        "value": {"robot": robot, "states": [
            {"q": [0.0, 1.6], "dq": [0.0, 0.0]},
            {"q": [0.3, 1.2], "dq": [0.5, -1.0], "ddq": [1.0, 0.0]}]}}}
    out["simulate"] = {"two-link-pulse": {
        "summary": "Two-link arm: a torque pulse on the elbow",
        "value": {"robot": robot, "t": [0.0, 0.5, 1.0], "tau": [[0.0], [0.05], [0.0]],
                  "interpolation": "linear", "initial": {"q": [0.0, 1.6], "dq": [0.0, 0.0]},
                  "samples_per_interval": 10}}}
    out["batch"] = {"two-link-sweep": {
        "summary": "Two-link plan: durations against wave amplitudes (6 members)",
        "value": {"base": library.example("two-link-plan").request,
                  "grid": {"duration": [1.5, 2.0, 2.5], "wave.1.amplitude": [0.04, 0.05]}}}}
    return out


def body_examples(kind: str) -> dict[str, dict[str, Any]] | None:
    """`openapi_examples` for the request body of an endpoint of this kind (None if none)."""
    return _by_kind().get(kind) or None
