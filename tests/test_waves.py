"""Wave design: every proven bound is checked by an independent dense random sample, with
an independent mass matrix (d'Alembert, no CasADi), and by the inverse dynamics; along a
motion also on the very polynomial the proof covers; a proof left undecided is never
reported certified."""

from __future__ import annotations

import functools
import math

import numpy as np
import pytest
from conftest import point_mass_dynamics
from pydantic import ValidationError
from scipy.optimize import minimize

from planner import coupling_block
from planner.certify import PROOF_RTOL
from planner.coupling import CouplingRequest, analyse
from planner.examples import MARGIN, example, seed_arm, seed_start, two_link, two_link_start
from planner.inverse import InverseDynamicsRequest, solve
from planner.model import Robot
from planner.ocp.interpolant import PiecewisePolynomial, hermite
from planner.waves import AMPLITUDE_FRACTION, WaveDesignRequest, WaveDesignResult, design
from planner.waves import region as region_problem

TOLERANCE = 1e-12
"""Allowed shortfall of the random sample below a proven bound [kg m^2]: rounding only
(the independent mass matrix rounds otherwise than the library's)."""


def independent_sigma(robot: Robot, q) -> float:
    M, _ = point_mass_dynamics(robot, q, np.zeros(robot.n))
    block = M[np.ix_(robot.passive, robot.active)]
    return float(np.linalg.svd(block, compute_uv=False)[len(robot.passive) - 1])


def random_minimum(robot: Robot, lower, upper, rng, count: int) -> float:
    """The least independent sigma_min over `count` random points of the box, lowered
    further by a bounded local minimisation from the best three (between grid points,
    where a sampled value passed off as a bound would be above it)."""
    lower, upper = np.asarray(lower), np.asarray(upper)
    Q = rng.uniform(lower, upper, (count, len(lower)))
    values = np.array([independent_sigma(robot, q) for q in Q])
    best = [values.min()]
    for q in Q[np.argsort(values)[:3]]:
        found = minimize(lambda x: independent_sigma(robot, x), q, method="L-BFGS-B",
                         bounds=list(zip(lower, upper, strict=True)))
        best.append(found.fun)
    return float(min(best))


def check_waves(result: WaveDesignResult, request: WaveDesignRequest) -> None:
    """Waves within the requested bounds, the returned robot carrying them, and a
    certificate that agrees with the status."""
    cert = result.certificate
    assert cert.target == request.margin and result.certified_sigma_min == cert.bound
    assert 0.0 <= cert.bound <= cert.sampled_min
    assert (cert.bound >= request.margin) == (result.status == "certified")
    assert (cert.sampled_min < request.margin) == (result.status == "infeasible")
    assert [w.joint for w in result.waves] == request.robot.active
    for wave in result.waves:
        length = request.robot.links[wave.joint].length
        assert 0.0 <= wave.amplitude <= min(request.amplitude_max, AMPLITUDE_FRACTION * length)
        assert 1 <= wave.frequency <= request.frequency_max
        assert -math.pi <= wave.phase < math.pi
        carried = result.robot.links[wave.joint].wave
        assert (carried.amplitude, carried.frequency, carried.phase) == (
            wave.amplitude, wave.frequency, wave.phase)


def region_request(robot: Robot, lower, upper, **options) -> WaveDesignRequest:
    return WaveDesignRequest.model_validate({
        "robot": robot.model_dump(), "amplitude_max": 0.06, "frequency_max": 4,
        "margin": 0.01, "region": {"lower": lower, "upper": upper}, **options})


# --------------------------------------------------------------------------- region


def test_two_link_box_around_the_singularity_is_certified(rng):
    robot = example("two-link-waveless").request["robot"]
    q0, q1 = two_link_start()
    lower, upper = [q0 - 0.1, q1 - 0.1], [q0 + 0.1, q1 + 0.1]
    req = region_request(Robot.model_validate(robot), lower, upper,
                         certification_points=10_000)
    result = design(req)
    assert result.status == "certified"
    assert result.certified_sigma_min >= req.margin
    check_waves(result, req)
    assert random_minimum(result.robot, lower, upper, rng, 20_000) >= (
        result.certified_sigma_min - TOLERANCE)
    assert independent_sigma(req.robot, [q0, q1]) < 1e-15  # singular without the wave
    assert "100 x 100 grid" in result.method


def test_seed_arm_box_in_all_four_joints_is_certified(rng):
    robot = Robot.model_validate(example("seed-arm-waveless").request["robot"])
    q = np.array(seed_start())
    lower, upper = (q - 0.03).tolist(), (q + 0.03).tolist()
    req = region_request(robot, lower, upper, certification_points=10_000)
    result = design(req)
    assert result.status == "certified"
    check_waves(result, req)
    assert random_minimum(result.robot, lower, upper, rng, 5_000) >= (
        result.certified_sigma_min - TOLERANCE)


@pytest.mark.slow
def test_seed_arm_box_with_the_default_dense_grid_survives_a_large_random_sample(rng):
    robot = Robot.model_validate(example("seed-arm-waveless").request["robot"])
    q = np.array(seed_start())
    lower, upper = (q - 0.05).tolist(), (q + 0.05).tolist()
    req = region_request(robot, lower, upper, frequency_max=6, starts=8)
    result = design(req)
    check_waves(result, req)
    assert "14 x 14 x 14 x 14 grid" in result.method
    assert random_minimum(result.robot, lower, upper, rng, 50_000) >= (
        result.certified_sigma_min - TOLERANCE)


def alternating(joints: str) -> Robot:
    """Point masses (absolute inertia 0), joints given as 'p'/'a' letters."""
    return Robot.model_validate({"links": [
        {"length": 0.5 - 0.05 * k, "mass": 1.0 - 0.1 * k, "joint": "passive" if j == "p"
         else "active"} for k, j in enumerate(joints)], "rotational_inertia": "absolute"})


@pytest.mark.parametrize("joints, free, frequency_max", [("paa", [1, 2], 2),
                                                        ("papapa", [3, 5], 1)])
def test_singular_points_of_non_square_and_three_row_blocks_are_lifted(joints, free,
                                                                      frequency_max, rng):
    """1 x 2 block (one passive joint) and 3 x 3 (six links): a box around a waveless
    singular point, found by the coupling analysis, gets a positive certified value."""
    robot = alternating(joints)
    lower, upper = [0.3] * robot.n, [0.3] * robot.n
    lower[-1], upper[-1] = 0.5, 3.0
    if joints == "paa":
        lower[1] = upper[1] = 0.3 + math.pi / 2
    report = analyse(CouplingRequest(robot=robot, grid={"lower": lower, "upper": upper,
                                                        "points": 26}, threshold=0.01))
    q = np.array(report.singular_points[0].q)
    assert independent_sigma(robot, q) < 1e-8
    lower, upper = q.copy(), q.copy()
    lower[free] -= 0.1
    upper[free] += 0.1
    req = region_request(robot, lower.tolist(), upper.tolist(), frequency_max=frequency_max,
                         starts=1, certification_points=900)
    result = design(req)
    check_waves(result, req)
    assert result.certified_sigma_min > 1e-3
    assert random_minimum(result.robot, lower, upper, rng, 2_000) >= (
        result.certified_sigma_min - TOLERANCE)


def two_link_box(margin: float) -> tuple[WaveDesignRequest, list[float], list[float]]:
    """A region design of the waveless two-link arm over its start ±0.1 rad [rad] under
    `margin` [kg m^2], with the box's lower and upper corners."""
    robot = Robot.model_validate(example("two-link-waveless").request["robot"])
    q0, q1 = two_link_start()
    lower, upper = [q0 - 0.1, q1 - 0.1], [q0 + 0.1, q1 + 0.1]
    return (region_request(robot, lower, upper, margin=margin, certification_points=2_500,
                           starts=2), lower, upper)


def test_an_unreachable_margin_is_infeasible_with_the_best_value_found(rng):
    req, lower, upper = two_link_box(margin=1.0)
    result = design(req)
    assert result.status == "infeasible"
    assert 0.0 < result.certified_sigma_min < 1.0
    check_waves(result, req)
    assert random_minimum(result.robot, lower, upper, rng, 5_000) >= (
        result.certified_sigma_min - TOLERANCE)


def test_a_proof_cut_short_is_undecided_never_certified(monkeypatch, rng):
    """Allowed one box, the proof over the two-link box bounds sigma_min by 0.03 kg m^2,
    below a margin of 0.035 that every sample keeps (0.039): undecided, the bound true."""
    monkeypatch.setattr(region_problem, "REGION_BOXES", 1)
    req, lower, upper = two_link_box(margin=0.035)
    result = design(req)
    assert result.status == "undecided" and result.certificate.status == "undecided"
    assert result.certificate.boxes == 1
    assert 0.0 < result.certified_sigma_min < req.margin <= result.certificate.sampled_min
    check_waves(result, req)
    assert random_minimum(result.robot, lower, upper, rng, 5_000) >= (
        result.certified_sigma_min - TOLERANCE)


# --------------------------------------------------------------------------- motion


@functools.cache
def designed(name: str) -> tuple[WaveDesignRequest, WaveDesignResult]:
    """A built-in motion design and its result, designed once."""
    req = WaveDesignRequest.model_validate(example(name).request)
    return req, design(req)


@pytest.mark.parametrize("name, arm", [("two-link-wave-design", two_link),
                                       ("seed-arm-wave-design", seed_arm)])
def test_motion_design_is_certified_by_an_independent_inverse_dynamics(name, arm):
    req, result = designed(name)
    assert result.status == "certified" and result.certified_sigma_min >= MARGIN
    assert result.certificate.status == "certified"
    check_waves(result, req)
    for wave in result.waves:  # the waves the examples carry
        built_in = arm(True).links[wave.joint].wave
        assert (wave.amplitude, wave.frequency) == (built_in.amplitude, built_in.frequency)
        assert abs(wave.phase - built_in.phase) < 1e-3
    m = req.motion
    check = solve(InverseDynamicsRequest(
        robot=result.robot, passive_motion=m.passive_motion, duration=m.duration,
        active_initial=m.active_initial, samples=3_001))  # other samples than the design's
    assert check.status == "completed"
    assert min(check.sigma_min) >= result.certified_sigma_min - 1e-9
    assert "2,001 evenly spaced samples" in result.method


@pytest.mark.parametrize("name", ["two-link-wave-design", "seed-arm-wave-design"])
def test_a_motion_bound_holds_on_the_whole_polynomial_it_was_proven_along(name):
    """The proof covers the cubic Hermite interpolant of the check's 2,001 inverse-dynamics
    samples: 20 points in every one of its 2,000 intervals stay above the bound, and
    the seed's arm is certified in one box per interval."""
    req, result = designed(name)
    m = req.motion
    run = solve(InverseDynamicsRequest(
        robot=result.robot, passive_motion=m.passive_motion, duration=m.duration,
        active_initial=m.active_initial, samples=2_001))  # the check's own samples
    t, q, dq = np.array(run.t), np.array(run.q), np.array(run.dq)
    motion = PiecewisePolynomial(t, hermite(q, dq, np.diff(t)))
    fine = np.linspace(0.0, m.duration, 20 * 2_000 + 1)
    sigma = coupling_block.along(result.robot, motion(fine)).least
    cert = result.certificate
    assert cert.bound <= sigma.min() and cert.bound <= cert.sampled_min <= min(run.sigma_min)
    assert cert.bound >= (1 - PROOF_RTOL) * sigma.min()
    assert "piecewise cubic Hermite interpolant of those samples" in result.method
    assert cert.boxes == 2_000 and cert.seconds > 0.0


def test_a_motion_that_cannot_keep_the_margin_is_infeasible_with_the_best_value_certified():
    # sigma_min stays far below 0.2 along this motion for every wave the search tries
    req = WaveDesignRequest.model_validate({**example("two-link-wave-design").request,
                                            "margin": 0.2})
    result = design(req)
    assert result.status == "infeasible" and 0.0 < result.certified_sigma_min < req.margin
    assert result.certificate.status == "refuted"
    check_waves(result, req)
    m = req.motion
    check = solve(InverseDynamicsRequest(
        robot=result.robot, passive_motion=m.passive_motion, duration=m.duration,
        active_initial=m.active_initial, samples=3_001))
    assert check.status == "completed"
    assert min(check.sigma_min) >= result.certified_sigma_min - 1e-9


# --------------------------------------------------------------------------- bad requests


def message(**changes) -> str:
    with pytest.raises(ValidationError) as exc:
        WaveDesignRequest.model_validate({**example("two-link-wave-design").request,
                                          **changes})
    (error,) = exc.value.errors()
    return error["msg"]


def test_messages_of_bad_requests():
    region = {"lower": [0.0, 1.0], "upper": [0.1, 1.1]}
    assert message(region=region) == (
        "Value error, region: give exactly one of region and motion")
    assert message(motion=None) == "Value error, region: give exactly one of region and motion"
    assert message(motion=None, region={"lower": [0.0], "upper": [0.1]}) == (
        "Value error, region: lower and upper need 2 entries each, one per joint")
    assert message(motion=None, region={"lower": [0.0, 1.0], "upper": [0.1, 0.9]}) == (
        "Value error, region.upper: every entry must be >= the matching entry of lower")
    motion = example("two-link-wave-design").request["motion"]
    assert message(motion={**motion, "active_initial": {"q": [], "dq": []}}) == (
        "Value error, motion.active_initial: q and dq need 1 entry each, one per active joint")
    assert message(frequency_max=0) == "Input should be greater than or equal to 1"
    assert message(margin=-0.1) == "Input should be greater than 0"
    assert message(amplitude_max=math.inf) == "Input should be a finite number"
