"""Which code decides an NLP's symbolic form: what names compiled kernels and warm starts.

Two NLPs of the same key (`planner.ocp.key.ProblemKey`) built by the same code have the
same variables, constraints and derivative kernels; `formulation_hash` stands for "the
same code", so that kernels compiled by other sources are never loaded
(`planner.ocp.stages.compiled_kernels`).
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

from planner.compiled import source_digest

FORMULATION_SOURCES = ("dynamics.py", "model.py", "rk4.py", "ocp/transcription.py",
                       "ocp/interpolant.py", "ocp/methods", "ocp/terms.py", "ocp/assembly.py",
                       "ocp/layout.py", "ocp/key.py", "ocp/parameters.py",
                       "ocp/stage_function.py", "ocp/boundary.py", "ocp/stages.py",
                       "ocp/problem.py", "margin_rows.py")
"""The modules and packages (under planner/) whose code decides an NLP's symbolic form."""


def formulation_sources() -> list[Path]:
    """The files of `FORMULATION_SOURCES`, a package's modules in name order."""
    root = Path(__file__).resolve().parents[1]
    return [source for name in FORMULATION_SOURCES for source in
            (sorted((root / name).glob("*.py")) if (root / name).is_dir() else [root / name])]


@lru_cache(maxsize=1)
def formulation_hash() -> str:
    """A hash of the CasADi version and of `FORMULATION_SOURCES`."""
    return source_digest(sources=formulation_sources())
