"""`ddgjax geodesic [MESH]`: the geodesic toolkit on a mesh, printed as numbers and drawn.

One mode per run, the default the distance from `--source` by the heat method drawn with isolines:

- `--log-map`: the logarithmic map at the source (`ddgjax.geodesics.vector_heat_solver(mesh).log_map`),
  drawn as a polar-grid decal (rings of equal geodesic radius crossed by sectors of equal angle at the
  source, a checkerboard in the `(r, angle)` coordinates, out to half the largest distance) beside the angle, the source
  marked; prints the largest and the mean radius (the geodesic distance integrated from the radial field);
- `--transport`: the source's unit tangent vector at `--angle` degrees from its frame's `e1`
  (`ddgjax.fields.tangent_bases`) transported to every vertex along shortest geodesics
  (`VectorHeatSolver.transport`), drawn as strokes over the distance; prints the transported lengths
  (parallel transport keeps them: 1 everywhere) and the largest normal component;
- `--signed`: the signed distance (`ddgjax.geodesics.signed_heat_solver(mesh).distance`) to the boundary
  of the geodesic ball of radius `--radius` around the source (the edges that bound the faces whose
  three vertices lie inside, joined into loops oriented clockwise seen from outside: negative inside,
  positive outside), with `--gap N` edges removed from its longest loop to show the method's
  robustness to holes; drawn with isolines, the zero level where blue meets red, the curve in black;
- `--point-cloud`: the mesh's vertices taken as a point cloud, the heat method run on its tufted
  triangulation (`ddgjax.pointcloud.point_cloud_heat_solver`) and compared with the mesh's heat
  distance (their mean absolute difference over the mesh distance's mean); drawn as a scatter of the
  points coloured by distance beside the mesh distance.

Defaults to the built-in torus it shares with `ddgjax spectrum` (`ddgjax._cli.spectral`); a mesh file is read with
`ddgjax.io.load_mesh`.
"""

from __future__ import annotations

import argparse
import sys
import time

import jax
import numpy as np

from .._errors import DDGInputError, MeshDataError
from ..fields import tangent_bases
from ..geodesics import heat_distance_solver, signed_heat_solver, vector_heat_solver
from ..mesh import Mesh, vertex_normals
from ..pointcloud import point_cloud_heat_solver
from ._common import write_figure
from .spectral import _common, _distance_summary, _draw, _mesh

_MODES = ("log_map", "transport", "signed", "point_cloud")
_CELLS, _SECTORS, _DECAL, _SUBDIVISION = 8, 16, 0.5, 4
"""The log map's polar grid: rings (default; `--cells`), sectors, its radius over the largest distance, and the
subdivision of each face it is drawn on."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `ddgjax geodesic`; its action is `run`."""
    _common(parser, "geodesic")
    parser.add_argument("--source", type=int, default=0, help="source vertex (default 0)")
    parser.add_argument("--t-coef", type=float, default=1.0, help="heat time in units of the squared mean edge length")
    parser.add_argument("--bands", type=int, default=12, help="number of colour bands, whose edges are the isolines")
    modes = parser.add_mutually_exclusive_group()
    modes.add_argument("--log-map", action="store_true", help="the log map at the source, drawn as a polar-grid decal")
    modes.add_argument(
        "--transport", action="store_true", help="a tangent vector at the source parallel-transported to every vertex"
    )
    modes.add_argument(
        "--signed", action="store_true", help="signed distance to the boundary loop of the geodesic ball around the source"
    )
    modes.add_argument(
        "--point-cloud",
        action="store_true",
        help="the heat distance on the mesh's vertices as a point cloud, compared with the mesh's",
    )
    parser.add_argument("--angle", type=float, default=None, help="--transport: the vector's angle from e1, degrees (0)")
    parser.add_argument(
        "--radius", type=float, default=None, help="--signed: the ball's geodesic radius (default 0.3 x the largest distance)"
    )
    parser.add_argument("--gap", type=int, default=None, help="--signed: edges removed from the longest loop (default 0)")
    parser.add_argument("--cells", type=int, default=None, help=f"--log-map: rings of the polar grid (default {_CELLS})")
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Action of `ddgjax geodesic`: the chosen mode's numbers and figure; 2 on bad input."""
    mode = next((name for name in _MODES if getattr(args, name)), "distance")
    try:
        name, mesh = _mesh(args)
        _check(args, mode, mesh)
        start = time.perf_counter()
        rows, draw = _MODE_RUNS[mode](mesh, args)
        elapsed = time.perf_counter() - start
    except (DDGInputError, MeshDataError) as error:
        print(f"ddgjax geodesic: error: {error}", file=sys.stderr)
        return 2
    rows = [
        ("mesh", f"{name}: {mesh.n_vertices} vertices, {mesh.n_faces} faces"),
        ("source", f"vertex {args.source}"),
        ("time", f"{elapsed:.3g} s (factorisations, queries, compilation included)"),
        *rows,
    ]
    print("\n".join(f"{key:10s} {value}" for key, value in rows))
    if args.no_plot:
        return 0
    return 0 if draw(name) else 2


def _check(args, mode: str, mesh: Mesh) -> None:
    if not 0 <= args.source < mesh.n_vertices:
        raise DDGInputError(f"--source: expected a vertex index in [0, {mesh.n_vertices}), got {args.source}")
    if not args.t_coef > 0 or args.bands < 2:
        raise DDGInputError("--t-coef: expected a positive number; --bands: expected at least 2")
    for option, owner in (("angle", "transport"), ("radius", "signed"), ("gap", "signed"), ("cells", "log_map")):
        if getattr(args, option) is not None and mode != owner:
            raise DDGInputError(f"--{option}: only with --{owner.replace('_', '-')}")
    if args.radius is not None and not args.radius > 0:
        raise DDGInputError(f"--radius: expected a positive number, got {args.radius}")
    if args.gap is not None and args.gap < 0:
        raise DDGInputError(f"--gap: expected a number of edges >= 0, got {args.gap}")
    if args.cells is not None and args.cells < 1:
        raise DDGInputError(f"--cells: expected at least 1, got {args.cells}")


def _distance(mesh: Mesh, args):
    distance = np.asarray(jax.block_until_ready(heat_distance_solver(mesh, t_coef=args.t_coef).distance([args.source])))
    rows = [("distance", _distance_summary(distance))]
    return rows, lambda name: _draw(mesh, [("geodesic distance (heat method)", distance)], name, args, bands=args.bands)


def _log_map(mesh: Mesh, args):
    coordinates = np.asarray(jax.block_until_ready(vector_heat_solver(mesh, t_coef=args.t_coef).log_map(args.source)))
    radius = np.linalg.norm(coordinates, axis=1)
    reached = np.isfinite(radius)
    rows = [
        (
            "log map",
            f"max radius {radius[reached].max():.4g} (the geodesic distance's maximum), mean {radius[reached].mean():.4g}",
        ),
    ]
    return rows, lambda name: _draw_log_map(mesh, coordinates, name, args)


def _transport(mesh: Mesh, args):
    bases = tangent_bases(mesh)
    angle = np.deg2rad(args.angle or 0.0)
    vector = np.cos(angle) * np.asarray(bases.e1[args.source]) + np.sin(angle) * np.asarray(bases.e2[args.source])
    solver = vector_heat_solver(mesh, t_coef=args.t_coef)
    field = np.asarray(jax.block_until_ready(solver.transport(args.source, vector)))
    lengths = np.linalg.norm(field, axis=1)
    reached = lengths > 0
    normal = np.abs(np.sum(field * np.asarray(bases.normal), axis=1)).max()
    rows = [
        ("vector", f"unit, {np.rad2deg(angle):.4g} degrees from e1 at the source"),
        (
            "transport",
            f"length min {lengths[reached].min():.12f}, max {lengths[reached].max():.12f} (parallel transport keeps "
            f"it: 1), largest normal component {normal:.2g}"
            + (f" ({int((~reached).sum())} vertices unreached: 0)" if not reached.all() else ""),
        ),
    ]
    # The colour under the strokes: the log map's radius, the heat-method distance, from the kept factorisations.
    return rows, lambda name: _draw_transport(
        mesh, field, np.linalg.norm(np.asarray(solver.log_map(args.source)), axis=1), name, args
    )


def _signed(mesh: Mesh, args):
    heat = np.asarray(jax.block_until_ready(heat_distance_solver(mesh, t_coef=args.t_coef).distance([args.source])))
    finite = np.isfinite(heat)
    radius = args.radius if args.radius is not None else 0.3 * heat[finite].max()
    curves = ball_boundary(mesh, heat < radius)
    if not curves:
        raise DDGInputError(
            f"--radius: the geodesic ball of radius {radius:.4g} around vertex {args.source} holds no whole face or "
            "covers its component; choose a radius between the mesh's edge length and its largest distance "
            f"({heat[finite].max():.4g})"
        )
    edges = sum(len(curve) - 1 for curve in curves)
    gap = args.gap or 0
    if gap:
        longest = max(range(len(curves)), key=lambda k: len(curves[k]))
        if gap > len(curves[longest]) - 2:
            raise DDGInputError(
                f"--gap: expected at most {len(curves[longest]) - 2} edges (the longest loop's less one), got {gap}"
            )
        curves[longest] = curves[longest][gap:]  # a loop `v0 ... vk v0` without its first `gap` edges
    closed = sum(curve[0] == curve[-1] for curve in curves)
    phi = np.asarray(jax.block_until_ready(signed_heat_solver(mesh, t_coef=args.t_coef).distance(curves)))
    # Inside: the vertices of the ball's whole faces; the curve's own vertices are held at 0 and left out.
    region = np.zeros(mesh.n_vertices, bool)
    region[np.asarray(mesh.faces)[(heat < radius)[np.asarray(mesh.faces)].all(axis=1)].ravel()] = True
    on_curve = np.zeros(mesh.n_vertices, bool)
    on_curve[np.concatenate(curves)] = True
    inside, outside = finite & region & ~on_curve, finite & ~region
    rows = [
        (
            "curve",
            f"boundary of the geodesic ball of radius {radius:.4g}: {len(curves)} curve(s), {closed} closed, {edges} edges"
            + (f", {gap} removed" if gap else ""),
        ),
        ("signed", f"min {phi[finite].min():.4g}, max {phi[finite].max():.4g}"),
        (
            "sign",
            f"negative at {np.mean(phi[inside] < 0):.1%} of the {inside.sum()} vertices inside, positive at "
            f"{np.mean(phi[outside] > 0):.1%} of the {outside.sum()} outside",
        ),
        ("vs heat", f"mean |signed - (distance - radius)| {np.abs(phi - (heat - radius))[finite].mean():.4g}"),
    ]
    return rows, lambda name: _draw_signed(mesh, phi, curves, name, args)


def _point_cloud(mesh: Mesh, args):
    points = np.asarray(mesh.vertices)
    referenced = np.zeros(mesh.n_vertices, bool)
    referenced[np.asarray(mesh.faces).ravel()] = True
    if not referenced.all():
        raise DDGInputError("MESH: --point-cloud takes the mesh's vertices as points; remove the vertices of no face first")
    cloud = np.asarray(
        jax.block_until_ready(point_cloud_heat_solver(points, t_coef=args.t_coef).distance(args.source)), dtype=float
    )
    heat = np.asarray(jax.block_until_ready(heat_distance_solver(mesh, t_coef=args.t_coef).distance([args.source])))
    both = np.isfinite(cloud) & np.isfinite(heat)
    difference = np.abs(cloud - heat)[both].mean() / heat[both].mean()
    rows = [
        ("points", f"{len(points)} (the mesh's vertices), 30 neighbours each"),
        ("cloud", _distance_summary(cloud)),
        ("mesh", _distance_summary(heat)),
        ("relative", f"mean |cloud - mesh| / mean mesh distance {difference:.4f}"),
    ]
    return rows, lambda name: _draw_point_cloud(mesh, cloud, heat, name, args)


_MODE_RUNS = {
    "distance": _distance,
    "log_map": _log_map,
    "transport": _transport,
    "signed": _signed,
    "point_cloud": _point_cloud,
}


def ball_boundary(mesh: Mesh, inside: np.ndarray) -> list[list[int]]:
    """The edge loops bounding the faces whose vertices are all `inside`, oriented with those faces on their right.

    The faces' half-edges whose reverse is a half-edge of another mesh face but not of an inside face,
    chained: closed loops repeat their first vertex; where the region meets the mesh's boundary the
    pieces are open paths. Returned reversed (clockwise around the region seen from outside), so the
    signed heat method, positive on a curve's left, is negative inside and positive outside.
    """
    faces = np.asarray(mesh.faces)
    chosen = inside[faces].all(axis=1)
    half = np.stack([faces, np.roll(faces, -1, axis=1)], axis=2).reshape(-1, 2)
    region = {tuple(e) for e in half[np.repeat(chosen, 3)].tolist()}
    every = {tuple(e) for e in half.tolist()}
    following: dict[int, list[int]] = {}
    for a, b in region:
        if (b, a) not in region and (b, a) in every:
            following.setdefault(a, []).append(b)
    incoming = {b for targets in following.values() for b in targets}
    # Open paths start where no boundary edge arrives; closed loops anywhere.
    starts = [a for a in following if a not in incoming] + list(following)
    curves = []
    for start in starts:
        if not following.get(start):
            continue
        curve = [start]
        while following.get(curve[-1]):
            curve.append(following[curve[-1]].pop())
            if curve[-1] == start:
                break
        curves.append(curve[::-1])
    return curves


def _draw_log_map(mesh: Mesh, coordinates: np.ndarray, name: str, args) -> bool:
    from matplotlib.colors import ListedColormap

    # A texture's way: each face split into _SUBDIVISION^2 triangles with the log coordinates interpolated
    # linearly, and on them a smooth function whose sign is the checkerboard, interpolated per pixel
    # (Gouraud) and cut by a two-colour map, so the cells' edges are smooth curves, not the mesh's staircase.
    fine, fine_coordinates = _subdivided(mesh, coordinates, _SUBDIVISION)
    radius = np.linalg.norm(fine_coordinates, axis=1)
    angle = np.arctan2(fine_coordinates[:, 1], fine_coordinates[:, 0])
    reach = np.max(np.linalg.norm(coordinates, axis=1), where=np.isfinite(coordinates).all(axis=1), initial=0.0)
    checker = np.sin(np.pi * radius / (_DECAL * reach / (args.cells or _CELLS))) * np.sin(_SECTORS / 2 * angle)
    # Beyond the decal (a triangle with a corner past its radius) and where the source does not reach: exactly
    # 0, the grey of the map's one middle entry; inside, +-1 but near the cells' edges.
    beyond = ~(np.isfinite(radius) & (radius < _DECAL * reach))[np.asarray(fine.faces)].all(axis=1)
    values = np.clip(40.0 * np.nan_to_num(checker), -1.0, 1.0)
    values[np.asarray(fine.faces)[beyond].reshape(-1)] = 0.0
    colours = ListedColormap(["tab:orange"] * 500 + ["0.75"] + ["0.97"] * 500)

    def source(axes):
        screen = _screen(mesh, args.up)[args.source]
        axes.scatter([screen[0]], [screen[2]], s=28, c="black", zorder=3)
        axes.annotate("source", (screen[0], screen[2]), xytext=(6, 6), textcoords="offset points", fontsize=8)

    panels = [
        _panel(
            "log map: a polar grid decal in ($r$, angle) at the source",
            values,
            colours,
            extra=source,
            limits=(-1.0, 1.0),
            colorbar=False,
            mesh=fine,
        ),
        _panel(
            "log map: the angle at the source (radians)",
            np.arctan2(coordinates[:, 1], coordinates[:, 0]),
            "twilight",
            extra=source,
        ),
    ]
    return _figure(mesh, panels, name, args)


def _subdivided(mesh: Mesh, values: np.ndarray, n: int) -> tuple[Mesh, np.ndarray]:
    """Each face split into `n^2` triangles, each with its own three corners (for drawing only: a triangle's
    colour never bleeds into its neighbours'), the positions and the per-vertex `values` interpolated linearly."""
    lattice = [(a, b) for a in range(n + 1) for b in range(n + 1 - a)]  # points (a, b) of one face, a + b <= n
    index = {point: k for k, point in enumerate(lattice)}
    i, j = np.array(lattice).T
    small = []
    for a in range(n):
        for b in range(n - a):
            small.append((index[a, b], index[a + 1, b], index[a, b + 1]))
            if a + b < n - 1:
                small.append((index[a + 1, b], index[a + 1, b + 1], index[a, b + 1]))
    weights = np.stack([n - i - j, i, j], axis=1) / n  # barycentric weights of the corners 0, 1, 2
    faces = np.asarray(mesh.faces)
    points = np.einsum("pk,fkd->fpd", weights, np.asarray(mesh.vertices)[faces]).reshape(-1, 3)
    interpolated = np.einsum("pk,fkd->fpd", weights, values[faces]).reshape(-1, values.shape[1])
    corners = (np.arange(faces.shape[0])[:, None, None] * weights.shape[0] + np.asarray(small)[None]).reshape(-1)
    triangles = np.arange(corners.size).reshape(-1, 3)
    return Mesh.from_arrays(points[corners], triangles), interpolated[corners]


def _draw_transport(mesh: Mesh, field: np.ndarray, distance: np.ndarray, name: str, args) -> bool:
    from ..plot import plot_direction_field

    units = field / np.maximum(np.linalg.norm(field, axis=1, keepdims=True), 1e-300)

    def strokes(axes):
        plot_direction_field(axes, mesh, units, up=args.up, color="black")

    panels = [_panel("the transported vector over the geodesic distance", distance, "viridis", extra=strokes)]
    return _figure(mesh, panels, name, args)


def _draw_signed(mesh: Mesh, phi: np.ndarray, curves, name: str, args) -> bool:
    from matplotlib import colormaps
    from matplotlib.collections import LineCollection

    limit = np.abs(phi[np.isfinite(phi)]).max()
    bands = args.bands + args.bands % 2  # even: 0 is a band edge, where blue meets red

    def curve(axes):
        screen, facing = _screen(mesh, args.up), _facing(mesh, args.up)
        segments = [screen[np.stack([c[:-1], c[1:]], axis=1)][:, :, [0, 2]] for c in map(np.asarray, curves)]
        # Segments on the back of a closed surface are hidden, as plot_direction_field hides its strokes.
        shown = np.concatenate([facing[c[:-1]] & facing[c[1:]] for c in map(np.asarray, curves)])
        segments = np.concatenate(segments)[shown]
        axes.add_collection(LineCollection(segments, colors="black", linewidths=1.2))

    cmap = colormaps["RdBu_r"].resampled(bands)
    panels = [_panel("signed distance to the black curve (signed heat method)", phi, cmap, extra=curve, limits=(-limit, limit))]
    return _figure(mesh, panels, name, args)


def _draw_point_cloud(mesh: Mesh, cloud: np.ndarray, heat: np.ndarray, name: str, args) -> bool:
    finite = np.isfinite(heat) & np.isfinite(cloud)
    limits = (0.0, max(heat[finite].max(), cloud[finite].max()))

    def scatter(axes):
        screen = _screen(mesh, args.up)
        order = np.argsort(-screen[:, 1], kind="stable")  # farthest first, as plot_mesh_function paints
        points = axes.scatter(
            screen[order, 0], screen[order, 2], c=cloud[order], s=6, cmap="viridis", vmin=limits[0], vmax=limits[1]
        )
        axes.set_aspect("equal")
        axes.set_axis_off()
        return points

    panels = [
        _panel("point cloud: heat distance on its tufted triangulation", None, None, extra=scatter),
        _panel("mesh: heat distance", heat, "viridis", limits=limits),
    ]
    return _figure(mesh, panels, name, args)


def _screen(mesh: Mesh, up: str) -> np.ndarray:
    """`(nv, 3)` the vertices in `plot_mesh_function`'s default view: screen `x`, depth, screen `y`."""
    from ..plot import OBLIQUE_VIEW, TOP_VIEW, is_flat, view_rotation
    from ..plot.internal import UP_ROTATIONS

    rotation = view_rotation(*(TOP_VIEW if is_flat(mesh) else OBLIQUE_VIEW)) @ UP_ROTATIONS[up]
    return np.asarray(mesh.vertices, dtype=float) @ rotation.T


def _facing(mesh: Mesh, up: str) -> np.ndarray:
    """`(nv,)` whether each vertex's normal faces the viewer of `_screen` (all of them on a flat mesh)."""
    from ..plot import OBLIQUE_VIEW, is_flat, view_rotation
    from ..plot.internal import UP_ROTATIONS

    if is_flat(mesh):
        return np.ones(mesh.n_vertices, bool)
    rotation = view_rotation(*OBLIQUE_VIEW) @ UP_ROTATIONS[up]
    return (np.asarray(vertex_normals(mesh)) @ rotation.T)[:, 1] <= 0  # the viewer looks along +depth


def _panel(title, values, cmap, *, extra=None, limits=(None, None), colorbar=True, mesh=None) -> dict:
    """One panel of `_figure`: `values` drawn by `plot_mesh_function` (flat shading for face values, on `mesh`
    when given, else the figure's), then `extra(axes)`; `values=None`: `extra(axes)` draws and returns the colour
    bar's mappable."""
    return {"title": title, "values": values, "cmap": cmap, "extra": extra, "limits": limits, "colorbar": colorbar, "mesh": mesh}


def _figure(mesh: Mesh, panels: list[dict], name: str, args) -> bool:
    # Imported here: matplotlib is only needed when a figure is written.
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from ..plot import plot_mesh_function

    figure = Figure(figsize=(max(4.6 * len(panels) + 0.6, 7.0), 4.4), layout="constrained")
    FigureCanvasAgg(figure)
    for index, panel in enumerate(panels):
        axes = figure.add_subplot(1, len(panels), index + 1)
        if panel["values"] is None:
            mappable = panel["extra"](axes)
        else:
            vmin, vmax = panel["limits"]
            drawn = mesh if panel["mesh"] is None else panel["mesh"]
            # Face colours drawn on their edges too: antialiased seams would let the back of the surface show through.
            edges = {"edgecolor": "face"} if (drawn.n_faces,) == np.shape(panel["values"]) else {}
            mappable = plot_mesh_function(
                axes, drawn, panel["values"], up=args.up, cmap=panel["cmap"], vmin=vmin, vmax=vmax, **edges
            )
            if panel["extra"] is not None:
                panel["extra"](axes)
        axes.set_title(panel["title"], fontsize=10)
        if panel["colorbar"]:
            figure.colorbar(mappable, ax=axes, shrink=0.8)
    figure.suptitle(name, fontsize=10)
    return write_figure(figure, args.output, "geodesic")
