"""The seed's printed 4-link equations (28), (30), (31) against the derived dynamics.

Random arms of the paper's structure (passive joints 1 and 3, waves on 2 and 4, 1-based
as printed) at random states. The derived coefficient of dq_j^2 in h_i is
h(q, e_j) - h(q, 0) and the gravity part is h(q, 0). Every printed term either agrees
to 1e-12 of its scale or is one of the misprints listed in docs/seed-errata.md, whose
corrected forms (written by hand in seed_printed.CORRECTED) agree to the same tolerance.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from conftest import seed_arm

from planner.dynamics import Dynamics
from planner.model import Robot
from testbed.seed_printed import (
    CORRECTED,
    Arm,
    arm_of,
    printed_bias,
    printed_kinetic,
    printed_mass,
    printed_potential,
)

RTOL = 1e-12
SAMPLES = 40
ERRATA = Path(__file__).resolve().parents[1] / "docs" / "seed-errata.md"


def paper_arm(rng: np.random.Generator) -> Robot:
    """A random robot of the paper's structure (0-based: passive 0, 2; waves on 1, 3)."""
    links = []
    for k in range(4):
        length = rng.uniform(0.2, 1.0)
        link = {"length": length, "mass": rng.uniform(0.2, 2.0),
                "inertia": rng.uniform(0.001, 0.05),
                "joint": "active" if k % 2 else "passive"}
        if k % 2:
            link["wave"] = {"amplitude": rng.uniform(0.01, 0.3) * length,
                            "frequency": rng.uniform(1.0, 5.0), "phase": rng.uniform(-np.pi, np.pi)}
        links.append(link)
    return Robot.model_validate({"links": links, "gravity": rng.uniform(1.0, 20.0)})


def derived_terms(dyn: Dynamics, q: np.ndarray) -> dict[str, float]:
    """'Mij', 'h{i}.dq{j}^2' and 'h{i}.g' (1-based) from the library at angles q (0-based)."""
    M = dyn.mass_matrix(q)
    h0 = dyn.bias(q, np.zeros(4))
    out = {f"M{i + 1}{j + 1}": M[i, j] for i in range(4) for j in range(i, 4)}
    for j in range(4):
        hj = dyn.bias(q, np.eye(4)[j]) - h0
        out.update({f"h{i + 1}.dq{j + 1}^2": hj[i] for i in range(4)})
    out.update({f"h{i + 1}.g": h0[i] for i in range(4)})
    return out


def scale(arm: Arm, term: str) -> float:
    """Size of a term's kind: sum m (sum l)^2 [kg m^2], times g / sum l for gravity terms."""
    mass, reach = sum(arm.m), sum(arm.l)
    return mass * reach * (arm.g if term.endswith(".g") else reach)


@pytest.fixture(scope="module")
def samples() -> list[tuple[Arm, np.ndarray, Dynamics, dict[str, float]]]:
    """(arm, q 1-based, dynamics, derived terms) at random arms and states."""
    rng = np.random.default_rng(20210407)
    out = []
    for _ in range(SAMPLES):
        robot = paper_arm(rng)
        dyn = Dynamics(robot)
        q = rng.uniform(-np.pi, np.pi, 4)
        out.append((arm_of(robot), np.r_[0.0, q], dyn, derived_terms(dyn, q)))
    return out


def printed_terms(arm: Arm, q: np.ndarray) -> dict[str, float]:
    return {**printed_mass(arm, q), **printed_bias(arm, q)}


def deviation(samples, term: str, value) -> float:
    """Largest |value - derived| / max(|derived|, scale) over the samples."""
    return max(abs(value(arm, q) - d[term]) / max(abs(d[term]), scale(arm, term))
               for arm, q, _, d in samples)


def documented_misprints() -> set[str]:
    """Terms named in the first column of the tables of docs/seed-errata.md."""
    pattern = re.compile(r"^\| `(M\d\d|h\d\.(?:dq\d\^2|g))` \|")
    return {m.group(1) for line in ERRATA.read_text().splitlines() if (m := pattern.match(line))}


PRINTED = sorted(printed_terms(arm_of(seed_arm()), np.zeros(5)))


@pytest.mark.parametrize("term", sorted(set(PRINTED) - set(CORRECTED)))
def test_printed_term_agrees(samples, term):
    assert deviation(samples, term, lambda arm, q: printed_terms(arm, q)[term]) <= RTOL


@pytest.mark.parametrize("term", sorted(CORRECTED))
def test_corrected_form_agrees(samples, term):
    assert deviation(samples, term, CORRECTED[term]) <= RTOL


@pytest.mark.parametrize("term", sorted(CORRECTED))
def test_misprint_is_wrong_by_far_more_than_rounding(samples, term):
    assert deviation(samples, term, lambda arm, q: printed_terms(arm, q)[term]) > 1e-3


def test_disagreeing_terms_are_exactly_the_documented_ones(samples):
    disagreeing = {term for term in PRINTED
                   if deviation(samples, term,
                                lambda arm, q, t=term: printed_terms(arm, q)[t]) > RTOL}
    assert disagreeing == set(CORRECTED)
    assert documented_misprints() == disagreeing


def test_terms_absent_from_the_print_vanish(samples):
    absent = {f"h{i}.dq{j}^2" for i in range(1, 5) for j in range(1, 5)} - set(PRINTED)
    assert absent == {"h1.dq1^2", "h3.dq3^2"}
    for term in absent:
        assert deviation(samples, term, lambda arm, q: 0.0) <= RTOL


def test_bias_has_no_products_of_different_rates(samples):
    eye = np.eye(4)
    for arm, q, dyn, _ in samples[:10]:
        h0 = dyn.bias(q[1:], np.zeros(4))
        for i in range(4):
            for j in range(i + 1, 4):
                cross = (dyn.bias(q[1:], eye[i] + eye[j]) - dyn.bias(q[1:], eye[i])
                         - dyn.bias(q[1:], eye[j]) + h0)
                assert np.abs(cross).max() <= RTOL * scale(arm, "M11")


@pytest.fixture(scope="module")
def motions(samples):
    """(arm, q, dq, dynamics) with random rates added to the samples (all 1-based)."""
    rng = np.random.default_rng(28)
    return [(arm, q, np.r_[0.0, rng.uniform(-3, 3, 4)], dyn) for arm, q, dyn, _ in samples]


def test_kinetic_energy_of_28_read_with_dq_i_is_the_derived_one(motions):
    for arm, q, dq, dyn in motions:
        T, _ = dyn.energy(q[1:], dq[1:])
        assert abs(printed_kinetic(arm, q, dq) - T) <= RTOL * max(T, scale(arm, "M11"))


def test_kinetic_energy_of_28_read_literally_is_wrong(motions):
    worst = max(abs(printed_kinetic(arm, q, dq, literal=True) - dyn.energy(q[1:], dq[1:])[0])
                / dyn.energy(q[1:], dq[1:])[0] for arm, q, dq, dyn in motions)
    assert worst > 1e-2


def test_literal_reading_differs_only_in_the_rotational_sum(motions):
    for arm, q, dq, _ in motions[:5]:
        still = Arm(arm.l, arm.m, (0.0,) * 5, arm.a, arm.n, arm.e, arm.g)
        assert printed_kinetic(still, q, dq, literal=True) == pytest.approx(
            printed_kinetic(still, q, dq), rel=RTOL)


def test_potential_energy_of_28_is_the_derived_one(motions):
    for arm, q, dq, dyn in motions:
        _, V = dyn.energy(q[1:], dq[1:])
        assert abs(printed_potential(arm, q) - V) <= RTOL * scale(arm, "h1.g")


def test_28_carries_the_right_M12(samples):
    """(28)'s dq1 dq2 term is right: the misprint of M12 is in (30) alone."""
    for arm, q, _, d in samples:
        e1, e2 = np.r_[0.0, 1, 0, 0, 0], np.r_[0.0, 0, 1, 0, 0]
        m12 = (printed_kinetic(arm, q, e1 + e2) - printed_kinetic(arm, q, e1)
               - printed_kinetic(arm, q, e2))
        assert abs(m12 - d["M12"]) <= RTOL * scale(arm, "M12")
