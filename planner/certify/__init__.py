"""Certified, not sampled: proven lower bounds of the coupling margin sigma_least(M_pa).

- `ball`: the model's own CasADi expression graphs run in ball arithmetic (python-flint's
  arb), so that one evaluation encloses M_pa over a whole box of configurations.
- `singular`: a proven lower bound of the least singular value of every matrix in a ball
  matrix (Weyl's inequality around the midpoint, whose own bound Sylvester's criterion
  proves in exact ball arithmetic).
- `boxes`: branch and bound, cutting boxes until the bound decides or a cap is reached
  ("undecided" is said, never hidden).
- `margin`: over a box of configurations (`region`) and along a piecewise polynomial
  motion, interval by interval (`along`).
"""

from planner.certify.boxes import Bound
from planner.certify.margin import along, region

__all__ = ["Bound", "along", "region"]
