"""Reference profiles of the prescribed passive motion: endpoints, rest-to-rest ends,
velocity and acceleration as the derivatives of position (central differences), the
quintic as Beta(3, 3), the sampled spline's knots and continuity, and the classical
inverse dynamics following each profile exactly.

Finite-difference tolerances: the central difference (f(t+h) - f(t-h)) / 2h differs
from f'(t) by at most h^2/6 max|f'''| (truncation) plus about eps |f| / h (rounding,
~1e-12 here). Every profile below has its next two derivatives (jerk and snap) under
DERIVATIVE_BOUND on the times tested (the largest, Beta(2.5, 7)'s snap on
[0.05 T, 0.95 T], is about 600 rad/s^4), so with H = 1e-4 s the tolerance is
H^2/6 * DERIVATIVE_BOUND ~ 3e-6, while a wrong chain-rule factor errs by O(1).
"""

from __future__ import annotations

import numpy as np
import pytest

from planner.examples import DURATION, TWO_LINK_PASSIVE, two_link, two_link_start
from planner.inverse import InverseDynamicsRequest, solve
from planner.profiles import BetaProfile, QuinticProfile, SampledProfile

T = 2.0
START = [0.1, -0.3, 1.2]
END = [0.7, 0.4, -0.5]
"""Three passive joints, one of them moving backwards [rad]."""
SHAPES = [(3.0, 3.0), (3.0, 5.0), (4.0, 2.5), (2.5, 7.0)]
"""(alpha, beta) of the Beta profiles, all > 2 (rest-to-rest in acceleration)."""

H = 1e-4
DERIVATIVE_BOUND = 2e3
FD_TOL = H**2 / 6 * DERIVATIVE_BOUND
INTERIOR = np.linspace(0.05, 0.95, 19) * T

SAMPLE_T = [0.0, 0.3, 0.7, 1.2, 1.6, 2.0]
SAMPLE_Q = [[0.0, 1.0], [0.3, 0.5], [0.1, 0.2], [0.2, 0.1], [0.5, -0.2], [0.6, 0.0]]
"""Two passive joints sampled at uneven times; joint 0 goes back and forth."""


def beta_profile(alpha: float, beta: float) -> BetaProfile:
    return BetaProfile(start=START, end=END, alpha=alpha, beta=beta)


def sampled() -> SampledProfile:
    return SampledProfile(t=SAMPLE_T, q=SAMPLE_Q)


def assert_rates_are_derivatives(profile: BetaProfile | SampledProfile,
                                 times: np.ndarray) -> None:
    """Velocity is the central difference of position, acceleration that of velocity."""
    _, dq, ddq = profile.evaluate(times, T)
    q_plus, dq_plus, _ = profile.evaluate(times + H, T)
    q_minus, dq_minus, _ = profile.evaluate(times - H, T)
    np.testing.assert_allclose(dq, (q_plus - q_minus) / (2 * H), rtol=0.0, atol=FD_TOL)
    np.testing.assert_allclose(ddq, (dq_plus - dq_minus) / (2 * H), rtol=0.0, atol=FD_TOL)


# --------------------------------------------------------------------------- Beta


@pytest.mark.parametrize(("alpha", "beta"), SHAPES)
def test_beta_position_goes_from_start_to_end(alpha: float, beta: float):
    q, _, _ = beta_profile(alpha, beta).evaluate(np.array([0.0, T]), T)
    np.testing.assert_allclose(q, [START, END], rtol=0.0, atol=1e-15)


@pytest.mark.parametrize(("alpha", "beta"), SHAPES)
def test_beta_position_moves_monotonically_between_the_endpoints(alpha: float, beta: float):
    q, _, _ = beta_profile(alpha, beta).evaluate(np.linspace(0.0, T, 401), T)
    steps = np.diff(q, axis=0) * np.sign(np.subtract(END, START))
    assert np.all(steps >= 0.0)


@pytest.mark.parametrize(("alpha", "beta"), SHAPES)
def test_beta_velocity_and_acceleration_are_derivatives_of_position(alpha: float, beta: float):
    assert_rates_are_derivatives(beta_profile(alpha, beta), INTERIOR)


@pytest.mark.parametrize(("alpha", "beta"), SHAPES)
def test_beta_is_rest_to_rest_above_two(alpha: float, beta: float):
    _, dq, ddq = beta_profile(alpha, beta).evaluate(np.array([0.0, T]), T)
    assert np.array_equal(dq, np.zeros((2, 3)))
    assert np.array_equal(ddq, np.zeros((2, 3)))


def test_beta_two_two_rests_in_velocity_only():
    """I_x(2, 2) = 3x^2 - 2x^3: s''(0) = 6, s''(1) = -6, so ddq = +-6 (end - start) / T^2."""
    _, dq, ddq = beta_profile(2.0, 2.0).evaluate(np.array([0.0, T]), T)
    delta = np.subtract(END, START)
    assert np.array_equal(dq, np.zeros((2, 3)))
    np.testing.assert_allclose(ddq, [6 * delta / T**2, -6 * delta / T**2], rtol=1e-14)


def test_beta_moves_several_joints_as_each_alone():
    times = np.linspace(0.0, T, 51)
    together = beta_profile(4.0, 2.5).evaluate(times, T)
    assert all(part.shape == (51, 3) for part in together)
    for j, (start, end) in enumerate(zip(START, END, strict=True)):
        alone = BetaProfile(start=[start], end=[end], alpha=4.0, beta=2.5).evaluate(times, T)
        for joint, single in zip(together, alone, strict=True):
            np.testing.assert_allclose(joint[:, j], single[:, 0], rtol=0.0, atol=1e-15)


# --------------------------------------------------------------------------- quintic


def test_quintic_equals_beta_three_three():
    times = np.linspace(0.0, T, 201)
    quintic = QuinticProfile(start=START, end=END).evaluate(times, T)
    reference = beta_profile(3.0, 3.0).evaluate(times, T)
    for got, expected in zip(quintic, reference, strict=True):
        np.testing.assert_allclose(got, expected, rtol=0.0, atol=1e-12)


# --------------------------------------------------------------------------- samples


def test_samples_are_reproduced_at_their_times():
    """Up to rounding: the last knot is evaluated on the last cubic piece."""
    q, _, _ = sampled().evaluate(np.array(SAMPLE_T), T)
    np.testing.assert_allclose(q, SAMPLE_Q, rtol=0.0, atol=1e-15)


def test_samples_start_and_end_at_rest_in_velocity():
    _, dq, _ = sampled().evaluate(np.array([0.0, T]), T)
    np.testing.assert_allclose(dq, np.zeros((2, 2)), rtol=0.0, atol=1e-14)


def test_samples_motion_is_continuous_across_interior_sample_times():
    """Across t_k +- eps a continuous quantity moves by at most 2 eps times its rate
    (velocity, acceleration, jerk, all under DERIVATIVE_BOUND): a kink or a jump in any
    of them would show as an O(1) difference."""
    eps = 1e-9
    knots = np.array(SAMPLE_T[1:-1])
    profile = sampled()
    for before, after in zip(profile.evaluate(knots - eps, T), profile.evaluate(knots + eps, T),
                             strict=True):
        np.testing.assert_allclose(after, before, rtol=0.0, atol=2 * eps * DERIVATIVE_BOUND)


def test_samples_velocity_and_acceleration_are_derivatives_of_position():
    """At the midpoints between samples, and near both ends."""
    knots = np.array(SAMPLE_T)
    times = np.concatenate([(knots[:-1] + knots[1:]) / 2, [0.05 * T, 0.95 * T]])
    assert_rates_are_derivatives(sampled(), times)


# --------------------------------------------------------------------------- inverse dynamics


@pytest.mark.parametrize("motion", [
    {"profile": "quintic", "start": TWO_LINK_PASSIVE[0], "end": TWO_LINK_PASSIVE[1]},
    {"profile": "samples", "t": [0.0, 0.5, 1.1, DURATION], "q": [[0.0], [0.1], [0.35], [0.6]]},
], ids=["quintic", "samples"])
def test_inverse_dynamics_follows_the_profile(motion: dict):
    """The two-link arm with its designed wave: M_pa stays regular along either motion."""
    req = InverseDynamicsRequest(
        robot=two_link(True), passive_motion=motion, duration=DURATION,
        active_initial={"q": [two_link_start()[1]], "dq": [0.0]}, samples=41)
    result = solve(req)
    assert result.status == "completed" and result.singularity is None
    assert len(result.t) == 41 and result.t[-1] == DURATION
    passive = req.robot.passive
    for got, expected in zip((result.q, result.dq, result.ddq),
                             req.passive_motion.evaluate(np.array(result.t), DURATION),
                             strict=True):
        np.testing.assert_allclose(np.array(got)[:, passive], expected, rtol=0.0, atol=1e-9)
