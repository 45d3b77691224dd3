"""Every synchronous endpoint answers within its budget plus a small margin, however much
its request asks for: each family below gets a request that needs many times its budget
(an 8-link arm, tens of thousands of points), and the answer is a budget-exceeded problem
that came from the deadline check of the loop doing the work, with most of that work
left undone (counted from the checks, not from the clock)."""

from __future__ import annotations

import re
import threading
import time
from dataclasses import dataclass

import numpy as np
import pytest
from service_fixtures import client

from planner import budget
from planner.budget import BudgetExceeded

BUDGET = 0.3
"""UNDERTOW_SYNC_WALL_TIME of these tests [s]: each request below needs from 6 times it
(the coupling analysis) to minutes on this machine."""
MARGIN = 1.5
"""How long past its budget an answer may come [s]: the longest piece of work between two
checks (0.2 s here, a CVODES slice or an RK4 chunk of an 8-link arm) and the request's
own overhead, with room for a machine several times slower."""

SETTINGS = {"sync_wall_time": BUDGET, "max_points": 200_000, "max_body_bytes": 5_000_000}

EIGHT = {"links": [{"length": 0.3, "mass": 0.5, "inertia": 0.005,
                    "joint": "passive" if k % 2 == 0 else "active",
                    "wave": None if k % 2 == 0 else {"amplitude": 0.03, "frequency": 3,
                                                      "phase": 0.2}}
                   for k in range(8)], "gravity": 9.81}
"""An 8-link arm, passive joints 0, 2, 4, 6, waves on the active ones."""


@dataclass(frozen=True)
class Check:
    """One call of `planner.budget.check`: when, what it named, and whether it raised."""

    at: float
    what: str
    raised: bool


@pytest.fixture
def checks(monkeypatch) -> list[Check]:
    """Every deadline check the library makes, in order."""
    real, seen = budget.check, []

    def spy(deadline: float | None, what: str) -> None:
        at = time.monotonic()
        try:
            real(deadline, what)
        except BudgetExceeded:
            seen.append(Check(at, what, True))
            raise
        seen.append(Check(at, what, False))
    monkeypatch.setattr(budget, "check", spy)
    return seen


def stopped(path: str, body: dict, tmp_path, checks: list[Check],
            progress: str) -> list[float]:
    """Post `body` to `path` under BUDGET; assert a budget-exceeded answer within BUDGET +
    MARGIN that the last check made raised, its detail matching `progress`; return the
    numbers `progress` captures (how far the work got)."""
    with client(tmp_path, **SETTINGS) as api:
        start = time.monotonic()
        r = api.post(path, json=body)
        elapsed = time.monotonic() - start
    assert r.status_code == 422, r.text
    problem = r.json()
    assert problem["type"] == "urn:undertow:problem:budget-exceeded", problem
    assert elapsed <= BUDGET + MARGIN, f"answered {elapsed:.2f} s after the request"
    assert checks and checks[-1].raised and not any(c.raised for c in checks[:-1])
    match = re.search(progress, problem["detail"])
    assert match, problem["detail"]
    return [float(group.replace(",", "")) for group in match.groups()]


def passed(checks: list[Check], prefix: str) -> int:
    """The checks named `prefix...` that let the work go on."""
    return sum(not c.raised and c.what.startswith(prefix) for c in checks)


def test_dynamics_at_many_states(tmp_path, checks):
    states = [{"q": [0.001 * k] * 8, "dq": [0.1] * 8} for k in range(10_000)]
    done, total = stopped("/v1/dynamics", {"robot": EIGHT, "states": states}, tmp_path, checks,
                          r"^the dynamics \(at state (\d+) of (\d+)\) ran past its deadline")
    assert total == 10_000 and done < total // 4
    assert passed(checks, "the dynamics") == done


def test_coupling_over_a_grid_stops_inside_its_first_evaluation(tmp_path, checks):
    """The largest grid: the analysis takes 1.8 s here, its first evaluation 1 s."""
    grid = {"lower": [0.0] * 8, "upper": [1.0] * 4 + [0.0] * 4, "points": [21] * 4 + [1] * 4}
    done, total = stopped(
        "/v1/coupling", {"robot": EIGHT, "grid": grid}, tmp_path, checks,
        r"^the coupling analysis: the evaluation of Mpa \(at configuration ([\d,]+) of "
        r"([\d,]+)\) ran past its deadline")
    assert total == 21**4 and done < total
    assert passed(checks, "the evaluation of Mpa") == done // 4096  # chunks evaluated


def test_a_wave_design_over_a_region_stops_inside_its_screening(tmp_path, checks):
    body = {"robot": EIGHT, "amplitude_max": 0.03, "frequency_max": 3, "margin": 0.001,
            "region": {"lower": [0.0] * 8, "upper": [0.5, 0.5] + [0.0] * 6}}
    done, total = stopped(
        "/v1/waves/design", body, tmp_path, checks,
        r"^the wave design: the evaluation of Mpa \(at configuration ([\d,]+) of "
        r"([\d,]+)\) ran past its deadline")
    assert total == 1296 * 17**2 and done < total // 4  # candidates x coarse grid


def motion_design() -> dict:
    """An 8-link design along a motion: its screening integrates 1,296 candidates."""
    passive = {"profile": "beta", "alpha": 3.0, "beta": 3.0, "start": [0.0] * 4,
               "end": [0.2] * 4}
    return {"robot": EIGHT, "amplitude_max": 0.03, "frequency_max": 3, "margin": 0.001,
            "motion": {"passive_motion": passive, "duration": 1.0,
                       "active_initial": {"q": [0.5] * 4, "dq": [0.0] * 4}}}


SCREENING = (r"^the wave design: the screening's inverse dynamics \(at candidate ([\d,]+) "
             r"of ([\d,]+)\) ran past its deadline")


def test_a_wave_design_along_a_motion_stops_inside_its_screening(tmp_path, checks):
    done, total = stopped("/v1/waves/design", motion_design(), tmp_path, checks, SCREENING)
    assert total == 1296 and done < total // 4
    assert passed(checks, "the screening's") == done // 16  # chunks integrated


def test_two_wave_designs_at_once_both_answer_within_the_budget(tmp_path):
    """The report: two concurrent 8-link designs along a motion answered after 30 to 40 s
    on a 20 s budget."""
    answers: list[tuple[float, int, str]] = []

    def post(api) -> None:
        start = time.monotonic()
        r = api.post("/v1/waves/design", json=motion_design())
        answers.append((time.monotonic() - start, r.status_code, r.json()["detail"]))

    with client(tmp_path, **SETTINGS) as api:
        threads = [threading.Thread(target=post, args=(api,)) for _ in range(2)]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join(60)
    assert len(answers) == 2
    for elapsed, status, detail in answers:
        assert status == 422 and re.match(SCREENING, detail), detail
        assert elapsed <= BUDGET + MARGIN, f"answered {elapsed:.2f} s after the request"


def test_inverse_dynamics_of_a_long_fast_motion(tmp_path, checks):
    """A two-link arm whose M_pa never loses rank, its shoulder swung 200 times: DOP853
    takes minutes over it."""
    robot = {"links": [{"length": 0.5, "mass": 1.0, "inertia": 0.01, "joint": "passive"},
                       {"length": 0.4, "mass": 0.5, "inertia": 1.0, "joint": "active"}],
             "gravity": 0.0}
    t = np.linspace(0.0, 100.0, 4001)
    passive = {"profile": "samples", "t": t.tolist(),
               "q": (0.3 * np.sin(4 * np.pi * t))[:, None].tolist()}
    body = {"robot": robot, "passive_motion": passive, "duration": 100.0,
            "active_initial": {"q": [0.0], "dq": [0.0]}, "rtol": 1e-12, "atol": 1e-12}
    reached, duration = stopped("/v1/inverse-dynamics", body, tmp_path, checks,
                                r"^the inverse dynamics \(at t = (\S+) s of (\S+) s\) ran past")
    assert duration == 100.0 and reached < duration / 4
    assert passed(checks, "the inverse dynamics") > 0


def test_a_simulation_whose_one_output_needs_many_steps(tmp_path, checks):
    """One output of an 8-link arm under huge torques: a single CVODES call took 8 s to
    give up on it."""
    body = {"robot": EIGHT, "t": [0.0, 1.0], "tau": [[1e3] * 4] * 2,
            "initial": {"q": [0.1] * 8, "dq": [0.0] * 8}, "rtol": 1e-12, "atol": 1e-12}
    reached, end = stopped("/v1/simulate", body, tmp_path, checks,
                           r"^the simulation \(at t = (\S+) s of (\S+) s\) ran past its deadline")
    assert end == 1.0 and reached < end
    assert passed(checks, "the simulation") < 200_000 // 5_000  # CVODES slices made
