"""Coupling singularities of the built-in examples, with and without their designed waves.

The classical inverse dynamics of each example waveless, waveless from a start moved by
OFFSET, and with its designed waves; the wave design of each example; the time of a large
coupling analysis. Writes the figures docs/img/singularity_*.png and the section
"Measured: inverse dynamics, wave design, coupling analysis" of docs/singularities.md.

    python -m bench singularities
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from matplotlib.figure import Figure

from bench import harness
from planner.coupling import CouplingRequest, analyse
from planner.coupling_block import along
from planner.examples import MARGIN, example, seed_arm, seed_start, two_link, two_link_start
from planner.inverse import InverseDynamicsRequest, InverseDynamicsResult, solve
from planner.model import Robot
from planner.simulate import simulate, torque_coefficients
from planner.waves import WaveDesignRequest, design

DOC = harness.DOCS / "singularities.md"
SECTION = "Measured: inverse dynamics, wave design, coupling analysis"
IMG = harness.DOCS / "img"
OFFSET = -0.05
"""Offset [rad] of the last active joint's start angle in the near-singular case."""


def cases(key: str) -> dict[str, tuple[InverseDynamicsRequest, InverseDynamicsResult]]:
    """Waveless, waveless from a start OFFSET away, and with the designed waves."""
    plain = example(f"{key}-waveless").request
    shifted = dict(plain, active_initial=dict(plain["active_initial"]))
    q = list(shifted["active_initial"]["q"])
    q[-1] += OFFSET
    shifted["active_initial"]["q"] = q
    out = {}
    for label, doc in (("waveless", plain), (f"waveless, start {OFFSET:+g} rad", shifted),
                       ("designed waves", example(f"{key}-waves").request)):
        req = InverseDynamicsRequest.model_validate(doc)
        out[label] = (req, solve(req))
    return out


def feed_forward_error(req: InverseDynamicsRequest, result: InverseDynamicsResult) -> float:
    """Largest passive angle error [rad] when the cubic spline of tau is simulated."""
    t, q, dq = np.array(result.t), np.array(result.q), np.array(result.dq)
    coeffs = torque_coefficients(t, np.array(result.tau), "cubic")
    run = simulate(req.robot, t, coeffs, np.concatenate([q[0], dq[0]]))
    return float(np.abs(np.array(run.q) - q)[:, req.robot.passive].max())


def det_map(robot: Robot, base: list[float], axes: tuple[int, int], spans, points=241):
    """det M_pa over a 2-D slice through `base`, varying joints `axes` over `spans`."""
    u, v = (np.linspace(lo, hi, points) for lo, hi in spans)
    U, V = np.meshgrid(u, v, indexing="xy")
    Q = np.tile(base, (U.size, 1))
    Q[:, axes[0]], Q[:, axes[1]] = U.ravel(), V.ravel()
    det = along(robot, Q).det
    if det is None:
        raise ValueError("det M_pa needs a square coupling block")
    return U, V, det.reshape(U.shape)


def plot_maps(name: str, arms, base, axes, spans, runs, labels) -> None:
    """det M_pa slices without and with the waves, each with the motions of its robot."""
    fig = Figure(figsize=(11, 4.8), layout="constrained")
    panels = fig.subplots(1, 2)
    for ax, (title, robot), wavy in zip(panels, arms, (False, True), strict=True):
        U, V, D = det_map(robot, base, axes, spans)
        limit = np.abs(D).max()
        mesh = ax.pcolormesh(U, V, D, cmap="RdBu_r", vmin=-limit, vmax=limit, shading="auto")
        ax.contour(U, V, D, levels=[0.0], colors="k", linewidths=1.2)
        fig.colorbar(mesh, ax=ax, label="det M_pa [kg² m⁴]")
        for k, (label, (req, result)) in enumerate(runs.items()):
            if (req.robot.links[req.robot.active[0]].wave is not None) != wavy:
                continue
            if result.t:
                q = np.array(result.q)
                ax.plot(q[:, axes[0]], q[:, axes[1]], color=f"C{k}", lw=2, label=label)
            if result.singularity:
                stop = result.singularity.q
                ax.plot(stop[axes[0]], stop[axes[1]], "kx", ms=10, mew=2)
        ax.plot(base[axes[0]], base[axes[1]], "o", mfc="none", mec="k", ms=9)
        ax.set_title(f"{title} (x: singular stop, o: start)")
        ax.legend(loc="lower right", fontsize=8)
        ax.set_xlabel(f"q{axes[0]} ({labels[0]}) [rad]")
        ax.set_ylabel(f"q{axes[1]} ({labels[1]}) [rad]")
    fig.savefig(harness.output(IMG / f"singularity_{name}_map.png"), dpi=110)


def plot_runs(name: str, title: str, runs) -> None:
    """|tau| and sigma_min over time; a singular stop is marked with a cross."""
    fig = Figure(figsize=(9, 6.5), layout="constrained")
    top, bottom = fig.subplots(2, 1, sharex=True)
    for k, (label, (req, result)) in enumerate(runs.items()):
        colour = f"C{k}"
        if result.t:
            t, tau = np.array(result.t), np.abs(np.array(result.tau))
            for j, joint in enumerate(req.robot.active):
                top.semilogy(t, np.maximum(tau[:, j], 1e-6), color=colour,
                             ls=("-", "--")[j % 2], label=f"{label}, joint {joint}")
            bottom.semilogy(t, result.sigma_min, color=colour, label=label)
        if result.singularity:
            stop = result.singularity
            bottom.semilogy(stop.time, max(stop.sigma_min, 1e-6), "x", color=colour,
                            ms=12, mew=2.5,
                            label=f"{label}: singular stop, t = {stop.time:.3g} s, "
                                  f"sigma_min = {stop.sigma_min:.1e} (drawn at >= 1e-6)")
    bottom.axhline(MARGIN, color="gray", ls=":", label=f"design margin {MARGIN}")
    top.set_ylabel("|tau| [N m]")
    bottom.set_ylabel("sigma_min(M_pa) [kg m²]")
    bottom.set_xlabel("t [s]")
    top.set_title(title)
    top.legend(fontsize=7, ncol=2)
    bottom.legend(fontsize=7)
    fig.savefig(harness.output(IMG / f"singularity_{name}_inverse.png"), dpi=110)


def run_table(key: str, runs) -> list[str]:
    rows = []
    for label, (req, result) in runs.items():
        stop = f"{result.singularity.time:.4g}" if result.singularity else "-"
        smin = f"{min(result.sigma_min):.4g}" if result.sigma_min else "-"
        tau = f"{np.abs(result.tau).max():.4g}" if result.tau else "-"
        error = (f"{feed_forward_error(req, result):.2e}" if result.status == "completed"
                 else "-")
        rows.append(f"| {key} | {label} | {result.status} | {stop} | {smin} | {tau} | {error} |")
    return rows


def design_table(key: str) -> str:
    req = WaveDesignRequest.model_validate(example(f"{key}-wave-design").request)
    start = time.perf_counter()
    result = design(req)
    elapsed = time.perf_counter() - start
    waves = "; ".join(f"joint {w.joint}: a = {w.amplitude:.4g} m, n = {w.frequency}, "
                      f"eps = {w.phase:.5f}" for w in result.waves)
    c = result.certificate
    return (f"| {key} | {result.status} | {c.bound:.6g} | {c.sampled_min:.6g} | {c.boxes:,} | "
            f"{c.seconds:.2f} | {waves} | {elapsed:.1f} |")


def coupling_timing() -> list[str]:
    """Wall time of a 100,000-point grid analysis and of the batch evaluation alone."""
    robot = seed_arm(False)
    q = np.array(seed_start())
    lower, upper = (q - 0.3).tolist(), (q + 0.3).tolist()
    lower[1] = upper[1] = float(q[1])
    request = CouplingRequest(robot=robot, grid={"lower": lower, "upper": upper,
                                                 "points": [20, 1, 50, 100]})
    analyse(request)  # first call builds the mapped function
    start = time.perf_counter()
    report = analyse(request)
    elapsed = time.perf_counter() - start
    Q = np.random.default_rng(0).uniform(-np.pi, np.pi, (100_000, 4))
    start = time.perf_counter()
    along(robot, Q)
    batch = time.perf_counter() - start
    return [f"| analyse: seed arm, 20 x 50 x 100 grid | {report.results_omitted:,} | "
            f"{len(report.singular_points)} | {elapsed:.2f} |",
            f"| det and sigma_min only: seed arm, random | {len(Q):,} | - | {batch:.2f} |"]


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench singularities", description=__doc__)
    parser.parse_args(argv)
    started, note = time.perf_counter(), harness.machine_note()
    two, seed = cases("two-link"), cases("seed-arm")
    q2 = two_link_start()
    plot_maps("two_link", [("without wave", two_link(False)),
                           ("with the designed wave", two_link(True))],
              q2, (0, 1), [(-0.3, 0.9), (-1.8, 4.6)], two,
              ("passive", "active"))
    qs = seed_start()
    plot_maps("seed_arm", [("without waves", seed_arm(False)),
                           ("with the designed waves", seed_arm(True))],
              qs, (0, 3), [(qs[0] - 0.6, qs[0] + 0.6), (qs[3] - 0.8, qs[3] + 0.8)], seed,
              ("passive", "active"))
    plot_runs("two_link", "Two-link arm: classical inverse dynamics", two)
    plot_runs("seed_arm", "Seed 4-link arm: classical inverse dynamics", seed)
    text = "\n\n".join([
        ("Times are wall-clock seconds; the run shared its cores with other work (load "
         f"average {harness.load()} at the end), so they are upper bounds."),
        "\n".join(["| example | case | status | singular stop [s] | min sigma_min [kg m^2] | "
                   "max abs tau [N m] | feed-forward error [rad] |",
                   "|---|---|---|---|---|---|---|",
                   *run_table("two-link", two), *run_table("seed-arm", seed)]),
        "\n".join(["| example | design | proven sigma_min [kg m^2] | sampled min [kg m^2] | "
                   "boxes | proof [s] | waves | time [s] |",
                   "|---|---|---|---|---|---|---|---|",
                   design_table("two-link"), design_table("seed-arm")]),
        "\n".join(["| coupling analysis | points | singular points | time [s] |",
                   "|---|---|---|---|", *coupling_timing()]),
        harness.manifest("singularities", argv, started, note)])
    harness.write_section(DOC, SECTION, text)
    print(text)
    return 0
