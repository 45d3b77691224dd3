"""Infeasible tasks said plainly and early: the checks before a solve (a 422 through the
service, an `infeasible` plan at once in the library), the retries that stop once two
starts agree, with the violated rows as evidence, and the job's error."""

from __future__ import annotations

import numpy as np
import pytest
from service_fixtures import client, two_link_scene

from app.job_run import _verdict
from planner import feasibility
from planner.ocp.infeasibility import AGREEING, CHECKS_STATUS, _node
from planner.ocp.instance import instance
from planner.ocp.mesh import Mesh
from planner.ocp.planner import plan
from planner.ocp.row_kinds import row_kinds
from planner.scene import Scene
from planner.simulate import simulate
from testbed.fake_solvers import fake_plan
from testbed.robots import chain_scene


def with_task(scene: Scene, **task) -> Scene:
    data = scene.model_dump(exclude_unset=True)
    data["task"].update(task)
    return Scene.model_validate(data)


def horizontal(scene: Scene) -> Scene:
    """The scene with its arm in a horizontal plane (no gravity)."""
    data = scene.model_dump(exclude_unset=True)
    data["robot"]["gravity"] = 0.0
    return Scene.model_validate(data)


def fields(scene: Scene) -> list[tuple[str, str]]:
    return [(issue.field, issue.kind) for issue in feasibility.check(scene)]


BASE = chain_scene(2)  # joints 0.0 -> 0.5 and 0.1 -> 0.6 rad in 1 s, rest to rest, gravity


def test_a_feasible_task_passes_every_check():
    assert feasibility.check(BASE) == []
    assert feasibility.check(with_task(BASE, torque_limit=2.0, coupling_margin=1e-3)) == []
    free = with_task(BASE, final={"q": [None, None], "dq": [0.0, 0.0]})
    assert feasibility.check(with_task(free, tip_target={"x": 0.5, "y": 0.3})) == []


def test_a_start_or_goal_outside_a_bound_names_its_entry():
    bounds = {"lower": [None, -1.0], "upper": [0.3, 1.0]}
    assert fields(with_task(BASE, position_bounds=bounds)) == [("task.final.q.0", "bounds")]
    rates = {"lower": [-5.0, 0.5], "upper": [5.0, 5.0]}
    assert ("task.initial.dq.1", "bounds") in fields(with_task(BASE, velocity_bounds=rates))


def test_velocity_bounds_that_cannot_cover_the_move_in_the_longest_duration():
    slow = {"lower": [-0.1, -1.0], "upper": [0.1, 1.0]}
    assert fields(with_task(BASE, velocity_bounds=slow)) == [("task.final.q.0",
                                                              "velocity reach")]
    # 0.5 rad at 0.1 rad/s needs 5 s: a duration range reaching 6 s allows it
    longer = with_task(BASE, velocity_bounds=slow, duration={"min": 1.0, "max": 6.0})
    assert fields(longer) == []
    backwards = {"lower": [0.0, -1.0], "upper": [0.0, 1.0]}  # joint 0 may not move at all
    assert fields(with_task(BASE, velocity_bounds=backwards)) == [("task.final.q.0",
                                                                   "velocity reach")]


def test_a_start_or_goal_inside_the_coupling_margin():
    from planner.coupling_block import at

    sigma = at(BASE.robot, BASE.task.initial.q).sigma_min
    assert sigma is not None
    found = fields(with_task(BASE, coupling_margin=2 * sigma))
    assert ("task.initial.q", "coupling margin") in found
    goal_free = with_task(BASE, coupling_margin=2 * sigma,
                          final={"q": [0.5, None], "dq": [0.0, 0.0]})
    assert ("task.final.q", "coupling margin") not in fields(goal_free)
    co = with_task(BASE, coupling_margin=2 * sigma,
                   co_design={"amplitude_max": 0.05, "frequency": [3.0]})
    assert fields(co) == []  # the waves are designed by the solve: not known before it


def test_a_tip_target_beyond_the_largest_link_radii():
    reach = feasibility.reach(BASE.robot)
    assert reach == pytest.approx(0.4 + 0.4 + 0.04)  # the active link's wave adds 0.1 l
    assert fields(with_task(BASE, tip_target={"x": 0.0, "y": 1.01 * reach})) == [
        ("task.tip_target", "reach")]
    free = with_task(BASE, final={"q": [None, None], "dq": [0.0, 0.0]})
    # the wavy link's radius dips where it points along y: even free, the tip cannot get
    # 0.99 of the largest radii that way, only within the arm's extent in that direction
    assert fields(with_task(free, tip_target={"x": 0.0, "y": 0.99 * reach})) == [
        ("task.tip_target", "reach within bounds")]
    along_y = float(feasibility.extent(free, np.array([np.pi / 2]))[0])
    assert along_y < 0.99 * reach
    assert fields(with_task(free, tip_target={"x": 0.0, "y": 0.99 * along_y})) == []
    # with the final angles given, the target must be their tip
    assert fields(with_task(BASE, tip_target={"x": 0.0, "y": 0.99 * reach})) == [
        ("task.tip_target", "reach within bounds")]


def test_a_tip_target_nearer_than_the_arm_folds():
    """A first link of 1 m and a second of 0.4 m cannot bring the tip within 0.6 m of the
    base."""
    robot = {"links": [{"length": 1.0, "mass": 1.0, "inertia": 0.01, "joint": "active"},
                       {"length": 0.4, "mass": 0.5, "inertia": 0.01, "joint": "active"}],
             "gravity": 0.0}
    scene = Scene.model_validate({"robot": robot, "task": {
        "duration": 1.0, "initial": {"q": [0.0, 0.0], "dq": [0.0, 0.0]},
        "final": {"q": [None, None], "dq": [0.0, 0.0]}, "tip_target": {"x": 0.3, "y": 0.4}}})
    assert feasibility.innermost(scene.robot) == pytest.approx(0.6)
    assert feasibility.check(scene)[0].message == (
        "(0.3, 0.4) is 0.5 m from the base, nearer than the arm folds: at least 0.6 m (a "
        "link's least radius less the other links' largest)")
    folded = with_task(scene, tip_target={"x": 0.36, "y": 0.48})  # 0.6 m: reachable
    assert feasibility.check(folded) == []


def test_the_tip_within_bounded_final_angles_is_never_refused_and_beyond_them_is():
    """Every tip of a configuration within the position bounds passes the check (it is
    sufficient for infeasibility); a target on the far side of the base does not."""
    from planner.dynamics import Dynamics

    lower, upper = [-0.3, 0.2, -1.0], [0.3, 0.6, -0.2]
    scene = with_task(chain_scene(3), final={"q": [None] * 3, "dq": [0.0] * 3},
                      initial={"q": [0.0, 0.3, -0.5], "dq": [0.0] * 3},
                      position_bounds={"lower": lower, "upper": upper},
                      tip_target={"x": 0.5, "y": 0.0})
    tips = Dynamics(scene.robot).tips
    rng = np.random.default_rng(7)
    for q in [np.array(lower), np.array(upper), *rng.uniform(lower, upper, (40, 3))]:
        x, y = tips(q)[-1]
        assert feasibility.check(with_task(scene, tip_target={"x": float(x),
                                                               "y": float(y)})) == []
    beyond = feasibility.check(with_task(scene, tip_target={"x": -0.5, "y": 0.0}))
    assert [(i.field, i.kind) for i in beyond] == [("task.tip_target", "reach within bounds")]
    # the same target is within the arm's reach once the bounds are gone
    free = with_task(scene, tip_target={"x": -0.5, "y": 0.0}, position_bounds=None)
    assert feasibility.check(free) == []


def test_zero_torque_is_infeasible_unless_the_free_motion_reaches_the_goal():
    assert fields(with_task(BASE, torque_limit=0.0)) == [("task.torque_limit", "zero torque")]
    assert fields(with_task(BASE, torque_limit=[0.0])) == [("task.torque_limit",
                                                            "zero torque")]
    # the goal where the arm falls to in 1 s under gravity alone: zero torque does it
    x0 = [0.0, 0.1, 0.0, 0.0]
    free = simulate(BASE.robot, [0.0, 1.0], np.zeros((1, 1, 1)), x0)
    goal = {"q": free.q[-1], "dq": free.dq[-1]}
    assert fields(with_task(BASE, torque_limit=0.0, final=goal)) == []


def test_plan_returns_at_once_with_the_fields_to_blame():
    scene = with_task(BASE, tip_target={"x": 3.0, "y": 0.0}, torque_limit=0.0)
    p = plan(scene)
    assert p.infeasibility is not None and p.infeasibility.source == "checks"
    assert [f.field for f in p.infeasibility.fields] == ["task.tip_target",
                                                          "task.torque_limit"]
    assert p.solver.status == CHECKS_STATUS and not p.solver.success
    assert p.mesh_passes == [] and p.t == [] and p.verification.verified is False
    status, error = _verdict(p, False, False, 60.0)
    assert status == "failed" and error is not None
    assert error.startswith("infeasible: the task is infeasible before any solve: "
                            "task.tip_target: ")


def test_two_starts_that_agree_stop_the_retries_with_the_violated_rows():
    """The first link's final angle given, the tip target 0.1 m beyond its elbow along it:
    the second link (0.4 m, its wave 0.04 m) cannot fold back that far, though the target
    lies within the checks' convex hull of the tip's reach; two starts end locally
    infeasible, and no further retry runs. That is no proof: the plan is a solver
    failure, its infeasibility the evidence of what the starts found."""
    elbow = 0.4 * np.array([np.cos(0.5), np.sin(0.5)])
    target = elbow * 1.25
    scene = with_task(chain_scene(2, intervals=10), final={"q": [0.5, None], "dq": [0.0, 0.0]},
                      tip_target={"x": float(target[0]), "y": float(target[1])})
    assert feasibility.check(scene) == []
    p = plan(scene)
    found = p.infeasibility
    assert found is not None and found.source == "solver"
    starts = {a.split(":")[0] for a in found.attempts} - {"restart from the last iterate"}
    assert len(starts) == AGREEING  # a restart from an attempt's last iterate not counted
    assert found.attempt in p.solver.strategy and found.durations == [1.0]
    assert p.solver.status in ("Infeasible_Problem_Detected", "Restoration_Failed",
                               "Local_Infeasibility")
    # the retries stopped at the second agreeing attempt: its solve is the last one
    assert p.mesh_passes[-1].strategy == found.attempts[-1].split(":")[0]
    assert "first mesh of 5 intervals" not in {m.strategy for m in p.mesh_passes}
    assert found.violations and found.violations[0].largest > 1e-3
    assert "tip target" in {v.kind for v in found.violations}
    assert [v.largest for v in found.violations] == sorted(
        (v.largest for v in found.violations), reverse=True)
    assert found.summary.startswith("no plan in 1 s: attempts from 2 different starts ended "
                                    "locally infeasible")
    assert found.summary.endswith("a sign, not a proof, that the task cannot be done")
    assert p.status == "solver-failure" and p.message == f"solver failure: {found.summary}"
    status, error = _verdict(p, False, False, 60.0)
    assert status == "failed" and error == p.message


def test_a_feasible_plan_has_no_infeasibility():
    p = plan(chain_scene(2, intervals=10))
    assert p.solver.success and p.infeasibility is None


@pytest.fixture(scope="module")
def api(tmp_path_factory):
    with client(tmp_path_factory.mktemp("infeasible"), solve=fake_plan) as c:
        yield c


def test_the_service_answers_422_at_the_infeasible_fields(api):
    scene = two_link_scene()
    scene["task"]["tip_target"] = {"x": 5.0, "y": 0.0}
    scene["task"]["position_bounds"] = {"lower": [None, None], "upper": [0.5, None]}
    r = api.post("/v1/plans", json=scene)
    assert r.status_code == 422, r.text
    assert r.headers["content-type"] == "application/problem+json"
    errors = r.json()["errors"]
    assert [(e["loc"], e["type"]) for e in errors] == [
        (["body", "task", "final", "q", 0], "infeasible"),
        (["body", "task", "tip_target"], "infeasible")]
    assert "above its upper bound 0.5" in errors[0]["msg"]
    assert "beyond the arm's reach" in errors[1]["msg"]
    assert api.post("/v1/plans", json=two_link_scene()).status_code == 202


def test_a_duration_range_found_infeasible_says_so_for_the_whole_range():
    scene = with_task(horizontal(chain_scene(2, intervals=10)),
                      duration={"min": 0.1, "max": 0.15}, torque_limit=1.0)
    p = plan(scene)
    assert p.infeasibility is not None and p.infeasibility.durations == [0.1, 0.15]
    assert "cannot be done with a free duration in [0.1, 0.15] s" in p.infeasibility.summary


FAST = with_task(chain_scene(2, under=False, intervals=10), torque_limit=1.0)
"""A fully actuated arm moving 0.5 rad per joint with 1 N m: about 1.09 s at the least."""


def _fastest() -> float:
    """[s] The shortest duration of FAST's move, planned on its own as a time-optimal task."""
    p = plan(with_task(FAST, duration={"min": 0.1, "max": 4.0},
                       objective={"effort": 1e-3, "time": 1.0}))
    assert p.verification.verified
    return p.duration


def test_a_duration_below_the_shortest_is_infeasible_with_the_shortest_as_evidence():
    """The probe's time-optimal solve, started from the unlimited motion stretched, finds
    the same shortest duration as the time-optimal task planned on its own; the plan is
    the task's own iterate at 0.5 s."""
    p = plan(with_task(FAST, duration=0.5))
    found = p.infeasibility
    assert found is not None and found.source == "duration"
    assert found.durations == [0.5] and found.shortest_duration is not None
    assert found.shortest_duration == pytest.approx(_fastest(), rel=1e-2)
    assert found.summary.startswith("the task cannot be done in 0.5 s: its attempts gave no "
                                    "converged plan (direct: ")
    assert (f"a time-optimal solve under the task's limits, from its motion without them "
            f"stretched to keep them, ended at a verified plan of "
            f"{found.shortest_duration:.4g} s") in found.summary
    assert "(a local optimum of that solve: the task can be done in" in found.summary
    assert p.solver.message == found.summary and not p.solver.success
    assert p.status == "infeasible" and p.message == f"infeasible: {found.summary}"
    assert p.duration == 0.5  # the plan is still the infeasible task's own iterate
    # the verdict came from the probe: no rescue start ran after it
    assert not any(m.strategy.startswith(("restart", "inverse-dynamics", "first mesh"))
                   for m in p.mesh_passes)
    # the evidence is true: the task can be done in the duration it names
    at = plan(with_task(FAST, duration=round(found.shortest_duration, 6)))
    assert at.status == "verified", at.message


def test_a_duration_just_above_the_shortest_is_planned_not_held_infeasible():
    p = plan(with_task(FAST, duration=round(1.1 * _fastest(), 3)))
    assert p.infeasibility is None
    assert p.solver.success and p.verification.verified


def test_a_stretched_motion_needs_its_torques_beside_gravity_over_the_square_of_the_stretch():
    """M(q) ddq + h(q, dq) scales with 1/s^2 when a motion is run s times as long, gravity's
    torque G(q) stays: the stretched guess's torques are (tau - G) / s^2 + G, which is what
    the probe's stretch factor counts on (without gravity: tau / s^2)."""
    from planner.dynamics import Dynamics
    from planner.ocp.guess import hermite_guess, stretched

    scene = with_task(FAST, duration=1.0)
    x = np.linspace(0.0, 1.0, 21)
    for gravity in (0.0, 9.81):
        robot = scene.robot.model_copy(update={"gravity": gravity})
        motion = hermite_guess(scene, robot, 1.0)
        G = np.array([Dynamics(robot).gravity(q)[robot.active] for q in motion(x)["q"]])
        for s in (1.0, 1.7, 3.0):
            slow = stretched(motion, s, robot)(x)
            np.testing.assert_allclose(slow["tau"], (motion(x)["tau"] - G) / s ** 2 + G,
                                       rtol=1e-11, atol=1e-12)
            np.testing.assert_allclose(slow["dq"], motion(x)["dq"] / s, rtol=1e-14)


def test_the_stretch_factor_is_the_least_that_keeps_the_limit_in_gravity():
    from planner.ocp import shortest

    scene = with_task(chain_scene(2, under=False, intervals=10), duration=0.3, torque_limit=None)
    motion = plan(scene)
    G = np.array([shortest.Dynamics(scene.robot).gravity(q)[scene.robot.active]
                  for q in motion.dense.q])
    tau = np.asarray(motion.dense.tau)
    assert np.abs(tau).max() > 2 * np.abs(G).max()
    # between: gravity alone keeps it, the motion does not
    limit = shortest.STRETCH_MARGIN * (np.abs(G).max() + np.abs(tau).max()) / 2
    factor = shortest.stretch_factor(with_task(scene, torque_limit=limit), motion)
    assert factor > 1.0

    def peak(s: float) -> float:
        return float(np.abs((tau - G) / s ** 2 + G).max())

    assert peak(factor) <= limit / shortest.STRETCH_MARGIN * (1 + 1e-9)
    assert peak(factor * (1 - 1e-6)) > limit / shortest.STRETCH_MARGIN


def _attempt(name: str, status: str, continues: bool = False):
    from types import SimpleNamespace

    solution = SimpleNamespace(status=status, success=False, g=None)
    outcome = SimpleNamespace(solution=solution, finite=True,
                              record=SimpleNamespace(margin_reserve=None))
    start = SimpleNamespace(name=name, continues=continues)
    return SimpleNamespace(start=start, outcomes=[outcome]), outcome


def test_attempts_that_do_not_agree_leave_the_verdict_but_name_the_one_that_found_infeasibility():
    from planner.ocp import infeasibility

    p = plan(with_task(BASE, tip_target={"x": 3.0, "y": 0.0}))  # any plan to annotate
    failed = p.model_copy(update={
        "infeasibility": None,
        "solver": p.solver.model_copy(update={"status": "Maximum_Iterations_Exceeded",
                                              "message": "the iteration limit was reached"})})
    first, best = _attempt("direct", "Maximum_Iterations_Exceeded")
    other, _ = _attempt("inverse-dynamics start", "Infeasible_Problem_Detected")
    last, _ = _attempt("first mesh of 100 intervals", "Maximum_Iterations_Exceeded")
    attempts = [first, other, last]
    assert not infeasibility.agreed(attempts)  # one start alone does not make a verdict
    out = infeasibility.annotate(failed, BASE, attempts, best, first)
    assert out.infeasibility is None
    assert out.solver.message == ("the iteration limit was reached; the attempt "
                                  "'inverse-dynamics start' ended Infeasible_Problem_Detected")
    restart, _ = _attempt("restart from the last iterate", "Infeasible_Problem_Detected",
                          continues=True)
    assert not infeasibility.agreed([first, other, restart])
    third, _ = _attempt("first mesh of 25 intervals", "Restoration_Failed")
    assert infeasibility.agreed([first, other, third])


def test_a_tip_just_beyond_the_reach_in_its_own_direction_is_refused_with_free_final_angles():
    # the wavy link reaches least where its radius dips: a target 2.7 mm beyond the arm's
    # extent in its direction (found here by brute force) is refused before any solve,
    # though it is nearer than the sum of the largest radii
    scene = with_task(BASE, final={"q": [None, None], "dq": [0.0, 0.0]})
    robot = scene.robot
    theta = (-np.pi / 2 - 0.3) / 3  # where the wave of joint 1 (n = 3, phase 0.3) dips
    q = np.linspace(-np.pi, np.pi, 400_001)
    extent = 0.0
    for link in robot.links:
        w = link.wave
        r = link.length + (0.0 if w is None else w.amplitude * np.sin(w.frequency * q + w.phase))
        extent += float((r * np.cos(q - theta)).max())
    target = (extent + 2.7e-3) * np.array([np.cos(theta), np.sin(theta)])
    assert np.hypot(*target) < feasibility.reach(robot)
    aimed = with_task(scene, tip_target={"x": float(target[0]), "y": float(target[1])})
    assert fields(aimed) == [("task.tip_target", "reach within bounds")]
    within = (extent - 2.7e-3) * np.array([np.cos(theta), np.sin(theta)])
    assert fields(with_task(scene, tip_target={"x": float(within[0]),
                                               "y": float(within[1])})) == []


def test_a_violated_row_is_placed_at_its_node():
    # Evidence of an infeasible task names where a violated row is: a stage's rows at the
    # node that starts the stage (the terminal has no rows here: the final state is
    # bounds), and a copy row of a global (here the free duration) at the node between
    # the two copies it keeps equal.
    data = two_link_scene()
    data["task"]["duration"] = {"min": 0.8, "max": 3.0}
    scene = Scene.model_validate(data)
    N = 12
    problem = instance(scene, scene.robot, Mesh.uniform(N), 1.0).problem
    _, per_stage = row_kinds(problem)
    copies_at = problem.lbg.size - N
    assert per_stage > 0 and copies_at == N * per_stage
    assert [_node(problem, row, per_stage, N) for row in (0, 3 * per_stage + 1)] == [0, 3]
    assert _node(problem, copies_at - 1, per_stage, N) == N - 1
    assert [_node(problem, copies_at + k, per_stage, N) for k in (0, 4, N - 1)] == [1, 5, N]
