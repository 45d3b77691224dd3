"""The service reaches the optimal-control planner through `planner.service` only."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from app.capacity import dynamics_knots
from app.limits import nodes
from app.settings import Settings
from app.worker import load_function
from planner import service
from planner.ocp import methods, plan
from planner.scene import Transcription

APP = Path(__file__).resolve().parents[1] / "app"


def imported_modules(path: Path) -> set[str]:
    """Every module a source file imports (absolute names)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found.add(node.module)
            found.update(f"{node.module}.{alias.name}" for alias in node.names)
    return found


def test_app_imports_nothing_of_the_ocp_package():
    """`planner.ocp` and its modules are the library's inside, and the scene comes with it:
    app/ sees `planner.service`."""
    inside = ("planner.ocp", "planner.scene")
    deeper = {str(path.relative_to(APP.parent)): sorted(
        m for m in imported_modules(path) if m in inside or m.startswith(inside[0] + "."))
        for path in sorted(APP.rglob("*.py"))}
    assert {path: mods for path, mods in deeper.items() if mods} == {}
    texts = {path: path.read_text() for path in APP.rglob("*.py")}
    assert [str(p) for p, text in texts.items() if "planner.ocp" in text] == []


def test_the_default_solve_function_is_the_interfaces_plan():
    assert load_function(Settings().solve_function) is plan is service.plan


@pytest.mark.parametrize("method", service.METHODS)
@pytest.mark.parametrize("intervals", [1, 5, 12])
def test_counts_are_the_transcriptions_own(method, intervals):
    settings = Transcription(method=method, intervals=30, degree=3, steps=6)
    tr = methods.create(method, intervals, 3, "rk4", 6)
    assert service.node_count(settings, intervals) == nodes(settings, intervals) == \
        tr.node_count()
    assert service.knot_count(settings, intervals) == tr.knot_count()
    own = settings.model_copy(update={"intervals": intervals})
    expected = tr.node_count() if method == "multiple-shooting" else tr.knot_count()
    assert dynamics_knots(own) == expected


def test_the_verdicts_reason_is_the_verifications():
    from planner.ocp.verification import Verification

    failed = Verification(resimulation_error=None, resimulation_status="x", defect=None,
                          min_sigma=None, waveless_min_sigma=None,
                          waveless_singular_crossings=[], verified=False, local_error=0.2,
                          tolerance=0.1)
    plan_like = type("P", (), {"verification": failed})()
    assert service.verdict_reason(plan_like) == service.unverified_reason(failed)
    assert "departs from the plan by 0.2 rad" in service.verdict_reason(plan_like)
