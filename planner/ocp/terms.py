"""Objective and constraint terms of the NLP, each a named piece that a scene switches on.

A term says whether a problem key wants it and how many parameters it reads, common to
the whole NLP or per stage ("local"); what it adds to one stage or to the final node (a
cost, or constraint rows with their bounds), and across stage boundaries (a cost coupling
neighbouring stages); and the numbers of its parameters for a scene on a mesh. Only
wanted terms are built, so a scene pays for nothing it does not ask for.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Generic

import casadi as ca
import numpy as np

from planner.dynamics import functions
from planner.margin_rows import margin_function
from planner.model import Robot, Structure
from planner.ocp.key import ProblemKey
from planner.ocp.mesh import Mesh
from planner.ocp.transcription import AnyTranscription, StagePiece
from planner.ocp.verify import coupling_along
from planner.scene import Scene
from planner.symbolic import Sym


@dataclass(frozen=True)
class Stage(Generic[Sym]):
    """What a term builds on in one stage (or at the final node, `terminal`): the stage's
    symbolic piece, its knots' quadrature weights [s] (1 x m), its width h [s], the
    duration T [s], the robot's parameters p, and the term's common and local parameters;
    all in the stage's symbolic type Sym; and the problem key the NLP is built for."""

    key: ProblemKey
    structure: Structure
    piece: StagePiece[Sym]
    weights: Sym
    h: Sym
    T: Sym
    p: Sym
    common: Callable[[str], Sym]
    local: Callable[[str], Sym]
    terminal: bool


@dataclass(frozen=True)
class Boundaries:
    """The torques on both sides of every stage boundary in time order (na x B each) and
    the time between them [s] (1 x B), for terms that couple neighbouring stages."""

    before: ca.MX
    after: ca.MX
    durations: ca.MX
    common: Callable[[str], ca.MX]


@dataclass(frozen=True)
class Numeric:
    """What terms need to set their parameters: the scene, the robot whose numbers the NLP
    starts from, the duration T [s], the mesh and its transcription, and the NLP's key."""

    scene: Scene
    robot: Robot
    T: float
    mesh: Mesh
    transcription: AnyTranscription
    key: ProblemKey
    virtual_weight: float | None = None
    """The weight of the passive joints' virtual torques in a relaxed NLP's effort (None:
    the NLP is not relaxed)."""

    def knot_times(self) -> np.ndarray:
        """(N + 1, m) time fractions of every stage's knots (the terminal's: 1, padded)."""
        tr = self.transcription
        stages = self.mesh.points(np.asarray(tr.knot_positions)).reshape(self.mesh.intervals, -1)
        return np.vstack([stages, np.ones((1, stages.shape[1]))])


Rows = tuple[Sym, float, float]
"""Constraint rows with their lower and upper bound."""


class Term:
    """A piece of the NLP; subclasses override what they add."""

    name = ""

    def wanted(self, key) -> bool:
        """Whether a problem key asks for the term."""
        raise NotImplementedError

    def common_size(self, key) -> int:
        """Parameters common to the whole NLP (default: one weight)."""
        return 1

    def local_size(self, key, tr: AnyTranscription) -> int:
        """Parameters of every stage."""
        return 0

    def cost(self, stage: Stage[Sym]) -> Sym | None:
        return None

    def rows(self, stage: Stage[Sym]) -> Rows[Sym] | None:
        return None

    def boundary_cost(self, b: Boundaries) -> ca.MX | None:
        return None

    def common_values(self, num: Numeric) -> np.ndarray:
        raise NotImplementedError

    def local_values(self, num: Numeric) -> np.ndarray:
        """(N + 1, local_size): per stage, the terminal's last."""
        return np.zeros((num.mesh.intervals + 1, 0))


def _integral(stage: Stage[Sym], integrand: Sym) -> Sym:
    """Quadrature of a per-knot quantity (1 x m) over the stage [unit s]."""
    return ca.mtimes(stage.weights, integrand.T)


class Effort(Term):
    """int sum_j w_j tau_j^2 dt [N^2 m^2 s]: w_j = effort on the active joints' torques, and
    `virtual_weight` on the passive joints' virtual torques of a relaxed NLP."""

    name = "effort"

    def wanted(self, key) -> bool:
        return key.effort or key.relaxed

    def common_size(self, key) -> int:
        return key.torque_count()

    def cost(self, stage: Stage[Sym]) -> Sym:
        weights = stage.common(self.name)
        return _integral(stage, ca.mtimes(weights.T, stage.piece.knot_tau**2))

    def common_values(self, num: Numeric) -> np.ndarray:
        active = np.full(len(num.robot.active), num.scene.task.objective.effort)
        if num.virtual_weight is None:
            return active
        return np.concatenate([active, np.full(len(num.robot.passive), num.virtual_weight)])


class Time(Term):
    """time * T [s]."""

    name = "time"

    def wanted(self, key) -> bool:
        return key.time

    def cost(self, stage: Stage[Sym]) -> Sym | None:
        return stage.common(self.name) * stage.T if stage.terminal else None

    def common_values(self, num: Numeric) -> np.ndarray:
        return np.array([num.scene.task.objective.time])


class Smoothness(Term):
    """smoothness * int |dtau/dt|^2 dt, by differences of consecutive torques divided by the
    time between them, inside stages and across their boundaries."""

    name = "smoothness"

    def wanted(self, key) -> bool:
        return key.smoothness

    def cost(self, stage: Stage[Sym]) -> Sym | None:
        taus, at = stage.piece.taus, stage.piece.tau_positions
        if len(at) < 2:
            return None
        steps = taus[:, 1:] - taus[:, :-1]
        durations = ca.DM(np.diff(at)).T * stage.h
        return stage.common(self.name) * ca.sum2(ca.sum1(steps**2) / durations)

    def boundary_cost(self, b: Boundaries) -> ca.MX:
        steps = b.after - b.before
        return b.common(self.name) * ca.sum2(ca.sum1(steps**2) / b.durations)

    def common_values(self, num: Numeric) -> np.ndarray:
        return np.array([num.scene.task.objective.smoothness])


class Tracking(Term):
    """weight * int |q_p - q_ref|^2 dt: least-squares tracking of a prescribed passive
    motion. Common: the weight; local: the reference at the stage's knots (n_passive x m)."""

    name = "tracking"

    def wanted(self, key) -> bool:
        return key.weighted_tracking

    def local_size(self, key, tr: AnyTranscription) -> int:
        return len(key.structure.passive_idx) * len(tr.knot_positions)

    def cost(self, stage: Stage[Sym]) -> Sym:
        passive = stage.structure.passive_idx
        knots = stage.piece.knot_q
        m = knots.size2()
        ref = ca.reshape(stage.local(self.name)[:len(passive) * m], len(passive), m)
        return stage.common(self.name) * _integral(stage, ca.sum1((knots[passive, :] - ref)**2))

    def common_values(self, num: Numeric) -> np.ndarray:
        tracking = num.scene.task.tracking
        assert tracking is not None  # wanted only then
        return np.array([tracking.weight])

    def local_values(self, num: Numeric) -> np.ndarray:
        return _reference_at_knots(num)


def _reference_at_knots(num: Numeric) -> np.ndarray:
    """(N + 1, m n_passive) the prescribed passive motion at every stage's knots (the
    terminal's row: at the end), knot-major, passive joints within."""
    tracking = num.scene.task.tracking
    assert tracking is not None  # wanted only then
    T, motion = num.T, tracking.motion
    times = num.knot_times()
    ref = motion.evaluate(times.ravel() * T, T)[0]  # (stages * m, n_passive)
    return ref.reshape(times.shape[0], -1)


class ExactTracking(Term):
    """q_p = q_ref at every knot, as rows: exact tracking of a prescribed passive motion
    where the knots' angles are not variables (their bounds hold it otherwise,
    `planner.ocp.instance`). Local: the reference at the stage's knots (n_passive x m)."""

    name = "exact_tracking"

    def wanted(self, key) -> bool:
        return key.exact_tracking

    def common_size(self, key) -> int:
        return 0

    def local_size(self, key, tr: AnyTranscription) -> int:
        return len(key.structure.passive_idx) * len(tr.knot_positions)

    def rows(self, stage: Stage[Sym]) -> Rows[Sym] | None:
        knots = stage.piece.knot_q
        m = knots.size2()
        if stage.terminal or not m:
            return None
        passive = stage.structure.passive_idx
        ref = ca.reshape(stage.local(self.name)[:len(passive) * m], len(passive), m)
        return ca.vec(knots[passive, :] - ref), 0.0, 0.0

    def common_values(self, num: Numeric) -> np.ndarray:
        return np.zeros(0)

    def local_values(self, num: Numeric) -> np.ndarray:
        return _reference_at_knots(num)


class TipTarget(Term):
    """The last link's tip at the target position [m] at the final time."""

    name = "tip"

    def wanted(self, key) -> bool:
        return key.tip

    def common_size(self, key) -> int:
        return 2

    def rows(self, stage: Stage[Sym]) -> Rows[Sym] | None:
        if not stage.terminal:
            return None
        tip = functions(stage.structure)["tips"](stage.piece.path_q[:, -1], stage.p)[:, -1]
        return tip - stage.common(self.name), 0.0, 0.0

    def common_values(self, num: Numeric) -> np.ndarray:
        target = num.scene.task.tip_target
        assert target is not None  # wanted only then
        return np.array([target.x, target.y])


class CouplingMargin(Term):
    """sigma_min(M_pa) >= margin at every knot and node (see `margin_function`).
    Common: the margin and the sign of det M_pa at the start."""

    name = "margin"

    def wanted(self, key) -> bool:
        return key.margin

    def common_size(self, key) -> int:
        return 2

    def rows(self, stage: Stage[Sym]) -> Rows[Sym]:
        par, path = stage.common(self.name), stage.piece.path_q
        minors = margin_function(stage.structure).map(path.size2())(path, stage.p, par[0], par[1])
        return ca.vec(minors), 0.0, np.inf

    def common_values(self, num: Numeric) -> np.ndarray:
        det = coupling_along(num.robot, np.array([num.scene.task.initial.q]))[1]
        return np.array([num.scene.task.coupling_margin,
                         1.0 if det is None or det[0] >= 0 else -1.0])


class TorqueLimit(Term):
    """|tau| <= limit on the whole of every interval. The torque variables have the limit as
    bounds (`planner.ocp.instance`); where the delivered torque polynomial is not just those
    variables (`Transcription.hulls`), its other Bernstein coefficients (`StagePiece.hull`)
    are held within the limit too, and the polynomial, which lies in their convex hull, with
    them. Sufficient, exact at the interval's ends, and within O(h^2) of the polynomial's
    own range. Rows limit - b >= 0 and limit + b >= 0, so that the limit is a parameter: one
    NLP serves every limit, 0 included (no division by it). Common: the limit per active
    joint [N m]."""

    name = "torque_limit"

    def wanted(self, key) -> bool:
        return key.torque_limit

    def common_size(self, key) -> int:
        return len(key.structure.active_idx)

    def rows(self, stage: Stage[Sym]) -> Rows[Sym] | None:
        hull = stage.piece.hull.get("tau")
        if stage.terminal or hull is None:
            return None
        hull = hull[:len(stage.structure.active_idx), :]  # a relaxed NLP's virtual rows: free
        limit = ca.repmat(stage.common(self.name), 1, hull.size2())
        return ca.vertcat(ca.vec(limit - hull), ca.vec(limit + hull)), 0.0, np.inf

    def common_values(self, num: Numeric) -> np.ndarray:
        limit = num.scene.task.torque_limit
        assert limit is not None  # wanted only then
        return np.broadcast_to(np.asarray(limit, float), (len(num.robot.active),)).copy()


class StateBounds(Term):
    """lower <= q (or dq) <= upper on the whole of every interval, for the joints the key
    names as bounded below and above: as `TorqueLimit`, the variables have the bounds, and
    the state polynomials' other Bernstein coefficients are held within them. Rows
    b - lower >= 0 and upper - b >= 0. Common: the lower bounds of the joints bounded below,
    then the upper bounds of those bounded above [rad or rad/s]."""

    def __init__(self, kind: str, name: str):
        self.kind, self.name = kind, name

    def joints(self, key) -> tuple[tuple[int, ...], tuple[int, ...]]:
        """The joints bounded below and above (the key's field of the term's name)."""
        return getattr(key, self.name)

    def wanted(self, key) -> bool:
        return any(self.joints(key))

    def common_size(self, key) -> int:
        return sum(len(joints) for joints in self.joints(key))

    def rows(self, stage: Stage[Sym]) -> Rows[Sym] | None:
        hull = stage.piece.hull.get(self.kind)
        if stage.terminal or hull is None:
            return None
        lower, upper = self.joints(stage.key)
        values, r = stage.common(self.name), hull.size2()
        rows = []
        if lower:
            rows.append(ca.vec(hull[list(lower), :] - ca.repmat(values[:len(lower)], 1, r)))
        if upper:
            rows.append(ca.vec(ca.repmat(values[len(lower):], 1, r) - hull[list(upper), :]))
        return ca.vertcat(*rows), 0.0, np.inf

    def common_values(self, num: Numeric) -> np.ndarray:
        bounds = getattr(num.scene.task, self.name)
        assert bounds is not None  # wanted only then
        lower, upper = self.joints(num.key)
        return np.array([bounds.lower[j] for j in lower] + [bounds.upper[j] for j in upper],
                        dtype=float)


TERMS: tuple[Term, ...] = (Effort(), Time(), Smoothness(), Tracking(), ExactTracking(),
                           TipTarget(), CouplingMargin(), TorqueLimit(),
                           StateBounds("q", "position_bounds"),
                           StateBounds("dq", "velocity_bounds"))
"""Every term, in the order their costs and rows enter the NLP."""


def terms_of(key: ProblemKey) -> list[Term]:
    """The objective and constraint terms a key asks for, in `TERMS` order."""
    return [term for term in TERMS if term.wanted(key)]
