"""`ddgjax reconstruct [POINTS_OR_MESH]`: Poisson surface reconstruction of a point cloud, printed and drawn.

The input: by default points sampled (area-uniform, with their faces' normals) from the built-in torus; a mesh
file (`.obj`, `.off`, `.stl`, or a `.ply` with faces) is sampled the same way; a point file is read: `.xyz`
(text, 3 columns of positions or 6 of positions and normals) or a `.ply` without faces (its normals are
used when it has them). Points without normals get `ddgjax.reconstruct.estimate_normals`. Prints the
points, the grid, the mesh's size and topology (closed, manifold, genus), the time, and (for a sampled mesh)
the distance from the reconstruction's vertices to the sampled surface; draws the input points beside the
reconstruction coloured by the sample density at its vertices.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

from .._errors import DDGInputError, MeshDataError
from ..io import load_mesh
from ..mesh import check_mesh, torus
from ..optim import nearest_neighbors, sample_points
from ..reconstruct import poisson_reconstruction
from ._common import add_output_argument, positive, write_figure

_DEFAULT_SHAPE = "built-in torus (R = 1, r = 0.4)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `ddgjax reconstruct`; its action is `run`."""
    parser.add_argument(
        "points",
        nargs="?",
        default=None,
        help=f"a point file (.xyz, .ply) or a mesh file to sample; default: the {_DEFAULT_SHAPE}",
    )
    parser.add_argument("--depth", type=positive(int), default=7, help="2^depth grid nodes per axis (default 7)")
    parser.add_argument("--samples", type=positive(int), default=20_000, help="points sampled from a mesh (default 20000)")
    parser.add_argument("--noise", type=float, default=0.0, help="Gaussian noise added to the points, in units of the diagonal")
    parser.add_argument("--screening", type=float, default=60.0, help="the screening weight (default 60; 0: none)")
    parser.add_argument("--estimate-normals", action="store_true", help="ignore the input's normals and estimate them")
    add_output_argument(parser, "reconstruct")
    parser.add_argument("--no-plot", action="store_true", help="print the numbers only")
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Action of `ddgjax reconstruct`: the reconstruction's numbers and figure; 2 on bad input."""
    try:
        name, points, normals, surface = _points(args)
        if args.noise:
            diagonal = np.linalg.norm(points.max(0) - points.min(0))
            points = points + args.noise * diagonal * np.random.default_rng(0).standard_normal(points.shape)
        start = time.perf_counter()
        reconstruction = poisson_reconstruction(
            points, None if args.estimate_normals else normals, depth=args.depth, screening=args.screening
        )
        jax.block_until_ready(reconstruction.value.vertices)
        elapsed = time.perf_counter() - start
    except (DDGInputError, MeshDataError, OSError, ValueError) as error:
        print(f"ddgjax reconstruct: error: {error}", file=sys.stderr)
        return 2
    mesh = reconstruction.value
    report = check_mesh(mesh)
    density = np.asarray(reconstruction.vertex_densities)
    rows = [
        (
            "points",
            f"{name}: {points.shape[0]} points"
            + (" (normals estimated)" if normals is None or args.estimate_normals else "")
            + f", {reconstruction.stats['outliers_removed']} dropped as outliers",
        ),
        ("grid", f"{1 << args.depth}^3 nodes, spacing {float(reconstruction.grid.spacing):.4g}"),
        ("mesh", f"{mesh.n_vertices} vertices, {mesh.n_faces} faces"),
        (
            "topology",
            f"closed {report.is_closed}, manifold {report.is_manifold}, components {report.n_components}, genus {report.genus}",
        ),
        ("density", f"samples per cell at the vertices: min {density.min():.3g}, median {np.median(density):.3g}"),
        ("time", f"{elapsed:.3g} s (compilation included)"),
    ]
    if surface is not None:
        nearest = np.asarray(nearest_neighbors(mesh.vertices, surface).nearest_in_b)
        distance = np.linalg.norm(np.asarray(mesh.vertices) - surface[nearest], axis=1)
        rows.append(
            ("distance", f"vertices to {surface.shape[0]} surface samples: mean {distance.mean():.3g}, max {distance.max():.3g}")
        )
    print("\n".join(f"{key:10s} {value}" for key, value in rows))
    if args.no_plot:
        return 0
    return 0 if _draw(points, reconstruction, name, args) else 2


def _points(args) -> tuple[str, np.ndarray, np.ndarray | None, np.ndarray | None]:
    """`(name, points, normals or None, dense samples of the true surface or None)` of the POINTS_OR_MESH argument."""
    if args.points is None:
        return _sampled(
            _DEFAULT_SHAPE, torus(major_radius=1.0, minor_radius=0.4, n_major=96, n_minor=48, dtype=jnp.float64), args
        )
    path = args.points
    if not os.path.isfile(path):
        raise DDGInputError(f"POINTS_OR_MESH: expected an existing file, got {path!r}")
    suffix = os.path.splitext(path)[1].lower()
    if suffix == ".xyz":
        table = np.loadtxt(path, ndmin=2)
        if table.shape[1] not in (3, 6):
            raise DDGInputError(f"{path}: expected 3 columns (positions) or 6 (positions and normals), got {table.shape[1]}")
        return os.path.basename(path), table[:, :3], table[:, 3:] if table.shape[1] == 6 else None, None
    if suffix == ".ply":
        import trimesh

        loaded = trimesh.load(path, process=False)
        if isinstance(loaded, trimesh.PointCloud):
            normals = loaded.metadata.get("_ply_raw", {}).get("vertex", {}).get("data")
            if normals is not None and all(key in normals.dtype.names for key in ("nx", "ny", "nz")):
                normals = np.stack([normals["nx"], normals["ny"], normals["nz"]], axis=1).astype(float)
            else:
                normals = None
            return os.path.basename(path), np.asarray(loaded.vertices, dtype=float), normals, None
    return _sampled(os.path.basename(path), load_mesh(path, dtype=jnp.float64), args)


def _sampled(name: str, mesh, args):
    sampled = sample_points(mesh, args.samples, key=jax.random.key(0), return_normals=True)
    surface = sample_points(mesh, 100_000, key=jax.random.key(1))
    return f"{name}, sampled", np.asarray(sampled.points), np.asarray(sampled.normals), np.asarray(surface)


def _draw(points: np.ndarray, reconstruction, name: str, args) -> bool:
    # Imported here: matplotlib is only needed when a figure is written.
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from ..plot import OBLIQUE_VIEW, plot_mesh_function, view_rotation

    figure = Figure(figsize=(10.0, 4.6), layout="constrained")
    FigureCanvasAgg(figure)
    left = figure.add_subplot(1, 2, 1)
    screen = points @ view_rotation(*OBLIQUE_VIEW).T
    order = np.argsort(-screen[:, 1], kind="stable")  # farthest first
    left.scatter(screen[order, 0], screen[order, 2], s=1.0, c=-screen[order, 1], cmap="Greys", vmin=-2.5, vmax=1.5)
    left.set_aspect("equal")
    left.set_axis_off()
    left.set_title(f"input: {points.shape[0]} points", fontsize=10)
    right = figure.add_subplot(1, 2, 2)
    mappable = plot_mesh_function(right, reconstruction.value, np.asarray(reconstruction.vertex_densities), cmap="viridis")
    right.set_title(f"Poisson reconstruction, depth {args.depth}: sample density", fontsize=10)
    figure.colorbar(mappable, ax=right, shrink=0.8)
    figure.suptitle(name, fontsize=10)
    return write_figure(figure, args.output, "reconstruct")
