"""The interactive 3D viewer: `show(mesh, values, vectors=...)` as a plotly figure to turn with the mouse."""

from __future__ import annotations

from numbers import Real

import numpy as np
from jaxtyping import ArrayLike

from .._errors import DDGInputError, check_choice, check_finite, check_positive, first_indices
from ..curves import Curve
from ..mesh import Mesh
from ._view import OBLIQUE_VIEW, TOP_VIEW, UP_ROTATIONS, points_are_flat, view_rotation

#: Colour of faces and points whose value is NaN or inf, and of a mesh drawn without values.
MISSING_COLOR = "#bdbdbd"
#: `vector_styles` of `show`: strokes from each point, or cones with their tail at it.
VECTOR_STYLES = ("lines", "cones")
# Stops sampled from a matplotlib colour map; plotly interpolates linearly between them.
_COLORSCALE_STOPS = 33
# Colour bars of later shapes added to one figure step to the right by this much (of the plot's width).
_COLORBAR_STEP = 0.12


def show(
    mesh: Mesh | Curve | ArrayLike,
    values: ArrayLike | None = None,
    *,
    vectors: ArrayLike | None = None,
    cmap="viridis",
    vmin: Real | None = None,
    vmax: Real | None = None,
    edges: bool = False,
    color: str = MISSING_COLOR,
    vector_style: str = "lines",
    vector_scale: Real | None = None,
    vector_color: str = "black",
    up: str = "z",
    name: str | None = None,
    figure=None,
):
    """An interactive 3D figure of a mesh, a curve or points, coloured by `values`, with `vectors` drawn on it.

    One call, as polyscope, meshplot or pyvista give, drawn by plotly (the `viewer` extra, `pip install
    "ddgjax[viewer]"`; WebGL in the browser, no OpenGL or VTK on the machine). In a notebook the figure
    shows when it is a cell's last expression; `fig.show()` opens it elsewhere (a browser from a script)
    and `fig.write_html("mesh.html")` saves a page that works offline (plotly.js inside, about 5 MB;
    `include_plotlyjs="cdn"` for a small page that loads it from plotly's CDN). Turn with the left
    button, pan with the right, zoom with the wheel. Nothing global is changed (plotly's renderer
    included).

        import ddgjax.mesh as dm
        from ddgjax.plot import show

        sphere = dm.icosphere(3)
        fig = show(sphere, dm.vertex_pointwise_gaussian_curvatures(sphere), edges=True)
        fig.write_html("curvature.html")

    Colours: vertex values are interpolated across each face (smooth), face values are flat; the colour
    bar spans `[vmin, vmax]` (default: the finite values' range). Faces touching a NaN or inf vertex
    value, faces with a NaN or inf value and such points are drawn grey (`#bdbdbd`) in a separate
    trace named "non-finite values", not refused (the finite part of a field stays readable).
    Coordinates, values and vectors travel to the browser as float32 (half the page; drawing needs no
    more). The axes are equal (`aspectmode="data"`) and hidden; the camera looks from `OBLIQUE_VIEW`
    (perspective), or straight down the `up` axis (orthographic) when every point lies in one plane
    across it (a flat mesh, a plane curve).

    Args:
        mesh: what to draw: a `ddgjax.Mesh`; a `ddgjax.Curve` (drawn in the plane `z = 0`, with its
            closing edge when closed, values on its points); or an `(n, 3)` / `(n, 2)` array of points.
        values: `(nv,)` one value per vertex or `(nf,)` per face (vertex values when `nv == nf`); for a
            curve or points `(n,)` one per point. JAX or NumPy, real.
        vectors: drawn from each vertex `(nv, 3)`, or from each face's centroid `(nf, 3)` (vertex
            vectors when `nv == nf`); `(nv, k, 3)` / `(nf, k, 3)` draws `k` per place (a cross field
            from `ddgjax.fields.field_to_vectors(mesh, field, n=4)`: four strokes, a cross); for a
            curve or points `(n, 3)`, or `(n, 2)` in the plane. Drawn as given (a tangent vector stays
            tangent), scaled by `vector_scale`. Finite entries only.
        cmap: a matplotlib colour map or its name (`"viridis"`, `"coolwarm"`, `"twilight"`, `"RdBu_r"`).
        vmin, vmax: the colour bar's limits (default: the range of the finite values).
        edges: draw the mesh's edges (a wireframe) over the faces.
        color: colour of the mesh, curve or points when `values` is None (a CSS colour).
        vector_style: `"lines"` (a stroke from each point) or `"cones"` (tail at the point).
        vector_scale: factor from a vector to its drawn length; default: the longest vector is drawn
            half the mean edge length (mean segment length of a curve, mean nearest-neighbour
            distance of points); `1.0` draws true lengths (polyscope's `vectortype="ambient"`).
        vector_color: colour of the vectors (a CSS colour).
        up: the coordinate axis that points up on screen, `"z"` (default), `"y"` (as in many scanned
            models, e.g. spot) or `"x"`; as `plot_mesh_function`.
        name: the shape's name in hover labels, the legend, and the colour bar's title.
        figure: a figure from an earlier `show` to draw into (several shapes in one scene; its camera
            and layout are kept), instead of a new one.

    Returns:
        A `plotly.graph_objects.Figure`: one `Mesh3d` for the faces (`x, y, z` the vertices; `i, j, k`
        the faces; `intensity` the values, `intensitymode` `"vertex"` or `"cell"`), a `Scatter3d` of
        lines for a curve, edges or vector strokes (segments separated by NaN), `Scatter3d` markers for
        points, a `Cone` for cones.

    Raises:
        DDGInputError: `mesh` of another kind, non-finite coordinates, `values` or `vectors` of the
            wrong shape or non-real, non-finite `vectors`, an unknown `cmap`, `vector_style` or `up`,
            a `figure` that is not a plotly figure.
        ImportError: plotly is not installed (`pip install "ddgjax[viewer]"`).

    Equivalents: polyscope `m = ps.register_surface_mesh("mesh", V, F, edge_width=1.0)`,
    `m.add_scalar_quantity("values", values, defined_on="vertices", cmap="viridis", enabled=True)`,
    `m.add_vector_quantity("vectors", vectors, defined_on="vertices", enabled=True)`, `ps.show()`;
    meshplot `p = meshplot.plot(V, F, c=values)`, `p.add_lines(starts, ends)`; pyvista
    `pv.PolyData(V, faces).plot(scalars=values, cmap="viridis", show_edges=True)`.
    """
    go = _plotly()
    check_choice("vector_style", vector_style, VECTOR_STYLES)
    check_choice("up", up, tuple(UP_ROTATIONS))
    if figure is not None and not isinstance(figure, go.Figure):
        raise DDGInputError(
            f"figure: expected a plotly Figure (the result of an earlier show(...)), got {type(figure).__name__}; "
            "leave it out for a new figure"
        )
    points, faces, closed = _geometry(mesh)
    n_points, n_faces = len(points), (0 if faces is None else len(faces))
    new_figure = figure is None
    figure = go.Figure() if new_figure else figure
    colorbars = sum(
        bool(getattr(t, "showscale", None) or getattr(getattr(t, "marker", None), "showscale", None)) for t in figure.data
    )
    coloring = None if values is None else _coloring(values, n_points, n_faces, cmap, vmin, vmax, name, colorbars)
    # Checked before anything is drawn, so a refused call leaves a given `figure` as it was.
    arrows = None if vectors is None else source_vectors(vectors, mesh, points, faces, vector_scale)
    if faces is not None:
        figure.add_traces(_surface(go, points, faces, coloring, color, name))
        if edges:
            figure.add_trace(_lines(go, points[np.asarray(mesh.edges)], "#404040", 1.5, f"{name or 'mesh'} edges"))
    else:
        if closed is not None:
            path = np.vstack([points, points[:1]]) if closed else points
            line_color = "#404040" if coloring is not None else color
            figure.add_trace(_lines(go, np.stack([path[:-1], path[1:]], axis=1), line_color, 4.0, name or "curve"))
        figure.add_traces(_markers(go, points, coloring, color, name))
    if arrows is not None:
        starts, segments = arrows
        if vector_style == "lines":
            figure.add_trace(_lines(go, np.stack([starts, starts + segments], axis=1), vector_color, 3.0, "vectors"))
        else:
            figure.add_trace(_cones(go, starts, segments, vector_color))
    if new_figure:
        figure.update_layout(scene=_scene(points, up), margin=dict(l=0, r=0, t=0, b=0), showlegend=False)
    return figure


def _plotly():
    """`plotly.graph_objects`, imported on first use so `import ddgjax.plot` does not need plotly."""
    try:
        import plotly.graph_objects as go
    except ImportError as error:
        raise ImportError(
            'ddgjax.plot.show draws with plotly, which is not installed: pip install "ddgjax[viewer]" (or pip install plotly)'
        ) from error
    return go


def _geometry(shape) -> tuple[np.ndarray, np.ndarray | None, bool | None]:
    """`(points (n, 3) float64, faces (nf, 3) or None, closed or None for a point set)` of what to draw."""
    if isinstance(shape, Mesh):
        points, faces, closed = np.asarray(shape.vertices, dtype=float), np.asarray(shape.faces), None
        check_finite("mesh", points)
        return points, faces, closed
    if isinstance(shape, Curve):
        points, closed = np.asarray(shape.points, dtype=float), shape.closed
    elif hasattr(shape, "shape") and hasattr(shape, "dtype"):
        points, closed = np.asarray(shape), None
        if points.ndim != 2 or points.shape[1] not in (2, 3) or not np.issubdtype(points.dtype, np.number):
            raise DDGInputError(f"mesh: expected points of shape (n, 3) or (n, 2), got an array of shape {points.shape}")
        if np.iscomplexobj(points):
            raise DDGInputError(f"mesh: expected real points, got dtype {points.dtype}")
        points = points.astype(float)
    else:
        raise DDGInputError(
            f"mesh: expected a ddgjax Mesh, a ddgjax Curve or an (n, 3) array of points, got {type(shape).__name__}; "
            "build a mesh with ddgjax.Mesh.from_arrays(vertices, faces), a curve with ddgjax.curves.Curve(points)"
        )
    check_finite("mesh", points)
    if points.shape[1] == 2:
        points = np.column_stack([points, np.zeros(len(points))])
    return points, None, closed


def _real_array(name: str, array) -> np.ndarray:
    """A float64 host copy of a real array, else `DDGInputError` naming the argument."""
    host = np.asarray(array)
    if not (np.issubdtype(host.dtype, np.number) or host.dtype == bool) or np.iscomplexobj(host):
        raise DDGInputError(f"{name}: expected real numbers, got dtype {host.dtype}; pass the real part or the modulus")
    return host.astype(float)


def _colorscale(cmap) -> list:
    """The matplotlib colour map `cmap` (or its name) as a plotly colour scale of `_COLORSCALE_STOPS` stops."""
    import matplotlib
    from matplotlib.colors import Colormap, to_hex

    colormap = matplotlib.colormaps.get(cmap) if isinstance(cmap, str) else cmap
    if not isinstance(colormap, Colormap):
        raise DDGInputError(
            f"cmap: expected a matplotlib colour map or its name (such as 'viridis', 'coolwarm', 'twilight'; "
            f"list(matplotlib.colormaps) names them all), got {cmap!r}"
        )
    return [[float(t), to_hex(colormap(t))] for t in np.linspace(0.0, 1.0, _COLORSCALE_STOPS)]


def _coloring(values, n_points, n_faces, cmap, vmin, vmax, name, colorbars) -> dict:
    """Values, where they live (`"vertex"` or `"cell"`), which are finite, and the colour-bar settings."""
    values = _real_array("values", values)
    if values.shape == (n_points,):
        where = "vertex"
    elif n_faces and values.shape == (n_faces,):
        where = "cell"
    else:
        expected = (
            f"({n_points},) one value per vertex or ({n_faces},) one per face" if n_faces else f"({n_points},) one per point"
        )
        raise DDGInputError(
            f"values: expected shape {expected}, got {values.shape}; for vectors pass vectors=, "
            "or colour by their length (jnp.linalg.norm(v, axis=-1))"
        )
    finite = np.isfinite(values)
    low = vmin if vmin is not None else (values[finite].min() if finite.any() else 0.0)
    high = vmax if vmax is not None else (values[finite].max() if finite.any() else 1.0)
    colorbar = dict(title=dict(text=name) if name else None, x=1.02 + _COLORBAR_STEP * colorbars)
    return dict(
        values=values,
        where=where,
        finite=finite,
        style=dict(colorscale=_colorscale(cmap), cmin=float(low), cmax=float(high), showscale=True, colorbar=colorbar),
    )


def _surface(go, points, faces, coloring, color, name) -> list:
    """`Mesh3d` traces: the faces coloured by their values, and those with a non-finite value grey."""
    vertices = dict(x=points[:, 0].astype(np.float32), y=points[:, 1].astype(np.float32), z=points[:, 2].astype(np.float32))
    lighting = dict(ambient=0.55, diffuse=0.6, specular=0.05, roughness=0.9, fresnel=0.1)
    faces = faces.astype(np.int32)

    def trace(selected, **style):
        return go.Mesh3d(**vertices, i=selected[:, 0], j=selected[:, 1], k=selected[:, 2], lighting=lighting, **style)

    if coloring is None:
        return [trace(faces, color=color, name=name or "mesh")]
    values, finite = coloring["values"], coloring["finite"]
    missing = ~finite[faces].all(axis=1) if coloring["where"] == "vertex" else ~finite
    traces = []
    if not missing.all():
        # Non-finite vertex values belong only to grey faces; cmin stands in for them so plotly gets numbers.
        intensity = np.where(finite, values, coloring["style"]["cmin"]).astype(np.float32)
        if coloring["where"] == "cell":
            intensity = intensity[~missing]
        traces.append(
            trace(
                faces[~missing], intensity=intensity, intensitymode=coloring["where"], name=name or "values", **coloring["style"]
            )
        )
    if missing.any():
        traces.append(trace(faces[missing], color=MISSING_COLOR, name="non-finite values"))
    return traces


def _markers(go, points, coloring, color, name) -> list:
    """`Scatter3d` markers at the points: coloured by their values, those with a non-finite value grey."""
    finite = np.ones(len(points), bool) if coloring is None else coloring["finite"]

    def trace(selected, marker, label):
        xyz = points[selected].astype(np.float32)
        return go.Scatter3d(x=xyz[:, 0], y=xyz[:, 1], z=xyz[:, 2], mode="markers", marker=dict(size=3, **marker), name=label)

    traces = []
    if finite.any():
        marker = (
            dict(color=color)
            if coloring is None
            else dict(color=coloring["values"][finite].astype(np.float32), **coloring["style"])
        )
        traces.append(trace(finite, marker, name or "points"))
    if not finite.all():
        traces.append(trace(~finite, dict(color=MISSING_COLOR), "non-finite values"))
    return traces


def _lines(go, segments, color, width, name):
    """One `Scatter3d` of `(m, 2, 3)` segments, NaN between them so plotly lifts the pen."""
    gaps = np.full((len(segments), 1, 3), np.nan)
    path = np.concatenate([segments, gaps], axis=1).reshape(-1, 3).astype(np.float32)
    return go.Scatter3d(
        x=path[:, 0], y=path[:, 1], z=path[:, 2], mode="lines", line=dict(color=color, width=width), name=name, hoverinfo="skip"
    )


def _cones(go, starts, segments, color):
    """One `Cone` trace: a cone per segment, its tail at the start and its length the segment's (`sizemode="raw"`)."""
    starts, segments = starts.astype(np.float32), segments.astype(np.float32)
    return go.Cone(
        x=starts[:, 0], y=starts[:, 1], z=starts[:, 2], u=segments[:, 0], v=segments[:, 1], w=segments[:, 2],
        sizemode="raw", anchor="tail", colorscale=[[0.0, color], [1.0, color]], showscale=False, name="vectors",
    )  # fmt: skip


def source_vectors(vectors, shape, points, faces, vector_scale) -> tuple[np.ndarray, np.ndarray]:
    """`(starts, segments)`, each `(m, 3)`: where each vector is drawn from and the drawn vector."""
    vectors = _real_array("vectors", vectors)
    n_points, n_faces = len(points), (0 if faces is None else len(faces))
    per_point = vectors.ndim in (2, 3) and vectors.shape[0] == n_points
    per_face = n_faces and vectors.ndim in (2, 3) and vectors.shape[0] == n_faces
    dims = (3,) if faces is not None else (2, 3)
    if not (per_point or per_face) or vectors.shape[-1] not in dims:
        where = (
            f"({n_points}, 3) per vertex or ({n_faces}, 3) per face (or (n, k, 3): k each)"
            if faces is not None
            else f"({n_points}, 3) or ({n_points}, 2), one per point"
        )
        raise DDGInputError(f"vectors: expected shape {where}, got {vectors.shape}")
    bad = ~np.isfinite(vectors)
    if bad.any():
        raise DDGInputError(
            f"vectors: expected finite entries, got NaN/inf at rows {first_indices(bad)}; zero them "
            "(jnp.nan_to_num(vectors)) to draw nothing there"
        )
    if vectors.shape[-1] == 2:
        vectors = np.concatenate([vectors, np.zeros(vectors.shape[:-1] + (1,))], axis=-1)
    anchors = points if per_point else points[faces].mean(axis=1)
    if vectors.ndim == 2:
        vectors = vectors[:, None, :]
    starts = np.repeat(anchors, vectors.shape[1], axis=0)
    vectors = vectors.reshape(-1, 3)
    if vector_scale is None:
        longest = float(np.linalg.norm(vectors, axis=1).max(initial=0.0))
        vector_scale = 0.5 * _spacing(shape, points, faces) / longest if longest > 0 else 1.0
    return starts, check_positive("vector_scale", vector_scale) * vectors


def _spacing(shape, points, faces) -> float:
    """The mean edge length of a mesh, mean segment length of a curve, mean nearest-neighbour distance of points."""
    if faces is not None:
        edges = np.asarray(shape.edges)
        return float(np.linalg.norm(points[edges[:, 1]] - points[edges[:, 0]], axis=1).mean())
    if isinstance(shape, Curve):
        return float(np.linalg.norm(np.diff(points, axis=0), axis=1).mean())
    from scipy.spatial import cKDTree

    return float(cKDTree(points).query(points, k=2)[0][:, 1].mean()) if len(points) > 1 else 1.0


def _scene(points, up) -> dict:
    """Equal axes, hidden, and a camera from `OBLIQUE_VIEW` (or from above, orthographic, for flat shapes)."""
    up_rotation = UP_ROTATIONS[up]
    flat = points_are_flat(points @ up_rotation.T)
    # Rows of the rotation in the data's coordinates: 1 the viewing direction, 2 the screen's up.
    rotation = view_rotation(*(TOP_VIEW if flat else OBLIQUE_VIEW)) @ up_rotation
    axis = dict(visible=False)
    camera = dict(
        eye=dict(zip("xyz", (-2.0 * rotation[1]).tolist())),
        up=dict(zip("xyz", rotation[2].tolist())),
        projection=dict(type="orthographic" if flat else "perspective"),
    )
    return dict(aspectmode="data", camera=camera, xaxis=axis, yaxis=axis, zaxis=axis)
