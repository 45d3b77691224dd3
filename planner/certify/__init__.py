"""Certified, not sampled: proven lower bounds of the coupling margin sigma_least(M_pa).

- `ball`: the model's own CasADi expression graphs run in ball arithmetic (python-flint's
  arb), so that one evaluation encloses M_pa over a whole box of configurations.
- `singular`: a proven lower bound of the least singular value of every matrix in a ball
  matrix (Weyl's inequality around the midpoint, whose own bound Sylvester's criterion
  proves in exact ball arithmetic).
- `boxes`: branch and bound, cutting boxes until the bound decides or a cap is reached
  ("undecided" is said, never hidden).
- `margin`: over a box of configurations (`region`) and along a piecewise polynomial
  motion, interval by interval (`along`) or joined over the whole of it (`path`).
- `decision`: what a proof says of a target margin (`decide`, `CouplingCertificate`).
"""

from planner.certify.boxes import Bound
from planner.certify.decision import PROOF_RTOL, CouplingCertificate, decide
from planner.certify.margin import along, path, region

__all__ = ["PROOF_RTOL", "Bound", "CouplingCertificate", "along", "decide", "path", "region"]
