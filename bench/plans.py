"""What the benchmarks read off a plan: its summary row, and its distance to a reference plan."""

from __future__ import annotations

import numpy as np
from scipy.interpolate import CubicSpline

from planner.ocp import Plan

SUMMARY_COLUMNS = [("status", "status"), ("iterations", "iterations"), ("solves", "solves"),
                   ("solve", "solve [s]"), ("objective", "objective"),
                   ("interval_error", "interval error [rad]"),
                   ("replay_error", "open-loop replay [rad]"), ("verified", "verified")]
"""Table columns (key, heading) of the usual part of `summary`."""


def verified(plan: Plan) -> bool:
    """Ipopt succeeded and every interval of the plan, re-integrated from the plan's own
    state with its torque, stays within the tolerance (`verification.verified`)."""
    return bool(plan.solver.success and plan.verification.verified)


def summary(plan: Plan) -> dict:
    """A plan's row: Ipopt's status of the last solve, iterations and Ipopt wall time [s]
    over every solve, the number of solves (mesh passes and retries), objective, interval
    error and open-loop replay error [rad] (`docs/planner.md`, "Verification"), smallest
    sigma_min(M_pa) [kg m^2], waveless singular crossings, the strategy that produced it,
    and whether it is verified ("yes"/"no")."""
    v = plan.verification
    return {"status": plan.solver.status, "iterations": plan.solver.iterations,
            "solves": len(plan.mesh_passes), "solve": plan.solver.solve_time,
            "objective": plan.objective, "interval_error": v.local_error,
            "replay_error": v.resimulation_error, "min_sigma": v.min_sigma,
            "crossings": len(v.waveless_singular_crossings), "strategy": plan.solver.strategy,
            "verified": "yes" if verified(plan) else "no"}


def dense_error(plan: Plan, reference: Plan) -> float:
    """max |q_plan - q_ref| [rad] over the plan's dense samples, the reference's dense output
    interpolated by a not-a-knot cubic spline (its own error is below 1e-9 rad here)."""
    t, q = np.asarray(plan.dense.t), np.asarray(plan.dense.q)
    spline = CubicSpline(np.asarray(reference.dense.t), np.asarray(reference.dense.q))
    return float(np.abs(q - spline(t)).max())


def spline_floor(reference: Plan) -> float:
    """Interpolation error of `dense_error`'s spline: fit every other dense sample of the
    reference, compare at the ones left out [rad] (an upper estimate of the floor)."""
    t, q = np.asarray(reference.dense.t), np.asarray(reference.dense.q)
    spline = CubicSpline(t[::2], q[::2])
    return float(np.abs(spline(t[1::2]) - q[1::2]).max())
