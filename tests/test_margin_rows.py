"""The coupling margin's NLP rows (planner.margin_rows.margin_function): every row at or
above 0 exactly where sigma_min(M_pa) >= margin with det M_pa of the kept sign, against
numpy's singular values, for the 2 x 2 block of the seed arm (its own rows) and the 2 x 1
and 1 x 1 blocks (leading principal minors); derivatives against central differences."""

from __future__ import annotations

import numpy as np
import pytest

from planner.coupling_block import blocks
from planner.examples import seed_arm
from planner.margin_rows import margin_function
from planner.model import Robot, Structure, parameters
from testbed.robots import chain

ARMS = {"2x2": seed_arm(True), "2x1": Robot.model_validate(chain(3, True)),
        "1x1": Robot.model_validate(chain(2, True))}


def _rows(robot: Robot, q: np.ndarray, margin: float, sign: float) -> np.ndarray:
    """The rows (m, K) at the configurations q (K, n)."""
    s = Structure.of(robot)
    q = np.atleast_2d(q)
    f = margin_function(s).map(len(q))
    return np.array(f(q.T, parameters(robot, s), margin, sign))


@pytest.mark.parametrize("name", list(ARMS))
def test_the_rows_hold_exactly_where_the_margin_and_the_sign_do(name):
    robot = ARMS[name]
    rng = np.random.default_rng(3)
    configurations = rng.uniform(-np.pi, np.pi, (300, robot.n))
    mpa = blocks(robot, configurations)
    sigma = np.linalg.svd(mpa, compute_uv=False)
    det = np.linalg.det(mpa) if mpa.shape[1] == mpa.shape[2] else None
    kinds = set()
    for margin in np.array([0.3, 1.0, 3.0]) * np.median(sigma[:, -1]):
        for sign in (1.0, -1.0):
            holds = (sigma[:, -1] >= margin) & (True if det is None else sign * det > 0)
            rows = _rows(robot, configurations, margin, sign)
            np.testing.assert_array_equal(np.all(rows >= 0, axis=0), holds)
            kinds |= set(holds.tolist())
    assert kinds == {True, False}


def test_a_square_blocks_margin_row_is_zero_where_sigma_min_equals_the_margin():
    robot = ARMS["2x2"]
    q = np.random.default_rng(5).uniform(-1.0, 1.0, robot.n)
    mpa = blocks(robot, q[None, :])[0]
    sigma, det = np.linalg.svd(mpa, compute_uv=False), np.linalg.det(mpa)
    rows = _rows(robot, q, float(sigma[-1]), float(np.sign(det))).ravel()
    assert abs(rows[0]) < 1e-9  # the margin row binds; the sign row does not
    assert rows[1] > 0.0


@pytest.mark.parametrize("name", list(ARMS))
def test_the_rows_derivatives_agree_with_central_differences(name):
    import casadi as ca

    robot = ARMS[name]
    s = Structure.of(robot)
    f = margin_function(s)
    q_sym = ca.SX.sym("q", robot.n)
    p = parameters(robot, s)
    jac = ca.Function("margin_jacobian", [q_sym], [ca.jacobian(f(q_sym, p, 0.01, 1.0), q_sym)])
    rng = np.random.default_rng(11)
    for q in rng.uniform(-1.0, 1.0, (5, robot.n)):
        exact = np.array(jac(q))
        step = 1e-6
        fd = np.stack([(np.array(f(q + step * e, p, 0.01, 1.0)) -
                        np.array(f(q - step * e, p, 0.01, 1.0))).ravel() / (2 * step)
                       for e in np.eye(robot.n)], axis=1)
        np.testing.assert_allclose(exact, fd, rtol=1e-5, atol=1e-5 * np.abs(exact).max())
