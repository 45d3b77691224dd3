"""An NLP from stage functions, with its derivatives assembled from per-stage blocks.

A stage function maps the variables of one stage w_k, the `link` entries of the next
stage, its copy of the global variables and the parameters to the stage's constraint
rows and cost; the terminal function does the same for the final node. The NLP maps them
over the N stages, and linear rows keep the globals' copies equal (`planner.ocp.layout`).
Since a stage reads its successor only linearly, the Hessian of the Lagrangian is
block diagonal over stages: its nonzeros are the
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
    """Start of the terminal's variables, of the globals' copies, and the number of stages."""
    return layout.intervals * layout.stage_size, layout.globals_start, layout.intervals


def _map_stages(link: int, layout: Layout, X: ca.MX, common: ca.MX, local: ca.MX):
    """The stage and terminal inputs: W (nw x N), NXT (link x N), the stages' copies of the
    globals (ng x N), the terminal's variables and copy, and the locals."""
    N, nw = layout.intervals, layout.stage_size
    start_t, start_g, _ = _columns(layout)
    W = ca.reshape(X[:start_t], nw, N)
    terminal = X[start_t:start_g]
    nxt = ca.horzcat(W[:link, 1:], terminal[:link]) if N > 1 else terminal[:link]
    glob = ca.reshape(X[start_g:], layout.globals_size, N + 1)
    return W, nxt, glob[:, :N], terminal, glob[:, N], local[:, :N], local[:, N]


def _copy_rows(glob: ca.MX, glob_t: ca.MX) -> ca.MX:
    """The rows g_k - g_{k+1} (ng N,) that keep the globals' copies equal, stage by stage,
    from the stages' copies (ng x N) and the terminal's."""
    return ca.vec(glob - ca.horzcat(glob[:, 1:], glob_t))


def nlp(kernels: Kernels | None, derivs: Derivatives | None, link: int, layout: Layout,
        X: ca.MX, common: ca.MX, local: ca.MX, boundary: ca.MX | None) -> tuple[ca.MX, ca.MX]:
    """The objective and the constraints (stage rows stage by stage, the terminal's, then
    the globals' copy rows): with derivative kernels from their rows and cost functions
    (compiled with them), so that an evaluation of the objective computes no row and
    neither is interpreted; else from the stage functions."""
    N = layout.intervals
    W, nxt, glob, terminal, glob_t, loc, loc_t = _map_stages(link, layout, X, common, local)
    stage_args, term_args = (W, nxt, glob, common, loc), (terminal, glob_t, common, loc_t)
    if derivs is None:
        assert kernels is not None  # stages without derivative kernels have their functions
        rows, costs = kernels.stage.map(N)(*stage_args)
        rows_t, cost_t = kernels.terminal(*term_args)
    else:
        rows, costs = derivs.stage.rows.map(N)(*stage_args), \
            derivs.stage.cost.map(N)(*stage_args)
        rows_t, cost_t = derivs.terminal.rows(*term_args), derivs.terminal.cost(*term_args)
    f = ca.sum2(costs) + cost_t + (boundary if boundary is not None else 0)
    return f, ca.vertcat(ca.vec(rows), rows_t, _copy_rows(glob, glob_t))


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


def _place(local: np.ndarray, nw: int, link: int, with_next: bool, stages: np.ndarray,
           copies: np.ndarray) -> np.ndarray:
    """Global columns of local indices into [w; nxt; glob] (or [w; glob]) for each stage in
    `stages` (the start of its variables; the terminal's for the terminal), whose copy of
    the globals starts at `copies`."""
    glob_at = nw + (link if with_next else 0)
    out = np.where(local < nw, stages[:, None] + local[None, :], 0)
    if with_next:
        nxt = (local >= nw) & (local < glob_at)
        out = np.where(nxt[None, :], stages[:, None] + local[None, :], out)  # next stage follows
    glob = local >= glob_at
    return np.where(glob[None, :], copies[:, None] + (local - glob_at)[None, :], out)


@dataclass(frozen=True)
class _Places:
    """Where the stages' and the terminal's variables and copies of the globals start."""

    nw: int
    nt: int
    link: int
    stages: np.ndarray
    copies: np.ndarray
    terminal: np.ndarray
    terminal_copy: np.ndarray

    @classmethod
    def of(cls, layout: Layout, link: int) -> _Places:
        N, ng = layout.intervals, layout.globals_size
        start_t, start_g, _ = _columns(layout)
        return cls(layout.stage_size, layout.terminal_size, link,
                   np.arange(N) * layout.stage_size, start_g + np.arange(N) * ng,
                   np.array([start_t]), np.array([start_g + N * ng]))

    def stage(self, local: np.ndarray, with_next: bool = False) -> np.ndarray:
        """Columns (N, len(local)) of a stage's local indices into [w; nxt; glob] (with_next)
        or [w; glob]."""
        return _place(local, self.nw, self.link if with_next else 0, with_next, self.stages,
                      self.copies)

    def final(self, local: np.ndarray) -> np.ndarray:
        """Columns (len(local),) of the terminal's local indices into [w; glob]."""
        return _place(local, self.nt, 0, False, self.terminal, self.terminal_copy)[0]


def _copy_jacobian(layout: Layout, first_row: int) -> tuple[np.ndarray, np.ndarray, ca.MX]:
    """Rows, columns and values (+1, -1) of the copy rows' constant Jacobian."""
    count = layout.copy_rows
    own = layout.globals_start + np.arange(count)
    rows = first_row + np.arange(count)
    values = np.concatenate([np.ones(count), -np.ones(count)])
    return np.concatenate([rows, rows]), np.concatenate([own, own + layout.globals_size]), \
        ca.MX(ca.DM(values))


def _assembled(derivs: Derivatives, link: int, layout: Layout, X: ca.MX, P: ca.MX,
               common: ca.MX, local: ca.MX, f: ca.MX, g: ca.MX, boundary: ca.MX | None) -> dict:
    """grad_f, jac_g and hess_lag functions for nlpsol, assembled from per-stage blocks."""
    N, nx = layout.intervals, layout.size
    W, nxt, glob, terminal, glob_t, loc, loc_t = _map_stages(link, layout, X, common, local)
    stage, term = derivs.stage, derivs.terminal
    stage_args = (W, nxt, glob, common, loc)
    term_args = (terminal, glob_t, common, loc_t)
    places = _Places.of(layout, link)
    n_rows, n_term = stage.rows.size1_out(0), term.rows.size1_out(0)

    # constraint Jacobian: every row belongs to one stage (or copy row), its entries unique
    r, c = (np.array(v, dtype=int) for v in stage.jac_sp.get_triplet())
    rt, ct = (np.array(v, dtype=int) for v in term.jac_sp.get_triplet())
    rc, cc, copies = _copy_jacobian(layout, N * n_rows + n_term)
    rows = np.concatenate([(r[None, :] + n_rows * np.arange(N)[:, None]).ravel(),
                           N * n_rows + rt, rc])
    cols = np.concatenate([places.stage(c, True).ravel(), places.final(ct), cc])
    nz = ca.vertcat(ca.vec(stage.jac.map(N)(*stage_args)), term.jac(*term_args), copies)
    sp, order = _scatter(rows, cols, (g.numel(), nx))
    jac = ca.MX(sp, nz[order])

    # objective gradient and Lagrangian Hessian (the copy rows are linear: no curvature)
    lam_f, lam_g = ca.MX.sym("lam_f"), ca.MX.sym("lam_g", g.numel())
    lam_stages = ca.reshape(lam_g[:N * n_rows], n_rows, N)
    lam_t = lam_g[N * n_rows:N * n_rows + n_term]
    grad = _stacked(stage.grad.map(N)(*stage_args), term.grad(*term_args), places,
                    (stage.grad_rows, None), (term.grad_rows, None), (nx, 1))
    hess = _stacked(stage.hess.map(N)(*stage_args, lam_f, lam_stages),
                    term.hess(*term_args, lam_f, lam_t), places,
                    (np.array(v, dtype=int) for v in stage.hess_sp.get_triplet()),
                    (np.array(v, dtype=int) for v in term.hess_sp.get_triplet()), (nx, nx))
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


def _stacked(stage_nz: ca.MX, term_nz: ca.MX, places: _Places, stage_at, term_at,
             shape: tuple[int, int]) -> ca.MX:
    """A matrix from per-stage nonzeros (one column per stage) and the terminal's, at local
    (rows, columns) into [w; glob] (columns None: a column vector); every entry is one
    stage's alone, as each reads its own copy of the globals."""
    (sr, sc), (tr, tc) = stage_at, term_at
    rows = [places.stage(sr).ravel(), places.final(tr)]
    cols = [np.zeros(rows[0].size, dtype=int), np.zeros(rows[1].size, dtype=int)] \
        if sc is None else [places.stage(sc).ravel(), places.final(tc)]
    sp, order = _scatter(np.concatenate(rows), np.concatenate(cols), shape)
    return ca.MX(sp, ca.vertcat(ca.vec(stage_nz), term_nz)[order])
