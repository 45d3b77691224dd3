"""Where an NLP's numbers go in its parameter vector.

The vector holds the common entries (robot, fixed duration, every wanted term's), then one
column of local entries per stage and one for the terminal (mesh width, quadrature
weights, boundary duration, every wanted term's); `planner.ocp.instance` fills it.
"""

from __future__ import annotations

from dataclasses import dataclass

from planner.ocp.key import ProblemKey
from planner.ocp.terms import Term
from planner.ocp.transcription import AnyTranscription


@dataclass(frozen=True)
class Parameters:
    """Where the NLP's numbers go: `common` entries by name, then per stage `local` entries
    by name (one column per stage, the terminal's last)."""

    common: dict[str, slice]
    local: dict[str, slice]

    @property
    def n_common(self) -> int:
        return max((s.stop for s in self.common.values()), default=0)

    @property
    def n_local(self) -> int:
        return max((s.stop for s in self.local.values()), default=0)


def parameters(key: ProblemKey, tr: AnyTranscription, terms: list[Term]) -> Parameters:
    """The parameters of a key's NLP with its transcription and wanted terms."""
    common = {"robot": key.structure.n_params}
    if not key.free_time:
        common["T"] = 1
    local = {"width": 1, "weights": len(tr.knot_positions), "boundary": 1}
    for term in terms:
        common[term.name] = term.common_size(key)
        if term.local_size(key, tr):
            local[term.name] = term.local_size(key, tr)
    return Parameters(slices(common), slices(local))


def slices(sizes: dict[str, int]) -> dict[str, slice]:
    """Consecutive slices of the given sizes, by name in order."""
    out, k = {}, 0
    for name, size in sizes.items():
        out[name] = slice(k, k + size)
        k += size
    return out
