"""`ddgjax fields [MESH]`: the globally smoothest n-direction field of a mesh, drawn with its singularities.

Defaults to a built-in shape (no file needed): the unit icosphere(3) and a cross field (`n = 4`), whose
singularities are eight faces of index +1/4 (they sum to the sphere's Euler characteristic, 2).
A mesh file is read with `ddgjax.io.load_mesh`; `--align` aligns the field to the principal
curvature directions (Knoeppel et al. 2013) instead of taking the smoothest one.
"""

from __future__ import annotations

import argparse
import sys
import time
from fractions import Fraction

import jax
import jax.numpy as jnp
import numpy as np

from .._errors import DDGInputError, MeshDataError
from ..fields import field_singularities, field_to_vectors, principal_curvature_alignment, smoothest_field
from ..mesh import Mesh, icosphere
from ._common import add_output_argument, load_cli_mesh, write_figure

_DEFAULT_SHAPE = "built-in icosphere(3)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `ddgjax fields`; its action is `run`."""
    parser.add_argument(
        "mesh", nargs="?", default=None, help=f"mesh file (.obj, .off, .ply, .stl); default: the {_DEFAULT_SHAPE}"
    )
    parser.add_argument("-n", type=int, default=4, help="number of directions: 1 vector, 2 line, 4 cross field (default 4)")
    parser.add_argument(
        "--align", type=float, default=None, metavar="WEIGHT", help="align to the principal curvature directions with this weight"
    )
    add_output_argument(parser, "fields")
    parser.add_argument("--no-plot", action="store_true", help="print the numbers only")
    parser.add_argument("--up", choices=("x", "y", "z"), default="z", help="the axis that points up in the view")
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Action of `ddgjax fields`: the field, its energy and singularities, drawn; 2 on bad input."""
    try:
        name, mesh = (_DEFAULT_SHAPE, icosphere(3, dtype=jnp.float64)) if args.mesh is None else load_cli_mesh(args.mesh)
        start = time.perf_counter()
        if args.align is None:
            result = smoothest_field(mesh, n=args.n)
        else:
            alignment = principal_curvature_alignment(mesh, n=args.n)
            result = smoothest_field(mesh, n=args.n, alignment=alignment, alignment_weight=args.align)
        indices = np.asarray(jax.block_until_ready(field_singularities(mesh, result.field, n=args.n)))
        elapsed = time.perf_counter() - start
    except (DDGInputError, MeshDataError) as error:
        print(f"ddgjax fields: error: {error}", file=sys.stderr)
        return 2
    counts = _index_counts(indices, args.n)
    kind = {1: "vector", 2: "line", 4: "cross"}.get(args.n, f"{args.n}-direction")
    rows = [
        (
            "mesh",
            f"{name}: {mesh.n_vertices} vertices, {mesh.n_faces} faces, Euler characteristic {mesh.topology.euler_characteristic}",
        ),
        (
            "field",
            f"smoothest {kind} field"
            + ("" if args.align is None else f", aligned to principal curvature (weight {args.align:g})"),
        ),
        ("time", f"{elapsed:.3g} s (compilation included)"),
        ("energy", f"{float(result.energy):.6g}"),
        ("singular", ", ".join(f"{count} x {index}" for index, count in counts.items()) or "none"),
        ("sum", f"{_signed(Fraction(round(float(indices.sum()) * args.n), args.n))} (Poincare-Hopf: the Euler characteristic)"),
    ]
    print("\n".join(f"{key:10s} {value}" for key, value in rows))
    if not args.no_plot and not _draw(mesh, result.field, indices, name, rows[1][1], args):
        return 2
    return 0


def _index_counts(indices: np.ndarray, n: int) -> dict[str, int]:
    """`{"+1/4": 8, ...}`: how many faces carry each non-zero index (multiples of `1 / n`)."""
    multiples = np.rint(indices * n).astype(np.int64)
    values, counts = np.unique(multiples[multiples != 0], return_counts=True)
    return {_signed(Fraction(int(v), n)): int(c) for v, c in zip(values, counts)}


def _signed(value: Fraction) -> str:
    return f"+{value}" if value > 0 else str(value)


def _draw(mesh: Mesh, field, indices: np.ndarray, name: str, description: str, args) -> bool:
    # Imported here: matplotlib is only needed when a figure is written.
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from ..plot import plot_direction_field, plot_mesh_function

    figure = Figure(figsize=(7.5, 6.5), layout="constrained")
    FigureCanvasAgg(figure)
    axes = figure.add_subplot(1, 1, 1)
    limit = max(float(np.abs(indices).max()), 1.0 / args.n)
    collection = plot_mesh_function(axes, mesh, indices, up=args.up, cmap="RdBu_r", vmin=-limit, vmax=limit, shading="flat")
    plot_direction_field(axes, mesh, np.asarray(field_to_vectors(mesh, field, n=args.n)), up=args.up)
    figure.colorbar(collection, ax=axes, shrink=0.7, label="singularity index per face")
    axes.set_title(f"{name}: {description}", fontsize=10)
    return write_figure(figure, args.output, "fields")
