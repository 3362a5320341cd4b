"""`ddgjax spectrum [MESH]`: the first Laplacian eigenfunctions, printed as numbers and drawn on the mesh,
and what it shares with `ddgjax geodesic` (`ddgjax._cli.geodesic`): the MESH argument and its options, the
panels of functions on the mesh.

Both default to a built-in shape (no file needed): the torus, whose distances wrap around its hole and
whose eigenfunctions come in pairs. A mesh file is read with `ddgjax.io.load_mesh`.
"""

from __future__ import annotations

import argparse
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

from .._errors import DDGInputError, MeshDataError
from ..mesh import Mesh, torus
from ..spectral import eigenpairs
from ._common import add_output_argument, load_cli_mesh, write_figure

_DEFAULT_SHAPE = "built-in torus(major_radius=1.0, minor_radius=0.4, n_major=64, n_minor=24)"


def add_spectrum_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `ddgjax spectrum`; its action is `run_spectrum`."""
    _common(parser, "spectrum")
    parser.add_argument("-k", type=int, default=8, help="number of eigenpairs (default 8; up to 6 non-constant ones drawn)")
    parser.add_argument("--boundary", choices=("neumann", "dirichlet"), default="neumann", help="boundary condition")
    parser.set_defaults(run=run_spectrum)


def _common(parser: argparse.ArgumentParser, command: str) -> None:
    parser.add_argument(
        "mesh", nargs="?", default=None, help=f"mesh file (.obj, .off, .ply, .stl); default: the {_DEFAULT_SHAPE}"
    )
    add_output_argument(parser, command)
    parser.add_argument("--no-plot", action="store_true", help="print the numbers only")
    parser.add_argument("--up", choices=("x", "y", "z"), default="z", help="the axis that points up in the view")


def _mesh(args) -> tuple[str, Mesh]:
    if args.mesh is None:
        return _DEFAULT_SHAPE, torus(major_radius=1.0, minor_radius=0.4, n_major=64, n_minor=24, dtype=jnp.float64)
    return load_cli_mesh(args.mesh)


def _distance_summary(distance: np.ndarray) -> str:
    """Max and mean over the reached vertices; the others (components without the source) are `inf`."""
    reached = distance[np.isfinite(distance)]
    unreached = distance.size - reached.size
    summary = f"max {reached.max():.4g}, mean {reached.mean():.4g}"
    return summary + (f" over the reached vertices ({unreached} unreachable: inf)" if unreached else "")


def run_spectrum(args: argparse.Namespace) -> int:
    """Action of `ddgjax spectrum`: the smallest eigenpairs of the Laplacian; 2 on bad input."""
    try:
        name, mesh = _mesh(args)
        start = time.perf_counter()
        values, vectors = jax.block_until_ready(eigenpairs(mesh, args.k, boundary=args.boundary))
        elapsed = time.perf_counter() - start
    except (DDGInputError, MeshDataError) as error:
        print(f"ddgjax spectrum: error: {error}", file=sys.stderr)
        return 2
    values, vectors = np.asarray(values), np.asarray(vectors)
    print(f"mesh       {name}: {mesh.n_vertices} vertices, {mesh.n_faces} faces")
    print(f"time       {elapsed:.3g} s (compilation included)")
    print("eigenvalues " + " ".join(f"{value:.6g}" for value in values))
    if not args.no_plot:
        # Constant eigenfunctions (lambda = 0, one per closed component) carry no picture: drawn from the first other one.
        first = int(np.argmax(values > 1e-8 * max(values.max(), 1e-300))) if values.max() > 0 else 0
        panels = [(f"$\\phi_{{{i}}}$, $\\lambda$ = {values[i]:.4g}", vectors[:, i]) for i in range(first, min(first + 6, args.k))]
        if not _draw(mesh, panels, name, args):
            return 2
    return 0


def _draw(mesh: Mesh, panels, name: str, args, bands: int | None = None) -> bool:
    # Imported here: matplotlib is only needed when a figure is written.
    from matplotlib import colormaps
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from ..plot import plot_mesh_function

    columns = min(3, len(panels))
    rows = -(-len(panels) // columns)
    # At least 7 inches wide: a one-panel figure must still hold the mesh's name as its title.
    figure = Figure(figsize=(max(4.6 * columns + 0.6, 7.0), 4.2 * rows), layout="constrained")
    FigureCanvasAgg(figure)
    # Bands of one colour each: their edges are the isolines.
    cmap = colormaps["viridis"].resampled(bands) if bands else "RdBu_r"
    for index, (title, values) in enumerate(panels):
        axes = figure.add_subplot(rows, columns, index + 1)
        limit = None if bands else np.abs(values).max()
        collection = plot_mesh_function(axes, mesh, values, up=args.up, cmap=cmap, vmin=None if bands else -limit, vmax=limit)
        axes.set_title(title, fontsize=10)
        figure.colorbar(collection, ax=axes, shrink=0.8)
    figure.suptitle(name, fontsize=10)
    return write_figure(figure, args.output, args.command)
