"""`ddgjax deform [MESH]`: move handles of a mesh, deform the rest by ARAP and / or k-harmonic deformation, draw both.

Defaults to a built-in shape (no file needed): an open cylinder of radius 0.5 and height 2 standing
on the up axis. The handles are picked by height along `--up` for the built-in shape and a file
alike: the vertices in the lowest `--band` of the height range stay where they are, those in the
highest `--band` are turned by `--turn` degrees about the up axis (through their centroid), then
lifted by `--lift` along it and shifted by `--shift` sideways. The default, a quarter turn of the top
(`--method both`), shows the difference: ARAP twists the cylinder keeping its cross-sections nearly
round, while the biharmonic displacement, which interpolates the handles' rotation linearly, pinches
the middle (the "candy wrapper").
"""

from __future__ import annotations

import argparse
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

from .._errors import DDGInputError, MeshDataError
from .._results import RESULTS
from ..deform import arap, biharmonic_deformation
from ..mesh import Mesh, cylinder
from ._common import add_output_argument, load_cli_mesh, write_figure

_DEFAULT_SHAPE = "built-in cylinder (radius 0.5, height 2, 32 x 16 quads split in two) standing on the up axis"
_AXES = {"x": 0, "y": 1, "z": 2}
_ORDER_NAMES = {1: "harmonic", 2: "biharmonic", 3: "triharmonic"}
# The outcomes named in the table (RESULTS names); any other failure is a "solver failure".
_FAILURES = ("max_steps_reached", "nonfinite")


def standing_cylinder(up: str = "z") -> Mesh:
    """The built-in shape: `cylinder(32, 16, radius=0.5, height=2)` with its axis along `up` (coordinates cycled)."""
    mesh = cylinder(32, 16, radius=0.5, height=2.0, dtype=jnp.float64)
    return mesh.with_vertices(np.roll(np.asarray(mesh.vertices), _AXES[up] - 2, axis=1))


def fixed_and_moved_vertices(vertices: np.ndarray, up: str, band: float, lift: float, turn: float, shift: float):
    """`(fixed, moved, targets)`: the vertices in the lowest / highest `band` of the height range along `up`,
    and the moved ones' new positions (turned by `turn` degrees about the up axis through their centroid,
    then lifted by `lift` along it and shifted by `shift` along the next axis, x -> y -> z -> x)."""
    axis = _AXES[up]
    height = vertices[:, axis]
    low, high = height.min(), height.max()
    span = high - low
    if not span > 0:
        raise DDGInputError(f"--up: the mesh has no extent along {up}; choose another axis")
    fixed = np.flatnonzero(height <= low + band * span)
    moved = np.flatnonzero(height >= high - band * span)
    # A right-handed rotation about `axis`, acting on the two other coordinates in cyclic order.
    a, b = (axis + 1) % 3, (axis + 2) % 3
    angle = np.deg2rad(turn)
    centre = vertices[moved].mean(axis=0)
    offset = vertices[moved] - centre
    targets = vertices[moved].copy()
    targets[:, a] = centre[a] + np.cos(angle) * offset[:, a] - np.sin(angle) * offset[:, b]
    targets[:, b] = centre[b] + np.sin(angle) * offset[:, a] + np.cos(angle) * offset[:, b]
    targets[:, axis] += lift
    targets[:, a] += shift
    return fixed, moved, targets


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `ddgjax deform`; its action is `run`."""
    parser.add_argument(
        "mesh",
        nargs="?",
        default=None,
        help=f"triangle mesh file (.obj, .off, .ply, .stl); default: the {_DEFAULT_SHAPE}",
    )
    parser.add_argument(
        "--method",
        choices=("arap", "biharmonic", "both"),
        default="arap",
        help="as-rigid-as-possible (default), k-harmonic displacement (-k), or both side by side",
    )
    parser.add_argument(
        "-k", type=int, choices=(1, 2, 3), default=2, help="order of the k-harmonic deformation: 1, 2 (default) or 3"
    )
    parser.add_argument("--up", choices=("x", "y", "z"), default="z", help="the up axis: handles are picked along it")
    parser.add_argument(
        "--band",
        type=float,
        default=0.1,
        help="handles: the vertices in the lowest BAND of the height range are fixed, those in the highest BAND "
        "are moved (default 0.1, in (0, 0.5))",
    )
    parser.add_argument("--turn", type=float, default=90.0, help="degrees the top handles turn about the up axis (default 90)")
    parser.add_argument("--lift", type=float, default=0.0, help="how far the top handles move along the up axis (default 0)")
    parser.add_argument(
        "--shift",
        type=float,
        default=0.0,
        help="how far the top handles move sideways, along the axis after --up (z -> x, x -> y, y -> z; default 0)",
    )
    parser.add_argument("--steps", type=int, default=5000, help="the most ARAP local-global steps (default 5000, arap's)")
    add_output_argument(parser, "deform")
    parser.add_argument("--no-plot", action="store_true", help="print the numbers only")
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Action of `ddgjax deform`: pick and move the handles, deform, report, draw; 2 on bad input."""
    try:
        if not 0 < args.band < 0.5:
            raise DDGInputError(f"--band: expected a fraction in (0, 0.5), got {args.band}")
        if args.steps < 1:
            raise DDGInputError(f"--steps: expected at least 1, got {args.steps}")
        for option in ("turn", "lift", "shift"):
            if not np.isfinite(getattr(args, option)):
                raise DDGInputError(f"--{option}: expected a finite number, got {getattr(args, option)}")
        if args.mesh is None:
            name, mesh = "built-in cylinder", standing_cylinder(args.up)
        else:
            name, mesh = load_cli_mesh(args.mesh)
        rest = np.asarray(mesh.vertices, dtype=float)
        fixed, moved, targets = fixed_and_moved_vertices(rest, args.up, args.band, args.lift, args.turn, args.shift)
        vertices = np.concatenate([fixed, moved])
        values = np.concatenate([rest[fixed], targets])
        methods = ("arap", "biharmonic") if args.method == "both" else (args.method,)
        results = [_deform(method, mesh, vertices, values, args) for method in methods]
    except (DDGInputError, MeshDataError) as error:
        print(f"ddgjax deform: error: {error}", file=sys.stderr)
        return 2
    print(f"{'mesh':10s} {name}: {mesh.n_vertices} vertices, {mesh.n_faces} faces")
    print(
        f"{'handles':10s} {fixed.size} fixed (lowest {args.band:g} along {args.up}), {moved.size} moved "
        f"(turn {args.turn:g} deg, lift {args.lift:g}, shift {args.shift:g})"
    )
    print(f"{'method':15s} {'steps':>6s}  {'energy / residual':24s} {'time':>9s}  {'max |d|':>9s}  outcome")
    for label, steps, measure, elapsed, positions, outcome in results:
        largest = np.linalg.norm(positions - rest, axis=1).max()
        print(f"{label:15s} {steps:6d}  {measure:24s} {elapsed:8.3g}s  {largest:9.4g}  {outcome}")
    if not args.no_plot and not _draw(mesh, fixed, moved, results, name, args):
        return 2
    return 0


def _deform(method: str, mesh: Mesh, vertices: np.ndarray, values: np.ndarray, args):
    """`(label, steps, energy or residual text, seconds, positions, outcome text)` of one method."""
    start = time.perf_counter()
    if method == "arap":
        solution = arap(mesh, fixed_vertices=vertices, fixed_values=values, max_steps=args.steps, throw=False)
        label, measure = "arap", f"energy {float(solution.stats['energy']):.6g}"
    else:
        solution = biharmonic_deformation(mesh, fixed_vertices=vertices, fixed_values=values, order=args.k, throw=False)
        label, measure = f"{_ORDER_NAMES[args.k]} k={args.k}", f"residual {float(solution.stats['residual']):.3g}"
    positions = np.asarray(jax.block_until_ready(solution.value))
    elapsed = time.perf_counter() - start
    failure = next((name for name in _FAILURES if bool(solution.result == getattr(RESULTS, name))), "")
    outcome = "successful" if bool(solution.result == RESULTS.successful) else f"failed: {failure or 'solver failure'}"
    return label, int(solution.stats["num_steps"]), measure, elapsed, positions, outcome


def _draw(mesh: Mesh, fixed: np.ndarray, moved: np.ndarray, results, name: str, args) -> bool:
    # Imported here: matplotlib is only needed when a figure is written.
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.colors import ListedColormap
    from matplotlib.figure import Figure

    from ..plot import plot_mesh_function

    rest = np.asarray(mesh.vertices, dtype=float)
    # One role per face, so no face between a handle and the free part takes a handle's colour.
    roles = np.zeros(mesh.n_vertices)
    roles[fixed], roles[moved] = 1.0, 2.0
    corners = roles[np.asarray(mesh.faces)]
    roles = np.where(corners.min(axis=1) == corners.max(axis=1), corners[:, 0], 0.0)
    lengths = [np.linalg.norm(positions - rest, axis=1) for *_, positions, _ in results]
    largest = max(float(length.max()) for length in lengths) or 1.0
    figure = Figure(figsize=(4.2 * (1 + len(results)) + 1.0, 5.4), layout="constrained")
    FigureCanvasAgg(figure)
    axes = figure.add_subplot(1, 1 + len(results), 1)
    roles_cmap = ListedColormap(["0.85", "tab:blue", "tab:orange"])
    plot_mesh_function(axes, mesh, roles, up=args.up, cmap=roles_cmap, vmin=-0.5, vmax=2.5)
    axes.set_title("rest shape: fixed (blue) and moved (orange) handles", fontsize=10)
    panels = []
    for index, ((label, *_, positions, _), length) in enumerate(zip(results, lengths, strict=True)):
        axes = figure.add_subplot(1, 1 + len(results), index + 2)
        panels.append(axes)
        shown = mesh.with_vertices(positions)
        collection = plot_mesh_function(axes, shown, length, up=args.up, cmap="viridis", vmin=0.0, vmax=largest)
        axes.set_title(f"{label}: coloured by displacement length", fontsize=10)
    figure.colorbar(collection, ax=panels, shrink=0.7, label="|displacement|")
    figure.suptitle(
        f"{name}: lowest {args.band:g} fixed, highest {args.band:g} turned {args.turn:g} deg, lifted {args.lift:g}, "
        f"shifted {args.shift:g}",
        fontsize=10,
    )
    return write_figure(figure, args.output, "deform")
