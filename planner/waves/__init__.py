"""Certified wave design: a numerical form of the seed's Proposition 1.

Every active joint j gets a wave r_j = l_j + a_j sin(n_j q_j + eps_j), with an amplitude
0 <= a_j <= amplitude_max (and below the link length), an integer frequency
1 <= n_j <= frequency_max and a free phase, so that sigma_min(M_pa) >= margin over a box
of configurations, or along the motion that the inverse dynamics then produces. Waves
already on the robot are replaced.

How (one module each):
1. Screening (`screening`). Every frequency combination with a few phases per joint
   (full amplitude) is scored: over a box by sigma_min at the optimisation samples; along
   a motion by a fixed-step RK4 inverse dynamics of all candidates at once. The best
   starts, one per frequency combination first, go to the NLP.
2. NLP (Ipopt; `nlp`, with the samples of the `region` or `motion` problem). With the
   frequencies fixed, maximise s over amplitudes and phases subject to
   lambda_min(M_pa M_pa^T) >= s^2 at every sample, as smooth dimensionless constraints.
   Along a motion the samples are the nodes of a collocation of the inverse dynamics
   whose active states are NLP variables.
3. Check (`certificate`), independent of the NLP's samples: sigma_min on a dense grid of
   the box, or at dense samples of the inverse dynamics of `planner.inverse.solve`. Where
   the check falls below the NLP's bound, the worst configurations join the samples (or
   the collocation intervals around the worst times are halved) and the NLP is solved
   again (exchange method; the loop is `design`). The best checked design wins.
4. Proof (`planner.certify`), of the winner only: a lower bound of sigma_min(M_pa) that
   holds on the whole box (`region`), or along the whole piecewise cubic Hermite
   interpolant of the check's inverse-dynamics samples (`path`), in ball arithmetic on
   M_pa with branch and bound.

The result is "certified" when the proven bound reaches the margin, "infeasible" when a
sampled value falls below it (the best design found, which proves nothing about other
waves), and "undecided" when the proof's box cap or the deadline leaves it between. The
request and result are `schemas`'.
"""

from planner.waves.design import AMPLITUDE_FRACTION, design
from planner.waves.schemas import Motion, Region, WaveDesignRequest, WaveDesignResult, WaveSpec

__all__ = ["AMPLITUDE_FRACTION", "Motion", "Region", "WaveDesignRequest", "WaveDesignResult",
           "WaveSpec", "design"]
