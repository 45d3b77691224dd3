"""Memory of the synchronous computations: an up-front estimate of each request, and the
budget the running ones share (UNDERTOW_SYNC_MEMORY_MB).

The synchronous endpoints compute in threads of the server's own process, so their memory
adds to the server's: six wave designs of eight links at once took it past 1.1 GB, with
nothing but the number of compute threads to bound it. Each computation reserves its
estimate from one budget for as long as it runs (`MemoryBudget`): one estimated above the
whole budget is refused at the field its size grows with (422 `limit`), one that does not
fit beside those running waits for room up to UNDERTOW_COMPUTE_WAIT, then 503 `busy` with
Retry-After (`app.routes._compute`). Quick requests (dynamics or coupling at no more than
UNDERTOW_QUICK_POINTS points: a few MB each) keep their own threads and reserve nothing.

The estimates are fitted to `bench/sync_memory.py`'s measurements
(bench/results/sync_memory.csv): the resident peak of one computation in a fresh process
with cold caches (the symbolic functions and NLPs it builds counted), over its size
before. Every estimate is a fixed part, a part growing with the robot's links (`n`; the
symbolic functions and, for a wave design, its NLPs: about n^3.6), and a part per point
the request asks for; the constants are rounded up so that every measured point needs at
most its estimate (tests/test_sync_memory.py). What the library's caches keep after a
computation (built functions and NLPs, bounded by their entry counts) is not reserved:
it is the same for the next request of the same structure. Re-fit with
`python -m bench sync_memory` when the library changes.
"""

from __future__ import annotations

from dataclasses import dataclass

import anyio
from pydantic import BaseModel

from app.errors import FieldError, field_error
from app.settings import Settings
from planner.coupling import CouplingRequest
from planner.evaluation import DynamicsRequest
from planner.inverse import InverseDynamicsRequest
from planner.simulate import SimulationRequest
from planner.waves import WaveDesignRequest
from planner.waves.screening import coarse_points

FIXED_MB = 6.0
"""Any computation: its thread's allocations and its result's objects."""
LINK_MB = 0.1
"""Per link squared: the symbolic functions of the robot's structure."""
STATE_MB = 0.001
"""Per state of /v1/dynamics, per link plus one (M is n x n)."""
POINT_MB = 0.00025
"""Per configuration or grid point of /v1/coupling, per link plus two."""
SAMPLE_MB = 0.0012
"""Per sample of /v1/inverse-dynamics."""
OUTPUT_MB = 0.00025
"""Per sample a simulation returns, per link plus two."""
WAVE_MB = 45.0
"""A wave design: Ipopt, the inverse dynamics and the design's own arrays."""
WAVE_NLP_MB = 0.12
"""Per link to the power WAVE_EXPONENT: the design's NLPs."""
WAVE_EXPONENT = 3.6
SCREEN_MB = 0.00005
"""Per configuration of the screening (`WaveDesignRequest.screening`), per link."""
REGION_SAMPLE_MB = 0.004
"""Per optimisation sample of a region design (its coarse grid), per link: the region NLP
is built again as the exchange adds samples."""
CERTIFY_MB = 0.00002
"""Per certification point, per link squared (the Jacobian of M_pa at each)."""
PLOT_MB = 25.0
"""A plan's figure (matplotlib; figures are drawn one at a time)."""
PLAN_SAMPLE_MB = 12.0
"""A plan sampled at up to 1000 times."""
SESSION_UPDATE_MB = 40.0
"""One replanning session update: the solver's workspace on the session's NLP."""
REGION_CERTIFICATION = 40_000
"""A region design's certification points when the request gives none (the library's)."""
MOTION_CERTIFICATION = 2_001
"""A motion design's certification points when the request gives none (the library's)."""


@dataclass(frozen=True)
class Estimate:
    """The memory [MB] a computation needs, and the field its largest growing part comes
    from (where a request too large for the budget is refused) with what to ask for."""

    mb: float
    loc: tuple[str | int, ...]
    advice: str


def estimate(request: BaseModel) -> Estimate:
    """The memory of the computation a request asks for (see the module)."""
    if isinstance(request, WaveDesignRequest):
        return _wave_design(request)
    n = request.robot.n  # type: ignore[attr-defined]  # every computation has a robot
    loc: tuple[str | int, ...]
    if isinstance(request, DynamicsRequest):
        points, loc, advice = (STATE_MB * (n + 1) * len(request.states), ("states",),
                               "fewer states")
    elif isinstance(request, CouplingRequest) and request.grid is not None:
        points, loc, advice = (POINT_MB * (n + 2) * request.grid.size, ("grid", "points"),
                               "fewer grid points")
    elif isinstance(request, CouplingRequest):
        points, loc, advice = (POINT_MB * (n + 2) * len(request.configurations or ()),
                               ("configurations",), "fewer configurations")
    elif isinstance(request, InverseDynamicsRequest):
        points, loc, advice = SAMPLE_MB * request.samples, ("samples",), "fewer samples"
    elif isinstance(request, SimulationRequest):
        points, loc, advice = (OUTPUT_MB * (n + 2) * request.output_samples,
                               ("samples_per_interval",),
                               "fewer samples per interval or fewer intervals")
    else:
        raise TypeError(f"no memory estimate for {type(request).__name__}")
    return Estimate(FIXED_MB + LINK_MB * n * n + points, loc, advice)


def _wave_design(request: WaveDesignRequest) -> Estimate:
    """A wave design's parts: its NLPs, its screening, a region's optimisation samples and
    the certification; the field of the largest."""
    n = request.robot.n
    parts = [(WAVE_NLP_MB * n**WAVE_EXPONENT, ("robot", "links"), "fewer links"),
             (SCREEN_MB * n * request.screening, ("frequency_max",),
              "a lower frequency_max, or fix joints of the region (lower == upper)")]
    if request.region is not None:
        free = sum(hi > lo for lo, hi in zip(request.region.lower, request.region.upper,
                                             strict=True))
        parts.append((REGION_SAMPLE_MB * n * coarse_points(free) ** free, ("region",),
                      "fix joints of the region (lower == upper)"))
        certification = request.certification_points or REGION_CERTIFICATION
    else:
        certification = request.certification_points or MOTION_CERTIFICATION
    parts.append((CERTIFY_MB * n * n * certification, ("certification_points",),
                  "fewer certification points"))
    _, loc, advice = max(parts, key=lambda part: part[0])
    return Estimate(FIXED_MB + WAVE_MB + sum(part[0] for part in parts), loc, advice)


def estimate_mb(request: BaseModel) -> float:
    """`estimate(request).mb`."""
    return estimate(request).mb


def too_large(need: Estimate, settings: Settings) -> list[FieldError]:
    """A field error when a computation needs more than the whole budget."""
    if need.mb <= settings.sync_memory_mb:
        return []
    return [field_error(["body", *need.loc],
                        f"this computation needs about {need.mb:.0f} MB, more than the "
                        f"{settings.sync_memory_mb} MB the synchronous computations may use "
                        f"on this server (UNDERTOW_SYNC_MEMORY_MB): ask for {need.advice}",
                        "limit")]


class MemoryBudget:
    """The megabytes reserved by the synchronous computations running now, out of `total`.
    Made inside the event loop; every method runs on it."""

    def __init__(self, total: float):
        self.total, self.used = float(total), 0.0
        self._changed = anyio.Condition()

    async def reserve(self, mb: float, wait: float) -> bool:
        """Reserve `mb` once the running computations leave room for it, waiting at most
        `wait` seconds; False when no room came."""
        if self.used + mb <= self.total:  # room now: no wait, not even a zero one
            self.used += mb
            return True
        with anyio.move_on_after(wait):
            async with self._changed:
                while self.used + mb > self.total:
                    await self._changed.wait()
                self.used += mb
                return True
        return False

    async def release(self, mb: float) -> None:
        """Give back what `reserve` took, and wake the computations waiting for room."""
        with anyio.CancelScope(shield=True):
            async with self._changed:
                self.used = max(self.used - mb, 0.0)
                self._changed.notify_all()
