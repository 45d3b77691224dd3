"""Server-side limits on what one request may ask for (each set by an UNDERTOW_* variable).

Every limit is checked by arithmetic on the validated request, before anything is
computed or allocated. Violations become 422 problems naming the field and the limit;
the body size is limited by the app itself (413) and the job queue by the runner (429).
"""

from __future__ import annotations

from pydantic import BaseModel

from app.errors import FieldError, field_error, invalid
from app.settings import Settings
from planner.service import DurationRange, Scene, Transcription, node_count


def nodes(transcription: Transcription, intervals: int | None = None) -> int:
    """Time nodes of a transcription's NLP on `intervals` intervals (default: its own), as
    the transcription method counts them (`planner.service.node_count`)."""
    return node_count(transcription, intervals)


def most_intervals(transcription: Transcription, max_nodes: int) -> int:
    """The most intervals whose NLP holds at most `max_nodes` time nodes (node counts are
    affine in the number of intervals)."""
    one, two = nodes(transcription, 1), nodes(transcription, 2)
    return max((max_nodes - one) // (two - one) + 1, 0)


def _sized(body: BaseModel) -> list[tuple[list[str], int]]:
    """How many points each sized field of a request asks for: top-level lists (states,
    configurations, sample times), `samples` and `certification_points` counts, a grid's
    size, a torque polynomial's breaks."""
    sizes = []
    for name in type(body).model_fields:
        value = getattr(body, name)
        if isinstance(value, list):
            sizes.append(([name], len(value)))
        elif name in ("samples", "certification_points") and isinstance(value, int):
            sizes.append(([name], value))
        elif name == "grid" and value is not None and hasattr(value, "size"):
            sizes.append(([name, "points"], value.size))
        elif name == "torque" and value is not None:
            sizes.append(([name, "breaks"], len(value.breaks)))
    return sizes


def points(body: BaseModel) -> int:
    """The most points any sized field of a request asks for (0 when it has none)."""
    return max((size for _, size in _sized(body)), default=0)


def _request_errors(body: BaseModel, settings: Settings) -> list[FieldError]:
    """Links of the robot, the number of points a request asks for or a simulation
    returns, and the size of a wave design's search."""
    errors = []
    robot = getattr(body, "robot", None)
    if robot is not None and robot.n > settings.max_links:
        errors.append(field_error(["body", "robot", "links"],
                                  f"at most {settings.max_links} links on this server "
                                  f"(UNDERTOW_MAX_LINKS), got {robot.n}", "limit"))
    for name, cap, var in (("starts", settings.max_wave_starts, "UNDERTOW_MAX_WAVE_STARTS"),
                           ("frequency_max", settings.max_wave_frequency,
                            "UNDERTOW_MAX_WAVE_FREQUENCY")):
        value = getattr(body, name, None)
        if isinstance(value, int) and value > cap:
            errors.append(field_error(["body", name], f"at most {cap} on this server ({var}), "
                                                      f"got {value}", "limit"))
    for loc, size in _sized(body):
        if size > settings.max_points:
            errors.append(field_error(["body", *loc],
                                      f"{size} points exceed this server's limit of "
                                      f"{settings.max_points} (UNDERTOW_MAX_POINTS)", "limit"))
    samples = getattr(body, "output_samples", None)
    if samples is not None and samples > settings.max_points:
        errors.append(field_error(["body", "samples_per_interval"],
                                  f"{samples} samples (intervals x samples_per_interval + 1) "
                                  f"exceed this server's limit of {settings.max_points} "
                                  "(UNDERTOW_MAX_POINTS)", "limit"))
    screening = getattr(body, "screening", None)
    if screening is not None and screening > settings.max_wave_screening:
        errors.append(field_error(["body", "frequency_max"],
                                  f"the screening would evaluate {screening} configurations, "
                                  f"more than this server's limit of "
                                  f"{settings.max_wave_screening} (UNDERTOW_MAX_WAVE_SCREENING); "
                                  "lower frequency_max or fix joints of the region "
                                  "(lower == upper)", "limit"))
    return errors


def check_request(body: BaseModel, settings: Settings) -> None:
    """422 when a request exceeds the server's limits on links or list lengths."""
    errors = _request_errors(body, settings)
    if errors:
        raise invalid(errors)


def check_scene(scene: Scene, settings: Settings) -> Scene:
    """The scene with its wall time capped, or 422 when it exceeds a limit.

    A wall time the client did not set is lowered to the cap; one it set above the cap
    is refused."""
    errors = _request_errors(scene, settings)
    count = nodes(scene.transcription)
    if count > settings.max_nodes:
        errors.append(field_error(["body", "transcription", "intervals"],
                                  f"{count} nodes exceed this server's limit of "
                                  f"{settings.max_nodes} (UNDERTOW_MAX_NODES)", "limit"))
    duration = scene.task.duration
    horizon = duration.max if isinstance(duration, DurationRange) else duration
    if horizon > settings.max_horizon:
        ranged = isinstance(duration, DurationRange)
        loc = ["body", "task", "duration"] + (["max"] if ranged else [])
        errors.append(field_error(loc, f"{horizon:g} s exceeds this server's horizon limit of "
                                       f"{settings.max_horizon:g} s (UNDERTOW_MAX_HORIZON)",
                                  "limit"))
    wall = scene.solver.max_wall_time
    explicit = "max_wall_time" in scene.solver.model_fields_set
    if explicit and wall > settings.max_wall_time:
        errors.append(field_error(["body", "solver", "max_wall_time"],
                                  f"{wall:g} s exceeds this server's limit of "
                                  f"{settings.max_wall_time:g} s (UNDERTOW_MAX_WALL_TIME)",
                                  "limit"))
    refinement = scene.transcription.refinement
    cap = most_intervals(scene.transcription, settings.max_nodes)
    if "max_intervals" in refinement.model_fields_set and refinement.max_intervals > cap:
        errors.append(field_error(["body", "transcription", "refinement", "max_intervals"],
                                  f"{refinement.max_intervals} intervals would hold "
                                  f"{nodes(scene.transcription, refinement.max_intervals)} "
                                  f"nodes, more than this server's limit of "
                                  f"{settings.max_nodes} (UNDERTOW_MAX_NODES): at most {cap}",
                                  "limit"))
    if errors:
        raise invalid(errors)
    if wall > settings.max_wall_time:
        solver = scene.solver.model_copy(update={"max_wall_time": settings.max_wall_time})
        scene = scene.model_copy(update={"solver": solver})
    if refinement.max_intervals > cap:
        capped = refinement.model_copy(update={"max_intervals": cap})
        scene = scene.model_copy(update={"transcription": scene.transcription.model_copy(
            update={"refinement": capped})})
    return scene
