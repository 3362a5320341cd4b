"""`ddgjax param [MESH]`: flatten a disk-topology mesh, print its distortion and draw it with a checkerboard.

Defaults to a built-in shape (no file needed): the unit hemisphere, `disk(24)` lifted onto the sphere
(the polar angle proportional to the radius), flattened by Boundary First Flattening with `u = 0` on
the boundary (for a hemisphere, the stereographic projection). A mesh file is read with
`ddgjax.io.load_mesh`; it must be a topological disk.
"""

from __future__ import annotations

import argparse
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

from .._errors import DDGInputError, MeshDataError
from ..mesh import Mesh, disk
from ..param import boundary_first_flattening, harmonic_map, lscm, map_distortion, spectral_conformal_map, tutte_embedding
from ._common import add_output_argument, load_cli_mesh, write_figure

_DEFAULT_SHAPE = "built-in hemisphere (disk(24) lifted onto the unit sphere)"
# Each method: the call that flattens, and a line on what it keeps.
METHODS = {
    "bff": (boundary_first_flattening, "Boundary First Flattening, u = 0 on the boundary (boundary lengths kept)"),
    "bff-disk": (lambda mesh: boundary_first_flattening(mesh, shape="circle"), "Boundary First Flattening onto a disk"),
    "bff-rectangle": (
        lambda mesh: boundary_first_flattening(mesh, shape="rectangle"),
        "Boundary First Flattening onto a rectangle (four right-angle corners)",
    ),
    "lscm": (lscm, "least squares conformal map, two pinned boundary vertices"),
    "spectral": (spectral_conformal_map, "spectral conformal map (no pins)"),
    "harmonic": (harmonic_map, "harmonic map, boundary on the circle by arc length"),
    "tutte": (tutte_embedding, "Tutte embedding (uniform weights), boundary on the circle"),
}


def hemisphere(n_rings: int = 24) -> Mesh:
    """The unit upper hemisphere as a disk-topology mesh: `disk(n_rings)` with `(r, phi) -> (theta = r pi / 2, phi)`."""
    flat = np.asarray(disk(n_rings, dtype=jnp.float64).vertices)
    r, phi = np.hypot(flat[:, 0], flat[:, 1]), np.arctan2(flat[:, 1], flat[:, 0])
    theta = r * np.pi / 2
    lifted = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], axis=1)
    return disk(n_rings, dtype=jnp.float64).with_vertices(lifted)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `ddgjax param`; its action is `run`."""
    parser.add_argument(
        "mesh", nargs="?", default=None, help=f"disk-topology mesh file (.obj, .off, .ply, .stl); default: the {_DEFAULT_SHAPE}"
    )
    parser.add_argument("--method", choices=tuple(METHODS), default="bff", help="the flattening (default bff)")
    parser.add_argument("--checks", type=int, default=10, help="checkerboard squares across the map (default 10)")
    add_output_argument(parser, "param")
    parser.add_argument("--no-plot", action="store_true", help="print the numbers only")
    parser.add_argument("--up", choices=("x", "y", "z"), default="z", help="the axis that points up in the 3D view")
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Action of `ddgjax param`: flatten, report distortion and flips, draw; 2 on bad input."""
    flatten, description = METHODS[args.method]
    try:
        if args.checks < 1:
            raise DDGInputError(f"--checks: expected at least 1, got {args.checks}")
        name, mesh = ("built-in hemisphere", hemisphere()) if args.mesh is None else load_cli_mesh(args.mesh)
        start = time.perf_counter()
        uv = np.asarray(jax.block_until_ready(flatten(mesh)))
        elapsed = time.perf_counter() - start
    except (DDGInputError, MeshDataError) as error:
        print(f"ddgjax param: error: {error}", file=sys.stderr)
        return 2
    distortion = map_distortion(mesh, uv)
    conformal = np.asarray(distortion.conformal_distortion)
    area = np.asarray(distortion.area_ratio)
    rows = [
        ("mesh", f"{name}: {mesh.n_vertices} vertices, {mesh.n_faces} faces"),
        ("method", description),
        ("time", f"{elapsed:.3g} s (compilation included)"),
        ("flipped", f"{int(distortion.n_flipped)} faces"),
        (
            "conformal",
            f"quasi-conformal ratio: area-weighted mean {float(distortion.mean_conformal_distortion):.4g}, max {conformal.max():.4g}",
        ),
        ("area", f"area ratio (1 = kept): min {area.min():.3g}, max {area.max():.3g}"),
    ]
    print("\n".join(f"{key:10s} {value}" for key, value in rows))
    if not args.no_plot and not _draw(mesh, uv, conformal, name, description, args):
        return 2
    return 0


def checkerboard(uv: np.ndarray, faces: np.ndarray, checks: int) -> np.ndarray:
    """`(nf,)` 0 / 1: the colour of the checkerboard square (`checks` across the map) holding each face's
    centroid in the map (a face-sized approximation of the texture: edges of the squares follow faces)."""
    low, size = uv.min(axis=0), max(float(np.ptp(uv, axis=0).max()), np.finfo(float).tiny)
    cells = np.floor((uv[faces].mean(axis=1) - low) / size * checks).astype(np.int64)
    return (cells.sum(axis=1) % 2).astype(float)


def _draw(mesh: Mesh, uv: np.ndarray, conformal: np.ndarray, name: str, description: str, args) -> bool:
    # Imported here: matplotlib is only needed when a figure is written.
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.colors import ListedColormap
    from matplotlib.figure import Figure

    from ..plot import plot_mesh_function

    checks = checkerboard(uv, np.asarray(mesh.faces), args.checks)
    two_greys = ListedColormap(["0.95", "0.45"])
    flat = mesh.with_vertices(np.column_stack([uv, np.zeros(len(uv))]))
    figure = Figure(figsize=(15, 4.8), layout="constrained")
    FigureCanvasAgg(figure)
    panels = [
        ("the surface, textured through the map", mesh, checks, two_greys, (0.0, 1.0)),
        ("the map", flat, checks, two_greys, (0.0, 1.0)),
        ("quasi-conformal ratio per face", flat, np.minimum(conformal, 10.0), "magma_r", (1.0, None)),
    ]
    for index, (title, shown, values, cmap, (vmin, vmax)) in enumerate(panels):
        axes = figure.add_subplot(1, 3, index + 1)
        collection = plot_mesh_function(axes, shown, values, up=args.up, cmap=cmap, vmin=vmin, vmax=vmax)
        axes.set_title(title, fontsize=10)
        if index == 2:
            figure.colorbar(collection, ax=axes, shrink=0.8)
    figure.suptitle(f"{name}: {description}", fontsize=10)
    return write_figure(figure, args.output, "param")
