"""Drawing curves, curve-shortening flows and functions on meshes on matplotlib axes (static figures)."""

from __future__ import annotations

from numbers import Real

import numpy as np
from jaxtyping import ArrayLike
from matplotlib.collections import LineCollection, PolyCollection
from matplotlib.colors import Normalize, to_rgb

from .._errors import DDGInputError, check_choice
from ..curves import Curve, CurveFlowResult, require_curve
from ..mesh import Mesh, edge_lengths, require_mesh, vertex_normals
from ._view import OBLIQUE_VIEW, TOP_VIEW, UP_ROTATIONS, is_flat, view_rotation


def polyline(points: ArrayLike, closed: bool = True) -> np.ndarray:
    """The `(n, 2)` points as a NumPy array to draw, with the first repeated at the end when `closed`.

    Args:
        points: `(n, 2)` points in order.
        closed: whether to repeat the first point at the end (default `True`).

    Returns:
        `(n + 1, 2)` NumPy array when `closed`, else the `(n, 2)` points.
    """
    points = np.asarray(points)
    return np.vstack([points, points[:1]]) if closed else points


def plot_curve(axes, curve: Curve, **style) -> list:
    """Draw `curve` as a polygon (with its closing edge when closed).

    Args:
        axes: matplotlib `Axes` to draw on.
        curve: the curve.
        **style: keyword arguments of `axes.plot` (colour, line width, ...).

    Returns:
        The list of matplotlib `Line2D` objects `axes.plot` made.
    """
    curve = require_curve("curve", curve)
    return axes.plot(*polyline(curve.points, curve.closed).T, **style)


def snapshot_indices(result: CurveFlowResult, snapshots: int) -> np.ndarray:
    """Indices of `snapshots` saved states of `result` spread evenly from the first to the last.

    Args:
        result: a curve flow's result, with its saved states `result.points`.
        snapshots: how many states to pick (fewer come back when the flow saved fewer).

    Returns:
        Sorted, distinct integer NumPy array of indices into `result.points`.
    """
    return np.unique(np.linspace(0, result.points.shape[0] - 1, snapshots).round().astype(int))


def plot_flow(axes, result: CurveFlowResult, *, snapshots: int = 6, color="tab:blue") -> np.ndarray:
    """Overlay snapshots of a curve-shortening flow and the path of its vertex centroid.

    The initial curve is drawn black and dashed; later snapshots in `color`, lighter early and full
    colour (thicker, with its vertices as dots) at the end; the centroid's path runs from `+` to `x`.
    The axes get an equal aspect ratio.

    Args:
        axes: matplotlib `Axes` to draw on.
        result: a curve flow's result (`curve_shortening_flow`), with its saved states and centroids.
        snapshots: how many saved states to draw, spread from the first to the last (keyword-only; default 6).
        color: a matplotlib colour of the later snapshots (keyword-only; default `"tab:blue"`).

    Returns:
        The indices of the saved states drawn, `snapshot_indices(result, snapshots)`.
    """
    points = np.asarray(result.points)
    chosen = snapshot_indices(result, snapshots)
    base = np.array(to_rgb(color))
    axes.plot(*polyline(points[0], result.closed).T, color="black", lw=1.2, ls="--")
    later = chosen[1:]
    for order, index in enumerate(later, start=1):
        shade = 0.25 + 0.75 * order / len(later)
        axes.plot(*polyline(points[index], result.closed).T, color=1 - shade * (1 - base), lw=1.0 + (index == chosen[-1]))
    axes.plot(*points[chosen[-1]].T, "o", color=base, ms=2.5)
    centroid = np.asarray(result.centroid)
    axes.plot(*centroid.T, color="black", lw=1)
    axes.plot(*centroid[0], "k+", ms=9)
    axes.plot(*centroid[-1], "kx", ms=7)
    axes.set_aspect("equal")
    return chosen


def plot_mesh_function(
    axes,
    mesh: Mesh,
    values: ArrayLike,
    *,
    view: tuple[Real, Real] | None = None,
    up: str = "z",
    shading: str = "gouraud",
    cmap="viridis",
    vmin: Real | None = None,
    vmax: Real | None = None,
    edgecolor="none",
    linewidth: Real = 0.3,
):
    """Draw `mesh` coloured by a function on it, in an orthographic view on ordinary 2-D `axes`.

    Faces are projected by `view_rotation(*view)` and painted from the farthest to the nearest
    (painter's algorithm), so a closed surface hides its back; the axes get an equal aspect ratio
    and no frame (screen coordinates carry no meaning for an oblique view).

    Args:
        axes: a matplotlib `Axes` (2-D).
        mesh: the mesh.
        values: `(nv,)` values at the vertices, or `(nf,)` one value per face (vertex values when
            `nv == nf`).
        view: `(azimuth, elevation)` in degrees; default `TOP_VIEW` for a mesh flat in z
            (`is_flat`), else `OBLIQUE_VIEW`.
        up: the coordinate axis that points up in the view, `"z"` (default), `"y"` (as in many
            scanned models, e.g. spot) or `"x"`.
        shading: `"gouraud"` (vertex values interpolated across each face) or `"flat"` (each face
            the mean of its vertex values); face values are always flat.
        cmap, vmin, vmax: colour map and limits (default: the values' range).
        edgecolor, linewidth: face edges (`"none"`: not drawn; flat shading only).

    Returns:
        The matplotlib collection, a `ScalarMappable` for `figure.colorbar`.
    """
    mesh = require_mesh("mesh", mesh)
    check_choice("shading", shading, ("gouraud", "flat"))
    check_choice("up", up, tuple(UP_ROTATIONS))
    values = np.asarray(values, dtype=float)
    if values.shape not in ((mesh.n_vertices,), (mesh.n_faces,)):
        raise DDGInputError(
            f"values: expected shape ({mesh.n_vertices},) (one value per vertex) or ({mesh.n_faces},) (per face), "
            f"got {values.shape}"
        )
    if view is None:
        view = TOP_VIEW if is_flat(mesh) else OBLIQUE_VIEW
    projected = np.asarray(mesh.vertices, dtype=float) @ (view_rotation(*view) @ UP_ROTATIONS[up]).T
    screen, depth = projected[:, [0, 2]], projected[:, 1]
    faces = np.asarray(mesh.faces)
    order = np.argsort(-depth[faces].mean(axis=1), kind="stable")  # farthest first
    faces = faces[order]
    finite = values[np.isfinite(values)]
    norm = Normalize(
        vmin=vmin if vmin is not None else (finite.min() if finite.size else 0.0),
        vmax=vmax if vmax is not None else (finite.max() if finite.size else 1.0),
    )
    per_vertex = values.shape == (mesh.n_vertices,)  # vertex values when nv == nf
    if per_vertex and shading == "gouraud":
        # tripcolor draws its triangles in the given (back-to-front) order.
        collection = axes.tripcolor(screen[:, 0], screen[:, 1], values, triangles=faces, shading="gouraud", cmap=cmap, norm=norm)
    else:
        face_values = values[faces].mean(axis=1) if per_vertex else values[order]
        collection = PolyCollection(screen[faces], cmap=cmap, norm=norm, edgecolors=edgecolor, linewidths=linewidth)
        collection.set_array(face_values)
        axes.add_collection(collection)
    axes.update_datalim(screen)
    axes.autoscale_view()
    axes.set_aspect("equal")
    axes.set_axis_off()
    return collection


def plot_direction_field(
    axes,
    mesh: Mesh,
    vectors: ArrayLike,
    *,
    view: tuple[Real, Real] | None = None,
    up: str = "z",
    length: Real | None = None,
    color="black",
    linewidth: Real = 0.6,
):
    """Draw tangent directions at the vertices of `mesh` as short strokes, in `plot_mesh_function`'s view.

    Each of the `k` directions at a vertex is a stroke from the vertex along it (a vector field: one
    arrow-like stroke; a cross field: four, a cross). Strokes at vertices whose normal points away
    from the viewer are left out, so a closed surface drawn with `plot_mesh_function` first hides its
    back's strokes too.

    Args:
        axes: a matplotlib `Axes` (2-D), usually with the mesh drawn by `plot_mesh_function`.
        mesh: the mesh.
        vectors: `(nv, k, 3)` unit directions per vertex (`ddgjax.fields.field_to_vectors(mesh, field, n=k)`),
            or `(nv, 3)` one per vertex.
        view, up: as `plot_mesh_function` (the same defaults).
        length: stroke length (default: 0.45 times the mean edge length).
        color, linewidth: the strokes' style.

    Returns:
        The matplotlib `LineCollection`.
    """
    mesh = require_mesh("mesh", mesh)
    check_choice("up", up, tuple(UP_ROTATIONS))
    vectors = np.asarray(vectors, dtype=float)
    if vectors.ndim == 2:
        vectors = vectors[:, None, :]
    if vectors.ndim != 3 or vectors.shape[0] != mesh.n_vertices or vectors.shape[2] != 3:
        raise DDGInputError(f"vectors: expected shape ({mesh.n_vertices}, k, 3) or ({mesh.n_vertices}, 3), got {vectors.shape}")
    if view is None:
        view = TOP_VIEW if is_flat(mesh) else OBLIQUE_VIEW
    rotation = view_rotation(*view) @ UP_ROTATIONS[up]
    vertices = np.asarray(mesh.vertices, dtype=float)
    if length is None:
        length = 0.45 * float(np.mean(np.asarray(edge_lengths(mesh))))
    # The viewer looks along +y of the rotated frame (plot_mesh_function paints larger y first).
    facing = np.ones(len(vertices), bool) if is_flat(mesh) else (np.asarray(vertex_normals(mesh)) @ rotation.T)[:, 1] <= 0
    starts = np.broadcast_to(vertices[facing][:, None, :], vectors[facing].shape)
    ends = starts + length * vectors[facing]
    segments = np.stack([starts, ends], axis=2).reshape(-1, 2, 3) @ rotation.T
    collection = LineCollection(segments[:, :, [0, 2]], colors=color, linewidths=linewidth)
    axes.add_collection(collection)
    return collection
