"""The transcription contract: what every direct transcription of M(q) ddq + h = B tau gives.

A transcription is written stage by stage: it lays out the variables of one interval (the
same parts for every interval) and of the final node, and states, for one interval of
width h [s], its defect constraints and where the dynamics and the path constraints hold.
A stage reads its own variables and the leading `link` parts of the next stage (the next
node's state), the latter only linearly, so that the NLP's Hessian is block diagonal over
stages (`planner.ocp.assembly`). It also gives the quadrature weights of its knots on a
mesh and the interpolant it assumes between them (states and torques), which the
verification feeds to an independent simulation. Time fractions are fractions of T.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Generic, Protocol, TypeAlias, runtime_checkable

import casadi as ca
import numpy as np

from planner.ocp.interpolant import PiecewisePolynomial
from planner.ocp.layout import Part
from planner.ocp.mesh import Mesh
from planner.symbolic import Sym

Accelerations = Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]
"""fd(q, dq, tau) -> ddq, numeric, rows are samples: (K, n), (K, n), (K, na) -> (K, n)."""


@dataclass(frozen=True)
class Model(Generic[Sym]):
    """The symbolic dynamics a stage is written with (in Sym): n joints, na active; implicit:
    the accelerations at the knots are variables (parts named ddq*) constrained by
    M ddq + h = B tau, else they are fd(q, dq, tau); p the robot's parameters."""

    n: int
    na: int
    implicit: bool
    fd: ca.Function
    ode: ca.Function
    p: Sym

    def accelerations(self, parts: dict[str, Sym], name: str, q: Sym, dq: Sym,
                      tau: Sym | None) -> Sym:
        """ddq (n x m) at m knots: the variables `name`, or the forward dynamics of the
        torques tau (which only the implicit form may lack)."""
        if self.implicit:
            return parts[name]
        if tau is None:
            raise ValueError("the explicit form needs the knots' torques")
        return self.fd.map(q.size2())(q, dq, tau, self.p)


@dataclass(frozen=True)
class StagePiece(Generic[Sym]):
    """The symbolic content of one stage (or of the final node).

    defects: equality rows; knot_q, knot_dq, knot_ddq (n x m), knot_tau (na x m): the
    knots, where the dynamics hold (implicit form: M ddq + h = B tau is added there);
    path_q (n x r): where path constraints hold; taus (na x s): the torques in time order,
    at `tau_positions` (fractions of the interval), for the smoothness term; gaps: rows
    next node state - F(stage variables) = 0 that close the gap to the next stage (a
    method whose defects read the next stage otherwise has none), the stage's first rows,
    the layout a structure-exploiting solver (fatrop) expects.

    hull: by kind ("q", "dq", "tau"), the Bernstein coefficients (rows x r) of the stage's
    interval polynomials (the interpolant's, `Transcription.interpolant`) that are not
    variables; with the variables' bounds, bounding them bounds the whole polynomial on the
    interval (it lies in their convex hull). A coefficient equal to the polynomial's end value
    may be left out where a constraint makes it the next node's (bounded) value. Only the
    kinds in `Transcription.hulls`, and only in stages (the terminal has no interval).
    """

    defects: Sym
    knot_q: Sym
    knot_dq: Sym
    knot_ddq: Sym
    knot_tau: Sym
    path_q: Sym
    taus: Sym
    tau_positions: tuple[float, ...]
    gaps: Sym | None = None
    hull: dict[str, Sym] = field(default_factory=dict)


@dataclass(frozen=True)
class Interpolant:
    """Numeric interpolant of a solved transcription: q, dq and tau as piecewise polynomials
    on the mesh's breakpoints [s]."""

    q: PiecewisePolynomial
    dq: PiecewisePolynomial
    tau: PiecewisePolynomial


class Transcription(Protocol[Sym]):
    """What every transcription method implements, its stages written in Sym."""

    name: str
    intervals: int
    order: int
    """Order p of the local error of its interpolant: about C h^p on an interval of width h
    (the refinement's model)."""
    terminal_knots: int
    """Knots at the final node (0 or 1)."""
    hulls: tuple[str, ...]
    """The kinds ("q", "dq", "tau") whose interval polynomials have Bernstein coefficients
    that are not variables (`StagePiece.hull`): a bound on such a kind holds on the whole
    interval only with rows on them. A kind absent here is bounded everywhere by its
    variables' bounds (a torque linear between nodes or constant per interval)."""

    @property
    def knot_positions(self) -> tuple[float, ...]:
        """Where a stage's knots sit in its interval (fractions), in the order of knot_q."""

    @property
    def link(self) -> tuple[str, ...]:
        """The leading parts of a stage (and of the terminal) that the previous stage reads."""

    @property
    def knot_blocks(self) -> tuple[str, ...]:
        """The angle blocks at the knots (where exact tracking holds)."""

    @property
    def symbolic(self) -> type[Sym]:
        """ca.SX, or ca.MX where a stage calls what SX cannot hold (an integrator)."""

    def node_count(self) -> int:
        """Time points the NLP holds variables at (server limits count these)."""

    def knot_count(self) -> int:
        """Points where the dynamics hold."""

    def parts(self, n: int, na: int) -> tuple[tuple[Part, ...], tuple[Part, ...]]:
        """The variables of a stage and of the terminal, the `link` parts first."""

    def stage(self, w: dict[str, Sym], nxt: dict[str, Sym], h: Sym,
              model: Model[Sym]) -> StagePiece[Sym]:
        """One interval of width h [s]: its parts w and the next stage's `link` parts nxt."""

    def terminal(self, w: dict[str, Sym], model: Model[Sym]) -> StagePiece[Sym]:
        """The final node."""

    def weights(self, mesh: Mesh) -> tuple[np.ndarray, np.ndarray]:
        """Quadrature weights as fractions of T: per stage (N, len(knot_positions)) and at
        the terminal (terminal_knots,): int f dt ~ T sum_j w_j f(knot j)."""

    def interpolant(self, sol: dict[str, np.ndarray], breaks: np.ndarray,
                    fd: Accelerations) -> Interpolant:
        """The states and torques between the knots of a solution (blocks by name, rows x
        columns in time order) on the mesh's breakpoints [s]; fd gives the accelerations
        where they are not variables."""


@runtime_checkable
class Lifted(Protocol):
    """A transcription whose stage is written on more quantities than its variables: the
    `lifted_parts`, linear functions of the stage's variables for a given width (`lift`),
    such as condensed collocation states. Its stage reads them from its parts like
    variables, so that derivatives follow by the chain rule from the lifted stage's, which
    are sparser (`planner.ocp.assembly`)."""

    def lifted_parts(self, n: int) -> tuple[Part, ...]:
        """The lifted quantities of a stage of an arm of n joints."""

    def lift(self, w: dict[str, ca.SX], h: ca.SX) -> dict[str, ca.SX]:
        """The lifted quantities of a stage with variables w and width h [s]."""


AnyTranscription: TypeAlias = Transcription[ca.SX] | Transcription[ca.MX]
"""A transcription whose stages are written in either symbolic type."""


def nodes(n: int, position: float = 0.0) -> tuple[Part, Part]:
    """The node angles and rates of a stage (position 0) or of the terminal."""
    return Part("q", "q", n, (position,)), Part("dq", "dq", n, (position,))


def knot_accelerations(sol: dict[str, np.ndarray], name: str, q: str, dq: str, tau: str,
                       fd: Accelerations) -> np.ndarray:
    """The accelerations block `name` of a solution (n x K), from fd where it is not a
    variable block (explicit form)."""
    if name in sol:
        return sol[name]
    return fd(sol[q].T, sol[dq].T, sol[tau].T).T
