"""Drawing curves, flows and direction fields (ddgjax/plot/_matplotlib.py) on matplotlib axes with the Agg canvas."""

from __future__ import annotations

import numpy as np
import pytest
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

import ddgjax.curves as dc
from ddgjax.plot import plot_curve, plot_flow, polyline


@pytest.fixture
def axes():
    figure = Figure()
    FigureCanvasAgg(figure)
    return figure.add_subplot()


def test_polyline_closes_only_closed_curves():
    points = np.arange(8.0).reshape(4, 2)
    np.testing.assert_array_equal(polyline(points), np.vstack([points, points[:1]]))
    np.testing.assert_array_equal(polyline(points, closed=False), points)


@pytest.mark.parametrize("closed", [True, False])
def test_plot_curve_draws_the_polygon(axes, closed):
    curve = dc.Curve(dc.regular_polygon(5).points, closed=closed)
    (line,) = plot_curve(axes, curve, color="red")
    assert line.get_xydata().shape == (5 + closed, 2) and line.get_color() == "red"


def test_plot_flow_overlays_snapshots_and_the_centroid_path(axes):
    result = dc.curve_shortening_flow(dc.regular_polygon(12), kind="B", tau=1e-2, steps=20, save_every=2, check_simple="saved")
    chosen = plot_flow(axes, result, snapshots=4, color="tab:orange")
    np.testing.assert_array_equal(chosen, [0, 3, 7, 10])
    lines = axes.get_lines()
    # start, three later snapshots, final vertices, centroid path, its two ends
    assert len(lines) == 1 + 3 + 1 + 1 + 2
    np.testing.assert_allclose(lines[0].get_xydata(), polyline(result.points[0]), rtol=1e-15)
    np.testing.assert_allclose(lines[3].get_xydata(), polyline(result.points[-1]), rtol=1e-15)
    assert not np.allclose(lines[1].get_color(), lines[3].get_color())  # early snapshots lighter than the last
    np.testing.assert_allclose(lines[5].get_xydata(), np.asarray(result.centroid), rtol=1e-15)
    assert axes.get_aspect() == 1.0


def test_plot_curve_refuses_points_with_what_to_call(axes, without_type_checker):
    from ddgjax import DDGInputError

    with pytest.raises(DDGInputError, match=r"curve: expected a ddgjax Curve.*Curve\(points"):
        plot_curve(axes, np.zeros((4, 2)))


def test_plot_direction_field_draws_the_front_strokes_in_the_mesh_view(axes, icosphere2):
    from ddgjax import DDGInputError
    from ddgjax.mesh import grid
    from ddgjax.plot import TOP_VIEW, plot_direction_field

    sphere = icosphere2
    normals = np.asarray(sphere.vertices)  # the unit sphere's normals: tangent strokes along z x p
    tangents = np.cross([0.0, 0.0, 1.0], normals) + 1e-3
    strokes = plot_direction_field(axes, sphere, np.stack([tangents, -tangents], axis=1), view=TOP_VIEW)
    # From the top only the upper hemisphere faces the viewer (the equator's vertices either way: their
    # estimated normals are horizontal to round-off): two strokes per such vertex, from its (x, y).
    segments = np.asarray(strokes.get_segments())
    above, on_or_above = normals[:, 2] > 1e-9, normals[:, 2] > -1e-9
    assert 2 * above.sum() <= len(segments) <= 2 * on_or_above.sum()
    starts = segments[::2, 0]  # each at a vertex's (x, y) (a vertex and its mirror below project alike)
    assert np.abs(starts[:, None, :] - normals[None, :, :2]).sum(axis=-1).min(axis=1).max() < 1e-12
    flat = grid(3, 3)
    assert len(plot_direction_field(axes, flat, np.tile([1.0, 0.0, 0.0], (flat.n_vertices, 1))).get_segments()) == flat.n_vertices
    with pytest.raises(DDGInputError, match="vectors: expected shape"):
        plot_direction_field(axes, flat, np.zeros((3, 3)))
