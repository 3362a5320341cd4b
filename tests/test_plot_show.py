"""The interactive viewer `ddgjax.plot.show` (ddgjax/plot/_viewer.py): its plotly traces hold the shape's own arrays."""

from __future__ import annotations

import sys

import jax.numpy as jnp
import numpy as np
import pytest

import ddgjax.curves as dc
import ddgjax.mesh as dm
from ddgjax import DDGInputError
from ddgjax.plot import OBLIQUE_VIEW, show, view_rotation

go = pytest.importorskip("plotly.graph_objects", reason="the viewer needs plotly (pip install -e .[test])")

F32 = dict(rtol=1e-6, atol=1e-7)  # coordinates and values travel to the browser as float32


def traces(figure, kind):
    return [trace for trace in figure.data if trace.type == kind]


def segments(trace) -> np.ndarray:
    """`(m, 2, 3)` segments of a lines trace (pairs of points separated by NaN)."""
    path = np.column_stack([trace.x, trace.y, trace.z]).reshape(-1, 3, 3)
    assert np.isnan(path[:, 2]).all()
    return path[:, :2]


def test_mesh_trace_holds_the_vertices_faces_and_vertex_values(icosphere1):
    values = jnp.asarray(icosphere1.vertices)[:, 2]  # a JAX array
    figure = show(icosphere1, values, name="height")
    assert isinstance(figure, go.Figure)
    (surface,) = figure.data
    np.testing.assert_allclose(np.column_stack([surface.x, surface.y, surface.z]), icosphere1.vertices, **F32)
    np.testing.assert_array_equal(np.column_stack([surface.i, surface.j, surface.k]), icosphere1.faces)
    np.testing.assert_allclose(surface.intensity, values, **F32)
    assert surface.intensitymode == "vertex" and surface.showscale and surface.colorbar.title.text == "height"
    assert (surface.cmin, surface.cmax) == (float(values.min()), float(values.max()))
    # matplotlib's viridis, sampled: its ends are plotly's
    assert surface.colorscale[0] == (0.0, "#440154") and surface.colorscale[-1] == (1.0, "#fde725")
    assert figure.layout.scene.aspectmode == "data"
    assert not figure.layout.scene.xaxis.visible


def test_per_face_values_colour_cells_and_limits_and_colormap_are_passed(icosphere1):
    values = np.asarray(dm.face_areas(icosphere1))
    (surface,) = show(icosphere1, values, cmap="coolwarm", vmin=0.0, vmax=1.0).data
    assert surface.intensitymode == "cell"
    np.testing.assert_allclose(surface.intensity, values, **F32)
    assert (surface.cmin, surface.cmax) == (0.0, 1.0) and surface.colorscale[0][1] == "#3b4cc0"  # coolwarm's blue end


def test_no_values_draws_one_plain_colour(icosphere1):
    (surface,) = show(icosphere1, color="tan").data
    assert surface.color == "tan" and surface.intensity is None


def test_non_finite_values_are_drawn_grey_in_their_own_trace(icosphere1):
    values = np.asarray(icosphere1.vertices)[:, 0].copy()
    values[[0, 5]] = [np.nan, np.inf]
    coloured, grey = show(icosphere1, values).data
    touching = np.isin(np.asarray(icosphere1.faces), [0, 5]).any(axis=1)
    np.testing.assert_array_equal(np.column_stack([grey.i, grey.j, grey.k]), np.asarray(icosphere1.faces)[touching])
    np.testing.assert_array_equal(np.column_stack([coloured.i, coloured.j, coloured.k]), np.asarray(icosphere1.faces)[~touching])
    assert grey.name == "non-finite values" and grey.intensity is None
    assert np.isfinite(coloured.intensity).all() and coloured.cmax == values[np.isfinite(values)].max()
    face_values = np.arange(float(icosphere1.n_faces))
    face_values[3] = np.nan
    coloured, grey = show(icosphere1, face_values).data
    assert len(grey.i) == 1 and grey.i[0] == icosphere1.faces[3, 0]
    np.testing.assert_allclose(coloured.intensity, np.delete(face_values, 3), **F32)


def test_edges_draw_every_mesh_edge_once(icosphere1):
    _, wireframe = show(icosphere1, edges=True).data
    drawn = segments(wireframe)
    np.testing.assert_allclose(drawn, np.asarray(icosphere1.vertices)[np.asarray(icosphere1.edges)], **F32)


def test_vertex_vectors_start_at_the_vertices_and_stay_tangent(icosphere1):
    normals = np.asarray(icosphere1.vertices)  # the unit sphere's normals
    tangents = np.cross([0.0, 0.0, 1.0], normals)
    _, strokes = show(icosphere1, vectors=tangents).data
    drawn = segments(strokes)
    np.testing.assert_allclose(drawn[:, 0], normals, **F32)
    along = drawn[:, 1] - drawn[:, 0]
    np.testing.assert_allclose(np.einsum("ij,ij->i", along, normals), 0.0, atol=1e-6)  # float32
    # default scale: the longest vector is drawn half the mean edge length, all in proportion
    mean_edge = float(np.mean(dm.edge_lengths(icosphere1)))
    scale = 0.5 * mean_edge / np.linalg.norm(tangents, axis=1).max()
    # differences of float32 coordinates (~1) relative to strokes up to 0.27 long (atol near the poles)
    np.testing.assert_allclose(along, scale * tangents, rtol=1e-5, atol=1e-6)
    _, strokes = show(icosphere1, vectors=tangents, vector_scale=1.0).data
    np.testing.assert_allclose(np.diff(segments(strokes), axis=1)[:, 0], tangents, **F32)


def test_face_vectors_start_at_centroids_and_k_directions_each(icosphere1):
    corners = np.asarray(icosphere1.vertices)[np.asarray(icosphere1.faces)]
    along_edge = corners[:, 1] - corners[:, 0]  # in each face's plane
    _, strokes = show(icosphere1, vectors=along_edge).data
    drawn = segments(strokes)
    np.testing.assert_allclose(drawn[:, 0], corners.mean(axis=1), **F32)
    normals = np.asarray(dm.face_normals(icosphere1))
    np.testing.assert_allclose(np.einsum("ij,ij->i", drawn[:, 1] - drawn[:, 0], normals), 0.0, atol=1e-6)  # float32
    cross = np.stack([along_edge, -along_edge], axis=1)  # (nf, 2, 3): two strokes per face
    _, strokes = show(icosphere1, vectors=cross).data
    drawn = segments(strokes)
    assert len(drawn) == 2 * icosphere1.n_faces
    np.testing.assert_allclose(drawn[0::2, 0], drawn[1::2, 0], **F32)
    np.testing.assert_allclose(drawn[0::2, 1] - drawn[0::2, 0], drawn[1::2, 0] - drawn[1::2, 1], atol=1e-6)  # float32


def test_cones_have_their_tail_at_the_point_and_the_drawn_length(icosphere1):
    tangents = np.cross([0.0, 0.0, 1.0], np.asarray(icosphere1.vertices))
    _, cones = show(icosphere1, vectors=tangents, vector_style="cones", vector_scale=0.1).data
    assert cones.type == "cone" and cones.sizemode == "raw" and cones.anchor == "tail"
    np.testing.assert_allclose(np.column_stack([cones.x, cones.y, cones.z]), icosphere1.vertices, **F32)
    np.testing.assert_allclose(np.column_stack([cones.u, cones.v, cones.w]), 0.1 * tangents, **F32)


def test_plane_curve_is_drawn_at_z0_from_above_with_its_closing_edge():
    curve = dc.flower(16)
    values = np.asarray(dc.curvature(curve, kind="D"))
    line, markers = show(curve, values).data
    drawn = segments(line)
    points = np.asarray(curve.points)
    np.testing.assert_allclose(drawn[:, 0, :2], points, **F32)
    np.testing.assert_allclose(drawn[:, 1, :2], np.roll(points, -1, axis=0), **F32)  # the last segment closes it
    assert np.all(drawn[..., 2] == 0.0)
    np.testing.assert_allclose(markers.marker.color, values, **F32)
    camera = show(curve).layout.scene.camera
    assert camera.projection.type == "orthographic"
    # from +z, y up on screen (to the round-off of cos(pi / 2))
    np.testing.assert_allclose([camera.eye.x, camera.eye.y, camera.eye.z], [0.0, 0.0, 2.0], atol=1e-15)
    np.testing.assert_allclose([camera.up.x, camera.up.y, camera.up.z], [0.0, 1.0, 0.0], atol=1e-15)
    open_line = show(dc.Curve(curve.points, closed=False)).data[0]
    assert len(segments(open_line)) == 15
    _, _, strokes = show(curve, vectors=np.ones((16, 2))).data
    np.testing.assert_allclose(segments(strokes)[:, 0, :2], points, **F32)


def test_point_set_with_a_missing_value():
    t = np.linspace(0.0, 4 * np.pi, 30)
    points = np.column_stack([np.cos(t), np.sin(t), 0.2 * t])  # a helix: not flat, so a perspective view
    values = points[:, 0].copy()
    values[7] = np.nan
    figure = show(jnp.asarray(points), values)
    coloured, grey = figure.data
    assert coloured.mode == "markers" and len(coloured.x) == 29 and grey.name == "non-finite values"
    np.testing.assert_allclose(np.column_stack([coloured.x, coloured.y, coloured.z]), np.delete(points, 7, axis=0), **F32)
    np.testing.assert_allclose([grey.x[0], grey.y[0], grey.z[0]], points[7], **F32)
    np.testing.assert_allclose(coloured.marker.color, np.delete(values, 7), **F32)
    assert figure.layout.scene.camera.projection.type == "perspective"
    # vectors from the points, half the mean nearest-neighbour distance long
    _, _, strokes = show(points, values, vectors=np.tile([0.0, 0.0, 2.0], (30, 1))).data
    drawn = segments(strokes)
    spacing = np.sort(np.linalg.norm(points[:, None] - points[None], axis=-1), axis=1)[:, 1].mean()
    np.testing.assert_allclose(drawn[:, 0], points, **F32)
    # a difference of float32 heights (up to 2.5) relative to the stroke (~0.2)
    np.testing.assert_allclose(drawn[:, 1, 2] - drawn[:, 0, 2], 0.5 * spacing, rtol=1e-5)


def test_default_camera_looks_from_the_oblique_view_with_the_chosen_axis_up(icosphere1):
    camera = show(icosphere1).layout.scene.camera
    rotation = view_rotation(*OBLIQUE_VIEW)
    np.testing.assert_allclose([camera.eye.x, camera.eye.y, camera.eye.z], -2.0 * rotation[1])
    assert camera.projection.type == "perspective"
    up = show(icosphere1, up="y").layout.scene.camera.up
    assert up.y > 0.9  # y points (nearly) up on screen


def test_figure_collects_several_shapes_and_keeps_its_camera(icosphere1):
    figure = show(icosphere1, np.asarray(icosphere1.vertices)[:, 0], up="y")
    camera = figure.layout.scene.camera.to_plotly_json()
    moved = icosphere1.with_vertices(icosphere1.vertices + jnp.array([3.0, 0.0, 0.0]))
    same = show(moved, np.asarray(icosphere1.vertices)[:, 1], figure=figure)
    assert same is figure and len(figure.data) == 2 and figure.layout.scene.camera.to_plotly_json() == camera
    assert figure.data[1].colorbar.x > figure.data[0].colorbar.x  # colour bars side by side
    show(np.zeros((2, 3)), np.array([0.0, 1.0]), figure=figure)
    assert figure.data[2].marker.colorbar.x > figure.data[1].colorbar.x
    with pytest.raises(DDGInputError, match="vectors"):
        show(icosphere1, vectors=np.zeros((3, 3)), figure=figure)
    assert len(figure.data) == 3  # a refused call draws nothing


def test_bad_input_names_the_argument_and_the_remedy(icosphere1):
    nv, nf = icosphere1.n_vertices, icosphere1.n_faces
    with pytest.raises(
        DDGInputError, match=rf"values: expected shape \({nv},\) one value per vertex or \({nf},\) one per face, got \(5,\)"
    ):
        show(icosphere1, np.zeros(5))
    with pytest.raises(DDGInputError, match=r"values: .*got \(42, 3\); for vectors pass vectors="):
        show(icosphere1, np.zeros((nv, 3)))
    with pytest.raises(DDGInputError, match="values: expected real numbers, got dtype complex128; pass the real part"):
        show(icosphere1, np.zeros(nv, complex))
    with pytest.raises(DDGInputError, match=rf"vectors: expected shape \({nv}, 3\) per vertex or \({nf}, 3\) per face"):
        show(icosphere1, vectors=np.zeros((nv, 2)))
    with pytest.raises(DDGInputError, match=r"vectors: expected finite entries, got NaN/inf at rows \[4\].*nan_to_num"):
        show(icosphere1, vectors=np.where(np.arange(nv)[:, None] == 4, np.nan, 1.0) * np.ones((nv, 3)))
    with pytest.raises(DDGInputError, match=r"vectors: expected shape \(16, 3\) or \(16, 2\), one per point"):
        show(dc.flower(16), vectors=np.zeros((15, 2)))
    with pytest.raises(DDGInputError, match=r"values: expected shape \(16,\) one per point"):
        show(dc.flower(16), np.zeros(17))
    with pytest.raises(DDGInputError, match="cmap: expected a matplotlib colour map or its name.*'no_such_map'"):
        show(icosphere1, np.zeros(nv), cmap="no_such_map")
    with pytest.raises(DDGInputError, match="vector_style"):
        show(icosphere1, vectors=np.zeros((nv, 3)), vector_style="arrows")
    with pytest.raises(DDGInputError, match="vector_scale: expected a finite number > 0"):
        show(icosphere1, vectors=np.ones((nv, 3)), vector_scale=-1.0)
    with pytest.raises(DDGInputError, match="up"):
        show(icosphere1, up="w")
    with pytest.raises(DDGInputError, match=r"mesh: expected points of shape \(n, 3\) or \(n, 2\)"):
        show(np.zeros((5, 4)))
    with pytest.raises(DDGInputError, match=r"mesh: expected finite coordinates, got NaN/inf at rows \[1\]"):
        show(np.array([[0.0, 0.0, 0.0], [np.nan, 0.0, 0.0]]))


def test_wrong_kinds_say_what_to_pass(icosphere1, without_type_checker):
    with pytest.raises(DDGInputError, match=r"mesh: expected a ddgjax Mesh, a ddgjax Curve .*Mesh.from_arrays"):
        show((icosphere1.vertices, icosphere1.faces))
    with pytest.raises(DDGInputError, match=r"figure: expected a plotly Figure .*got dict"):
        show(icosphere1, figure={})


def test_missing_plotly_says_which_extra_to_install(icosphere1, monkeypatch):
    monkeypatch.setitem(sys.modules, "plotly", None)  # `import plotly...` now raises ImportError
    monkeypatch.setitem(sys.modules, "plotly.graph_objects", None)
    with pytest.raises(ImportError, match=r'pip install "ddgjax\[viewer\]"'):
        show(icosphere1)
