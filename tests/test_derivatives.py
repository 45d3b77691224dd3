"""The NLP's derivatives as Ipopt gets them, checked at random points.

For every transcription (both forms where it has two) and every term, the gradient of the
objective, the constraint Jacobian and the upper triangle of the Lagrangian's Hessian that
the built solver hands Ipopt (`nlp_grad_f`, `nlp_jac_g`, `nlp_hess_l`: on most structures
the per-stage kernels that `planner.ocp.assembly` scatters into place, elsewhere CasADi's
own) are compared with

- CasADi's derivatives of the same NLP written as one plain SX expression graph (the
  problem's f and g expanded; no stages, no permutations), to rounding, and
- central finite differences of f, g and of the Lagrangian's gradient along random
  directions, to truncation error,

at random variables x, multipliers lam_g and objective factor sigma (and sigma = 0). The
numbers (robot, mesh widths, quadrature weights, references, weights) are those a scene's
solve uses, on a non-uniform mesh. A fault in any stage kernel or in the scatter fails
these tests within seconds, where the OCP tests notice it (if at all) as solves that no
longer converge.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass, replace
from functools import cache

import casadi as ca
import numpy as np
import pytest

from planner.ocp import problem as problem_module
from planner.ocp.assembly import Derivatives
from planner.ocp.instance import instance
from planner.ocp.key import ProblemKey
from planner.ocp.mesh import Mesh
from planner.ocp.solvers.fatrop import oracle_functions
from planner.scene import Scene

N = 3
"""Intervals: enough for interior stages, a terminal and sums of global entries over stages."""

TWO: dict = {"links": [
    {"length": 0.5, "mass": 1.0, "inertia": 0.01, "joint": "passive"},
    {"length": 0.4, "mass": 0.8, "inertia": 0.008, "joint": "active",
     "wave": {"amplitude": 0.05, "frequency": 3, "phase": 0.3}}], "gravity": 9.81}
THREE: dict = {"links": [
    {"length": 0.5, "mass": 1.0, "inertia": 0.01, "joint": "passive"},
    {"length": 0.4, "mass": 0.8, "inertia": 0.008, "joint": "active",
     "wave": {"amplitude": 0.05, "frequency": 3, "phase": 0.3}},
    {"length": 0.3, "mass": 0.5, "inertia": 0.004, "joint": "active",
     "wave": {"amplitude": 0.04, "frequency": 2, "phase": -0.7}}], "gravity": 9.81}

TRANSCRIPTIONS: dict[str, dict] = {
    "trapezoidal-implicit": {"method": "trapezoidal", "form": "implicit"},
    "trapezoidal-explicit": {"method": "trapezoidal", "form": "explicit"},
    "hermite-simpson-implicit": {"method": "hermite-simpson", "form": "implicit"},
    "hermite-simpson-explicit": {"method": "hermite-simpson", "form": "explicit"},
    "legendre-implicit": {"method": "legendre", "degree": 2, "form": "implicit"},
    "legendre-explicit": {"method": "legendre", "degree": 2, "form": "explicit"},
    "radau-implicit": {"method": "radau", "degree": 2, "form": "implicit"},
    "radau-explicit": {"method": "radau", "degree": 2, "form": "explicit"},
    "shooting-rk4": {"method": "multiple-shooting", "integrator": "rk4", "steps": 4},
}


def _terms(robot: dict) -> dict[str, dict]:
    """Per term, the task entries that switch it on (effort off unless it is the term)."""
    passive = [k for k, link in enumerate(robot["links"]) if link["joint"] == "passive"]
    active = [link for link in robot["links"] if link["joint"] == "active"]
    off = {"objective": {"effort": 0.0}}
    return {
        "effort": {"objective": {"effort": 1.0}},
        "free-time": {**off, "duration": {"min": 0.3, "max": 1.0},
                      "objective": {"effort": 0.0, "time": 0.7}},
        "smoothness": {"objective": {"effort": 0.0, "smoothness": 0.3}},
        "weighted-tracking": {**off, "tracking": {
            "motion": {"profile": "quintic", "start": [0.0] * len(passive),
                       "end": [0.6] * len(passive)}, "mode": "weighted", "weight": 50.0}},
        "tip-target": {**off, "tip_target": {"x": 0.3, "y": 0.7}},
        "coupling-margin": {**off, "coupling_margin": 0.02},
        "wave-co-design": {**off, "co_design": {"amplitude_max": 0.1,
                                                "frequency": [3.0] * len(active)}},
    }


def _combined(robot: dict, free: bool) -> dict:
    """Every term a fixed duration allows (weighted tracking), or every one a free duration
    allows (time, wave co-design), with effort and smoothness on."""
    terms = _terms(robot)
    task: dict = {"objective": {"effort": 1.0, "smoothness": 0.3, "time": 0.7 if free else 0.0},
                  "tip_target": terms["tip-target"]["tip_target"],
                  "coupling_margin": terms["coupling-margin"]["coupling_margin"]}
    if free:
        task["duration"] = terms["free-time"]["duration"]
        task["co_design"] = terms["wave-co-design"]["co_design"]
    else:
        task["tracking"] = terms["weighted-tracking"]["tracking"]
    return task


def _scene(robot: dict, transcription: dict, task: dict) -> Scene:
    n = len(robot["links"])
    base = {"duration": 0.6, "initial": {"q": [0.1] * n, "dq": [0.0] * n},
            "final": {"q": [0.5] * n, "dq": [0.0] * n}}
    return Scene.model_validate({"robot": robot, "task": {**base, **task},
                                 "transcription": {**transcription, "intervals": N}})


CASES: dict[str, tuple[dict, dict, dict]] = {}
for _name, _tr in TRANSCRIPTIONS.items():
    CASES[f"{_name}/fixed-T-all-terms"] = (THREE, _tr, _combined(THREE, free=False))
    CASES[f"{_name}/free-T-all-terms"] = (THREE, _tr, _combined(THREE, free=True))
for _name in ("radau-implicit", "trapezoidal-implicit", "shooting-rk4"):
    for _term, _task in _terms(THREE).items():
        CASES[f"{_name}/{_term}"] = (THREE, TRANSCRIPTIONS[_name], _task)
CASES["legendre-explicit/coupling-margin-square-block"] = (
    TWO, TRANSCRIPTIONS["legendre-explicit"], _terms(TWO)["coupling-margin"])
CASES["hermite-simpson-implicit/wave-co-design-one-wave"] = (
    TWO, TRANSCRIPTIONS["hermite-simpson-implicit"], _terms(TWO)["wave-co-design"])

STRUCTURED = {
    *(f"{name}/fixed-T-all-terms" for name in (
        "trapezoidal-implicit", "hermite-simpson-implicit", "legendre-implicit",
        "legendre-explicit", "radau-implicit", "radau-explicit", "shooting-rk4")),
    *(f"{name}/free-T-all-terms" for name in (
        "legendre-implicit", "legendre-explicit", "radau-implicit", "radau-explicit",
        "shooting-rk4")),
}
"""Cases whose derivatives Ipopt gets assembled from per-stage kernels (the rest: CasADi's
own, where a stage's Lagrangian is nonlinear in its successor's entries)."""


@dataclass(frozen=True)
class Point:
    """A random point of a case's NLP and what both sides give there."""

    x: np.ndarray
    p: np.ndarray
    sigma: float
    lam: np.ndarray


@dataclass(frozen=True)
class Case:
    """A case's built NLP: the functions Ipopt gets, the plain graph's, and random points."""

    key: ProblemKey
    structured: bool
    ipopt: dict[str, ca.Function]  # grad_f, jac_g, hess_lag as the solver calls them
    plain: ca.Function  # (x, p, sigma, lam) -> (f, g, grad_f, jac_g, triu hess_lag)
    fg: ca.Function  # (x, p) -> (f, g), the oracle
    points: tuple[Point, ...]


def _random_x(layout, rng: np.random.Generator, robot: dict) -> np.ndarray:
    """Variables in their physical ranges: angles, rates, torques; T in [0.3, 1] s; wave
    amplitudes well inside the links, any phase."""
    x = layout.zeros()
    scale = {"q": 1.0, "dq": 1.0, "ddq": 5.0, "tau": 2.0}
    for kind, idx in layout.blocks.values():
        if kind == "global":
            continue
        x[idx] = rng.uniform(-1, 1, idx.shape) * scale[kind]
    copies = layout.intervals + 1  # each a little apart, so that a stage reading another
    if "T" in layout:  # stage's copy of the globals shows in its derivatives
        layout.put(x, "T", rng.uniform(0.3, 1.0) + rng.uniform(0, 0.01, (1, copies)))
    if "wave" in layout:
        n_waves = layout.blocks["wave"][1].shape[0] // 2
        design = np.ravel([(rng.uniform(0.01, 0.08), rng.uniform(-np.pi, np.pi))
                           for _ in range(n_waves)])
        layout.put(x, "wave", design[:, None] * rng.uniform(1, 1.01, (1, copies)))
    return x


@cache
def case(name: str) -> Case:
    robot, transcription, task = CASES[name]
    scene = _scene(robot, transcription, task)
    rng = np.random.default_rng(zlib.crc32(name.encode()))
    breaks = np.concatenate([[0.0], np.sort(rng.uniform(0.1, 0.9, N - 1)), [1.0]])
    mesh = Mesh(breaks)
    inst = instance(scene, scene.robot, mesh, 0.6)
    prob = inst.problem
    solver = prob.solver
    ipopt = {name: solver.get_function(f"nlp_{short}")
             for name, short in (("grad_f", "grad_f"), ("jac_g", "jac_g"), ("hess_lag", "hess_l"))}
    fg = ca.Function("fg", [prob.oracle["x"], prob.oracle["p"]],
                     [prob.oracle["f"], prob.oracle["g"]])
    plain_fg = fg.expand()
    assert plain_fg.is_a("SXFunction")
    x, p = ca.SX.sym("x", prob.layout.size), ca.SX.sym("p", prob.n_params)
    sigma, lam = ca.SX.sym("sigma"), ca.SX.sym("lam", prob.lbg.size)
    f, g = plain_fg(x, p)
    plain = ca.Function("plain", [x, p, sigma, lam], [
        f, g, ca.gradient(f, x), ca.jacobian(g, x),
        ca.triu(ca.hessian(sigma * f + ca.dot(lam, g), x)[0])])
    # the last with sigma = 0, as Ipopt's restoration phase asks for the constraints alone
    sigmas = [float(rng.uniform(0.2, 3.0)) for _ in range(2)] + [0.0]
    points = tuple(Point(_random_x(prob.layout, rng, robot), inst.P, sigma,
                         rng.normal(size=prob.lbg.size)) for sigma in sigmas)
    return Case(prob.key, prob.structured, ipopt, plain, fg, points)


def dense(value) -> np.ndarray:
    return np.asarray(ca.DM(value).full(), dtype=float)


def full_hessian(triu: np.ndarray) -> np.ndarray:
    return triu + triu.T - np.diag(np.diag(triu))


def assert_close(actual: np.ndarray, expected: np.ndarray, rtol: float, what: str) -> None:
    """Entrywise within rtol of the largest entry (the derivatives mix scales)."""
    scale = max(1.0, float(np.abs(expected).max(initial=0.0)))
    err = np.abs(actual - expected)
    worst = np.unravel_index(np.argmax(err), err.shape) if err.size else ()
    assert err.max(initial=0.0) <= rtol * scale, (
        f"{what}: worst entry {worst} is {actual[worst]!r}, expected {expected[worst]!r} "
        f"(scale {scale:.3g})")


NAMES = sorted(CASES)


def test_every_case_builds_the_derivatives_it_should():
    """The assembled path is exercised where it is meant to be (a regression that falls
    back to CasADi's derivatives everywhere would otherwise pass unnoticed)."""
    assert {name for name in NAMES if case(name).structured} >= STRUCTURED
    for name in STRUCTURED:
        assert case(name).ipopt["hess_lag"].name() == "nlp_hess_l_stages", name


@pytest.mark.parametrize("name", NAMES)
def test_objective_gradient_matches_the_plain_graph(name):
    c = case(name)
    for k, pt in enumerate(c.points):
        f, grad = c.ipopt["grad_f"](pt.x, pt.p)
        ref = c.plain(pt.x, pt.p, pt.sigma, pt.lam)
        assert_close(dense(f), dense(ref[0]), 1e-12, f"f at point {k}")
        assert_close(dense(grad), dense(ref[2]), 1e-10, f"grad_f at point {k}")


@pytest.mark.parametrize("name", NAMES)
def test_constraint_jacobian_matches_the_plain_graph(name):
    c = case(name)
    for k, pt in enumerate(c.points):
        g, jac = c.ipopt["jac_g"](pt.x, pt.p)
        ref = c.plain(pt.x, pt.p, pt.sigma, pt.lam)
        assert_close(dense(g), dense(ref[1]), 1e-12, f"g at point {k}")
        assert_close(dense(jac), dense(ref[3]), 1e-10, f"jac_g at point {k}")


@pytest.mark.parametrize("name", NAMES)
def test_lagrangian_hessian_matches_the_plain_graph(name):
    c = case(name)
    for k, pt in enumerate(c.points):
        hess = c.ipopt["hess_lag"](pt.x, pt.p, pt.sigma, pt.lam)
        ref = c.plain(pt.x, pt.p, pt.sigma, pt.lam)
        assert_close(dense(hess), dense(ref[4]), 1e-10, f"hess_lag (upper) at point {k}")
        assert not np.tril(dense(hess), -1).any(), "hess_lag must hold the upper triangle only"


def _lagrangian_gradient(c: Case, x: np.ndarray, pt: Point) -> np.ndarray:
    grad = dense(c.ipopt["grad_f"](x, pt.p)[1]).ravel()
    jac = dense(c.ipopt["jac_g"](x, pt.p)[1])
    return pt.sigma * grad + jac.T @ pt.lam


@pytest.mark.parametrize("name", NAMES)
def test_derivatives_match_central_differences(name):
    """Along random directions: grad_f . v and jac_g v against differences of f and g, and
    hess_lag v against differences of sigma grad_f + jac_g' lam (the Ipopt functions')."""
    c = case(name)
    rng = np.random.default_rng(zlib.crc32(name.encode()) + 1)
    for k, pt in enumerate(c.points):
        hess = full_hessian(dense(c.ipopt["hess_lag"](pt.x, pt.p, pt.sigma, pt.lam)))
        grad = dense(c.ipopt["grad_f"](pt.x, pt.p)[1]).ravel()
        jac = dense(c.ipopt["jac_g"](pt.x, pt.p)[1])
        for _ in range(2):
            v = rng.normal(size=pt.x.size)
            v /= np.linalg.norm(v)
            h = 1e-5
            (f1, g1), (f0, g0) = c.fg(pt.x + h * v, pt.p), c.fg(pt.x - h * v, pt.p)
            assert_close(np.atleast_1d(grad @ v), (dense(f1) - dense(f0)).ravel() / (2 * h),
                         1e-6, f"grad_f . v at point {k}")
            assert_close(jac @ v, (dense(g1) - dense(g0)).ravel() / (2 * h), 1e-6,
                         f"jac_g v at point {k}")
            dL = (_lagrangian_gradient(c, pt.x + h * v, pt)
                  - _lagrangian_gradient(c, pt.x - h * v, pt)) / (2 * h)
            assert_close(hess @ v, dL, 1e-6, f"hess_lag v at point {k}")


def test_the_checks_catch_a_halved_stage_hessian(monkeypatch):
    """The fault these tests exist for: a stage Hessian kernel off by a factor (here 1/2)
    makes the assembled Hessian differ from the plain graph's."""
    c = case("radau-implicit/fixed-T-all-terms")
    stage_key = replace(c.key, intervals=0)
    good = problem_module.stages(stage_key)
    assert good.derivatives is not None
    stage = good.derivatives.stage
    ins = [ca.SX.sym(f"i{k}", stage.hess.sparsity_in(k)) for k in range(stage.hess.n_in())]
    halved = ca.Function(stage.hess.name(), ins, [0.5 * stage.hess(*ins)])
    faulty = Derivatives(replace(stage, hess=halved), good.derivatives.terminal)
    monkeypatch.setattr(problem_module, "stages",
                        lambda key, compiled=False: replace(good, derivatives=faulty))
    hess_lag = problem_module.build(c.key).solver.get_function("nlp_hess_l")
    pt = c.points[0]
    with pytest.raises(AssertionError, match="hess_lag"):
        assert_close(dense(hess_lag(pt.x, pt.p, pt.sigma, pt.lam)),
                     dense(c.plain(pt.x, pt.p, pt.sigma, pt.lam)[4]), 1e-10, "hess_lag")


FATROP_CASES = sorted(name for name in STRUCTURED if name.endswith("fixed-T-all-terms")
                      and name.split("/")[0].startswith(("legendre", "radau", "shooting")))
"""Structured cases a fatrop scene can name (stages that close their gaps, a fixed
duration)."""


@pytest.mark.parametrize("name", FATROP_CASES)
def test_fatrop_functions_match_the_plain_graph(name):
    """What fatrop gets from the assembled kernels (`oracle_functions`): the objective's
    gradient, the rows and Jacobian, the Lagrangian's gradient and its whole Hessian, and
    the objective, rows and Lagrangian gradient the multipliers are read from."""
    c = case(name)
    functions = oracle_functions(c.ipopt)
    for k, pt in enumerate(c.points):
        ref = c.plain(pt.x, pt.p, pt.sigma, pt.lam)
        gradient = dense(ref[2]).ravel() * pt.sigma + dense(ref[3]).T @ pt.lam
        assert_close(dense(functions["nlp_grad_f"](pt.x, pt.p)), dense(ref[2]), 1e-10,
                     f"nlp_grad_f at point {k}")
        g, jac = functions["nlp_jac_g"](pt.x, pt.p)
        assert_close(dense(g), dense(ref[1]), 1e-12, f"nlp_jac_g's rows at point {k}")
        assert_close(dense(jac), dense(ref[3]), 1e-10, f"nlp_jac_g at point {k}")
        grad_l, hess = functions["nlp_hess_l"](pt.x, pt.p, pt.sigma, pt.lam)
        assert_close(dense(grad_l).ravel(), gradient, 1e-10, f"Lagrangian gradient at point {k}")
        assert_close(dense(hess), full_hessian(dense(ref[4])), 1e-10,
                     f"nlp_hess_l (whole) at point {k}")
        f, g, grad_x, grad_p = functions["nlp_grad"](pt.x, pt.p, pt.sigma, pt.lam)
        assert_close(dense(f), dense(ref[0]), 1e-12, f"nlp_grad's objective at point {k}")
        assert_close(dense(grad_x).ravel(), gradient, 1e-10, f"nlp_grad at point {k}")
        assert dense(grad_p).shape == (pt.p.size, 1) and not dense(grad_p).any()
