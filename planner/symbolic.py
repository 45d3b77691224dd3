"""The symbolic matrix types an expression is written in."""

from __future__ import annotations

from typing import TypeVar

import casadi as ca

Sym = TypeVar("Sym", ca.SX, ca.MX)
"""ca.SX, or ca.MX where an expression calls what SX cannot hold (an integrator); one
expression never mixes them."""
