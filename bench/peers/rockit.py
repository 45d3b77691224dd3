"""rockit (`rockit-meco`, KU Leuven's optimal control layer on CasADi) on a planning scene,
written as a rockit user would.

An `Ocp` of duration T with states q, dq (n each) and controls tau (one per active joint,
piecewise constant: rockit's default), der(q) = dq, der(dq) = fd(q, dq, tau) with fd the
library's forward dynamics (`planner.dynamics.functions`, a CasADi Function called on
rockit's symbols); objective effort * integral |tau|^2 dt (rockit's `integral`, exact for
a piecewise-constant tau); the torque limit on every control; boundary states by `at_t0`
and `at_tf`; the coupling margin as in the Opti peer (bench/peers/opti.py: leading
principal minors of G / delta^2 - I >= 0 and, for a square M_pa, the sign of det M_pa
kept from the start) but imposed where rockit puts a path constraint by default, at the
N + 1 nodes only (the Opti peer adds the collocation points). Guess: the planner's own
(`planner.ocp.guess.hermite_guess`), tau at the interval midpoints, q and dq as functions
of `ocp.t` (linear between 8 samples per interval): rockit 0.6.7's DirectCollocation
fails on a state guess given on the grid (NameError on `kron` in its set_initial).

Methods on the scene's N intervals (50 by default):
- "collocation": `DirectCollocation(N, degree=3, scheme="legendre")`, the planner's state
  discretisation with rockit's piecewise-constant torque;
- "multiple shooting": `MultipleShooting(N, M=1, intg="rk")`, one RK4 step per interval.
Solvers: Ipopt (default options but print level and a wall cap), and CasADi's fatrop
(`ocp.solver("fatrop", {"structure_detection": "auto"})`, which recognises the stage
structure of rockit's multiple shooting: x0, u0, x1, ... with gap constraints first; it
rejects rockit's collocation, whose helper states read the previous interval, so fatrop
runs with multiple shooting only).

The plan is judged by the planner's own code as the Opti peer's: states between the nodes
are what rockit reports (`sample(..., grid="integrator", refine=4)`: its integrator's or
collocation polynomial's values at s = 0, 1/4, 1/2, 3/4, 1 of every interval, the points
`planner.ocp.accuracy` compares at), held by the quartic through them; the delivered
torque is the degree-0 polynomial of the controls. Every interval is re-integrated by
CVODES from the plan's own state (`interval_errors`), plus the whole-horizon replay.
"""

from __future__ import annotations

import math
import time

import casadi as ca
import numpy as np

from bench.scenes import fixed_duration
from planner.dynamics import functions
from planner.model import Structure, parameters
from planner.ocp.accuracy import SAMPLES, interval_errors
from planner.ocp.guess import hermite_guess
from planner.ocp.interpolant import PiecewisePolynomial
from planner.ocp.solvers.fatrop import FATROP
from planner.ocp.transcription import Interpolant
from planner.ocp.verify import open_loop
from planner.scene import Scene

GUESS_POINTS = 8  # samples of the state guess per interval (linear between them)
WALL_CAP = 600.0  # [s] Ipopt max_wall_time, a safety cap (not an Ipopt default)
METHODS = ("collocation", "multiple shooting")
SOLVERS = ("ipopt", "fatrop")


def _method(name: str, N: int):
    """rockit's method object of a method name on N intervals."""
    from rockit import DirectCollocation, MultipleShooting

    if name == "collocation":
        return DirectCollocation(N=N, degree=3, scheme="legendre")
    if name == "multiple shooting":
        return MultipleShooting(N=N, M=1, intg="rk")
    raise ValueError(f"method: one of {', '.join(METHODS)} (got {name!r})")


def _solver_options(solver: str, wall_time: float) -> dict:
    """rockit's `ocp.solver` options of a solver name: Ipopt's defaults but its print level
    and max_wall_time wall_time [s]; fatrop's defaults (it has no wall-time option), the
    NLP expanded to SX and its stage structure detected."""
    if solver == "ipopt":
        return {"print_time": False, "record_time": True,
                "ipopt": {"print_level": 0, "sb": "yes", "max_wall_time": wall_time}}
    if solver == "fatrop":
        return {"print_time": False, "record_time": True, "expand": True,
                "structure_detection": "auto", "fatrop": {"print_level": 0}}
    raise ValueError(f"solver: one of {', '.join(SOLVERS)} (got {solver!r})")


def build(scene: Scene, method: str = "collocation", solver: str = "ipopt",
          wall_time: float = WALL_CAP) -> dict:
    """The rockit Ocp of a scene and its handles: {"ocp", "q", "dq", "tau", "build_time"}."""
    from rockit import Ocp

    started = time.perf_counter()
    robot, task = scene.robot, scene.task
    N = scene.transcription.intervals
    s = Structure.of(robot)
    n, na = s.n, len(s.active_idx)
    p = ca.DM(parameters(robot, s))
    f = functions(s)
    T = fixed_duration(scene)

    ocp = Ocp(t0=0, T=T)
    q = ocp.state(n)
    dq = ocp.state(n)
    tau = ocp.control(na)
    ocp.set_der(q, dq)
    ocp.set_der(dq, f["fd"](q, dq, tau, p))
    ocp.add_objective(task.objective.effort * ocp.integral(ca.sumsqr(tau)))
    if task.torque_limit is not None:
        limit = np.broadcast_to(np.asarray(task.torque_limit, float), (na,))
        ocp.subject_to(-limit <= (tau <= limit))
    ocp.subject_to(ocp.at_t0(q) == task.initial.q)
    ocp.subject_to(ocp.at_t0(dq) == task.initial.dq)
    ocp.subject_to(ocp.at_tf(q) == task.final.q)
    ocp.subject_to(ocp.at_tf(dq) == task.final.dq)
    margin = task.coupling_margin
    if margin is not None:
        square = len(s.passive_idx) == na
        start_block = np.array(f["M"](task.initial.q, p))[np.ix_(s.passive_idx, s.active_idx)]
        sign = float(np.sign(np.linalg.det(start_block))) if square else 0.0
        mpa = f["M"](q, p)[s.passive_idx, s.active_idx]
        gram = ca.mtimes(mpa, mpa.T) if mpa.size1() <= mpa.size2() else ca.mtimes(mpa.T, mpa)
        shifted = gram / margin**2 - ca.MX.eye(gram.size1())
        for k in [] if square and na == 1 else range(1, gram.size1() + 1):
            ocp.subject_to(ca.det(shifted[:k, :k]) >= 0)
        if square:
            ocp.subject_to(sign * ca.det(mpa) / margin**na - 1 >= 0)
    ocp.method(_method(method, N))
    ocp.solver(solver, _solver_options(solver, wall_time))

    guess = hermite_guess(scene, robot, T)
    fine = np.linspace(0.0, 1.0, GUESS_POINTS * N + 1)
    dense = guess(fine)
    for var, key in ((q, "q"), (dq, "dq")):  # functions of ocp.t (see the module docstring)
        table = ca.interpolant(f"guess_{key}", "linear", [T * fine], dense[key].ravel())
        ocp.set_initial(var, table(ocp.t))
    ocp.set_initial(tau, guess((np.arange(N) + 0.5) / N)["tau"].T)
    return {"ocp": ocp, "q": q, "dq": dq, "tau": tau,
            "build_time": time.perf_counter() - started}


def solve(scene: Scene, method: str = "collocation", solver: str = "ipopt",
          wall_time: float = WALL_CAP) -> dict:
    """Build and solve; the same keys as `bench.peers.opti.solve` (build_time, solve_time,
    cpu_time, iterations, status, success, objective, local_error [rad],
    resimulation_error [rad]) and the method and solver."""
    built = build(scene, method, solver, wall_time)
    ocp = built["ocp"]
    started = time.perf_counter()
    try:
        sol = ocp.solve()
    except RuntimeError:  # the solver did not succeed: read the last iterate
        sol = ocp.non_converged_solution
    total = time.perf_counter() - started
    stats = sol.stats
    solve_time = float(stats.get("t_wall_total", total))
    result = {"method": method, "solver": solver,
              "build_time": built["build_time"] + total - solve_time, "solve_time": solve_time,
              "cpu_time": float(stats.get("t_proc_total", math.nan)),
              "iterations": int(stats.get("iter_count", 0)),
              "status": FATROP.status(stats) if solver == "fatrop"
              else str(stats.get("return_status", "?")),
              "success": bool(stats.get("success")),
              "objective": float(sol.value(ocp.objective))}
    result.update(verification(scene, built, sol))
    return result


def interpolant(scene: Scene, built: dict, sol) -> Interpolant | None:
    """The plan rockit reports, as the planner's interpolant (see the module's docstring);
    None when it has non-finite entries."""
    N = scene.transcription.intervals
    breaks = np.linspace(0.0, fixed_duration(scene), N + 1)
    _, q = sol.sample(built["q"], grid="integrator", refine=SAMPLES)
    _, dq = sol.sample(built["dq"], grid="integrator", refine=SAMPLES)
    _, tau = sol.sample(built["tau"], grid="control")
    q, dq = np.reshape(q, (N * SAMPLES + 1, -1)), np.reshape(dq, (N * SAMPLES + 1, -1))
    tau = np.reshape(tau, (N + 1, -1))[:N]
    if not all(np.all(np.isfinite(a)) for a in (q, dq, tau)):
        return None
    s = np.linspace(0.0, 1.0, SAMPLES + 1)
    to_coeffs = np.linalg.inv(s[:, None] ** np.arange(SAMPLES + 1)[None, :])

    def quartics(values: np.ndarray) -> PiecewisePolynomial:
        points = np.stack([values[k * SAMPLES:(k + 1) * SAMPLES + 1] for k in range(N)])
        return PiecewisePolynomial(breaks, np.einsum("ms,ksd->kmd", to_coeffs, points))

    return Interpolant(quartics(q), quartics(dq), PiecewisePolynomial(breaks, tau[:, None, :]))


def verification(scene: Scene, built: dict, sol) -> dict:
    """The planner's checks of rockit's plan: the largest interval error [rad] (what
    `verification.local_error` is for a plan) and the whole-horizon replay error [rad]."""
    interp = interpolant(scene, built, sol)
    if interp is None:
        return {"local_error": math.nan, "resimulation_error": math.nan}
    errors, _ = interval_errors(scene.robot, interp)
    error, _ = open_loop(scene.robot, interp)
    local = float(errors.max())
    return {"local_error": local if math.isfinite(local) else math.nan,
            "resimulation_error": math.nan if error is None else error}
