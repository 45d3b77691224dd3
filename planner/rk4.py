"""The classical fourth-order Runge-Kutta step, written once for every symbolic integrator."""

from __future__ import annotations

from collections.abc import Callable

from planner.symbolic import Sym


def rk4_step(f: Callable[[Sym, float], Sym], x: Sym, h) -> Sym:
    """x after one RK4 step of x' = f(x, c) over a step of length h, where c in {0, 1/2, 1}
    is the fraction of the step at which f is evaluated (for time-varying inputs)."""
    k1 = f(x, 0.0)
    k2 = f(x + h / 2 * k1, 0.5)
    k3 = f(x + h / 2 * k2, 0.5)
    k4 = f(x + h * k3, 1.0)
    return x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
