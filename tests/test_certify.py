"""Proven lower bounds of the coupling margin (planner.certify) against dense sampling.

A bound is never above the smallest sampled sigma_least(M_pa) (numpy's SVD of the block the
planner evaluates, at points drawn inside the box or along the motion), and where it says
"decided" it is within the stated RTOL of it. The enclosures are checked on their own too:
M_pa at every sampled point lies in the balls. A planted fault (an operation that drops its
radius, a Weyl step without the radius) makes these checks fail. A whole motion's bound
(`path`) joins its intervals', and `decide` reads a target off a proof without calling an
undecided one certified.
"""

from __future__ import annotations

import time

import casadi as ca
import numpy as np
import pytest
from flint import arb

from planner.certify import Bound, along, ball, decide, margin, path, region, singular
from planner.certify.boxes import minimise
from planner.certify.margin import RTOL, Block
from planner.coupling_block import along as sampled
from planner.coupling_block import blocks
from planner.examples import seed_arm, seed_start, two_link, two_link_start
from planner.model import Robot
from planner.ocp.interpolant import PiecewisePolynomial
from testbed.robots import random_robot


def _generated() -> list[tuple[Robot, np.ndarray]]:
    """Arms of 2 to 5 links with passive joints, each with a configuration."""
    rng = np.random.default_rng(20261127)
    out = []
    while len(out) < 6:
        robot = random_robot(rng, int(rng.integers(2, 6)))
        if robot.active and len(robot.active) < robot.n:
            out.append((robot, rng.uniform(-np.pi, np.pi, robot.n)))
    return out


ARMS = [(seed_arm(True), np.array(seed_start())), (two_link(True), np.array(two_link_start())),
        *_generated()]


def _inside(balls: list[list[arb]], matrix: np.ndarray) -> bool:
    return all(b.contains(arb(float(x))) for row, mrow in zip(balls, matrix, strict=True)
               for b, x in zip(row, mrow, strict=True))


@pytest.mark.parametrize("k", range(len(ARMS)))
def test_the_enclosure_holds_the_block_at_every_point_of_the_box(k):
    robot, q0 = ARMS[k]
    rng = np.random.default_rng(k)
    half = 0.05
    box = [arb(float(x), half) for x in q0]
    enclosure, _ = Block(robot).over(box, q0)
    points = q0 + rng.uniform(-half, half, (400, robot.n))
    assert all(_inside(enclosure, m) for m in blocks(robot, points))


def test_a_region_bound_is_never_above_the_sampled_minimum_and_decides_within_rtol():
    """Boxes 0.01 rad wide with one side five times longer; the 4-link arm drawn at 7e-5
    kg m^2 from a singularity, and one 5-link arm, stay undecided within 2,000 boxes."""
    decided = 0
    for k, (robot, q0) in enumerate(ARMS):
        lower, upper = q0 - 0.005, q0 + 0.005
        upper[0] = lower[0] + 0.05
        bound = region(robot, lower, upper, max_boxes=2000)
        rng = np.random.default_rng(k)
        dense = sampled(robot, lower + (upper - lower) * rng.random((20_000, robot.n))).least
        assert bound.lower <= dense.min()
        if bound.status == "decided":
            decided += 1
            assert bound.lower >= (1 - RTOL) * bound.sampled
    assert decided == len(ARMS) - 2


def _motion(q0: np.ndarray, seed: int) -> PiecewisePolynomial:
    """A random motion of 8 cubic intervals near q0 (not continuous at the breaks)."""
    rng = np.random.default_rng(seed)
    coeffs = rng.normal(0.0, 0.05, (8, 4, q0.size))
    coeffs[:, 0] = q0 + rng.normal(0.0, 0.05, (8, q0.size))
    return PiecewisePolynomial(np.linspace(0.0, 2.0, 9), coeffs)


def test_bounds_along_a_motion_hold_between_every_pair_of_samples():
    """Undecided within 200 boxes: the intervals that pass within 1e-3 kg m^2 of a
    singularity and some of the near-singular 4-link arm's (7 of 64)."""
    decided = 0
    for k, (robot, q0) in enumerate(ARMS):
        q = _motion(q0, k)
        bounds = along(robot, q)
        least = sampled(robot, q(np.linspace(0.0, 2.0, 8 * 2000 + 1))).least
        for i, b in enumerate(bounds):
            inside = least[i * 2000:(i + 1) * 2000]  # the break belongs to the next
            assert b.lower <= inside.min()
            if b.status == "decided":
                decided += 1
                assert b.lower >= (1 - RTOL) * b.sampled
    assert decided >= 57


def test_a_target_is_certified_refuted_or_undecided_as_it_stands():
    robot, q0 = ARMS[0]
    q = _motion(q0, 0)
    t = np.linspace(0.0, 2.0, 16_001)
    least = sampled(robot, q(t)).least.min()
    assert all(b.status == "certified" for b in along(robot, q, target=0.9 * least))
    assert any(b.status == "refuted" for b in along(robot, q, target=1.01 * least))
    undecided = along(robot, q, target=0.999999 * least, max_boxes=3)
    assert any(b.status == "undecided" and b.boxes <= 3 for b in undecided)


def test_weyls_step_without_the_radius_passes_the_sampled_minimum(monkeypatch):
    """Weyl's step subtracts the radius: with it planted away, the bound passes the
    sampled minimum somewhere, which the checks above would catch."""
    robot, q0 = ARMS[0]
    rng = np.random.default_rng(5)
    half = 0.05
    box = [arb(float(x), half) for x in q0]
    points = q0 + rng.uniform(-half, half, (2000, robot.n))
    dense = sampled(robot, points).least.min()
    enclosure, _ = Block(robot).over(box, q0)
    assert singular.least_lower(enclosure) <= dense
    monkeypatch.setattr(singular, "_norm_upper", lambda rad: 0.0)
    assert singular.least_lower(enclosure) > dense


def test_an_operation_that_drops_its_radius_is_caught(monkeypatch):
    robot, q0 = ARMS[0]
    monkeypatch.setitem(ball._UNARY, ca.OP_SIN, lambda x: arb(x.mid()).sin())
    monkeypatch.setitem(ball._UNARY, ca.OP_COS, lambda x: arb(x.mid()).cos())
    margin._functions.cache_clear()
    try:
        box = [arb(float(x), 0.05) for x in q0]
        enclosure, _ = Block(robot).over(box, q0)
        points = q0 + np.random.default_rng(1).uniform(-0.05, 0.05, (400, robot.n))
        assert not all(_inside(enclosure, m) for m in blocks(robot, points))
    finally:
        margin._functions.cache_clear()


def test_an_exact_square_block_is_bounded_within_rounding():
    a = np.array([[2.0, 1.0], [0.5, 3.0]])
    exact = np.linalg.svd(a, compute_uv=False)[-1]
    bound = singular.least_lower([[arb(float(x)) for x in row] for row in a])
    assert exact * (1 - 1e-8) <= bound <= exact


def test_a_nan_ball_proves_nothing():
    nan = arb(0) / arb(0, 1)
    assert singular.least_lower([[nan, arb(1)]]) == 0.0


def test_the_box_cap_leaves_the_bound_undecided_but_true():
    calls = []

    def enclose(lo, hi):
        calls.append(1)
        return -1.0, 1.0  # never decides
    out = minimise(enclose, np.zeros(2), np.ones(2), target=0.5, rtol=RTOL, max_boxes=9)
    assert out.status == "undecided" and out.lower == -1.0 and out.boxes == len(calls) <= 9


def test_a_half_keeps_its_parents_bound():
    """An enclosure whose bound worsens as boxes shrink: the first box's bound stands."""
    out = minimise(lambda lo, hi: (-1.0 / float((hi - lo).sum()), 1.0), np.zeros(2),
                   np.ones(2), target=None, rtol=RTOL, max_boxes=9)
    assert out.lower == -0.5 and out.boxes == 9


def test_a_path_joins_its_intervals_and_skips_those_past_the_deadline():
    robot, q0 = ARMS[1]
    q = _motion(q0, 1)
    bounds, whole = along(robot, q), path(robot, q)
    k = int(np.argmin([b.sampled for b in bounds]))
    assert whole.lower == min(b.lower for b in bounds) and whole.sampled == bounds[k].sampled
    assert whole.boxes == sum(b.boxes for b in bounds)
    assert q.breaks[k] < whole.where[0] < q.breaks[k + 1]
    assert whole.status == ("decided" if all(b.status == "decided" for b in bounds)
                            else "undecided")
    late = path(robot, q, target=0.0, deadline=time.monotonic() - 1.0)
    assert (late.status, late.lower, late.boxes) == ("undecided", 0.0, 0)


def _runs(*bounds: Bound):
    """A proof that answers `bounds` in turn, and the targets it was asked for."""
    asked: list[float | None] = []

    def run(target: float | None) -> Bound:
        asked.append(target)
        return bounds[len(asked) - 1]
    return run, asked


def _bound(lower: float, sampled: float, status) -> Bound:
    return Bound(lower, sampled, np.zeros(1), status, 3, 0.5)


def test_a_target_between_a_decided_bound_and_the_samples_is_proven_for_itself():
    run, asked = _runs(_bound(0.97, 1.0, "decided"), _bound(0.99, 1.01, "certified"))
    cert = decide(run, 0.98)
    assert asked == [None, 0.98] and cert.status == "certified"
    assert (cert.bound, cert.sampled_min, cert.boxes, cert.seconds) == (0.99, 1.0, 6, 1.0)


def test_a_bound_stopped_by_its_cap_is_undecided_and_not_run_again():
    run, asked = _runs(_bound(0.5, 1.0, "undecided"))
    cert = decide(run, 0.8)
    assert asked == [None] and cert.status == "undecided" and cert.bound == 0.5


def test_a_sample_below_the_target_refutes_it_and_nothing_proven_reads_zero():
    run, asked = _runs(_bound(-0.1, 1.0, "decided"))
    cert = decide(run, 0.5, sampled=0.4)
    assert asked == [None] and cert.status == "refuted"
    assert (cert.bound, cert.sampled_min) == (0.0, 0.4)


def test_an_unsupported_operation_is_named():
    x = ca.SX.sym("x")
    with pytest.raises(ball.Unsupported, match="has no ball enclosure"):
        ball.BallFunction(ca.Function("f", [x], [ca.erf(x)]))


def _keeps_agrees(robot: Robot, q0: np.ndarray, seed: int, block: Block) -> bool:
    """Whether the row test never proves a target that the samples break (targets a
    little below and above the sampled minimum of a 0.02 rad box)."""
    rng = np.random.default_rng(seed)
    box = [arb(float(x), 0.01) for x in q0]
    least = sampled(robot, q0 + rng.uniform(-0.01, 0.01, (4000, robot.n))).least.min()
    return not block.keeps(box, q0, 1.02 * least) and (
        block.keeps(box, q0, 0.5 * least) or least < 1e-3)


@pytest.mark.parametrize("k", range(len(ARMS)))
def test_the_margin_rows_prove_only_what_holds(k):
    robot, q0 = ARMS[k]
    assert _keeps_agrees(robot, q0, k, Block(robot))


def test_rows_without_their_slopes_prove_too_much():
    robot, q0 = ARMS[0]
    block = Block(robot)
    flat = ball.BallFunction(ca.Function("flat", [ca.SX.sym("q", 4), ca.SX.sym("p", 18),
                                                  ca.SX.sym("m"), ca.SX.sym("s")],
                                         [ca.SX.zeros(2, 4)]))
    block.row_slopes = flat
    assert not all(_keeps_agrees(robot, q0 + 0.3 * j, j, block) for j in range(6))


def test_targets_along_a_motion_are_proven_only_where_they_hold():
    """Per interval, a target just below the densely sampled minimum and one just above:
    the first proven (the rows' form in s decides where Weyl's bound alone would need
    tiny pieces), the second never."""
    proven = 0
    for k, (robot, q0) in enumerate(ARMS):
        q = _motion(q0, k)
        least = sampled(robot, q(np.linspace(0.0, 2.0, 8 * 2000 + 1))).least
        for i in range(8):
            low = float(least[i * 2000:(i + 1) * 2000].min())
            if low < 1e-3:
                continue
            piece = PiecewisePolynomial(q.breaks[i:i + 2], q.coeffs[i:i + 1])
            above = along(robot, piece, target=low * 1.0005)[0]
            below = along(robot, piece, target=low * 0.999)[0]
            assert above.status != "certified"
            proven += below.status == "certified"
    assert proven >= 57  # of 61 (Weyl's bound alone: 51, in four times the pieces)
