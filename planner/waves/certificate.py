"""The dense check of a design, which drives the exchange of samples and the choice among
starts; the design chosen is then proven (`planner.certify`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from planner.ocp.interpolant import PiecewisePolynomial

EXCHANGE_TOL = 0.01
"""The exchange stops when the dense minimum is within this fraction of the NLP bound."""


@dataclass
class Check:
    """Dense check of one design, independent of the NLP's samples: the smallest sampled
    sigma_min [kg m^2] (for a motion that stopped, the one at the stop), whether the
    exchange may stop, what was sampled, where to add samples, the fraction of the motion
    the inverse dynamics completed, and the motion q(t) to prove along (a completed
    motion's piecewise polynomial; None over a region)."""

    sampled: float
    converged: bool
    describe: str
    worst: np.ndarray = field(default_factory=lambda: np.empty(0))
    reached: float = 1.0
    motion: PiecewisePolynomial | None = None

    def beats(self, other: Check | None) -> bool:
        """Among motions that stop, the one that gets further; else the higher minimum."""
        return other is None or (self.reached, self.sampled) > (other.reached, other.sampled)
