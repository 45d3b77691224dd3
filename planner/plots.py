"""Figures of plans and inverse-dynamics results (matplotlib, Agg; PNG or SVG bytes).

Plan figure: a strip of arm snapshots (links, tip masses, and the mass path
r_i(q) e(q) of every active link drawn around its joint: wavy with a wave, a circle
without), then the joint angles [rad], the
active torques [N m] and sigma_min(M_pa) [kg m^2] over time, the last with and without
the waves (the plan's own `verification.sigma_min` and `waveless_sigma_min`). The times
where the waveless arm is singular (the plan's
`waveless_singular_crossings`) are vertical lines on every time axis.

Inverse-dynamics figure: angles, torques and sigma_min over time, the singular stop
marked by a vertical line.

Figures are built with `matplotlib.figure.Figure` directly (no pyplot state). Drawing text
goes through FreeType and the rc parameters, which matplotlib shares between threads, so
one figure is built and rendered at a time (`_RENDERING`); callers may run in several
threads.
Drawing convention: the model's x axis points along gravity, drawn downwards; y to the
right.
"""

from __future__ import annotations

import io
import threading
from pathlib import Path
from typing import Literal

import numpy as np
from matplotlib import rc_context
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from planner.dynamics import Dynamics
from planner.errors import InputError
from planner.inverse import InverseDynamicsRequest, InverseDynamicsResult
from planner.model import Robot, Wave
from planner.ocp.result import Plan
from planner.ocp.verification import Verification
from planner.scene import Task

Format = Literal["png", "svg"]
FORMATS: tuple[Format, ...] = ("png", "svg")
MEDIA_TYPES = {"png": "image/png", "svg": "image/svg+xml"}
_RENDERING = threading.RLock()  # FreeType's glyph cache and rcParams are process-wide

CROSSING_GID = "waveless-crossing"
"""gid prefix of the vertical lines marking waveless singular crossings."""
STOP_GID = "singular-stop"
"""gid prefix of the vertical lines marking an inverse-dynamics singular stop."""
SNAPSHOTS = 6
_SPIKE = 100.0  # a torque peak this many times the median switches to a symlog axis
_SIGMA_FLOOR = 1e-12  # [kg m^2] lower clip of sigma_min on the log axis
_WITH, _WITHOUT, _MARK = "#1f6fb4", "#9a9a9a", "#d62728"
_ACTIVE, _PASSIVE = "#ff7f0e", "#555555"
JOINT_COLOURS = ("#1f6fb4", "#ff7f0e", "#2ca02c", "#9467bd", "#8c564b", "#e377c2", "#17becf",
                 "#bcbd22")
"""Colour of joint j's curves (j modulo 8): neither the marks' red nor the waveless grey."""
PALETTE = {"joints": list(JOINT_COLOURS), "with": _WITH, "without": _WITHOUT, "mark": _MARK,
           "active": _ACTIVE, "passive": _PASSIVE}
"""Every colour of the figures by role; the browser viewer draws with the same ones."""
GRAVITY_GID = "gravity"
"""gid of the gravity arrow in each snapshot."""


# --------------------------------------------------------------------------- public API


def plan_robot(robot: Robot, plan: Plan) -> Robot:
    """The scene's robot carrying the plan's waves (they differ after wave co-design)."""
    waves = {w.joint: Wave(amplitude=w.amplitude, frequency=w.frequency, phase=w.phase)
             for w in plan.waves}
    return robot.with_waves(waves) if waves else robot


def plan_figure(plan: Plan, robot: Robot, snapshots: int = SNAPSHOTS,
                task: Task | None = None) -> Figure:
    """Snapshots, angles, torques and sigma_min of a plan of `robot` (the scene's robot);
    the scene's `task`, when given, names the objective's terms in the title."""
    robot = plan_robot(robot, plan)
    t, q = np.asarray(plan.dense.t), np.asarray(plan.dense.q)
    tau = np.asarray(plan.dense.tau)
    crossings = [c.time for c in plan.verification.waveless_singular_crossings]

    fig = Figure(figsize=(11.0, 9.0), layout="constrained")
    rows = fig.add_gridspec(4, 1, height_ratios=[0.8, 1, 1, 1.1])
    strip = rows[0].subgridspec(1, snapshots + 1, width_ratios=[1.0] * snapshots + [1.1])
    _snapshots(fig, strip, robot, t, q, snapshots)
    ax_q = fig.add_subplot(rows[1])
    ax_tau = fig.add_subplot(rows[2], sharex=ax_q)
    ax_s = fig.add_subplot(rows[3], sharex=ax_q)
    _angles(ax_q, t, q, robot)
    _torques(ax_tau, t, tau, robot)
    _sigma(ax_s, t, robot, plan.verification)
    for ax, panel in ((ax_q, "angles"), (ax_tau, "torques"), (ax_s, "sigma")):
        _mark(ax, crossings, CROSSING_GID, "waveless singular crossing", panel)
        _legend(ax)
    ax_s.set_xlabel("t [s]")
    if len(t) > 1 and t[-1] > t[0]:
        ax_q.set_xlim(t[0], t[-1])
    fig.suptitle(_plan_title(plan, task), fontsize=11)
    return fig


def inverse_figure(result: InverseDynamicsResult,
                   request: InverseDynamicsRequest | None = None) -> Figure:
    """Angles, torques and sigma_min of an inverse-dynamics result with the singular stop
    marked; the request (when given) names the joints, draws the threshold and sets the
    time axis to [0, duration]."""
    t, q = np.asarray(result.t), np.asarray(result.q)
    robot = request.robot if request is not None else None
    fig = Figure(figsize=(10.0, 8.0), layout="constrained")
    ax_q, ax_tau, ax_s = fig.subplots(3, 1, sharex=True)
    stop = [result.singularity.time] if result.singularity is not None else []
    if len(t):
        _angles(ax_q, t, q, robot)
        _torques(ax_tau, t, np.asarray(result.tau), robot)
        sigma = np.clip(np.asarray(result.sigma_min), _SIGMA_FLOOR, None)
        ax_s.semilogy(t, sigma, color=_WITH, lw=1.6, label="sigma_min(M_pa)")
    else:
        ax_q.set_ylabel("q [rad]")
        ax_tau.set_ylabel("active torque [N m]")
        for ax in (ax_q, ax_tau):
            ax.text(0.5, 0.5, "no samples: singular at the start", ha="center",
                    va="center", transform=ax.transAxes, color=_MARK)
    if result.singularity is not None:
        ax_s.semilogy([result.singularity.time],
                      [max(result.singularity.sigma_min, _SIGMA_FLOOR)], "o", color=_MARK)
    if request is not None:
        ax_s.axhline(request.sigma_threshold, color=_MARK, ls=":", lw=1.0,
                     label=f"threshold {request.sigma_threshold:g}")
        ax_s.set_xlim(0.0, request.duration)
    ax_s.set_ylabel("sigma_min(M_pa) [kg m^2]")
    ax_s.set_xlabel("t [s]")
    for ax, panel in ((ax_q, "angles"), (ax_tau, "torques"), (ax_s, "sigma")):
        _mark(ax, stop, STOP_GID, "singular stop", panel)
        ax.grid(True, alpha=0.3)
        _legend(ax)
    note = "" if result.message == result.status else f" — {result.message}"
    fig.suptitle(f"inverse dynamics: {result.status}{note}", fontsize=11)
    return fig


def render(fig: Figure, fmt: Format = "png", dpi: int = 110) -> bytes:
    """The figure as PNG or SVG bytes; the same figure always gives the same bytes."""
    if fmt not in FORMATS:
        raise InputError(f"format: must be one of {', '.join(FORMATS)} (got {fmt!r})")
    FigureCanvasAgg(fig)
    buffer = io.BytesIO()
    metadata = {"Date": None} if fmt == "svg" else {"Software": None}
    with _RENDERING, rc_context({"svg.hashsalt": "undertow"}):  # stable element ids
        fig.savefig(buffer, format=fmt, dpi=dpi, metadata=metadata)
    return buffer.getvalue()


def plan_plot(plan: Plan, robot: Robot, fmt: Format = "png", task: Task | None = None) -> bytes:
    """`render(plan_figure(plan, robot, task=task), fmt)`, the figure built and drawn in
    one turn."""
    with _RENDERING:
        return render(plan_figure(plan, robot, task=task), fmt)


def inverse_plot(result: InverseDynamicsResult, request: InverseDynamicsRequest | None = None,
                 fmt: Format = "png") -> bytes:
    """`render(inverse_figure(result, request), fmt)`, built and drawn in one turn."""
    with _RENDERING:
        return render(inverse_figure(result, request), fmt)


def format_of(path: str | Path) -> Format:
    """The image format named by a file's suffix (.png or .svg)."""
    suffix = Path(path).suffix.lower().lstrip(".")
    if suffix not in FORMATS:
        raise InputError(f"plot: the file name must end in .png or .svg (got {str(path)!r})")
    return suffix


# --------------------------------------------------------------------------- geometry


def wave_path(robot: Robot, joint: int, angles: np.ndarray) -> np.ndarray:
    """Points r_j(q) e(q) [m] (K, 2) of link j's wavy mass path at the angles q (K,),
    relative to the joint."""
    link = robot.links[joint]
    wave = link.wave or Wave(amplitude=0.0, frequency=0.0)
    r = link.length + wave.amplitude * np.sin(wave.frequency * angles + wave.phase)
    return np.stack([r * np.cos(angles), r * np.sin(angles)], axis=1)


def _screen(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Model (x along gravity, y) to drawing coordinates (right, up): (y, -x)."""
    return points[..., 1], -points[..., 0]


# --------------------------------------------------------------------------- panels


def _snapshots(fig: Figure, strip, robot: Robot, t: np.ndarray, q: np.ndarray,
               count: int) -> None:
    """`count` arm drawings at evenly spaced times on common axes limits, with the path
    of the last tip over the whole plan; a key in the strip's last cell."""
    dyn = Dynamics(robot)
    picks = np.unique(np.linspace(0, len(t) - 1, count).round().astype(int))
    trace = np.array([dyn.tips(qk) for qk in q[:: max(1, len(q) // 200)]])
    masses = np.array([link.mass for link in robot.links])
    sizes = 25 + 90 * masses / masses.max()
    colors = [_ACTIVE if link.joint == "active" else _PASSIVE for link in robot.links]
    full = np.linspace(0.0, 2.0 * np.pi, 361)
    drawings: list[tuple[int, np.ndarray, list[tuple[np.ndarray, np.ndarray]]]] = []
    for k in picks:
        tips = np.vstack([[0.0, 0.0], dyn.tips(q[k])])
        paths = [(tips[j] + wave_path(robot, j, full),
                  tips[j] + wave_path(robot, j, np.linspace(q[:, j].min(), q[:, j].max(), 120)))
                 for j, link in enumerate(robot.links) if link.joint == "active"]
        drawings.append((k, tips, paths))
    extent = np.vstack([trace.reshape(-1, 2), np.zeros((1, 2))]
                       + [p for _, _, paths in drawings for pair in paths for p in pair])
    xs, ys = _screen(extent)
    pad = 0.08 * max(np.ptp(xs), np.ptp(ys), 1e-3)
    cx, cy = (xs.max() + xs.min()) / 2, (ys.max() + ys.min()) / 2
    half = max(np.ptp(xs), np.ptp(ys)) / 2 + pad
    for col, (k, tips, paths) in enumerate(drawings):
        ax: Axes = fig.add_subplot(strip[0, col])
        for whole, swept in paths:
            ax.plot(*_screen(whole), color=_ACTIVE, lw=0.6, alpha=0.35, zorder=2)
            ax.plot(*_screen(swept), color=_ACTIVE, lw=1.5, zorder=2)
        ax.plot(*_screen(trace[:, -1]), color="#c7c7c7", lw=0.9, zorder=1)
        ax.plot(*_screen(tips), color="#333333", lw=2.2, solid_capstyle="round", zorder=3)
        ax.scatter(*_screen(tips[1:]), s=sizes, c=colors, zorder=4, edgecolors="white",
                   linewidths=0.6)
        ax.plot([0.0], [0.0], marker="s", color="#222222", ms=5, zorder=5)
        if robot.gravity:  # no arrow for a weightless arm (g = 0)
            ax.annotate("", xy=(0.07, 0.66), xytext=(0.07, 0.94), xycoords="axes fraction",
                        arrowprops={"arrowstyle": "-|>", "color": "#777777", "lw": 1.2},
                        gid=f"{GRAVITY_GID}-{col}")  # the model's x axis: drawn downwards
        ax.set_title(f"t = {t[k]:.2f} s", fontsize=9)
        ax.set_xlim(cx - half, cx + half)
        ax.set_ylim(cy - half, cy + half)
        ax.set_aspect("equal")
        ax.set_xticks([])
        ax.set_yticks([])
        for side in ax.spines.values():
            side.set_color("#dddddd")
    _snapshot_key(fig.add_subplot(strip[0, -1]), bool(robot.gravity))


def _snapshot_key(ax: Axes, gravity: bool) -> None:
    """The legend of the snapshot strip, in an empty cell."""
    ax.axis("off")
    handles = [Line2D([], [], color="#333333", lw=2.2, label="link"),
               Line2D([], [], ls="", marker="o", color=_PASSIVE, label="mass, passive joint"),
               Line2D([], [], ls="", marker="o", color=_ACTIVE, label="mass, active joint"),
               Line2D([], [], color=_ACTIVE, lw=1.5,
                      label="active link's mass\npath r(q) e(q), swept"),
               Line2D([], [], color="#c7c7c7", lw=0.9, label="last tip's path")]
    handles.append(Line2D([], [], ls="", marker="$\\downarrow$", color="#777777",
                          label="gravity (x) down") if gravity else
                   Line2D([], [], ls="", marker="", label="no gravity (g = 0)"))
    ax.legend(handles=handles, loc="center left", fontsize=7.5, frameon=False,
              borderaxespad=0.0, handlelength=1.6)


def _joint_colour(j: int) -> str:
    return JOINT_COLOURS[j % len(JOINT_COLOURS)]


def _joint_label(robot: Robot | None, j: int) -> str:
    if robot is None:
        return f"q{j}"
    return f"q{j} ({robot.links[j].joint})"


def _angles(ax: Axes, t: np.ndarray, q: np.ndarray, robot: Robot | None) -> None:
    for j in range(q.shape[1]):
        active = robot is not None and robot.links[j].joint == "active"
        ax.plot(t, q[:, j], lw=1.6, ls="-" if active or robot is None else "--",
                color=_joint_colour(j), label=_joint_label(robot, j))
    ax.set_ylabel("q [rad]")
    ax.grid(True, alpha=0.3)


def _torques(ax: Axes, t: np.ndarray, tau: np.ndarray, robot: Robot | None) -> None:
    active = robot.active if robot is not None else list(range(tau.shape[1]))
    for col, j in enumerate(active):
        ax.plot(t, tau[:, col], lw=1.6, color=_joint_colour(j), label=f"tau{j}")
    magnitude = np.abs(tau[np.isfinite(tau)])
    if magnitude.size and magnitude.max() > _SPIKE * max(np.median(magnitude), 1e-12):
        typical = max(float(np.percentile(magnitude, 90)), 1e-9)
        ax.set_yscale("symlog", linthresh=10.0 ** np.ceil(np.log10(typical)))
    ax.set_ylabel("active torque [N m]")
    ax.grid(True, alpha=0.3)


def _sigma(ax: Axes, t: np.ndarray, robot: Robot, v: Verification) -> None:
    """The plan's sigma_min(M_pa) at the times t with and without the waves (log scale)."""
    ax.set_ylabel("sigma_min(M_pa) [kg m^2]")
    ax.grid(True, alpha=0.3, which="both")
    note = ("no passive joint: no coupling block" if not robot.passive else
            None if len(v.sigma_min) == len(t) else "sigma_min not recorded in this plan")
    if note:
        ax.text(0.5, 0.5, note, ha="center", va="center", transform=ax.transAxes)
        return
    with_waves, waveless = (np.array(values, dtype=float)  # None -> NaN: a gap in the curve
                            for values in (v.sigma_min, v.waveless_sigma_min))
    minimum = v.min_sigma
    label = "with waves" + (f" (min {minimum:.3g})" if minimum is not None else "")
    ax.semilogy(t, np.clip(waveless, _SIGMA_FLOOR, None), color=_WITHOUT, lw=1.2,
                label="without waves")
    ax.semilogy(t, np.clip(with_waves, _SIGMA_FLOOR, None), color=_WITH, lw=1.8, label=label)
    top = float(max(np.nanmax(with_waves), np.nanmax(waveless), _SIGMA_FLOOR))
    low = float(np.clip(min(np.nanmin(with_waves), np.nanmin(waveless)), _SIGMA_FLOOR, None))
    ax.set_ylim(max(low / 3.0, top * 1e-9), top * 3.0)


def _mark(ax: Axes, times: list[float], gid: str, label: str, panel: str) -> None:
    """Vertical lines at `times`, tagged "gid-panel-k" (unique ids in SVG); the first
    one labelled."""
    for k, time in enumerate(times):
        ax.axvline(time, color=_MARK, ls="--", lw=1.0, gid=f"{gid}-{panel}-{k}",
                   label=label if k == 0 else None)


def _legend(ax: Axes) -> None:
    """The panel's legend right of its frame, where it can never cover a curve."""
    if ax.get_legend_handles_labels()[0]:
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0,
                  fontsize=8, frameon=False)


_TERMS = (  # (weight's field, the term's integral, its unit)
    ("effort", "∫|τ|² dt", "N²m²s"),
    ("time", "T", "s"),
    ("smoothness", "∫|dτ/dt|² dt", "N²m²/s"),
)


def objective_text(value: float | None, task: Task | None = None) -> str:
    """The objective's value with what it is: its weighted terms from the scene's task and
    its unit when there is one term ("objective (effort ∫|τ|² dt) 1.122 N²m²s"); without
    the task, the bare value."""
    shown = "n/a" if value is None else f"{value:.4g}"
    if task is None:
        return f"objective {shown}"
    weights = task.objective
    terms = [(name, integral, unit, getattr(weights, name)) for name, integral, unit in _TERMS]
    if task.tracking is not None and task.tracking.mode == "weighted":
        terms.append(("tracking", "∫|q_p − q_ref|² dt", "rad²s", task.tracking.weight))
    used = [term for term in terms if term[3] > 0.0]
    if not used:
        return f"objective {shown}"
    parts = [f"{name} {integral}" if weight == 1.0 else f"{name} {weight:g}·{integral}"
             for name, integral, _, weight in used]
    unit = f" {used[0][2]}" if len(used) == 1 and value is not None else ""
    return f"objective ({' + '.join(parts)}) {shown}{unit}"


def _plan_title(plan: Plan, task: Task | None = None) -> str:
    """Whether the plan is verified (its re-simulation error against the tolerance), then
    Ipopt's outcome and the plan's figures."""
    v = plan.verification
    verdict = ("not checked" if v.verified is None
               else "verified" if v.verified else "not verified")
    if v.resimulation_error is not None:
        bound = f" (tolerance {v.tolerance:.2g} rad)" if v.tolerance is not None else ""
        verdict += f": re-simulation error {v.resimulation_error:.2g} rad{bound}"
    parts = [f"Ipopt {plan.solver.status} ({plan.solver.iterations} iterations)",
             f"T = {plan.duration:.3g} s", objective_text(plan.objective, task),
             f"{len(v.waveless_singular_crossings)} waveless singular crossing(s)"]
    return f"plan {verdict}\n" + " · ".join(parts)
