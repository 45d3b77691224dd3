"""What a key's NLP is made of, whatever its number of intervals: its stage functions.

The stage and terminal functions (`planner.ocp.stage_function`) with their derivative
kernels, the variable parts, the parameters and the bounds of the rows of one stage are
built once per key (its `intervals` ignored) and serve every mesh; the derivative kernels
run compiled (`planner.compiled`) once a library of them is on disk.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import lru_cache

from planner.compiled import library
from planner.ocp.assembly import Derivatives, Kernels, derivatives
from planner.ocp.key import ProblemKey
from planner.ocp.layout import Layout, Part
from planner.ocp.parameters import Parameters, parameters
from planner.ocp.stage_function import RowGroups, stage_function
from planner.ocp.terms import terms_of
from planner.ocp.transcription import AnyTranscription


@dataclass(frozen=True)
class Stages:
    """What a key's NLP is made of, whatever its number of intervals: the stage and terminal
    functions with their derivative kernels, the variable parts, the parameters, and the
    bounds of the rows of a stage and of the terminal."""

    transcription: AnyTranscription
    kernels: Kernels
    derivatives: Derivatives | None
    parts: tuple[tuple[Part, ...], tuple[Part, ...]]
    params: Parameters
    bounds: tuple[RowGroups, RowGroups]
    kinds: tuple[tuple[str, ...], tuple[str, ...]] = ((), ())
    """What each row group of a stage and of the terminal is (`ROW_KINDS`)."""


@lru_cache(maxsize=32)
def stages(key: ProblemKey, compiled: bool = False) -> Stages:
    """The stages of a key (its `intervals` ignored; cached); compiled: with the derivative
    kernels of `compiled_kernels`, which the caller found on disk."""
    if compiled:
        plain = stages(key)
        loaded = None if plain.derivatives is None else compiled_kernels(key, plain.derivatives)
        return plain if loaded is None else replace(plain, derivatives=loaded)
    s = key.structure
    tr, terms = key.transcription(), terms_of(key)
    parts = tr.parts(s.n, key.torque_count())
    layout = Layout(*parts, key.global_variables(), 1)
    params = parameters(key, tr, terms)
    stage = stage_function(key, tr, layout, params, terms, False)
    terminal = stage_function(key, tr, layout, params, terms, True)
    kernels = Kernels(stage.function, terminal.function,
                      sum(p.size for p in layout.stage if p.name in tr.link), stage.lifting)
    return Stages(tr, kernels, derivatives(kernels), parts, params,
                  (stage.bounds, terminal.bounds), (stage.kinds, terminal.kinds))


def compiled_kernels(key: ProblemKey, derivatives: Derivatives,
                     wait: bool = False) -> Derivatives | None:
    """The derivative kernels (what an iteration spends its time in) compiled to C
    (`planner.compiled`), named by the stage key's digest: every number of intervals of the
    key, every process and every later run share the library. None while the library is
    being built in the background (unless wait). The stage functions themselves stay
    symbolic: nlpsol differentiates them for what it computes once per solve."""
    loaded = library(f"stages_{key.digest()}", derivatives.functions(), background=not wait)
    return None if loaded is None else derivatives.replaced(loaded)


def compiled_ready(key: ProblemKey, wait: bool) -> bool:
    """Whether a key's NLP can have compiled kernels now: it asks for them (`solver.jit`)
    and they are on disk, or are built here (wait). If they are not, their build starts in
    the background."""
    if not key.jit:
        return False
    plain = stages(key)
    return plain.derivatives is not None and \
        compiled_kernels(key, plain.derivatives, wait) is not None
