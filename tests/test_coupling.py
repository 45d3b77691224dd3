"""Coupling analysis: batch values against an independent M, singular points against
closed forms, the three split kinds, and the exact messages of bad requests."""

from __future__ import annotations

import json
import math
import tracemalloc

import numpy as np
import pytest
from conftest import point_mass_dynamics
from pydantic import ValidationError

from planner.coupling import MAX_RESULTS, CouplingRequest, analyse
from planner.coupling_block import blocks, measures
from planner.coupling_request import MAX_POINTS
from planner.coupling_singularities import MAX_SINGULAR
from planner.model import Robot

L0, L1, M1, I1 = 0.5, 0.4, 0.5, 0.005


def two_link(wave: dict | None = None, rotational: str = "cumulative") -> Robot:
    return Robot.model_validate({"links": [
        {"length": L0, "mass": 1.0, "inertia": 0.01, "joint": "passive"},
        {"length": L1, "mass": M1, "inertia": I1, "joint": "active", "wave": wave}],
        "rotational_inertia": rotational})


def chain(joints: str, inertia: float = 0.0, rotational: str = "absolute") -> Robot:
    """Links of length 0.5 m and mass 1 kg; joints given as 'p'/'a' letters."""
    return Robot.model_validate({"links": [
        {"length": 0.5, "mass": 1.0, "inertia": inertia,
         "joint": "passive" if j == "p" else "active"} for j in joints],
        "rotational_inertia": rotational})


def independent_block(robot: Robot, q) -> np.ndarray:
    M, _ = point_mass_dynamics(robot, q, np.zeros(robot.n))
    return M[np.ix_(robot.passive, robot.active)]


def wavy_det(q0: float, q1: float, a: float, n: float, eps: float) -> float:
    """Closed-form M_01 of the two-link arm (cumulative inertia) with an elbow wave."""
    r = L1 + a * math.sin(n * q1 + eps)
    dr = a * n * math.cos(n * q1 + eps)
    return I1 + M1 * L0 * (r * math.cos(q0 - q1) + dr * math.sin(q1 - q0))


# --------------------------------------------------------------------------- values


@pytest.mark.parametrize("joints", ["pa", "papa", "paa", "ppa", "appap"])
def test_batch_measures_match_an_independent_mass_matrix(joints, rng):
    robot = chain(joints, inertia=0.01)
    Q = rng.uniform(-np.pi, np.pi, (300, robot.n))
    B = blocks(robot, Q)
    reference = np.array([independent_block(robot, q) for q in Q])
    assert np.abs(B - reference).max() < 1e-12
    m = measures(B)
    det, smin, smax = m.det, m.sigma_min, m.sigma_max
    sv = np.array([np.linalg.svd(b, compute_uv=False) for b in reference])
    rows, cols = B.shape[1:]
    expected_min = sv[:, rows - 1] if rows <= cols else np.zeros(len(Q))
    assert np.allclose(smin, expected_min, rtol=1e-10, atol=1e-14)
    assert np.allclose(smax, sv[:, 0], rtol=1e-10)
    assert np.allclose(m.least, sv[:, -1], rtol=1e-10, atol=1e-14)
    assert (det is None) == (rows != cols)
    if det is not None:
        assert np.allclose(det, np.linalg.det(reference), rtol=1e-10, atol=1e-14)


def test_report_lists_every_configuration_with_condition(rng):
    robot = chain("papa", inertia=0.01)
    Q = rng.uniform(-np.pi, np.pi, (50, 4))
    report = analyse(CouplingRequest(robot=robot, configurations=Q.tolist()))
    assert len(report.results) == 50 and report.results_omitted == 0
    for row, q in zip(report.results, Q, strict=True):
        sv = np.linalg.svd(independent_block(robot, q), compute_uv=False)
        assert row.det == pytest.approx(np.linalg.det(independent_block(robot, q)), abs=1e-13)
        assert row.condition == pytest.approx(sv[0] / sv[-1], rel=1e-8)


def test_large_grids_omit_the_per_point_results_but_keep_the_minimum():
    robot = two_link()
    grid = {"lower": [-1.0, 0.0], "upper": [1.0, 3.0], "points": [200, 150]}
    report = analyse(CouplingRequest(robot=robot, grid=grid))
    assert MAX_RESULTS < 200 * 150
    assert report.results == [] and report.results_omitted == 30_000
    assert report.min_sigma.sigma_min < 1e-12


# --------------------------------------------------------------------------- singular points


def test_det_sign_change_is_refined_to_the_closed_form_singularity():
    """Waveless: M_01 = I1 + m1 l0 l1 cos(q1 - q0) vanishes at q1 = q0 + acos(-I1/(m1 l0 l1))."""
    q0 = 0.3
    expected = q0 + math.acos(-I1 / (M1 * L0 * L1))
    report = analyse(CouplingRequest(robot=two_link(), grid={
        "lower": [q0, 0.0], "upper": [q0, 3.0], "points": 13}))
    (point,) = report.singular_points
    assert point.source == "det-sign-change"
    assert abs(point.q[1] - expected) < 1e-9
    assert point.q[0] == q0
    assert report.min_sigma.sigma_min == point.sigma_min < 1e-15


def test_every_singular_point_of_a_wavy_grid_solves_the_closed_form_det():
    wave = {"amplitude": 0.05, "frequency": 3.0, "phase": 0.4}
    report = analyse(CouplingRequest(robot=two_link(wave), grid={
        "lower": [-1.0, 0.5], "upper": [1.0, 3.0], "points": 37}))
    assert len(report.singular_points) > 20
    for point in report.singular_points:
        q0, q1 = point.q
        det = wavy_det(q0, q1, 0.05, 3.0, 0.4)
        slope = (wavy_det(q0, q1 + 1e-6, 0.05, 3.0, 0.4)
                 - wavy_det(q0, q1 - 1e-6, 0.05, 3.0, 0.4)) / 2e-6
        assert abs(det) < 1e-15
        assert abs(det / slope) < 1e-9  # distance to the singular curve along q1 [rad]


def test_a_path_crossing_the_singularity_is_refined_between_its_configurations():
    expected = math.acos(-I1 / (M1 * L0 * L1))
    path = [[0.0, 0.2], [0.0, 1.0], [0.0, 2.2], [0.0, 2.9]]
    report = analyse(CouplingRequest(robot=two_link(), configurations=path))
    (point,) = report.singular_points
    assert abs(point.q[1] - expected) < 1e-9


def test_more_active_singularity_is_a_refined_minimum_of_sigma_min():
    """1 x 2 block (absolute inertia): both entries vanish at q1 = q2 = q0 + pi/2."""
    robot = chain("paa")
    grid = {"lower": [0.0, 1.0, 1.2], "upper": [0.0, 2.1, 2.3], "points": 12}
    report = analyse(CouplingRequest(robot=robot, grid=grid, threshold=0.05))
    assert report.split.kind == "more-active"
    (point,) = report.singular_points
    assert point.source == "sigma-minimum" and point.det is None
    assert np.allclose(point.q[1:], [math.pi / 2, math.pi / 2], atol=1e-6)
    assert point.sigma_min < 1e-6


def test_no_singular_points_where_sigma_min_stays_above_the_threshold():
    report = analyse(CouplingRequest(robot=chain("paa"), grid={
        "lower": [0.0, -0.5, -0.5], "upper": [0.0, 0.5, 0.5], "points": 9}))
    assert report.singular_points == []
    assert report.min_sigma.sigma_min > 0.1


# --------------------------------------------------------------------------- splits


@pytest.mark.parametrize("joints, kind, fragment", [
    ("pa", "square", "1 x 1"),
    ("papa", "square", "2 x 2"),
    ("ppa", "fewer-active", "cannot be prescribed in full"),
    ("paa", "more-active", "minimum-norm"),
])
def test_split_kind_and_note(joints, kind, fragment):
    robot = chain(joints, inertia=0.01)
    report = analyse(CouplingRequest(robot=robot, configurations=[[0.1] * robot.n]))
    assert report.split.kind == kind
    assert fragment in report.split.note
    assert report.split.passive == robot.passive and report.split.active == robot.active


def test_fewer_active_reports_zero_sigma_and_nothing_infinite(rng):
    robot = chain("ppa", inertia=0.01)
    report = analyse(CouplingRequest(robot=robot, grid={
        "lower": [-1.0, -1.0, -1.0], "upper": [1.0, 1.0, 1.0], "points": 5}))
    assert all(r.sigma_min == 0.0 and r.condition is None and r.det is None
               for r in report.results)
    assert report.singular_points == []
    json.dumps(report.model_dump(), allow_nan=False)


# --------------------------------------------------------------------------- bad requests


def message(**request) -> str:
    with pytest.raises(ValidationError) as exc:
        CouplingRequest.model_validate(request)
    (error,) = exc.value.errors()
    return error["msg"]


def test_exactly_one_of_configurations_and_grid():
    robot = two_link().model_dump()
    expected = "Value error, configurations: give exactly one of configurations and grid"
    assert message(robot=robot) == expected
    assert message(robot=robot, configurations=[[0.0, 0.0]],
                   grid={"lower": [0, 0], "upper": [1, 1]}) == expected


def test_grid_size_is_bounded():
    side = math.isqrt(MAX_POINTS) + 1
    assert message(robot=two_link().model_dump(), grid={
        "lower": [0, 0], "upper": [1, 1], "points": side}) == (
        f"Value error, grid.points: {side * side:,} points exceed the limit of 200,000; "
        "use fewer points per axis")


@pytest.mark.parametrize("points", [10**8, 10**10, [10**9, 10**9]])
def test_grid_size_is_checked_without_allocating_the_grid(points):
    """Validation runs on the server's event loop: it must not build the grid's axes."""
    tracemalloc.start()
    try:
        text = message(robot=two_link().model_dump(),
                       grid={"lower": [0, 0], "upper": [1, 1], "points": points})
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert text.startswith("Value error, grid.points: ") and "exceed the limit" in text
    assert peak < 1_000_000


def test_rows_must_hold_one_angle_per_joint():
    assert message(robot=two_link().model_dump(), configurations=[[0.0, 1.0], [0.5]]) == (
        "Value error, configurations: every row needs 2 entries, one per joint")
    assert message(robot=two_link().model_dump(), grid={
        "lower": [0, 0, 0], "upper": [1, 1, 1]}) == (
        "Value error, grid.lower: needs 2 entries, one per joint")


def test_grid_bounds_must_be_ordered_and_axes_sampled():
    robot = two_link().model_dump()
    assert message(robot=robot, grid={"lower": [0, 1], "upper": [1, 0]}) == (
        "Value error, upper: every entry must be >= the matching entry of lower")
    assert message(robot=robot, grid={"lower": [0, 0], "upper": [1, 1], "points": 1}) == (
        "Value error, points: an axis with lower < upper needs at least 2 points")
    CouplingRequest.model_validate({"robot": robot, "grid": {
        "lower": [0, 0], "upper": [0, 1], "points": [1, 5]}})


def test_a_robot_without_passive_joints_has_no_coupling_block():
    robot = chain("aa").model_dump()
    assert message(robot=robot, configurations=[[0.0, 0.0]]) == (
        "Value error, robot: has no passive joint, so there is no coupling block "
        "(the arm is fully actuated)")


def test_non_finite_angles_and_extra_fields_are_rejected():
    robot = two_link().model_dump()
    assert message(robot=robot, configurations=[[0.0, math.nan]]) == (
        "Input should be a finite number")
    assert message(robot=robot, configurations=[[0.0, 0.0]], extra=1) == (
        "Extra inputs are not permitted")


def test_singular_points_are_capped_and_the_rest_counted():
    """A 600 x 300 grid over two turns of q1 crosses the singular curve on ~1,200 edges."""
    report = analyse(CouplingRequest(robot=two_link(), grid={
        "lower": [-1.0, -2 * math.pi], "upper": [1.0, 2 * math.pi], "points": [300, 600]}))
    refined = len(report.singular_points)
    assert refined == MAX_SINGULAR
    assert report.singular_points_omitted > 0
    expected = math.acos(-I1 / (M1 * L0 * L1))
    for point in report.singular_points[:50]:
        relative = (point.q[1] - point.q[0] + math.pi) % (2 * math.pi) - math.pi
        assert abs(abs(relative) - expected) < 1e-9
