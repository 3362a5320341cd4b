"""`ddgjax match [SOURCE TARGET]`: a point-to-point map between two meshes, drawn as a texture carried through it.

Without files it matches a built-in pair with known ground truth: a lumpy sphere (four bumps of
different sizes, no mirror symmetry) meshed as an icosphere, and the same surface meshed as a UV
sphere then bent by ARAP (one bump held, another pulled sideways), so the two meshes share no
vertex and differ by a near-isometry. Each target vertex's true source vertex is the one at the
nearest direction from the centre before bending; the command prints the mean geodesic error of
the map (normalised by the square root of the source's area, Kim et al. 2011) next to what the
plain functional map gives before refinement.

The figure: the source painted with a 3-D checkerboard (the sign of `sin(a x) sin(a y) sin(a z)`),
the target painted by pulling that pattern back through the map (each target vertex takes its
source vertex's colour) and, with ground truth, the same through the true map.
"""

from __future__ import annotations

import argparse
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np
import scipy.spatial

from .._errors import DDGInputError, MeshDataError, check_count
from ..deform import arap
from ..matching import geodesic_error, match_shapes
from ..matching import point_map as matching_point_map
from ..mesh import Mesh, icosphere, uv_sphere
from ._common import add_output_argument, load_cli_mesh, write_figure

_DEFAULT_PAIR = "built-in lumpy sphere: an icosphere (source) and a UV sphere bent by ARAP (target), ground truth known"
# Four bumps (direction, height, width) at generic directions: the surface has no symmetry a map could flip to.
_BUMPS = (
    ((0.0, 0.0, 1.0), 0.9, 0.06),
    ((1.0, 0.0, 0.2), 0.7, 0.05),
    ((-0.3, 0.9, -0.2), 0.5, 0.08),
    ((-0.5, -0.6, -0.6), 0.4, 0.04),
)


def lumpy_sphere(mesh: Mesh) -> Mesh:
    """The unit-sphere `mesh` pushed out along each direction `u` to radius `1 + sum_i h_i exp(-(1 - u.d_i) / w_i)`."""
    directions = np.asarray(mesh.vertices, dtype=float)
    directions = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    radius = np.ones(len(directions))
    for direction, height, width in _BUMPS:
        d = np.asarray(direction) / np.linalg.norm(direction)
        radius += height * np.exp(-(1.0 - directions @ d) / width)
    return mesh.with_vertices(jnp.asarray(directions * radius[:, None]))


def built_in_pair(subdivisions: int = 4) -> tuple[Mesh, Mesh, np.ndarray]:
    """`(source, target, true_point_map)`: the lumpy sphere on an icosphere and on a UV sphere bent by ARAP;
    the true source vertex of each target vertex is the nearest in direction.

    `subdivisions` sets the size: the icosphere's (`10 * 4**s + 2` vertices: 2,562 at the default 4,
    10,242 at 5, 40,962 at 6); the UV sphere's rings and meridians scale with it (2,420 vertices at 4,
    9,798 at 5, 39,434 at 6), so the two meshes never share a vertex layout.
    """
    check_count("subdivisions", subdivisions, minimum=1)
    scale = 2.0 ** (subdivisions - 4)
    source = lumpy_sphere(icosphere(subdivisions, dtype=jnp.float64))
    rest = lumpy_sphere(uv_sphere(max(4, round(40 * scale)), max(6, round(62 * scale)), dtype=jnp.float64))
    vertices = np.asarray(rest.vertices)
    directions = vertices / np.linalg.norm(vertices, axis=1, keepdims=True)
    held = np.flatnonzero(directions @ np.array([0.0, 0.0, 1.0]) > 0.97)  # the tallest bump's tip
    pulled_axis = np.array([1.0, 0.0, 0.2]) / np.linalg.norm([1.0, 0.0, 0.2])
    pulled = np.flatnonzero(directions @ pulled_axis > 0.97)  # the second bump's tip, pulled sideways
    values = np.concatenate([vertices[held], vertices[pulled] + np.array([0.0, 0.4, -0.2])])
    # ARAP's steps to its default tolerance grow with the mesh, and a bend need only be near-isometric:
    # the default size converges fully (the pair as it always was), larger ones stop at 1e-4.
    rtol = None if subdivisions <= 4 else 1e-4
    target = rest.with_vertices(arap(rest, fixed_vertices=np.concatenate([held, pulled]), fixed_values=values, rtol=rtol))
    source_directions = np.asarray(source.vertices) / np.linalg.norm(np.asarray(source.vertices), axis=1, keepdims=True)
    true_map = scipy.spatial.cKDTree(source_directions).query(directions)[1]
    return source, target, true_map


def checkerboard(vertices: np.ndarray, cells: float) -> np.ndarray:
    """`(nv,)` 0 / 1: the sign of `sin(a x) sin(a y) sin(a z)` with `cells` squares across the bounding box's diagonal."""
    centred = vertices - vertices.mean(axis=0)
    a = np.pi * cells / np.linalg.norm(np.ptp(vertices, axis=0))
    return (np.prod(np.sin(a * centred + 0.5), axis=1) > 0).astype(float)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `ddgjax match`; its action is `run`."""
    parser.add_argument("source", nargs="?", default=None, help="source mesh file; default: the " + _DEFAULT_PAIR)
    parser.add_argument("target", nargs="?", default=None, help="target mesh file (with SOURCE)")
    parser.add_argument("-k", type=int, default=None, help="eigenpairs the functional map is fitted in (default: match_shapes')")
    parser.add_argument(
        "--refine",
        choices=("zoomout", "icp", "none"),
        default="zoomout",
        help="refinement of the functional map: ZoomOut (default), spectral ICP or none",
    )
    parser.add_argument("--cells", type=float, default=8.0, help="checkerboard squares across the source (default 8)")
    parser.add_argument("--up", choices=("x", "y", "z"), default="z", help="the axis drawn upwards (default z)")
    add_output_argument(parser, "match")
    parser.add_argument("--no-plot", action="store_true", help="print the numbers only")
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Action of `ddgjax match`: load or build the pair, match, report, draw; 2 on bad input."""
    try:
        if (args.source is None) != (args.target is None):
            raise DDGInputError("SOURCE TARGET: give both mesh files, or neither for the built-in pair")
        if not args.cells > 0:
            raise DDGInputError(f"--cells: expected a positive number, got {args.cells}")
        if args.source is None:
            name = "built-in lumpy sphere"
            source, target, true_map = built_in_pair()
        else:
            (source_name, source), (target_name, target) = load_cli_mesh(args.source), load_cli_mesh(args.target)
            name, true_map = f"{source_name} -> {target_name}", None
        options = {} if args.k is None else {"k": args.k}
        start = time.perf_counter()
        result = match_shapes(source, target, refine=None if args.refine == "none" else args.refine, **options)
        point_map = np.asarray(jax.block_until_ready(result.point_map))
        elapsed = time.perf_counter() - start
    except (DDGInputError, MeshDataError) as error:
        print(f"ddgjax match: error: {error}", file=sys.stderr)
        return 2
    print(f"{'source':8s} {source.n_vertices} vertices, {source.n_faces} faces")
    print(f"{'target':8s} {target.n_vertices} vertices, {target.n_faces} faces ({name})")
    k_target, k_source = result.functional_map.shape
    print(f"{'map':8s} functional map {k_target} x {k_source}, refine {args.refine}, {elapsed:.3g} s")
    if true_map is not None:
        error = float(geodesic_error(source, point_map, true_map))
        initial_map = np.asarray(matching_point_map(result.initial_functional_map, result.source, result.target))
        initial_error = float(geodesic_error(source, initial_map, true_map))
        print(f"{'error':8s} mean geodesic error / sqrt(area) {error:.4f} ({initial_error:.4f} before refinement)")
    if args.no_plot:
        return 0
    return 0 if _draw(source, target, point_map, true_map, name, args) else 2


def _draw(source: Mesh, target: Mesh, point_map: np.ndarray, true_map, name: str, args) -> bool:
    # Imported here: matplotlib is only needed when a figure is written.
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.colors import ListedColormap
    from matplotlib.figure import Figure

    from ..plot import plot_mesh_function

    pattern = checkerboard(np.asarray(source.vertices, dtype=float), args.cells)
    colours = ListedColormap(["tab:orange", "0.95"])
    panels = [
        (source, pattern, "source: a 3-D checkerboard"),
        (target, pattern[point_map], "target: the checkerboard pulled through the map"),
    ]
    if true_map is not None:
        panels.append((target, pattern[true_map], "target: the checkerboard through the true map"))
    figure = Figure(figsize=(4.3 * len(panels), 4.8), layout="constrained")
    FigureCanvasAgg(figure)
    for index, (mesh, values, title) in enumerate(panels):
        axes = figure.add_subplot(1, len(panels), index + 1)
        # Flat shading: a checkerboard's colour is one per face, not interpolated across an edge of the pattern.
        plot_mesh_function(axes, mesh, values, up=args.up, cmap=colours, shading="flat", vmin=0.0, vmax=1.0)
        axes.set_title(title, fontsize=10)
    figure.suptitle(f"{name}: point map by functional maps (ddgjax.matching.match_shapes)", fontsize=10)
    return write_figure(figure, args.output, "match")
