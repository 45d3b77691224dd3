"""The objects a long-lived process makes as it starts (its modules, the app, the
planner's and CasADi's imports: about 100,000), kept out of Python's cyclic garbage
collector from then on.

The collector's oldest generation is walked whenever enough objects have survived into
it; a walk of the startup objects takes tens of milliseconds, and the allocations of a
plan or of a plan's JSON set one off every few requests, which then answer that much
later (docs/bench-service.md, "Plan jobs through the service: submit to answer"). They
live as long as the process, so after one collection they are frozen (`gc.freeze`): the
collector leaves them alone, and a forked child (a plan's companion) touches fewer of
their pages. Once per process: what a later start makes is collected as usual.
"""

from __future__ import annotations

import gc

_frozen = False


def freeze() -> None:
    """Collect what is garbage now, then move every object that is left to the
    collector's permanent generation; only the first call in a process does anything."""
    global _frozen
    if _frozen:
        return
    _frozen = True
    gc.collect()
    gc.freeze()
