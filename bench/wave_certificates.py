"""Wave designs and co-designs proven, not sampled (`planner.certify`).

- Along a motion: the built-in wave-design examples (`two-link-wave-design`,
  `seed-arm-wave-design`: the seed's 4-link arm from its singular start along the
  seed example's passive motion). The proof covers the piecewise cubic Hermite
  interpolant of the inverse dynamics' 2,001 samples; `departure` is how far that
  interpolant lies from the integrated motion at the middle of its intervals (the
  inverse dynamics run again at 4,001 samples, whose even ones are the design's).
- Over a region: there is no built-in region example, so a box around each arm's
  singular start (0.1 rad a side of the two-link arm's two joints, 0.03 rad of the seed
  arm's four), margin 0.01, amplitudes up to 0.06 m, frequencies up to 4.
- Co-design: the built-in plans `two-link-plan` and `seed-arm-plan` with their waves'
  amplitudes (up to 0.08 and 0.06 m) and phases co-designed, frequencies fixed (3; 3 and
  4): the plan's `verification.margin_certificate`.

Each row: the proven lower bound of sigma_min(M_pa), the smallest value sampled, the
status against the target, the boxes, the proof's seconds and the whole design's (or
plan's). Writes bench/results/wave_certificates.csv and the section "Proven wave
designs" of docs/benchmarks.md.

    python -m bench wave_certificates [--arms two-link,seed-arm]
"""

from __future__ import annotations

import argparse
import copy
import time

import numpy as np

from bench import harness
from planner.examples import example, seed_start, two_link_start
from planner.inverse import InverseDynamicsRequest, solve
from planner.ocp import plan
from planner.ocp.interpolant import PiecewisePolynomial, hermite
from planner.scene import Scene
from planner.waves import WaveDesignRequest, WaveDesignResult, design

DOC = harness.DOCS / "benchmarks.md"
SECTION = "Proven wave designs"
ARMS = "two-link,seed-arm"
BOX = {"two-link": 0.1, "seed-arm": 0.03}
"""Half-width [rad] of each arm's region around its singular start."""
START = {"two-link": two_link_start, "seed-arm": seed_start}
CO_DESIGN = {"two-link": {"amplitude_max": 0.08, "frequency": [3.0]},
             "seed-arm": {"amplitude_max": 0.06, "frequency": [3.0, 4.0]}}


def certified(case: str, arm: str, result: WaveDesignResult, seconds: float) -> dict:
    """A design's row."""
    c = result.certificate
    return {"case": case, "arm": arm, "status": result.status, "bound": c.bound,
            "sampled_min": c.sampled_min, "target": c.target, "proof": c.status,
            "boxes": c.boxes, "proof_s": c.seconds, "total_s": seconds}


def departure(req: WaveDesignRequest, result: WaveDesignResult) -> float:
    """[rad] The largest distance of the proven interpolant (cubic Hermite through the
    2,001 samples' angles and rates) from the integrated motion, at its intervals' middles."""
    m = req.motion
    assert m is not None
    run = solve(InverseDynamicsRequest(
        robot=result.robot, passive_motion=m.passive_motion, duration=m.duration,
        active_initial=m.active_initial, samples=4_001))
    t, q, dq = np.array(run.t), np.array(run.q), np.array(run.dq)
    proven = PiecewisePolynomial(t[::2], hermite(q[::2], dq[::2], np.diff(t[::2])))
    return float(np.abs(proven(t[1::2]) - q[1::2]).max())


def along_motion(arm: str) -> dict:
    """The arm's built-in wave design along its motion."""
    req = WaveDesignRequest.model_validate(example(f"{arm}-wave-design").request)
    started = time.perf_counter()
    result = design(req)
    row = certified("motion", arm, result, time.perf_counter() - started)
    return {**row, "departure": departure(req, result)}


def over_region(arm: str) -> dict:
    """A design over the box around the arm's singular start."""
    q, half = np.array(START[arm]()), BOX[arm]
    req = WaveDesignRequest.model_validate({
        "robot": example(f"{arm}-waveless").request["robot"], "amplitude_max": 0.06,
        "frequency_max": 4, "margin": 0.01,
        "region": {"lower": (q - half).tolist(), "upper": (q + half).tolist()}})
    started = time.perf_counter()
    result = design(req)
    return certified("region", arm, result, time.perf_counter() - started)


def co_designed(arm: str) -> dict:
    """The arm's built-in plan with its waves co-designed."""
    request = copy.deepcopy(example(f"{arm}-plan").request)
    request["task"]["co_design"] = CO_DESIGN[arm]
    started = time.perf_counter()
    result = plan(Scene.model_validate(request))
    seconds = time.perf_counter() - started
    c = result.verification.margin_certificate
    assert c is not None  # co-design with a margin
    return {"case": "co-design", "arm": arm, "status": result.status, "bound": c.bound,
            "sampled_min": c.sampled_min, "target": c.target, "proof": c.status,
            "boxes": c.boxes, "proof_s": c.seconds, "total_s": seconds}


SETUP = """\
Each arm's wave design along its built-in motion (`two-link-wave-design`,
`seed-arm-wave-design`: the seed's 4-link arm from its singular start along the seed
example's passive motion), proven along the piecewise cubic Hermite interpolant of the
inverse dynamics' 2,001 samples (their angles and rates); `departure` is the largest
distance of that interpolant from the integrated motion at the middle of its intervals
(the inverse dynamics run again at 4,001 samples). There is no built-in region example:
the region rows design over a box around each arm's singular start (0.1 rad a side of
the two-link arm's two joints, 0.03 rad of the seed arm's four), margin 0.01, amplitudes
up to 0.06 m, frequencies up to 4. The co-design rows plan the built-in `two-link-plan`
and `seed-arm-plan` with their waves' amplitudes (up to 0.08 and 0.06 m) and phases
co-designed, frequencies fixed (3; 3 and 4), and report the plan's
`verification.margin_certificate`.
Times are wall-clock seconds on a shared machine."""

COLUMNS = [("case", "case"), ("arm", "arm"), ("status", "result"), ("proof", "proof"),
           ("bound", "proven bound [kg m^2]"), ("sampled_min", "sampled min [kg m^2]"),
           ("target", "target [kg m^2]"), ("boxes", "boxes"), ("proof_s", "proof [s]"),
           ("total_s", "design or plan [s]"), ("departure", "departure [rad]")]


def shown(row: dict) -> dict:
    """A row for the table: bounds and samples to 5 digits, so that the two differ."""
    return {**row, **{k: f"{row[k]:.5g}" for k in ("bound", "sampled_min", "target")}}


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench wave_certificates",
                                     description=__doc__)
    parser.add_argument("--arms", default=ARMS, help="two-link and/or seed-arm, comma-separated")
    args = parser.parse_args(argv)
    arms = args.arms.split(",")
    started, note = time.perf_counter(), harness.machine_note()
    rows = []
    for run in (along_motion, over_region, co_designed):
        for arm in arms:
            rows.append(run(arm))
            print(rows[-1], flush=True)
    harness.write_csv(harness.RESULTS / "wave_certificates.csv", rows)
    text = "\n\n".join([
        SETUP,
        ("`result`: the design's status (certified, infeasible, undecided) or the plan's; "
         "`proof`: the certificate's (certified: the proven bound reaches the target, "
         "refuted: a sampled value falls below it, undecided: neither within the box cap "
         "or the deadline). The target is the design's margin, or the plan's coupling "
         "margin (1 - 1e-3). How the bound is proven: docs/model.md, \"Proven coupling "
         "margins\"."),
        harness.table([shown(r) for r in rows], COLUMNS),
        (f"Rows: `bench/results/wave_certificates.csv`. "
         f"{harness.manifest('wave_certificates', argv, started, note)}")])
    harness.write_section(DOC, SECTION, text)
    print(text)
    return 0
