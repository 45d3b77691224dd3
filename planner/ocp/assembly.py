"""An NLP from stage functions, with its derivatives assembled from per-stage blocks.

A stage function maps the variables of one stage w_k, the `link` entries of the next
stage, the global variables and the parameters to the stage's constraint rows and cost;
the terminal function does the same for the final node. The NLP maps them over the N
stages. Since a stage reads its successor only linearly, the Hessian of the Lagrangian is
block diagonal over stages (with a border for the globals): its nonzeros are the
per-stage Hessians, computed by one small SX function mapped over the stages and
scattered into place by a fixed permutation; likewise the constraint Jacobian and the
objective gradient. Building costs a fraction of a second for any N, and an iteration
costs what the fully expanded NLP costs (no colouring sweeps through the whole graph).
Terms that couple neighbouring stages (`boundary`) are small quadratics; CasADi
differentiates them directly.

A stage function that Hessian-couples to its successor, or that SX cannot hold (an
integrator), gets CasADi's own derivatives instead (`derivatives` gives None).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import cast

import casadi as ca
import numpy as np

from planner.ocp.layout import Layout


@dataclass(frozen=True)
class Kernels:
    """The symbolic functions of one stage and of the terminal.

    stage(w, nxt, glob, common, local) -> (rows, cost); terminal(w, glob, common, local) ->
    (rows, cost): w the stage's variables, nxt the next stage's leading `link` entries,
    glob the global variables, common and local the parameters."""

    stage: ca.Function
    terminal: ca.Function
    link: int
    lifting: Lifting | None = None
    """The stage written on its lifted quantities, where its transcription has them."""


@dataclass(frozen=True)
class Lifting:
    """A stage function written on lifted quantities z, linear in the stage's variables for
    a given width: function(w, z, nxt, glob, common, local) -> (rows, cost) and
    lift(w, nxt, glob, common, local) -> z, so that stage(w, ...) = function(w, lift(w, ...),
    ...). Its derivatives follow by the chain rule from the function's, which are sparse
    where the stage's own are dense (each collocation point's rows read that point's
    quantities alone)."""

    function: ca.Function
    lift: ca.Function


@dataclass(frozen=True)
class Assembly:
    """The NLP (x, p, f, g) and, when structured, its derivative functions for nlpsol."""

    nlp: dict
    derivatives: dict

    @property
    def structured(self) -> bool:
        return bool(self.derivatives)


def _columns(layout: Layout) -> tuple[int, int, int]:
    """Start of the terminal's variables, of the globals, and the number of stages."""
    N, nw = layout.intervals, layout.stage_size
    return N * nw, N * nw + layout.terminal_size, N


def _map_stages(link: int, layout: Layout, X: ca.MX, common: ca.MX, local: ca.MX):
    """The stage and terminal inputs: W (nw x N), NXT (link x N), glob, locals."""
    N, nw = layout.intervals, layout.stage_size
    start_t, start_g, _ = _columns(layout)
    W = ca.reshape(X[:start_t], nw, N)
    terminal = X[start_t:start_g]
    nxt = ca.horzcat(W[:link, 1:], terminal[:link]) if N > 1 else terminal[:link]
    glob = X[start_g:]
    return W, nxt, terminal, glob, local[:, :N], local[:, N]


def nlp(kernels: Kernels | None, derivs: Derivatives | None, link: int, layout: Layout,
        X: ca.MX, common: ca.MX, local: ca.MX, boundary: ca.MX | None) -> tuple[ca.MX, ca.MX]:
    """The objective and the constraints (stage rows stage by stage, then the terminal's):
    with derivative kernels from their rows and cost functions (compiled with them), so
    that an evaluation of the objective computes no row and neither is interpreted; else
    from the stage functions."""
    N = layout.intervals
    W, nxt, terminal, glob, loc, loc_t = _map_stages(link, layout, X, common, local)
    stage_args, term_args = (W, nxt, glob, common, loc), (terminal, glob, common, loc_t)
    if derivs is None:
        assert kernels is not None  # stages without derivative kernels have their functions
        rows, costs = kernels.stage.map(N)(*stage_args)
        rows_t, cost_t = kernels.terminal(*term_args)
    else:
        rows, costs = derivs.stage.rows.map(N)(*stage_args), \
            derivs.stage.cost.map(N)(*stage_args)
        rows_t, cost_t = derivs.terminal.rows(*term_args), derivs.terminal.cost(*term_args)
    f = ca.sum2(costs) + cost_t + (boundary if boundary is not None else 0)
    return f, ca.vertcat(ca.vec(rows), rows_t)


def _hessian_couples(kernels: Kernels) -> bool:
    """Whether a stage's Lagrangian is nonlinear in its successor's entries."""
    f = kernels.stage
    if not f.is_a("SXFunction"):
        return True
    w, nxt, glob, common, local = f.sx_in()
    rows, cost = f(w, nxt, glob, common, local)
    lam = ca.SX.sym("lam", rows.numel())
    grad = ca.gradient(cost + ca.dot(lam, rows), nxt)
    return ca.depends_on(grad, ca.vertcat(w, nxt, glob))


def assemble(kernels: Kernels | None, derivs: Derivatives | None, link: int, layout: Layout,
             n_common: int, n_local: int,
             boundary: Callable[[ca.MX, ca.MX, ca.MX], ca.MX] | None = None) -> Assembly:
    """The NLP of N stages, each reading `link` entries of the next, with `n_common`
    parameters and `n_local` per stage (the terminal has its own column); boundary(X,
    common, local) -> a cost coupling neighbouring stages. Without derivative kernels
    nlpsol derives the NLP itself from the stage functions (`kernels`, which stages loaded
    with their compiled kernels alone need not have)."""
    X = ca.MX.sym("x", layout.size)
    N = layout.intervals
    P = ca.MX.sym("p", n_common + n_local * (N + 1))
    common = P[:n_common]
    local = ca.reshape(P[n_common:], n_local, N + 1)
    extra = boundary(X, common, local) if boundary is not None else None
    f, g = nlp(kernels, derivs, link, layout, X, common, local, extra)
    oracle = {"x": X, "p": P, "f": f, "g": g}
    if derivs is None:
        return Assembly(oracle, {})
    return Assembly(oracle, _assembled(derivs, link, layout, X, P, common, local, f, g, extra))


# --------------------------------------------------------------------------- derivatives


@dataclass(frozen=True)
class Blocks:
    """The kernels of a stage (or terminal) function, its rows and cost apart and its
    derivatives, and where the derivatives' nonzeros go."""

    rows: ca.Function  # (w, nxt, glob, common, local) -> rows
    cost: ca.Function  # -> cost
    jac: ca.Function  # -> jacobian nonzeros
    grad: ca.Function  # -> gradient nonzeros (y = [w; glob])
    hess: ca.Function  # (w, nxt, glob, common, local, sigma, lam) -> hessian nonzeros
    jac_sp: ca.Sparsity  # rows x [w; nxt; glob]
    grad_rows: np.ndarray  # nonzero rows of the gradient in [w; glob]
    hess_sp: ca.Sparsity  # upper triangle in [w; glob]


@dataclass(frozen=True)
class Derivatives:
    """The derivative kernels of the stage and of the terminal function."""

    stage: Blocks
    terminal: Blocks

    def functions(self) -> list[ca.Function]:
        return [f for b in (self.stage, self.terminal)
                for f in (b.rows, b.cost, b.jac, b.grad, b.hess)]

    def replaced(self, functions: dict[str, ca.Function]) -> Derivatives:
        """The same kernels with each function replaced by the one of its name."""
        def swap(b: Blocks) -> Blocks:
            rows, cost, jac, grad, hess = (functions[f.name()]
                                           for f in (b.rows, b.cost, b.jac, b.grad, b.hess))
            return Blocks(rows, cost, jac, grad, hess, b.jac_sp, b.grad_rows, b.hess_sp)
        return Derivatives(swap(self.stage), swap(self.terminal))


def derivatives(kernels: Kernels) -> Derivatives | None:
    """Per-stage derivative kernels, or None where the Hessian is not block diagonal over
    stages or a stage is not SX (nlpsol then derives the whole NLP)."""
    if not kernels.terminal.is_a("SXFunction") or _hessian_couples(kernels):
        return None
    return Derivatives(_blocks(kernels.stage, True, kernels.lifting),
                       _blocks(kernels.terminal, False))


def _blocks(f: ca.Function, with_next: bool, lifting: Lifting | None = None) -> Blocks:
    """Derivative kernels of a stage (with_next) or terminal function, by the chain rule
    through its lifting where it has one."""
    ins = f.sx_in()
    w, glob = ins[0], ins[2 if with_next else 1]
    nxt = ins[1] if with_next else ca.SX(0, 1)
    z, y = ca.vertcat(w, nxt, glob), ca.vertcat(w, glob)
    rows, cost = f.call(ins)
    lam, sigma = ca.SX.sym("lam", rows.numel()), ca.SX.sym("sigma")
    if lifting is None:
        J = ca.jacobian(rows, z)
        grad = ca.gradient(cost, y)
        H = ca.triu(ca.hessian(sigma * cost + ca.dot(lam, rows), y)[0])
    else:
        J, grad, H = _chained(lifting, ins, z, y, lam, sigma)
    grad_rows = np.array(grad.sparsity().get_triplet()[0], dtype=int)

    def nz(m: ca.SX) -> ca.SX:
        # CasADi's stubs type the nonzeros as SXElem; Python receives each as a 1 x 1 SX.
        return ca.vertcat(*cast(list[ca.SX], m.nonzeros())) if m.nnz() else ca.SX(0, 1)

    name = f.name()
    return Blocks(ca.Function(f"{name}_rows", ins, [rows]),
                  ca.Function(f"{name}_cost", ins, [cost]),
                  ca.Function(f"{name}_jac", ins, [nz(J)]),
                  ca.Function(f"{name}_grad", ins, [nz(grad)]),
                  ca.Function(f"{name}_hess", [*ins, sigma, lam], [nz(H)]),
                  J.sparsity(), grad_rows, H.sparsity())


def _chained(lifting: Lifting, ins: list[ca.SX], z: ca.SX, y: ca.SX, lam: ca.SX,
             sigma: ca.SX) -> tuple[ca.SX, ca.SX, ca.SX]:
    """The Jacobian of a lifted stage's rows in z = [w; nxt; glob], the gradient of its cost
    and the upper triangle of its Lagrangian's Hessian in y = [w; glob], from the lifted
    function's derivatives in its own quantities (sparse) and the lift's: with
    u = lift(w, ...) and P = du/dy, H = [I; P]' H_(y,u) [I; P] + sum_i mu_i d2u_i/dy2,
    mu = dL/du (the second term vanishes for a lift linear in y: a fixed duration)."""
    u = ca.SX.sym("u", lifting.function.size1_in(1))
    rows, cost = lifting.function(ins[0], u, *ins[1:])
    lift = lifting.lift(*ins)
    J = ca.jacobian(rows, z) + ca.mtimes(ca.jacobian(rows, u), ca.jacobian(lift, z))
    P = ca.jacobian(lift, y)
    grad = ca.gradient(cost, y) + ca.mtimes(P.T, ca.gradient(cost, u))
    lagrangian = sigma * cost + ca.dot(lam, rows)
    yu = ca.vertcat(y, u)
    embed = ca.vertcat(ca.SX.eye(y.numel()), P)
    H = ca.mtimes([embed.T, ca.hessian(lagrangian, yu)[0], embed])
    mu = ca.SX.sym("mu", u.numel())
    curvature = ca.hessian(ca.dot(mu, lift), y)[0]
    if curvature.nnz():
        H = H + ca.substitute(curvature, mu, ca.gradient(lagrangian, u))
    J, grad, H = ca.substitute([J, grad, ca.triu(H)], [u], [lift])
    return J, grad, H


def _scatter(rows: np.ndarray, cols: np.ndarray,
             shape: tuple[int, int]) -> tuple[ca.Sparsity, list[int]]:
    """The sparsity of entries (rows, cols) and the permutation that orders their nonzeros
    column-major."""
    order = np.lexsort((rows, cols))
    sp = ca.Sparsity.triplet(shape[0], shape[1], rows[order].tolist(), cols[order].tolist())
    return sp, order.tolist()


def _place(local: np.ndarray, nw: int, link: int, start_g: int, with_next: bool,
           stages: np.ndarray) -> np.ndarray:
    """Global columns of local indices into [w; nxt; glob] (or [w; glob]) for each stage in
    `stages` (terminal: its start given as the stage's offset)."""
    glob_at = nw + (link if with_next else 0)
    out = np.where(local < nw, stages[:, None] + local[None, :], 0)
    if with_next:
        nxt = (local >= nw) & (local < glob_at)
        out = np.where(nxt[None, :], stages[:, None] + local[None, :], out)  # next stage follows
    glob = local >= glob_at
    return np.where(glob[None, :], start_g + (local - glob_at)[None, :], out)


def _assembled(derivs: Derivatives, link: int, layout: Layout, X: ca.MX, P: ca.MX,
               common: ca.MX, local: ca.MX, f: ca.MX, g: ca.MX, boundary: ca.MX | None) -> dict:
    """grad_f, jac_g and hess_lag functions for nlpsol, assembled from per-stage blocks."""
    N, nw = layout.intervals, layout.stage_size
    start_t, start_g, _ = _columns(layout)
    nx = layout.size
    W, nxt, terminal, glob, loc, loc_t = _map_stages(link, layout, X, common, local)
    stage, term = derivs.stage, derivs.terminal
    stage_args = (W, nxt, glob, common, loc)
    term_args = (terminal, glob, common, loc_t)
    starts = np.arange(N) * nw
    n_rows = stage.rows.size1_out(0)

    # constraint Jacobian: every row belongs to one stage, its entries are unique
    r, c = (np.array(v, dtype=int) for v in stage.jac_sp.get_triplet())
    rows = (r[None, :] + n_rows * np.arange(N)[:, None]).ravel()
    cols = _place(c, nw, link, start_g, True, starts).ravel()
    rt, ct = (np.array(v, dtype=int) for v in term.jac_sp.get_triplet())
    rows = np.concatenate([rows, N * n_rows + rt])
    cols = np.concatenate([cols, _place(ct, layout.terminal_size, 0, start_g, False,
                                        np.array([start_t]))[0]])
    nz = ca.vertcat(ca.vec(stage.jac.map(N)(*stage_args)), term.jac(*term_args))
    sp, order = _scatter(rows, cols, (g.numel(), nx))
    jac = ca.MX(sp, nz[order])

    # objective gradient and Lagrangian Hessian: global-global entries summed over stages
    lam_f, lam_g = ca.MX.sym("lam_f"), ca.MX.sym("lam_g", g.numel())
    lam_stages = ca.reshape(lam_g[:N * n_rows], n_rows, N)
    lam_t = lam_g[N * n_rows:]
    grad = _summed(stage.grad.map(N)(*stage_args), term.grad(*term_args),
                   stage.grad_rows, np.zeros_like(stage.grad_rows), term.grad_rows,
                   np.zeros_like(term.grad_rows), nw, layout.terminal_size, start_t, start_g,
                   (nx, 1), vector=True)
    hr, hc = (np.array(v, dtype=int) for v in stage.hess_sp.get_triplet())
    tr, tc = (np.array(v, dtype=int) for v in term.hess_sp.get_triplet())
    hess = _summed(stage.hess.map(N)(*stage_args, lam_f, lam_stages),
                   term.hess(*term_args, lam_f, lam_t), hr, hc, tr, tc, nw,
                   layout.terminal_size, start_t, start_g, (nx, nx))
    if boundary is not None:
        grad = grad + ca.gradient(boundary, X)
        hess = hess + lam_f * ca.triu(ca.hessian(boundary, X)[0])
    return {
        "grad_f": ca.Function("nlp_grad_f_stages", [X, P], [f, grad], ["x", "p"],
                              ["f", "grad_f_x"]),
        "jac_g": ca.Function("nlp_jac_g_stages", [X, P], [g, jac], ["x", "p"], ["g", "jac_g_x"]),
        "hess_lag": ca.Function("nlp_hess_l_stages", [X, P, lam_f, lam_g], [hess],
                                ["x", "p", "lam_f", "lam_g"], ["triu_hess_gamma_x_x"]),
    }


def _summed(stage_nz: ca.MX, term_nz: ca.MX, sr: np.ndarray, sc: np.ndarray, tr: np.ndarray,
            tc: np.ndarray, nw: int, nt: int, start_t: int, start_g: int,
            shape: tuple[int, int], vector: bool = False) -> ca.MX:
    """A matrix from per-stage nonzeros (one column per stage) and the terminal's, with
    local indices (rows sr/tr, columns sc/tc) into [w; glob]: entries within a stage's
    own variables are unique, entries between two globals are summed over all stages."""
    N = stage_nz.size2() if stage_nz.size1() else 0
    starts = np.arange(N) * nw
    s_glob = (sr >= nw) & (sc >= nw) if not vector else sr >= nw
    t_glob = (tr >= nt) & (tc >= nt) if not vector else tr >= nt
    # unique entries: every stage's, then the terminal's
    s_idx, t_idx = np.flatnonzero(~s_glob), np.flatnonzero(~t_glob)
    rows = [_place(sr[s_idx], nw, 0, start_g, False, starts).ravel(),
            _place(tr[t_idx], nt, 0, start_g, False, np.array([start_t]))[0]]
    if vector:
        cols = [np.zeros(rows[0].size, dtype=int), np.zeros(rows[1].size, dtype=int)]
    else:
        cols = [_place(sc[s_idx], nw, 0, start_g, False, starts).ravel(),
                _place(tc[t_idx], nt, 0, start_g, False, np.array([start_t]))[0]]
    values = [ca.vec(stage_nz[s_idx.tolist(), :]) if s_idx.size else ca.MX(0, 1),
              term_nz[t_idx.tolist()] if t_idx.size else ca.MX(0, 1)]
    # global entries: sum the stages' and add the terminal's at the same place
    g_keys: dict[tuple[int, int], ca.MX] = {}
    for k in np.flatnonzero(s_glob):
        key = (start_g + sr[k] - nw, 0 if vector else start_g + sc[k] - nw)
        g_keys[key] = g_keys.get(key, 0) + ca.sum2(stage_nz[int(k), :])
    for k in np.flatnonzero(t_glob):
        key = (start_g + tr[k] - nt, 0 if vector else start_g + tc[k] - nt)
        g_keys[key] = g_keys.get(key, 0) + term_nz[int(k)]
    if g_keys:
        keys = list(g_keys)
        rows.append(np.array([k[0] for k in keys], dtype=int))
        cols.append(np.array([k[1] for k in keys], dtype=int))
        values.append(ca.vertcat(*g_keys.values()))
    sp, order = _scatter(np.concatenate(rows), np.concatenate(cols), shape)
    return ca.MX(sp, ca.vertcat(*values)[order])
