"""Certification: what the dense check of a design proves, independent of the NLP's
samples, and when the exchange of samples may stop."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

EXCHANGE_TOL = 0.01
"""The exchange stops when the dense minimum is within this fraction of the NLP bound."""


@dataclass
class Certificate:
    """Dense check of one design: the certified value, whether the exchange may stop, and
    where to add samples."""

    value: float
    converged: bool
    describe: str
    worst: np.ndarray = field(default_factory=lambda: np.empty(0))
    reached: float = 1.0  # fraction of the motion the inverse dynamics completed

    def beats(self, other: Certificate | None) -> bool:
        """Higher certified value; among motions that stop, the one that gets further."""
        return other is None or (self.value, self.reached) > (other.value, other.reached)
