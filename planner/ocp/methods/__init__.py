"""The direct transcriptions, each implementing `planner.ocp.transcription.Transcription`."""

from __future__ import annotations

from planner.ocp.methods.collocation import Collocation
from planner.ocp.methods.hermite_simpson import HermiteSimpson
from planner.ocp.methods.shooting import MultipleShooting, multiple_shooting
from planner.ocp.methods.trapezoidal import Trapezoidal
from planner.ocp.transcription import AnyTranscription
from planner.scene import Transcription as Settings


def create(method: str, intervals: int, degree: int = 3, integrator: str = "rk4",
           steps: int = 4, implicit: bool = True) -> AnyTranscription:
    """The transcription `method` on `intervals` intervals (degree: collocation's; integrator
    and steps: multiple shooting's, which is always explicit; implicit: the accelerations
    at the knots are variables)."""
    if method == "trapezoidal":
        return Trapezoidal(intervals, implicit)
    if method == "hermite-simpson":
        return HermiteSimpson(intervals, implicit)
    if method in ("legendre", "radau"):
        return Collocation(intervals, degree, method, implicit)
    return multiple_shooting(intervals, integrator, steps)


def of(settings: Settings) -> AnyTranscription:
    """The transcription a scene's settings ask for."""
    return create(settings.method, settings.intervals, settings.degree, settings.integrator,
                  settings.steps, settings.form == "implicit")


__all__ = ["Collocation", "HermiteSimpson", "MultipleShooting", "Trapezoidal", "create", "of"]
