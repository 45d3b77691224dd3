"""Server limits computed from what a transcription method says of itself."""

from __future__ import annotations

import pytest
from service_fixtures import two_link_scene

from app.limits import check_scene, most_intervals, nodes
from app.settings import Settings
from planner.ocp import methods
from planner.ocp.mesh import Mesh
from planner.scene import Scene, Transcription


@pytest.mark.parametrize("method, degree, per_interval, extra", [
    ("legendre", 3, 4, 0), ("radau", 9, 10, 0), ("hermite-simpson", 3, 2, 1),
    ("trapezoidal", 3, 1, 1), ("multiple-shooting", 3, 4, 0)])
def test_nodes_are_counted_by_the_method(method, degree, per_interval, extra):
    tr = Transcription(method=method, intervals=20, degree=degree)
    assert nodes(tr) == methods.of(tr).node_count() == 20 * per_interval + extra
    assert nodes(tr, 7) == 7 * per_interval + extra
    cap = most_intervals(tr, 1000)
    assert nodes(tr, cap) <= 1000 < nodes(tr, cap + 1)


def test_an_unset_refinement_budget_is_lowered_to_the_node_limit():
    scene = Scene.model_validate({**two_link_scene(), "transcription": {
        "method": "radau", "degree": 9, "intervals": 10}})
    assert scene.transcription.refinement.max_intervals == 400
    capped = check_scene(scene, Settings(max_nodes=2000))
    assert capped.transcription.refinement.max_intervals == 200
    assert nodes(capped.transcription, 200) == 2000


@pytest.mark.parametrize("method", ["legendre", "radau", "hermite-simpson", "trapezoidal",
                                    "multiple-shooting"])
def test_the_knot_count_is_where_the_quadrature_weights_sit(method):
    # The contract's knot count is the number of quadrature points of the objective: the
    # stage knots of every interval and the terminal knots, on any mesh.
    tr = methods.of(Transcription(method=method, intervals=6, degree=3))
    stage, terminal = tr.weights(Mesh.uniform(6))
    assert stage.shape == (6, len(tr.knot_positions)) and terminal.shape == (tr.terminal_knots,)
    assert stage.size + terminal.size == tr.knot_count()
    assert stage.sum() + terminal.sum() == pytest.approx(1.0)
