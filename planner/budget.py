"""Wall-time budgets of library computations: a deadline on the `time.monotonic` clock.

The long loops of the library (the coupling analysis' chunks and refinements, the wave
design's starts, screening chunks and exchange rounds, the simulation's CVODES slices,
the inverse dynamics' right-hand side and output chunks, the dynamics' states) call
`check` and stop with `BudgetExceeded` once their deadline has passed; a batch over many
points goes in `chunks`, checked before each; an Ipopt solve inside them stops at its
next iteration through `ipopt_stop`. Every deadline is optional: None runs unbounded.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from functools import lru_cache

import casadi as ca
import numpy as np

from planner.errors import InputError


class BudgetExceeded(InputError):
    """A computation ran past its deadline: the request asks for more than its budget
    allows (an InputError, as a motion too fast for `planner.inverse.WALL_TIME` is)."""


def check(deadline: float | None, what: str) -> None:
    """Raise BudgetExceeded("{what} ran past its deadline") once `deadline` has passed."""
    if deadline is not None and time.monotonic() > deadline:
        raise BudgetExceeded(f"{what} ran past its deadline")


def chunks(count: int, size: int, deadline: float | None, what: str,
           unit: str) -> Iterator[slice]:
    """The slices [start, start + size) that cover range(count), each given only after
    `check(deadline, "{what} (at {unit} {start} of {count})")`: a batch evaluated chunk by
    chunk stops within one chunk of its deadline, its first chunk included."""
    for start in range(0, count, size):
        check(deadline, f"{what} (at {unit} {start:,} of {count:,})")
        yield slice(start, min(start + size, count))


@contextmanager
def part_of(what: str) -> Iterator[None]:
    """Name the computation `what` in a BudgetExceeded raised in this block by one of its
    parts ("the wave design: the inverse dynamics (at t = 0.5 s of 1 s) ran past ...")."""
    try:
        yield
    except BudgetExceeded as exc:
        if str(exc).startswith(what):
            raise
        raise BudgetExceeded(f"{what}: {exc}") from None


_solve_deadline: ContextVar[float | None] = ContextVar("solve_deadline", default=None)


@contextmanager
def solving(deadline: float | None) -> Iterator[None]:
    """Let the Ipopt solves run in this block (in this thread) stop at `deadline`."""
    token = _solve_deadline.set(deadline)
    try:
        yield
    finally:
        _solve_deadline.reset(token)


_OUTPUTS = tuple(ca.nlpsol_out())
"""nlpsol's outputs, an iteration callback's inputs, in order."""


class IterationCallback(ca.Callback):
    """The plumbing of an Ipopt iteration callback (nlpsol's `iteration_callback`): the
    solver's outputs x, f, g and their multipliers in, one flag out, non-zero to stop.
    A subclass sets its state, calls this constructor last, and gives `stop`, which reads
    the solver's buffers in place (no matrix is built per iteration)."""

    def __init__(self, name: str, nx: int, ng: int, np_: int):
        ca.Callback.__init__(self)
        self.sizes = {"x": nx, "lam_x": nx, "g": ng, "lam_g": ng, "p": np_, "lam_p": np_,
                      "f": 1}
        self.construct(name, {})

    def get_n_in(self) -> int:
        return len(_OUTPUTS)

    def get_n_out(self) -> int:
        return 1

    def get_name_in(self, i: int) -> str:
        return _OUTPUTS[i]

    def get_name_out(self, i: int) -> str:
        return "stop"

    def get_sparsity_in(self, i: int) -> ca.Sparsity:
        return ca.Sparsity.dense(self.sizes[_OUTPUTS[i]], 1)

    def has_eval_buffer(self) -> bool:
        return True

    def eval_buffer(self, arg, res) -> int:
        """CasADi's copy-free call: the inputs as arrays over the solver's own memory (an
        input the solver does not give, None, left out)."""
        values = {name: np.frombuffer(arg[i], dtype=np.float64)
                  for i, name in enumerate(_OUTPUTS) if arg[i] is not None}
        np.frombuffer(res[0], dtype=np.float64)[0] = float(self.stop(values))
        return 0

    def stop(self, values: dict[str, np.ndarray]) -> bool:
        """Whether to stop the solve, given the iterate: x (nx,), f (1,), g (ng,), lam_x,
        lam_g, lam_p, those the solver gives, arrays valid during the call only."""
        raise NotImplementedError


class _Stop(IterationCallback):
    """Stop Ipopt (status User_Requested_Stop) once the deadline of the thread's current
    `solving` block has passed."""

    def __init__(self, nx: int, ng: int, np_: int):
        super().__init__(f"stop_{nx}_{ng}_{np_}", nx, ng, np_)

    def stop(self, values: dict[str, np.ndarray]) -> bool:
        deadline = _solve_deadline.get()
        return deadline is not None and time.monotonic() > deadline


@lru_cache(maxsize=64)
def _stop(nx: int, ng: int, np_: int) -> _Stop:
    return _Stop(nx, ng, np_)  # cached: a callback must outlive the solvers using it


def ipopt_stop(nlp: dict) -> dict:
    """nlpsol options that make a solve of `nlp` ({x, p, g, ...}) stop at the deadline
    of its `solving` block."""
    sizes = (nlp["x"].numel(), nlp["g"].numel() if "g" in nlp else 0,
             nlp["p"].numel() if "p" in nlp else 0)
    return {"iteration_callback": _stop(*sizes)}
