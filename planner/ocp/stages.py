"""What a key's NLP is made of, whatever its number of intervals: its stage functions.

The stage and terminal functions (`planner.ocp.stage_function`) with their derivative
kernels, the variable parts, the parameters and the bounds of the rows of one stage are
built once per key (its `intervals` ignored) and serve every mesh; the derivative kernels
run compiled (`planner.compiled`) once a library of them is on disk.
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from dataclasses import dataclass, replace
from functools import lru_cache
from pathlib import Path

import casadi as ca
import numpy as np

from planner.compiled import cache_dir, library, loaded
from planner.ocp.assembly import Blocks, Derivatives, Kernels, derivatives
from planner.ocp.key import ProblemKey
from planner.ocp.layout import Layout, Part
from planner.ocp.parameters import Parameters, parameters
from planner.ocp.stage_function import RowGroups, stage_function
from planner.ocp.terms import terms_of
from planner.ocp.transcription import AnyTranscription


@dataclass(frozen=True)
class Stages:
    """What a key's NLP is made of, whatever its number of intervals: the stage and terminal
    functions (None where the stages were loaded with their compiled kernels alone,
    `stored`) with their derivative kernels, the entries of a stage its predecessor reads
    (`link`), the variable parts, the parameters, and the bounds of the rows of a stage and
    of the terminal."""

    transcription: AnyTranscription
    kernels: Kernels | None
    derivatives: Derivatives | None
    link: int
    parts: tuple[tuple[Part, ...], tuple[Part, ...]]
    params: Parameters
    bounds: tuple[RowGroups, RowGroups]
    kinds: tuple[tuple[str, ...], tuple[str, ...]] = ((), ())
    """What each row group of a stage and of the terminal is (`ROW_KINDS`)."""


@lru_cache(maxsize=32)
def stages(key: ProblemKey, compiled: bool = False) -> Stages:
    """The stages of a key (its `intervals` ignored; cached); compiled: with the derivative
    kernels of `compiled_kernels`, which the caller found on disk, loaded without any
    symbolic work where their layout is stored beside them (`stored`)."""
    if compiled:
        found = stored(key)
        if found is not None:
            return found
        plain = stages(key)
        loaded = None if plain.derivatives is None else compiled_kernels(key, plain)
        return plain if loaded is None else replace(plain, derivatives=loaded)
    s = key.structure
    tr, terms = key.transcription(), terms_of(key)
    parts = tr.parts(s.n, key.torque_count())
    layout = Layout(*parts, key.global_variables(), 1)
    params = parameters(key, tr, terms)
    stage = stage_function(key, tr, layout, params, terms, False)
    terminal = stage_function(key, tr, layout, params, terms, True)
    link = sum(p.size for p in layout.stage if p.name in tr.link)
    kernels = Kernels(stage.function, terminal.function, link, stage.lifting)
    return Stages(tr, kernels, derivatives(kernels), link, parts, params,
                  (stage.bounds, terminal.bounds), (stage.kinds, terminal.kinds))


def _name(key: ProblemKey) -> str:
    """The compiled library of a key's stages (and its layout file, `.json`)."""
    return f"stages_{key.digest()}"


def _files(key: ProblemKey) -> tuple[Path, Path]:
    """A key's compiled library of stages and its layout file, in the cache folder."""
    return cache_dir() / f"{_name(key)}.so", cache_dir() / f"{_name(key)}.json"


def compiled_kernels(key: ProblemKey, plain: Stages, wait: bool = False) -> Derivatives | None:
    """The derivative kernels (what an iteration spends its time in) and the rows and cost
    of the symbolic stages `plain` compiled to C (`planner.compiled`), named by the stage
    key's digest: every number of intervals of the key, every process and every later run
    share the library, and its layout is stored beside it (`stored`). None while the
    library is being built in the background (unless wait)."""
    assert plain.derivatives is not None  # asked for only of stages that have kernels
    _store_layout(key, plain)
    loaded = library(_name(key), plain.derivatives.functions(), background=not wait)
    return None if loaded is None else plain.derivatives.replaced(loaded)


def compiled_ready(key: ProblemKey, wait: bool) -> bool:
    """Whether a key's NLP can have compiled kernels now: it asks for them (`solver.jit`)
    and they are on disk, or are built here (wait). If they are not, their build starts in
    the background."""
    if not key.jit:
        return False
    if all(path.exists() for path in _files(key)):
        return True
    plain = stages(key)
    return plain.derivatives is not None and compiled_kernels(key, plain, wait) is not None


# --------------------------------------------------------------------------- stored layout

def _sparsity(sp: ca.Sparsity) -> list:
    rows, cols = sp.get_triplet()
    return [sp.size1(), sp.size2(), list(rows), list(cols)]


def _store_layout(key: ProblemKey, plain: Stages) -> None:
    """Write what a key's stages are beside their library (once, atomically): the rows'
    bounds and kinds, the names of the kernels and where their nonzeros go, so that later
    processes load the stages with no symbolic work (`stored`). Nothing where the cache
    folder takes no file."""
    path = _files(key)[1]
    if path.exists() or plain.derivatives is None:
        return
    d = plain.derivatives
    layout = {"link": plain.link,
              **{name: {"bounds": plain.bounds[k], "kinds": list(plain.kinds[k]),
                        "functions": [f.name() for f in (b.rows, b.cost, b.jac, b.grad,
                                                         b.hess)],
                        "jac": _sparsity(b.jac_sp), "grad_rows": b.grad_rows.tolist(),
                        "hess": _sparsity(b.hess_sp)}
                 for k, (name, b) in enumerate((("stage", d.stage), ("terminal", d.terminal)))}}
    with contextlib.suppress(OSError):
        path.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile("w", dir=path.parent, delete=False,
                                         suffix=".tmp") as f:
            json.dump(layout, f)
        os.replace(f.name, path)


def stored(key: ProblemKey) -> Stages | None:
    """A key's stages loaded from their compiled library and its layout file, without
    building the symbolic stage functions or their derivatives; None unless both are on
    disk (and the key asks for compiled kernels)."""
    path = _files(key)[1]
    if not key.jit or not path.exists():
        return None
    layout = json.loads(path.read_text())
    functions = loaded(_name(key), [f for part in ("stage", "terminal")
                                    for f in layout[part]["functions"]])
    if functions is None:
        return None

    def blocks(part: str) -> Blocks:
        entry = layout[part]
        rows, cols, r, c = entry["jac"]
        hr, hc, hrow, hcol = entry["hess"]
        rows_f, cost, jac, grad, hess = (functions[f] for f in entry["functions"])
        return Blocks(rows_f, cost, jac, grad, hess, ca.Sparsity.triplet(rows, cols, r, c),
                      np.array(entry["grad_rows"], dtype=int),
                      ca.Sparsity.triplet(hr, hc, hrow, hcol))

    s, tr, terms = key.structure, key.transcription(), terms_of(key)

    def groups(part: str) -> RowGroups:
        return [(float(lo), float(hi), int(n)) for lo, hi, n in layout[part]["bounds"]]

    return Stages(tr, None, Derivatives(blocks("stage"), blocks("terminal")), layout["link"],
                  tr.parts(s.n, key.torque_count()), parameters(key, tr, terms),
                  (groups("stage"), groups("terminal")),
                  (tuple(layout["stage"]["kinds"]), tuple(layout["terminal"]["kinds"])))
