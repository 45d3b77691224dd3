"""The energy a torque limit lets the actuators add or take in a given time
(planner.energy_bound), and the task it proves infeasible before any solve."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from planner import feasibility
from planner.dynamics import Dynamics
from planner.energy_bound import energy_reach, lowest_potential
from planner.examples import example
from planner.ocp import plan
from planner.scene import Scene
from testbed.robots import chain_scene


def test_the_least_potential_is_below_every_configuration():
    scene = chain_scene(3)
    robot, dyn = scene.robot, Dynamics(scene.robot)
    rng = np.random.default_rng(3)
    least = lowest_potential(robot)
    values = [dyn.energy(q, np.zeros(3))[1] for q in rng.uniform(-np.pi, np.pi, (2000, 3))]
    assert least <= min(values)
    assert min(values) - least < 0.1 * abs(least)  # and not far below the true least


@pytest.fixture(scope="module")
def limited() -> tuple[Scene, object]:
    """The two-link example under a torque limit that binds (0.8 of its own peak), with a
    budget ten times the default: its first solve takes a tenth of the budget at most
    (`planner.ocp.shortest.FIRST_SHARE`), which a busy machine reached."""
    request = copy.deepcopy(example("two-link-plan").request)
    free = plan(Scene.model_validate(request))
    request["task"]["torque_limit"] = 0.8 * float(np.abs(np.asarray(free.dense.tau)).max())
    request.setdefault("solver", {})["max_wall_time"] = 600.0
    scene = Scene.model_validate(request)
    result = plan(scene)
    assert result.status == "verified"
    return scene, result


def test_a_verified_limited_plan_stays_within_its_energy_reach_at_every_time(limited):
    scene, result = limited
    dyn = Dynamics(scene.robot)
    limit = np.array([scene.task.torque_limit], float)
    t, q = np.asarray(result.dense.t), np.asarray(result.dense.q)
    dq = result.interpolant().dq(t)
    start = (result.q[0], result.dq[0])
    for k in range(1, len(t), 25):
        energy = sum(dyn.energy(q[k], dq[k]))
        reach = energy_reach(scene.robot, *start, limit, float(t[k]))
        assert reach.lowest - 1e-9 <= energy <= reach.highest + 1e-9


def _raise(limit: float, duration: float = 1.0) -> Scene:
    """Two links hanging along gravity at rest, asked to point the other way at rest."""
    scene = chain_scene(2)
    data = scene.model_dump(exclude_unset=True)
    data["task"].update(duration=duration, torque_limit=limit,
                        initial={"q": [0.0, 0.0], "dq": [0.0, 0.0]},
                        final={"q": [np.pi, np.pi], "dq": [0.0, 0.0]})
    return Scene.model_validate(data)


def test_a_task_that_needs_more_energy_than_the_limit_can_give_is_refused_before_a_solve():
    issues = feasibility.check(_raise(0.05))
    assert [(i.field, i.kind) for i in issues] == [("task.torque_limit", "energy")]
    assert issues[0].message.startswith("the final state's energy is 23.") \
        and "above the initial state's, and under this limit the actuators can add at most" \
        in issues[0].message
    assert feasibility.check(_raise(50.0)) == []  # a limit that allows it is no issue
    free = _raise(0.05).model_copy(deep=True)
    data = free.model_dump(exclude_unset=True)
    data["task"]["final"]["dq"] = [None, None]  # rates free: the potential alone is needed
    kinds = [i.kind for i in feasibility.check(Scene.model_validate(data))]
    assert kinds == ["energy"]
