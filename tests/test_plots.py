"""Figures of plans and inverse-dynamics results, and the plot endpoints."""

from __future__ import annotations

import threading
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest
from conftest import point_mass_dynamics
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from service_fixtures import client, two_link_scene

from planner import plots
from planner.dynamics import Dynamics
from planner.examples import example
from planner.inverse import InverseDynamicsRequest, solve
from planner.ocp import Plan, plan
from planner.ocp.verify import coupling_along
from planner.scene import Scene
from testbed.fake_solvers import fake_plan
from testbed.service import wait_final

PNG = b"\x89PNG\r\n\x1a\n"

# Without inertia and waves M_pa = m2 l1 l2 cos(q0 - q1): this rest-to-rest motion makes the
# links perpendicular (waveless singular) several times; the wave keeps M_pa regular.
CROSSING_SCENE = example("two-link-plan").request


@pytest.fixture(scope="module")
def scene() -> Scene:
    return Scene.model_validate(CROSSING_SCENE)


@pytest.fixture(scope="module")
def crossing_plan(scene) -> Plan:
    result = plan(scene)
    assert result.solver.success and len(result.verification.waveless_singular_crossings) >= 1
    return result


def time_axes(fig: Figure) -> dict[str, object]:
    """The plan figure's time axes by what they show."""
    names = {"q [rad]": "angles", "active torque [N m]": "torques",
             "sigma_min(M_pa) [kg m^2]": "sigma"}
    return {names[ax.get_ylabel()]: ax for ax in fig.axes if ax.get_ylabel() in names}


def marks(ax, prefix: str) -> list[float]:
    """x positions of the vertical lines whose gid starts with `prefix`."""
    return sorted(float(line.get_xdata()[0]) for line in ax.get_lines()
                  if (line.get_gid() or "").startswith(prefix))


# --------------------------------------------------------------------------- plan figure


def test_every_time_axis_marks_each_waveless_crossing_at_its_time(crossing_plan, scene):
    fig = plots.plan_figure(crossing_plan, scene.robot)
    times = sorted(c.time for c in crossing_plan.verification.waveless_singular_crossings)
    axes = time_axes(fig)
    assert set(axes) == {"angles", "torques", "sigma"}
    for ax in axes.values():
        assert marks(ax, plots.CROSSING_GID) == pytest.approx(times, abs=0.0)


def test_a_plan_without_crossings_has_no_marks(crossing_plan, scene):
    data = crossing_plan.model_dump()
    data["verification"]["waveless_singular_crossings"] = []
    fig = plots.plan_figure(Plan.model_validate(data), scene.robot)
    for ax in time_axes(fig).values():
        assert marks(ax, plots.CROSSING_GID) == []


def test_the_sigma_panel_shows_both_robots_along_the_dense_path(crossing_plan, scene):
    ax = time_axes(plots.plan_figure(crossing_plan, scene.robot))["sigma"]
    curves = {line.get_label(): line for line in ax.get_lines()
              if not (line.get_gid() or "").startswith(plots.CROSSING_GID)}
    q = np.asarray(crossing_plan.dense.q)
    waveless = curves["without waves"].get_ydata()
    wavy = next(line for label, line in curves.items()
                if label.startswith("with waves")).get_ydata()
    assert np.allclose(waveless,
                       np.clip(coupling_along(scene.robot.without_waves(), q)[0], 1e-12, None))
    assert np.allclose(wavy, np.clip(coupling_along(scene.robot, q)[0], 1e-12, None))
    assert ax.get_yscale() == "log"
    t = np.asarray(crossing_plan.dense.t)
    for c in crossing_plan.verification.waveless_singular_crossings:
        k = int(np.argmin(np.abs(t - c.time)))
        assert waveless[k] < 1e-2 * np.median(waveless)  # the dip is where the mark is


def test_the_plan_carries_sigma_min_at_its_dense_times_with_and_without_waves(crossing_plan,
                                                                              scene):
    v, q = crossing_plan.verification, np.asarray(crossing_plan.dense.q)
    assert len(v.sigma_min) == len(v.waveless_sigma_min) == len(crossing_plan.dense.t)
    for values, robot, minimum in ((v.sigma_min, scene.robot, v.min_sigma),
                                   (v.waveless_sigma_min, scene.robot.without_waves(),
                                    v.waveless_min_sigma)):
        blocks = [point_mass_dynamics(robot, qk, np.zeros(robot.n))[0][np.ix_(robot.passive,
                                                                               robot.active)]
                  for qk in q]  # M_pa by d'Alembert's principle, independent of the library
        independent = np.linalg.svd(np.array(blocks), compute_uv=False)[:, -1]
        assert np.allclose(values, independent, rtol=1e-9, atol=1e-14)
        assert min(values) == minimum
    for c in v.waveless_singular_crossings:  # the waveless dips are where the crossings are
        k = int(np.argmin(np.abs(np.asarray(crossing_plan.dense.t) - c.time)))
        assert v.waveless_sigma_min[k] < 1e-2 * np.median(v.waveless_sigma_min)


def test_the_sigma_panel_draws_the_plans_own_values(crossing_plan, scene):
    data = crossing_plan.model_dump()
    v = data["verification"]
    v["sigma_min"] = [2.0 * s for s in v["sigma_min"]]
    v["waveless_sigma_min"][:10] = [None] * 10  # undefined there: a gap
    ax = time_axes(plots.plan_figure(Plan.model_validate(data), scene.robot))["sigma"]
    curves = {line.get_label(): line.get_ydata() for line in ax.get_lines()}
    wavy = next(y for label, y in curves.items() if label.startswith("with waves"))
    assert np.allclose(wavy, np.clip(v["sigma_min"], 1e-12, None))
    assert np.isnan(curves["without waves"][:10]).all()
    assert np.isfinite(curves["without waves"][10:]).all()


def test_a_plan_without_sigma_min_says_so_instead_of_drawing_it(crossing_plan, scene):
    data = crossing_plan.model_dump()
    for name in ("sigma_min", "waveless_sigma_min"):
        del data["verification"][name]  # as stored before the plan carried them
    ax = time_axes(plots.plan_figure(Plan.model_validate(data), scene.robot))["sigma"]
    assert [t.get_text() for t in ax.texts] == ["sigma_min not recorded in this plan"]
    assert not [line for line in ax.get_lines() if line.get_label().startswith("with")]


def test_the_snapshots_draw_the_links_through_the_dynamics_tips(crossing_plan, scene):
    fig = plots.plan_figure(crossing_plan, scene.robot, snapshots=4)
    strip = [ax for ax in fig.axes if ax.get_title().startswith("t = ")]
    assert len(strip) == 4
    first = strip[0]
    links = next(line for line in first.get_lines() if len(line.get_xdata()) == scene.robot.n + 1)
    tips = np.vstack([[0.0, 0.0], Dynamics(scene.robot).tips(crossing_plan.dense.q[0])])
    assert np.allclose(links.get_xdata(), tips[:, 1])
    assert np.allclose(links.get_ydata(), -tips[:, 0])


def gravity_arrows(fig: Figure) -> list[list]:
    strip = [ax for ax in fig.axes if ax.get_title().startswith("t = ")]
    return [[a for a in ax.texts if (a.get_gid() or "").startswith(plots.GRAVITY_GID)]
            for ax in strip]


def legend_texts(fig: Figure) -> list[str]:
    return [t.get_text() for ax in fig.axes if ax.get_legend() for t in ax.get_legend().texts]


def test_a_weightless_arm_has_no_gravity_arrow(crossing_plan, scene):
    assert scene.robot.gravity == 0.0
    fig = plots.plan_figure(crossing_plan, scene.robot, snapshots=4)
    assert gravity_arrows(fig) == [[], [], [], []]
    keys = legend_texts(fig)
    assert "no gravity (g = 0)" in keys and "gravity (x) down" not in keys


def test_each_snapshot_draws_the_gravity_arrow_of_its_key(crossing_plan, scene):
    heavy = scene.robot.model_copy(update={"gravity": 9.81})
    fig = plots.plan_figure(crossing_plan, heavy, snapshots=4)
    arrows = gravity_arrows(fig)
    assert [len(a) for a in arrows] == [1, 1, 1, 1]
    (tail,), (head,) = [arrows[0][0].xyann], [arrows[0][0].xy]
    assert head[0] == tail[0] and head[1] < tail[1]  # straight down the drawing
    assert "gravity (x) down" in legend_texts(fig)


def test_legends_sit_beside_the_panels_not_on_their_curves(crossing_plan, scene):
    fig = plots.plan_figure(crossing_plan, scene.robot)
    FigureCanvasAgg(fig)
    fig.draw_without_rendering()
    for name, ax in time_axes(fig).items():
        legend, frame = ax.get_legend().get_window_extent(), ax.get_window_extent()
        assert legend.x0 >= frame.x1, name


def test_the_title_says_what_the_objective_is(crossing_plan, scene):
    title = plots.plan_figure(crossing_plan, scene.robot, task=scene.task)._suptitle.get_text()
    assert f"objective (effort ∫|τ|² dt) {crossing_plan.objective:.4g} N²m²s" in title
    bare = plots.plan_figure(crossing_plan, scene.robot)._suptitle.get_text()
    assert f"objective {crossing_plan.objective:.4g}" in bare


def test_the_objective_names_every_weighted_term():
    task = Scene.model_validate(CROSSING_SCENE).task
    mixed = task.model_copy(update={"objective": task.objective.model_copy(
        update={"effort": 2.0, "time": 0.5})})
    assert plots.objective_text(1.5, mixed) == "objective (effort 2·∫|τ|² dt + time 0.5·T) 1.5"
    only_time = task.model_copy(update={"objective": task.objective.model_copy(
        update={"effort": 0.0, "time": 1.0})})
    assert plots.objective_text(3.0, only_time) == "objective (time T) 3 s"
    assert plots.objective_text(None, task) == "objective (effort ∫|τ|² dt) n/a"


@pytest.mark.parametrize("verified, word", [(True, "verified"), (False, "not verified")])
def test_the_title_says_whether_the_plan_is_verified(crossing_plan, scene, verified, word):
    data = crossing_plan.model_dump()
    data["verification"].update(verified=verified, resimulation_error=0.25, tolerance=0.001)
    title = plots.plan_figure(Plan.model_validate(data), scene.robot)._suptitle.get_text()
    first, second = title.split("\n")
    assert first == f"plan {word}: re-simulation error 0.25 rad (tolerance 0.001 rad)"
    assert second.startswith(f"Ipopt {crossing_plan.solver.status} (")


def test_joint_curves_take_the_shared_palette(crossing_plan, scene):
    axes = time_axes(plots.plan_figure(crossing_plan, scene.robot))
    angles = {line.get_label(): line.get_color() for line in axes["angles"].get_lines()}
    torques = {line.get_label(): line.get_color() for line in axes["torques"].get_lines()}
    assert angles == {"q0 (passive)": plots.JOINT_COLOURS[0], "q1 (active)": plots.JOINT_COLOURS[1],
                      "waveless singular crossing": plots.PALETTE["mark"]}
    assert torques["tau1"] == plots.JOINT_COLOURS[1]
    assert plots.PALETTE["mark"] not in plots.JOINT_COLOURS


def test_the_wavy_mass_path_passes_through_each_wavy_tip(make_robot, rng):
    for _ in range(5):
        robot = make_robot(int(rng.integers(2, 6)))
        q = rng.uniform(-np.pi, np.pi, robot.n)
        tips = np.vstack([[0.0, 0.0], Dynamics(robot).tips(q)])
        for j in robot.active:
            point = tips[j] + plots.wave_path(robot, j, np.array([q[j]]))[0]
            assert np.allclose(point, tips[j + 1], atol=1e-12)


def test_plan_robot_takes_the_plans_waves(crossing_plan, scene):
    data = crossing_plan.model_dump()
    data["waves"] = [{"joint": 1, "amplitude": 0.02, "frequency": 2.0, "phase": -1.0}]
    robot = plots.plan_robot(scene.robot, Plan.model_validate(data))
    assert robot.links[1].wave.model_dump() == {"amplitude": 0.02, "frequency": 2.0, "phase": -1.0}
    assert robot.links[0] == scene.robot.links[0]


def test_png_and_svg_bytes(crossing_plan, scene):
    png = plots.plan_plot(crossing_plan, scene.robot, "png")
    svg = plots.plan_plot(crossing_plan, scene.robot, "svg")
    assert png.startswith(PNG) and len(png) > 50_000
    assert svg.startswith(b"<?xml") and b"<svg" in svg[:2000] and len(svg) > 50_000
    crossings = len(crossing_plan.verification.waveless_singular_crossings)
    ids = [f'id="{plots.CROSSING_GID}-{panel}-{k}"'.encode()
           for panel in ("angles", "torques", "sigma") for k in range(crossings)]
    assert all(svg.count(i) == 1 for i in ids)


def test_figures_render_from_several_threads_at_once(crossing_plan, scene):
    with ThreadPoolExecutor(2) as pool:
        images = list(pool.map(lambda _: plots.plan_plot(crossing_plan, scene.robot), range(2)))
    assert len(set(images)) == 1 and images[0].startswith(PNG)


def test_format_names():
    assert plots.format_of("out/PLAN.SVG") == "svg" and plots.format_of("a.png") == "png"
    with pytest.raises(ValueError, match=r"^plot: the file name must end in \.png or \.svg"):
        plots.format_of("plan.jpg")
    with pytest.raises(ValueError, match="format: must be one of png, svg"):
        plots.render(Figure(), "pdf")


# --------------------------------------------------------------------------- inverse dynamics


def singular_midway() -> InverseDynamicsRequest:
    """The two-link waveless motion started 0.3 rad away from the singular elbow angle."""
    request = example("two-link-waveless").request
    request["active_initial"]["q"] = [request["active_initial"]["q"][0] - 0.3]
    return InverseDynamicsRequest.model_validate(request)


def test_the_inverse_figure_marks_a_singular_stop():
    request = singular_midway()
    result = solve(request)
    assert result.status == "singular" and 0.0 < result.singularity.time < request.duration
    fig = plots.inverse_figure(result, request)
    assert len(fig.axes) == 3
    for ax in fig.axes:
        assert marks(ax, plots.STOP_GID) == [result.singularity.time]
    sigma = fig.axes[2]
    assert sigma.get_yscale() == "log" and sigma.get_xlim() == (0.0, request.duration)
    assert any(line.get_ydata()[0] == request.sigma_threshold for line in sigma.get_lines())


def test_a_completed_inverse_result_has_no_stop_mark():
    request = InverseDynamicsRequest.model_validate(example("two-link-waves").request)
    result = solve(request)
    assert result.status == "completed"
    fig = plots.inverse_figure(result, request)
    assert all(marks(ax, plots.STOP_GID) == [] for ax in fig.axes)
    assert plots.inverse_plot(result, request, "svg").startswith(b"<?xml")


def test_a_start_on_the_singularity_still_draws():
    request = InverseDynamicsRequest.model_validate(example("seed-arm-waveless").request)
    result = solve(request)
    assert result.status == "singular" and result.t == []
    fig = plots.inverse_figure(result, request)
    assert all(marks(ax, plots.STOP_GID) == [0.0] for ax in fig.axes)
    assert plots.render(fig).startswith(PNG)


# --------------------------------------------------------------------------- endpoints


def finished(api, scene: dict, timeout: float = 20.0) -> dict:
    """POST a plan and wait for its job to end."""
    return wait_final(api, api.post("/v1/plans", json=scene).json()["id"], timeout)


@pytest.fixture(scope="module")
def api(tmp_path_factory):
    with client(tmp_path_factory.mktemp("plots"), solve=fake_plan, workers=1) as c:
        yield c


@pytest.mark.parametrize("fmt, media", [("png", "image/png"), ("svg", "image/svg+xml")])
def test_the_plot_endpoint_serves_the_library_figure(api, fmt, media):
    scene = two_link_scene(iterations=2)
    job = finished(api, scene)
    r = api.get(f"/v1/plans/{job['id']}/plot.{fmt}")
    assert r.status_code == 200 and r.headers["content-type"] == media
    posted = Scene.model_validate(scene)
    expected = plots.plan_plot(Plan.model_validate(job["plan"]), posted.robot, fmt, posted.task)
    assert r.content == expected
    # the same bytes as application/octet-stream for a client that asks only for that
    for accept, served in (("application/octet-stream", "application/octet-stream"),
                           (f"{media}, application/octet-stream;q=0.5", media),
                           ("image/*, application/octet-stream", media), ("*/*", media)):
        r = api.get(f"/v1/plans/{job['id']}/plot.{fmt}", headers={"accept": accept})
        assert r.headers["content-type"] == served and r.content == expected, accept


def test_a_failed_job_with_its_last_iterate_is_drawn(api):
    job = finished(api, two_link_scene(iterations=2, tol=0.6))
    assert job["status"] == "failed" and job["plan"] is not None
    assert api.get(f"/v1/plans/{job['id']}/plot.png").content.startswith(PNG)


def test_unknown_job_is_404_and_a_job_without_plan_is_409(api):
    r = api.get("/v1/plans/nope/plot.png")
    assert r.status_code == 404 and r.headers["content-type"] == "application/problem+json"
    assert r.json()["detail"] == "there is no plan job 'nope'"

    broken = finished(api, two_link_scene(iterations=2, tol=0.3))  # the solver raises
    r = api.get(f"/v1/plans/{broken['id']}/plot.svg")
    assert r.status_code == 409 and r.headers["content-type"] == "application/problem+json"
    assert r.json()["type"] == "urn:undertow:problem:no-plan"
    assert r.json()["detail"].startswith(f"plan job {broken['id']!r} is failed (")

    slow = api.post("/v1/plans", json=two_link_scene(iterations=200)).json()
    r = api.get(f"/v1/plans/{slow['id']}/plot.png")
    assert r.status_code == 409
    assert r.json()["detail"] in (f"plan job {slow['id']!r} is {s}; a plot needs its plan"
                                  for s in ("queued", "running"))
    api.delete(f"/v1/plans/{slow['id']}")


def test_drawing_does_not_block_the_event_loop(tmp_path, monkeypatch):
    from app.routes import plots as route

    drawing = threading.Event()

    def slow_plot(plan, robot, fmt, task=None):
        drawing.set()
        time.sleep(1.0)
        return b"drawn"

    monkeypatch.setattr(route.plots, "plan_plot", slow_plot)
    with client(tmp_path, solve=fake_plan) as api:
        job = finished(api, two_link_scene(iterations=1))
        with ThreadPoolExecutor(1) as pool:
            image = pool.submit(api.get, f"/v1/plans/{job['id']}/plot.png")
            assert drawing.wait(10)
            start = time.monotonic()
            assert api.get("/healthz").status_code == 200
            assert time.monotonic() - start < 0.5 and not image.done()
            assert image.result().content == b"drawn"
