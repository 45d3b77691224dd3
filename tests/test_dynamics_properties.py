"""Structural properties of the derived dynamics and of its per-structure cache.

M symmetric positive definite; C from the Christoffel symbols of M (computed here from
a CasADi Jacobian of the library's M) makes Mdot - 2C skew-symmetric and reproduces
h - gravity = C dq; forward and inverse dynamics are each other's inverse; energies and
tips are consistent with M; robots of one structure share compiled functions; a
structure without gravity, waves or inertia builds fewer expression nodes.
"""

from __future__ import annotations

import json
from dataclasses import asdict
from functools import cache

import casadi as ca
import numpy as np
import pytest
from conftest import point_mass_dynamics, seed_arm

from planner.coupling_block import Coupling, at, blocks, condition, measures
from planner.dynamics import Dynamics, functions
from planner.errors import InputError
from planner.model import (
    MAX_FREQUENCY,
    MAX_GRAVITY,
    MAX_INERTIA,
    MAX_LENGTH,
    MAX_MASS,
    MAX_PHASE,
    MIN_LENGTH,
    MIN_MASS,
    Robot,
    Structure,
    parameters,
)
from testbed.robots import random_robot, random_state

RTOL = 1e-12
SIZES = [1, 2, 3, 5, 8]


def robots(rng: np.random.Generator, count: int = 2):
    """Random robots of every size in SIZES, both conventions, gravity drawn."""
    for n in SIZES:
        for rotational in ("cumulative", "absolute"):
            for _ in range(count):
                yield random_robot(rng, n, rotational=rotational)


@cache
def mass_jacobian(s: Structure) -> ca.Function:
    """dM/dq (q, p) -> n^2 x n, column k holding vec(dM/dq_k) (column-major)."""
    q, p = ca.SX.sym("q", s.n), ca.SX.sym("p", s.n_params)
    return ca.Function("dM", [q, p], [ca.jacobian(ca.vec(functions(s)["M"](q, p)), q)])


def mass_derivative(robot: Robot, q) -> np.ndarray:
    """dM[i, j, k] = dM_ij/dq_k."""
    s = Structure.of(robot)
    jac = np.array(mass_jacobian(s)(q, parameters(robot, s)))
    return jac.reshape(s.n, s.n, s.n, order="F")


def christoffel(robot: Robot, q) -> np.ndarray:
    """Gamma[i, j, k] = 1/2 (dM_ij/dq_k + dM_ik/dq_j - dM_jk/dq_i)."""
    dM = mass_derivative(robot, q)
    return 0.5 * (dM + dM.transpose(0, 2, 1) - np.einsum("jki->ijk", dM))


def mass_rate(robot: Robot, q, dq) -> np.ndarray:
    """Mdot = sum_k dM/dq_k dq_k."""
    return mass_derivative(robot, q) @ np.asarray(dq)


def test_mass_matrix_is_symmetric_positive_definite(rng):
    for robot in robots(rng):
        dyn = Dynamics(robot)
        for _ in range(5):
            q, _ = random_state(rng, robot.n)
            M = dyn.mass_matrix(q)
            assert np.abs(M - M.T).max() <= RTOL * np.abs(M).max()
            assert np.linalg.eigvalsh(M).min() > 0.0


def test_point_masses_alone_give_a_positive_definite_mass_matrix(rng):
    for n in SIZES:
        robot = random_robot(rng, n, inertia=False)
        q, _ = random_state(rng, n)
        assert np.linalg.eigvalsh(Dynamics(robot).mass_matrix(q)).min() > 0.0


def test_mass_rate_minus_twice_christoffel_matrix_is_skew(rng):
    for robot in robots(rng, count=1):
        q, dq = random_state(rng, robot.n)
        C = christoffel(robot, q) @ dq
        N = mass_rate(robot, q, dq) - 2 * C
        assert np.abs(N + N.T).max() <= RTOL * max(1.0, np.abs(N).max())


def test_velocity_terms_are_christoffel_matrix_times_rates(rng):
    for robot in robots(rng):
        dyn = Dynamics(robot)
        q, dq = random_state(rng, robot.n)
        C = christoffel(robot, q) @ dq
        expected = C @ dq
        got = dyn.bias(q, dq) - dyn.gravity(q)
        assert np.abs(got - expected).max() <= RTOL * max(np.abs(expected).max(), np.abs(C).max())


def test_power_balance_of_the_library_bias(rng):
    """dT/dt = dq' (tau - G): dq' Mdot dq = 2 dq' (h - G), with the library's h."""
    for robot in robots(rng):
        dyn = Dynamics(robot)
        q, dq = random_state(rng, robot.n)
        left = dq @ mass_rate(robot, q, dq) @ dq
        right = 2 * dq @ (dyn.bias(q, dq) - dyn.gravity(q))
        assert abs(left - right) <= RTOL * max(1.0, abs(left))


def test_inverse_undoes_forward(rng):
    for robot in robots(rng):
        dyn = Dynamics(robot)
        q, dq = random_state(rng, robot.n)
        tau = rng.uniform(-5.0, 5.0, len(robot.active))
        ddq = dyn.forward(q, dq, tau)
        generalized = dyn.inverse(q, dq, ddq)
        scale = np.abs(dyn.mass_matrix(q)).max() * np.abs(ddq).max() + np.abs(tau).max()
        assert np.abs(generalized - dyn.B @ tau).max() <= RTOL * scale


def test_kinetic_energy_is_the_quadratic_form_of_M(rng):
    for robot in robots(rng):
        dyn = Dynamics(robot)
        q, dq = random_state(rng, robot.n)
        T, _ = dyn.energy(q, dq)
        assert pytest.approx(0.5 * dq @ dyn.mass_matrix(q) @ dq, rel=RTOL) == T


def test_potential_energy_and_gravity_follow_from_the_tips(rng):
    for robot in robots(rng):
        dyn = Dynamics(robot)
        q, dq = random_state(rng, robot.n)
        tips = dyn.tips(q)
        masses = np.array([link.mass for link in robot.links])
        _, V = dyn.energy(q, dq)
        assert pytest.approx(-robot.gravity * masses @ tips[:, 0], rel=RTOL, abs=1e-14) == V
        step = 1e-6
        fd = [(dyn.energy(q + step * e, dq)[1] - dyn.energy(q - step * e, dq)[1]) / (2 * step)
              for e in np.eye(robot.n)]
        assert np.allclose(dyn.gravity(q), fd, rtol=1e-7, atol=1e-7)


def test_tips_follow_the_waves(rng):
    for robot in robots(rng):
        q, _ = random_state(rng, robot.n)
        radius = [link.length + (w.amplitude * np.sin(w.frequency * qi + w.phase)
                                 if (w := link.wave) else 0.0)
                  for link, qi in zip(robot.links, q, strict=True)]
        expected = np.cumsum(np.stack([radius * np.cos(q), radius * np.sin(q)], axis=1), axis=0)
        assert np.allclose(Dynamics(robot).tips(q), expected, rtol=0, atol=1e-14)


def test_robots_of_one_structure_share_compiled_functions(rng):
    first = random_robot(rng, 4, gravity=9.81)
    second = first.model_copy(update={"links": [
        link.model_copy(update={"length": link.length * 1.3, "mass": link.mass * 0.7})
        for link in first.links]})
    assert Structure.of(second) == Structure.of(first)
    dyn1 = Dynamics(first)
    before = functions.cache_info()
    dyn2 = Dynamics(second)
    after = functions.cache_info()
    assert (after.hits, after.misses) == (before.hits + 1, before.misses)
    assert dyn2.f is dyn1.f
    q, dq = random_state(rng, 4)
    assert not np.allclose(dyn1.mass_matrix(q), dyn2.mass_matrix(q))
    for robot, dyn in ((first, dyn1), (second, dyn2)):
        M, h = point_mass_dynamics(robot, q, dq)
        assert np.allclose(dyn.mass_matrix(q), M, rtol=RTOL, atol=0)
        assert np.allclose(dyn.bias(q, dq), h, rtol=RTOL, atol=RTOL * np.abs(h).max())


def test_forced_wave_terms_with_zero_amplitude_change_nothing(rng):
    robot = random_robot(rng, 4, waves=False, gravity=9.81)
    forced = Structure.of(robot, wavy=(True,) * 4)
    plain, wavy = Dynamics(robot), Dynamics(robot, forced)
    assert wavy.f is not plain.f
    q, dq = random_state(rng, 4)
    assert np.allclose(wavy.mass_matrix(q), plain.mass_matrix(q), rtol=RTOL, atol=0)
    assert np.allclose(wavy.bias(q, dq), plain.bias(q, dq), rtol=RTOL, atol=1e-14)


def nodes(robot: Robot) -> dict[str, int]:
    f = functions(Structure.of(robot))
    return {name: f[name].n_nodes() for name in ("M", "h", "fd")}


def test_gravity_costs_nodes_only_where_it_enters():
    on, off = nodes(seed_arm(gravity=9.81)), nodes(seed_arm(gravity=0.0))
    assert off["M"] == on["M"]
    assert off["h"] < on["h"] and off["fd"] < on["fd"]


def test_waves_cost_nodes():
    wavy, plain = nodes(seed_arm()), nodes(seed_arm(waves=False))
    assert all(plain[k] < wavy[k] for k in wavy)


def test_inertia_costs_nodes():
    doc = seed_arm().model_dump()
    for link in doc["links"]:
        link["inertia"] = 0.0
    assert nodes(Robot.model_validate(doc))["M"] < nodes(seed_arm())["M"]


# --------------------------------------------------------------------------- argument checks

def two_link() -> Robot:
    """Passive joint 0, active joint 1 carrying a wave."""
    return Robot.model_validate({"links": [
        {"length": 0.5, "mass": 1.0, "joint": "passive"},
        {"length": 0.4, "mass": 0.5, "joint": "active",
         "wave": {"amplitude": 0.05, "frequency": 3.0}}]})


Q, DQ, DDQ, TAU = [0.1, 0.2], [0.3, -0.4], [1.0, 2.0], [0.5]
CALLS = {  # method, arguments, index of the argument to spoil, its name, entries needed
    "mass_matrix q": ("mass_matrix", [Q], 0, "q", "2 entries, one per joint"),
    "bias q": ("bias", [Q, DQ], 0, "q", "2 entries, one per joint"),
    "bias dq": ("bias", [Q, DQ], 1, "dq", "2 entries, one per joint"),
    "gravity q": ("gravity", [Q], 0, "q", "2 entries, one per joint"),
    "energy dq": ("energy", [Q, DQ], 1, "dq", "2 entries, one per joint"),
    "tips q": ("tips", [Q], 0, "q", "2 entries, one per joint"),
    "forward q": ("forward", [Q, DQ, TAU], 0, "q", "2 entries, one per joint"),
    "forward tau": ("forward", [Q, DQ, TAU], 2, "tau", "1 entry, one per active joint"),
    "inverse ddq": ("inverse", [Q, DQ, DDQ], 2, "ddq", "2 entries, one per joint"),
    "coupling q": ("coupling", [Q], 0, "q", "2 entries, one per joint"),
}


def call(case: str, value):
    method, args, k, _, _ = CALLS[case]
    args = list(args)
    args[k] = value
    if method == "coupling":  # the coupling block's measures at one configuration
        return at(two_link(), *args)
    return getattr(Dynamics(two_link()), method)(*args)


@pytest.mark.parametrize("case", CALLS)
@pytest.mark.parametrize("size", [0, 1, 3])
def test_a_vector_of_the_wrong_length_is_refused(case, size):
    _, args, k, name, needs = CALLS[case]
    if size == len(args[k]):
        size += 1
    with pytest.raises(InputError) as info:
        call(case, [0.1] * size)
    assert str(info.value) == f"{name}: needs {needs} (got {size})"


@pytest.mark.parametrize("case", CALLS)
@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_a_non_finite_entry_is_refused(case, bad):
    _, args, k, name, _ = CALLS[case]
    value = [bad] + list(args[k][1:])
    with pytest.raises(InputError) as info:
        call(case, value)
    assert str(info.value) == f"{name}: every entry must be a finite number (got {value})"


def test_matrices_and_text_are_refused():
    dyn = Dynamics(two_link())
    with pytest.raises(InputError,
                       match=r"^q: must be a flat list of numbers \(got shape \(2, 1\)\)$"):
        dyn.mass_matrix([[0.1], [0.2]])
    with pytest.raises(InputError, match="^dq: must be a list of numbers$"):
        dyn.bias(Q, ["fast", "slow"])


def test_a_one_joint_robot_takes_plain_numbers():
    robot = Robot.model_validate({"links": [{"length": 0.5, "mass": 1.0, "joint": "active"}],
                                  "gravity": 9.81})
    dyn = Dynamics(robot)
    assert dyn.forward(0.3, 0.1, 2.0) == pytest.approx(dyn.forward([0.3], [0.1], [2.0]), rel=1e-15)
    assert dyn.forward(0.3, 0.1, 2.0)[0] == pytest.approx((2.0 - 9.81 * 0.5 * np.sin(0.3)) / 0.25)


def corner_robots(rng: np.random.Generator, count: int):
    """Robots with every number at a bound of planner.model (waves at 0.999 of the length)."""
    for _ in range(count):
        n = int(rng.integers(1, 5))
        active = rng.random(n) < 0.5
        active[rng.integers(n)] = True
        links = []
        for k in range(n):
            length = float(rng.choice([MIN_LENGTH, MAX_LENGTH]))
            link = {"length": length, "mass": float(rng.choice([MIN_MASS, MAX_MASS])),
                    "inertia": float(rng.choice([0.0, MAX_INERTIA])),
                    "joint": "active" if active[k] else "passive"}
            if active[k]:
                link["wave"] = {"amplitude": 0.999 * length, "frequency": MAX_FREQUENCY,
                                "phase": float(rng.choice([-MAX_PHASE, MAX_PHASE]))}
            links.append(link)
        yield Robot.model_validate({"links": links,
                                    "gravity": float(rng.choice([0.0, MAX_GRAVITY])),
                                    "rotational_inertia":
                                        str(rng.choice(["cumulative", "absolute"]))})


def test_robots_at_the_bounds_give_finite_values_or_a_clear_error(rng):
    """M, h, G, energies, tips and M_pa stay finite; forward dynamics is finite or refused."""
    for robot in corner_robots(rng, 60):
        dyn = Dynamics(robot)
        q, dq = random_state(rng, robot.n, speed=10.0)
        values = [dyn.mass_matrix(q), dyn.bias(q, dq), dyn.gravity(q), dyn.energy(q, dq),
                  dyn.tips(q), blocks(robot, q[None, :])]
        assert all(np.all(np.isfinite(v)) for v in values), robot.model_dump_json()
        try:
            assert np.all(np.isfinite(dyn.forward(q, dq, np.ones(len(robot.active)))))
        except ValueError as error:
            assert str(error).startswith("the accelerations are not finite at this state")


def test_a_numerically_singular_mass_matrix_is_refused_not_answered_with_nan():
    """1e6 kg m^2 on the active link (cumulative) swamps the 1e-14 kg m^2 of the point masses."""
    robot = Robot.model_validate({"links": [
        {"length": MIN_LENGTH, "mass": MIN_MASS, "joint": "passive"},
        {"length": MIN_LENGTH, "mass": MIN_MASS, "inertia": MAX_INERTIA, "joint": "active"}]})
    dyn = Dynamics(robot)
    assert np.linalg.cond(dyn.mass_matrix(Q)) > 1e15
    with pytest.raises(ValueError) as info:
        dyn.forward(Q, DQ, TAU)
    assert str(info.value) == ("the accelerations are not finite at this state: M(q) is "
                               "numerically singular or the values are too large")


# --------------------------------------------------------------------------- coupling measures

def test_a_robot_without_passive_joints_has_no_coupling_measures_but_finite_json():
    robot = Robot.model_validate({"links": [{"length": 0.5, "mass": 1.0, "joint": "active"}] * 2})
    coupling = at(robot, Q)
    assert coupling == Coupling(det=None, sigma_min=None, sigma_max=None, condition=1.0)
    assert json.loads(json.dumps(asdict(coupling), allow_nan=False))["sigma_min"] is None


def test_coupling_measures_agree_with_numpy(rng):
    square = rng.normal(size=(5, 2, 2))
    sv = np.linalg.svd(square, compute_uv=False)
    m = measures(square)
    assert np.allclose(m.det, np.linalg.det(square), rtol=1e-14, atol=0.0)
    assert np.allclose([m.sigma_min, m.least, m.sigma_max], [sv[:, 1], sv[:, 1], sv[:, 0]],
                       rtol=1e-14, atol=0.0)
    assert condition(m.sigma_min, m.sigma_max) == pytest.approx(sv[:, 0] / sv[:, 1], rel=1e-14)
    for shape, rank in (((5, 2, 3), 1), ((5, 3, 2), None)):  # fewer, more passive than active
        block = rng.normal(size=shape)
        sv = np.linalg.svd(block, compute_uv=False)
        m = measures(block)
        assert m.det is None and np.allclose(m.sigma_max, sv[:, 0], rtol=1e-14, atol=0.0)
        assert np.allclose(m.least, sv[:, -1], rtol=1e-14, atol=0.0)
        assert np.allclose(m.sigma_min, 0.0 if rank is None else sv[:, rank], rtol=1e-14, atol=0.0)


@pytest.mark.parametrize(("block", "sigma_min"), [
    (np.ones((2, 1)), 0.0),              # more passive than active joints: no full row rank
    (np.zeros((1, 2)), 0.0),             # a zero block
    (np.diag([1e300, 1e-10]), 1e-10),    # sigma_max / sigma_min overflows
])
def test_condition_is_none_where_it_is_undefined_or_overflows(block, sigma_min):
    m = measures(block[None])
    assert m.sigma_min[0] == pytest.approx(sigma_min, rel=1e-14)
    assert condition(m.sigma_min, m.sigma_max) == [None]
