"""The delivered torque is the verified torque: a plan's piecewise polynomial, fed to
POST /v1/simulate, reproduces the plan's reported replay error; it keeps the task's torque
limit on the whole of every interval (not only where the torque variables live), as the
planned states keep their bounds, and a plan that does not is not verified."""

from __future__ import annotations

import numpy as np
import pytest
from service_fixtures import client

from planner.examples import example
from planner.ocp import plan
from planner.ocp import problem as problem_module
from planner.ocp.interpolant import PiecewisePolynomial, bernstein, hull
from planner.ocp.key import ProblemKey
from planner.ocp.problem import problem
from planner.ocp.replays import REPLAY_SAMPLES
from planner.ocp.terms import TorqueLimit
from planner.ocp.verdict import unverified_reason
from planner.scene import Scene

METHODS = ("legendre", "radau", "hermite-simpson", "trapezoidal", "multiple-shooting")
ARM = {"links": [
    {"length": 0.5, "mass": 1.0, "inertia": 0.01, "joint": "active"},
    {"length": 0.4, "mass": 0.8, "inertia": 0.008, "joint": "active",
     "wave": {"amplitude": 0.05, "frequency": 3, "phase": 0.3}}], "gravity": 9.81}
LIMIT = 4.0  # [N m]: binds on the time-optimal motion below (it would take 6.9 N m)


def time_optimal(method: str, N: int = 10, **task) -> Scene:
    """The two-link arm rest to rest as fast as |tau| <= LIMIT allows (a little effort
    keeps the torque unique where the limit does not bind)."""
    base = {"duration": {"min": 0.2, "max": 3.0}, "initial": {"q": [0.0, 0.5], "dq": [0.0, 0.0]},
            "final": {"q": [0.6, 1.2], "dq": [0.0, 0.0]}, "torque_limit": LIMIT,
            "objective": {"time": 1.0, "effort": 1e-3}}
    return Scene.model_validate({"robot": ARM, "task": {**base, **task},
                                 "transcription": {"method": method, "intervals": N}})


def exact_extremes(coefficients) -> tuple[np.ndarray, np.ndarray]:
    """The smallest and largest value per component of a piecewise polynomial (K, m, dim),
    ascending powers of s on [0, 1]: at the interval ends and the real roots of the
    derivative inside (numpy's roots, independent of the library's extrema)."""
    c = np.asarray(coefficients, float)
    K, m, dim = c.shape
    low, high = np.full(dim, np.inf), np.full(dim, -np.inf)
    P = np.polynomial.polynomial
    for k in range(K):
        for d in range(dim):
            roots = P.polyroots(P.polyder(c[k, :, d])) if m > 2 else np.zeros(0)
            inside = roots[(np.abs(roots.imag) < 1e-9) & (roots.real > 0) & (roots.real < 1)]
            values = P.polyval(np.concatenate([[0.0, 1.0], inside.real]), c[k, :, d])
            low[d], high[d] = min(low[d], values.min()), max(high[d], values.max())
    return low, high


@pytest.fixture
def without_torque_rows(monkeypatch):
    """The planted fault: the torque limit held at the torque variables only (the term
    that bounds the rest of each interval's polynomial switched off), in NLPs built apart
    from the cached ones."""
    for cached in (problem_module.stages, problem_module.cached_problem):
        cached.cache_clear()
    monkeypatch.setattr(TorqueLimit, "wanted", lambda self, key: False)
    yield
    for cached in (problem_module.stages, problem_module.cached_problem):
        cached.cache_clear()


@pytest.fixture(scope="module")
def api(tmp_path_factory):
    with client(tmp_path_factory.mktemp("torque")) as c:
        yield c


@pytest.fixture(scope="module")
def two_link():
    sc = Scene.model_validate(example("two-link-plan").request)
    return sc, plan(sc)


def _replay_error(api, sc: Scene, result, body: dict) -> float:
    """max |q_sim - q_plan| over a /v1/simulate answer, the plan taken at its dense samples."""
    answer = api.post("/v1/simulate", json={
        "robot": sc.robot.model_dump(mode="json"),
        "initial": {"q": result.q[0], "dq": result.dq[0]},
        "samples_per_interval": REPLAY_SAMPLES, **body})
    assert answer.status_code == 200, answer.text
    sim = answer.json()
    assert sim["status"] == "completed"
    dense_t, dense_q = np.asarray(result.dense.t), np.asarray(result.dense.q)
    at = [int(np.argmin(np.abs(dense_t - t))) for t in sim["t"]]
    assert np.allclose(dense_t[at], sim["t"], rtol=0.0, atol=1e-12)
    return float(np.abs(np.asarray(sim["q"]) - dense_q[at]).max())


def test_the_plans_torque_polynomial_reproduces_its_replay_error_through_simulate(api, two_link):
    sc, result = two_link
    reported = result.verification.resimulation_error
    error = _replay_error(api, sc, result, {"torque": result.torque.model_dump(mode="json")})
    # both integrate with CVODES at rtol = atol = 1e-10, each with its own steps
    assert error == pytest.approx(reported, rel=0.0, abs=1e-8)
    assert reported < result.verification.tolerance
    # the node torques, linearly interpolated, are another torque: they miss the plan
    nodes = _replay_error(api, sc, result, {"t": result.t, "tau": result.tau})
    assert nodes > 100 * reported


def test_the_polynomial_is_the_torque_at_the_nodes_and_between(two_link):
    _, result = two_link
    assert np.allclose(result.torque.evaluate(np.asarray(result.dense.t)), result.dense.tau,
                       rtol=0.0, atol=1e-12)
    # Legendre collocation of degree 3: a quadratic per interval
    assert np.asarray(result.torque.coefficients).shape == (len(result.t) - 1, 3, 1)


def test_simulate_takes_either_samples_or_a_polynomial(api, two_link):
    sc, result = two_link
    base = {"robot": sc.robot.model_dump(mode="json"),
            "initial": {"q": result.q[0], "dq": result.dq[0]}}
    torque = result.torque.model_dump(mode="json")
    both = api.post("/v1/simulate", json={**base, "torque": torque, "t": result.t,
                                           "tau": result.tau})
    assert both.status_code == 422
    assert "give either t and tau, or torque (got t, tau, torque)" in both.text
    wide = {**torque, "coefficients": [[[*row, 0.0] for row in interval]
                                       for interval in torque["coefficients"]]}
    answer = api.post("/v1/simulate", json={**base, "torque": wide})
    assert answer.status_code == 422
    assert ("coefficients: every power needs 1 entries, one per active joint (got 2)"
            in answer.text)


@pytest.mark.parametrize("method", METHODS)
def test_a_binding_torque_limit_holds_for_the_delivered_polynomial_everywhere(method):
    result = plan(time_optimal(method))
    v = result.verification
    assert result.solver.success and v.verified, (result.solver.status, v)
    low, high = exact_extremes(result.torque.coefficients)
    peak = float(np.max(np.maximum(-low, high)))
    assert peak <= LIMIT * (1 + 1e-6)
    assert peak >= LIMIT * (1 - 1e-3)  # the limit binds: the time is the least it allows
    assert v.torque_excess is not None and v.torque_excess <= 1e-6 * LIMIT
    assert v.limit_violations == []
    # the reported minimum time is achievable within the limit: the delivered torque,
    # replayed from the start over the whole reported duration, moves the arm to the goal
    assert v.resimulation_error is not None and v.resimulation_error < 1e-2
    assert np.allclose(result.q[-1], [0.6, 1.2]) and np.allclose(result.dq[-1], 0.0)


@pytest.mark.parametrize("method", ["legendre", "hermite-simpson"])
def test_a_plan_whose_delivered_torque_passes_its_limit_between_the_points_is_not_verified(
        method, without_torque_rows):
    result = plan(time_optimal(method))
    v = result.verification
    low, high = exact_extremes(result.torque.coefficients)
    excess = float(np.max(np.maximum(-low, high))) - LIMIT
    assert result.solver.success and excess > 0.1  # the variables keep it, the polynomial not
    # the reported excess is the polynomial's exact one, not the dense samples' (which
    # miss the interval ends where a Legendre torque peaks)
    assert v.torque_excess == pytest.approx(excess, rel=1e-9)
    assert v.verified is False and v.local_error <= v.tolerance
    reason = unverified_reason(v)
    assert reason is not None and reason.startswith(
        "the plan does not keep the task's limits everywhere: the delivered torque at joint")
    assert f"beyond its limit of {LIMIT:g} N m" in reason


def test_a_limit_of_zero_holds_a_joint_still_everywhere():
    result = plan(time_optimal("legendre", torque_limit=[5.0, 0.0]))
    assert result.solver.success and result.verification.verified
    low, high = exact_extremes(result.torque.coefficients)
    assert (low[1], high[1]) == (0.0, 0.0)
    assert high[0] <= 5.0 * (1 + 1e-6) and -low[0] <= 5.0 * (1 + 1e-6)


@pytest.mark.parametrize("method", ["legendre", "hermite-simpson", "multiple-shooting"])
def test_velocity_and_position_bounds_hold_along_the_state_interpolant(method):
    bounds = {"velocity_bounds": {"lower": [-1.5, None], "upper": [1.5, 2.0]},
              "position_bounds": {"lower": [-0.05, None], "upper": [None, 1.2]}}
    result = plan(time_optimal(method, N=12, **bounds))
    v = result.verification
    assert result.solver.success and v.verified, v.limit_violations
    assert v.position_excess is not None and v.position_excess <= 1e-6
    assert v.velocity_excess is not None and v.velocity_excess <= 1e-6
    assert np.max(np.asarray(result.dense.q)[:, 1]) <= 1.2 + 1e-6
    # the bounds bind: the fastest motion runs joint 0 at its rate bound
    assert np.max(np.asarray(result.dq)[:, 0]) > 1.45


def test_the_key_asks_for_rows_only_where_the_variables_do_not_bound_the_polynomial():
    for method, rows in (("trapezoidal", False), ("multiple-shooting", False),
                         ("legendre", True), ("radau", True), ("hermite-simpson", True)):
        limited, free = ProblemKey.of(time_optimal(method)), ProblemKey.of(
            time_optimal(method, torque_limit=None))
        assert limited.torque_limit is rows, method
        assert (limited == free) is not rows, method  # one NLP with and without a limit
    # a position bound builds rows for the bounded joints only
    key = ProblemKey.of(time_optimal("legendre", position_bounds={
        "lower": [None, -1.0], "upper": [None, None]}))
    assert key.position_bounds == ((1,), ()) and key.velocity_bounds == ((), ())
    # one NLP serves every limit: the limit is a parameter
    assert problem(ProblemKey.of(time_optimal("radau", torque_limit=1.0))) is \
        problem(ProblemKey.of(time_optimal("radau", torque_limit=9.0)))


def test_bernstein_coefficients_bound_the_polynomial_and_extrema_are_exact():
    rng = np.random.default_rng(24)
    points = np.array([0.1127, 0.5, 0.8873])
    values = rng.normal(size=3)
    b = bernstein(points) @ values
    s = np.linspace(0.0, 1.0, 1001)
    p = np.polynomial.polynomial.polyval(
        s, np.linalg.solve(np.vander(points, increasing=True), values))
    assert b.min() - 1e-12 <= p.min() and p.max() <= b.max() + 1e-12
    # the ends are the polynomial's values there; a point at 0 or 1 makes them variables
    assert b[0] == pytest.approx(p[0]) and b[-1] == pytest.approx(p[-1])
    assert hull([0.0, 0.5, 1.0]).shape == (1, 3) and hull([0.5]).shape == (0, 1)
    assert hull([1 / 3, 1.0]).shape == (1, 2)
    assert hull([0.0, 0.2, 0.6], end_known=True).shape == (1, 3)
    coeffs = rng.normal(size=(30, 5, 2))
    ext = PiecewisePolynomial(np.linspace(0.0, 3.0, 31), coeffs).extrema()
    low, high = exact_extremes(coeffs)
    assert np.allclose(ext.low.min(axis=0), low, atol=1e-12)
    assert np.allclose(ext.high.max(axis=0), high, atol=1e-12)
