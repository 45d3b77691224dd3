"""Screening: the candidate waves of a design, and how many configurations scoring them
takes.

Every frequency combination with a few evenly spaced phases per joint (full amplitude)
is a candidate; the problem scores them all (`RegionProblem.screen`,
`MotionProblem.screen`), and the best, one per frequency combination first, start the
NLP.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field

import numpy as np

from planner.model import Robot, Structure, Wave, wave_slots

SCREEN_STEPS = 100
"""RK4 steps of the screening's inverse dynamics along a motion."""


@dataclass
class Candidate:
    """Waves of the active joints: amplitudes [m], integer frequencies, phases [rad]."""

    amplitude: np.ndarray
    frequency: np.ndarray
    phase: np.ndarray
    bound: float = 0.0  # the NLP's s, or the screening score
    solved: bool = False  # the NLP converged
    guess: np.ndarray | None = field(default=None, repr=False)  # NLP node states (motion)

    def robot(self, base: Robot) -> Robot:
        waves = {j: Wave(amplitude=float(a), frequency=float(n), phase=float(e))
                 for j, a, n, e in zip(base.active, self.amplitude, self.frequency, self.phase,
                                       strict=True)}
        return base.with_waves(waves)


def wrap(phase: np.ndarray) -> np.ndarray:
    """Phases in [-pi, pi)."""
    return (np.asarray(phase) + np.pi) % (2 * np.pi) - np.pi


def candidates(na: int, frequency_max: int, amplitude: np.ndarray,
                starts: int) -> list[Candidate]:
    """Every frequency combination with `starts` evenly spaced phases per joint."""
    phases = 2 * np.pi * np.arange(starts) / starts - np.pi
    out = []
    for freq in itertools.product(range(1, frequency_max + 1), repeat=na):
        for phase in itertools.product(phases, repeat=na):
            out.append(Candidate(amplitude.copy(), np.array(freq, float), np.array(phase)))
    return out


def params(s: Structure, base: np.ndarray, cands: list[Candidate]) -> np.ndarray:
    """One parameter vector per candidate (rows)."""
    P = np.tile(base, (len(cands), 1))
    for k, slot in enumerate(sorted(wave_slots(s).values())):
        P[:, slot] = [c.amplitude[k] for c in cands]
        P[:, slot + 1] = [c.frequency[k] for c in cands]
        P[:, slot + 2] = [c.phase[k] for c in cands]
    return P


def phases_per_joint(na: int) -> int:
    """Starting phases per joint of `na` active joints: about 36 phase combinations per
    frequency combination."""
    return max(2, min(8, math.floor(36 ** (1 / na) + 1e-9)))


def coarse_points(free: int) -> int:
    """Optimisation samples per free axis of a region: about 300 in all, 3 to 17 a side."""
    return min(17, max(3, round(300 ** (1 / max(free, 1)))))


def diverse(cands: list[Candidate], scores: list[float], count: int) -> list[int]:
    """Indices of the `count` best candidates, the best of each frequency combination
    first, so that the starts do not all fall into one basin."""
    order = list(np.argsort(scores)[::-1])
    seen: set[tuple[float, ...]] = set()
    first: list[int] = []
    rest: list[int] = []
    for k in order:
        key = tuple(cands[k].frequency)
        (rest if key in seen or scores[k] <= 0.0 else first).append(k)
        seen.add(key)
    return (first + rest)[:count]
