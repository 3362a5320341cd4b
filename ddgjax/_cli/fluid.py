"""`ddgjax fluid [MESH]`: incompressible Euler flow on a closed surface, printed as invariants and drawn.

The flow is `ddgjax.fluids.euler_flow` (the vorticity equation reduced to the first `-k` Laplacian
eigenfunctions, implicit midpoint steps). Two initial vorticities (`--initial`):

- `vortex-pair` (default): two Gaussian vortices of opposite sign, `w = A (G(p, c1) - G(p, c2))` with
  `G(p, c) = exp(-d(p, c)^2 / (2 sigma^2))`, `d` the geodesic distance and `sigma = WIDTH R`, `R` the
  radius of the sphere of the mesh's area. On the built-in unit sphere `d` is the great-circle
  distance and the centres lie symmetric about the equator, so the pair travels east along it; on a
  mesh file they sit at two vertices far apart (the farthest vertex from vertex 0, and the farthest
  from that, by the heat method) and `d` is the heat-method distance.
- `rossby-haurwitz`: the spherical harmonic `P_l^m(z) cos(m lon)` of degree `--degree` and order
  `--order` on a sphere turning at `--rotation` (default 1 for this preset): a Rossby-Haurwitz wave,
  whose pattern turns about z at `-2 Omega / (l (l + 1))` relative to the rotating frame (westward;
  Haurwitz 1940). The turn is measured from the saved vorticity: the phase of its order-`m` component
  `atan2(<w, P_l^m sin(m lon)>, <w, P_l^m cos(m lon)>) / m` (mass-weighted inner products), unwrapped
  over the saved states and fitted by a line against time. Needs a unit sphere (the built-in one or a
  file whose vertices lie on it).

A passive dye (`--dye`) is advected along: latitude bands `sin(5 asin(z))` or a checker
`Im((x + i y)^4) z`, both in normalised coordinates about the vertex centroid and of degree 5, so on a
sphere the basis (degrees up to 7 for `k = 64`) holds them up to the discretisation.

Printed: the mesh, the basis, the time span, kinetic energy and enstrophy (and the dye's `L^2` norm)
of the first and last saved states with their relative drift (energy is conserved without viscosity,
enstrophy also needs no rotation, the dye's norm is always kept), the measured Rossby-Haurwitz rate
against the closed form, and the outcome. Figures (Agg canvas, no display): `--output` a grid of four
saved states (vorticity, and the dye below it), `--frames DIR` one PNG per saved state, `--animation
FILE.gif` all of them through matplotlib's `PillowWriter`.

Reference: B. Haurwitz, "The motion of atmospheric disturbances on the spherical earth" (J. Marine
Research, 1940).
"""

from __future__ import annotations

import argparse
import importlib.util
import math
import os
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

from .._errors import DDGInputError, MeshDataError
from .._results import RESULTS
from ..fluids import euler_flow, fluid_basis
from ..geodesics import heat_distance_solver
from ..mesh import Mesh, icosphere, total_area
from ._common import add_output_argument, load_cli_mesh, positive, write_figure

_SUBDIVISIONS = 4
_DEFAULT_SHAPE = f"built-in unit icosphere({_SUBDIVISIONS})"
_INITIALS = ("vortex-pair", "rossby-haurwitz")
_DYES = ("bands", "checker", "none")
_LATITUDE, _LONGITUDE = 0.4, -75.0
"""The built-in vortex pair's centres: latitudes +-0.4 rad at longitude -75 degrees, left of the view's centre
(`ddgjax.plot.OBLIQUE_VIEW` looks at longitude -30): the pair crosses the view eastwards."""
_PEAK = 2.0
"""The vortices' peak vorticity: the pair travels about 0.15 rad per unit time."""
_PANELS = 4
"""Saved states drawn in the `--output` grid."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `ddgjax fluid`; its action is `run`."""
    parser.add_argument(
        "mesh", nargs="?", default=None, help=f"closed mesh file (.obj, .off, .ply, .stl); default: the {_DEFAULT_SHAPE}"
    )
    parser.add_argument(
        "--initial",
        choices=_INITIALS,
        default="vortex-pair",
        help="initial vorticity: two opposite Gaussian vortices (default), or a Rossby-Haurwitz wave (unit sphere only)",
    )
    parser.add_argument("--tau", type=positive(float), default=0.05, help="time step (default 0.05)")
    parser.add_argument("--steps", type=positive(int), default=200, help="number of time steps (default 200)")
    parser.add_argument(
        "--save-every",
        type=positive(int),
        default=None,
        help="save the state every this many steps; must divide --steps (default: the largest divisor of --steps "
        "that saves at least 20 states)",
    )
    parser.add_argument(
        "--rotation",
        type=float,
        default=None,
        help="the frame's angular velocity Omega about +z (Coriolis parameter 2 Omega z); default 0, 1 for "
        "--initial rossby-haurwitz",
    )
    parser.add_argument("--viscosity", type=float, default=0.0, help="kinematic viscosity nu >= 0 (default 0: inviscid)")
    parser.add_argument("-k", type=int, default=64, help="number of Laplacian eigenfunctions of the basis (default 64)")
    parser.add_argument(
        "--width",
        type=positive(float),
        default=0.3,
        help="vortex-pair: the Gaussians' width over the radius of the sphere of the mesh's area (default 0.3)",
    )
    parser.add_argument(
        "--degree", type=int, default=None, help="rossby-haurwitz: degree l of the spherical harmonic (default 4)"
    )
    parser.add_argument("--order", type=int, default=None, help="rossby-haurwitz: order m, 1 <= m <= l (default 3)")
    parser.add_argument(
        "--dye",
        choices=_DYES,
        default="bands",
        help="passive dye advected along: latitude bands (default), a checker, or none",
    )
    add_output_argument(parser, "fluid", "figure of four saved states")
    parser.add_argument("--frames", default=None, metavar="DIR", help="also write one PNG per saved state into DIR")
    parser.add_argument(
        "--animation", default=None, metavar="FILE.gif", help="also write the saved states as a GIF (needs Pillow)"
    )
    parser.add_argument("--no-plot", action="store_true", help="print the numbers only (no --output figure)")
    parser.add_argument("--up", choices=("x", "y", "z"), default="z", help="the axis that points up in the view")
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Action of `ddgjax fluid`: build the basis and the initial state, run the flow, report, draw; 2 on bad input."""
    try:
        _check(args)
        if args.mesh is None:
            name, mesh = _DEFAULT_SHAPE, icosphere(_SUBDIVISIONS, dtype=jnp.float64)
        else:
            name, mesh = load_cli_mesh(args.mesh)
        start = time.perf_counter()
        if args.initial == "rossby-haurwitz":
            vorticity, initial = _rossby_haurwitz(mesh, args)
        # Before the vortex pair's distances: the basis refuses meshes with a boundary.
        basis = fluid_basis(mesh, args.k)
        if args.initial == "vortex-pair":
            vorticity, initial = _vortex_pair(mesh, args, builtin=args.mesh is None)
        dye = None if args.dye == "none" else _dye(mesh, args.dye)
        flow = euler_flow(
            mesh,
            vorticity,
            tau=args.tau,
            steps=args.steps,
            save_every=args.save_every,
            rotation=args.rotation,
            viscosity=args.viscosity,
            dye=dye,
            basis=basis,
            throw=False,  # a failed run is reported, not raised
        )
        jax.block_until_ready(flow.vorticity)
        elapsed = time.perf_counter() - start
    except (DDGInputError, MeshDataError) as error:
        print(f"ddgjax fluid: error: {error}", file=sys.stderr)
        return 2
    succeeded = bool(flow.result == RESULTS.successful)
    times = np.asarray(flow.times)
    rows = [
        ("mesh", f"{name}: {mesh.n_vertices} vertices, {mesh.n_faces} faces"),
        ("initial", initial),
        ("basis", f"k = {args.k} eigenfunctions, eigenvalues 0 to {float(basis.values[-1]):.4g}"),
        (
            "flow",
            f"{args.steps} steps of tau {args.tau:g}, t = {times[0]:g} to {times[-1]:g}, {times.size} saved states; "
            f"rotation {args.rotation:g}, viscosity {args.viscosity:g}",
        ),
        ("energy", _drift(flow.kinetic_energy) + ("" if args.viscosity else " (conserved)")),
        ("enstrophy", _drift(flow.enstrophy) + ("" if args.viscosity or args.rotation else " (conserved)")),
    ]
    if flow.dye is not None:
        norm = np.sqrt(np.sum(np.asarray(basis.mass) * np.asarray(flow.dye) ** 2, axis=1))
        rows.append(("dye", f"{args.dye}, L2 norm " + _drift(norm) + " (kept)"))
    if args.initial == "rossby-haurwitz":
        rows.append(("haurwitz", _haurwitz_rate(flow, mesh, basis, args) if succeeded else "not measured (the flow failed)"))
    rows += [
        ("time", f"{elapsed:.3g} s (basis, flow, compilation included)"),
        ("result", "successful" if succeeded else f"failure at step {int(flow.first_failure_step)}: {_failure(flow)}"),
    ]
    print("\n".join(f"{key:10s} {value}" for key, value in rows))
    if not _draw_all(flow, mesh, name, args):
        return 2
    return 0 if succeeded else 1


def _check(args) -> None:
    """Options argparse cannot check alone; fills in the preset-dependent defaults."""
    if args.save_every is None:
        args.save_every = next(d for d in range(max(1, args.steps // 20), 0, -1) if args.steps % d == 0)
    elif args.steps % args.save_every:
        raise DDGInputError(f"--save-every: expected a divisor of --steps ({args.steps}), got {args.save_every}")
    if args.rotation is None:
        args.rotation = 1.0 if args.initial == "rossby-haurwitz" else 0.0
    if not math.isfinite(args.rotation):
        raise DDGInputError(f"--rotation: expected a finite number, got {args.rotation}")
    if not (math.isfinite(args.viscosity) and args.viscosity >= 0):
        raise DDGInputError(f"--viscosity: expected a finite number >= 0, got {args.viscosity}")
    for option in ("degree", "order"):
        if getattr(args, option) is not None and args.initial != "rossby-haurwitz":
            raise DDGInputError(f"--{option}: only with --initial rossby-haurwitz")
    args.degree = 4 if args.degree is None else args.degree
    args.order = 3 if args.order is None else args.order
    if args.degree < 1 or not 1 <= args.order <= args.degree:
        raise DDGInputError(f"--degree, --order: expected 1 <= m <= l, got l = {args.degree}, m = {args.order}")
    if args.animation is not None:
        if not args.animation.lower().endswith(".gif"):
            raise DDGInputError(f"--animation: expected a .gif file name, got {args.animation!r}")
        if importlib.util.find_spec("PIL") is None:
            raise DDGInputError("--animation: needs Pillow (pip install pillow); --frames DIR writes PNG frames without it")


def _drift(values) -> str:
    """`first -> last (relative drift d)` of a saved series."""
    values = np.asarray(values)
    first, last = float(values[0]), float(values[-1])
    drift = abs(last - first) / abs(first) if first else abs(last)
    return f"{first:.10g} -> {last:.10g} (relative drift {drift:.2e})"


def _vortex_pair(mesh: Mesh, args, *, builtin: bool) -> tuple[np.ndarray, str]:
    """`(vorticity, description)`: two opposite geodesic Gaussians of peak `_PEAK` (module docstring)."""
    points = np.asarray(mesh.vertices, dtype=float)
    sigma = args.width * math.sqrt(float(total_area(mesh)) / (4 * math.pi))
    if builtin:
        longitude = np.deg2rad(_LONGITUDE)
        centres = [
            [math.cos(latitude) * math.cos(longitude), math.cos(latitude) * math.sin(longitude), math.sin(latitude)]
            for latitude in (_LATITUDE, -_LATITUDE)
        ]
        distances = [np.arccos(np.clip(points @ np.asarray(centre), -1.0, 1.0)) for centre in centres]
        where = f"latitudes +-{_LATITUDE:g} rad at longitude {_LONGITUDE:g} deg"
    else:
        solver = heat_distance_solver(mesh)
        first = int(np.argmax(_finite(solver.distance([0]))))
        from_first = _finite(solver.distance([first]))
        second = int(np.argmax(from_first))
        distances = [from_first, _finite(solver.distance([second]))]
        where = f"vertices {first} and {second}, {from_first[second]:.4g} apart (heat method)"
    gaussians = [np.exp(-(d**2) / (2 * sigma**2)) for d in distances]
    vorticity = _PEAK * (gaussians[0] - gaussians[1])
    return vorticity, f"vortex pair: Gaussians of width {sigma:.3g} and peak vorticity +-{_PEAK:g} at {where}"


def _finite(distance) -> np.ndarray:
    """The heat-method distance with unreachable vertices (`inf`, another component) at 0: never chosen as farthest."""
    distance = np.asarray(distance, dtype=float)
    return np.where(np.isfinite(distance), distance, 0.0)


def _harmonic_pair(mesh: Mesh, degree: int, order: int) -> tuple[np.ndarray, np.ndarray]:
    """`P_l^m(z) cos(m lon)`, `P_l^m(z) sin(m lon)` at the vertices (the second a quarter period turned)."""
    from scipy.special import lpmv

    x, y, z = np.asarray(mesh.vertices, dtype=float).T
    longitude = np.arctan2(y, x)
    legendre = lpmv(order, degree, np.clip(z, -1.0, 1.0))
    return legendre * np.cos(order * longitude), legendre * np.sin(order * longitude)


def _rossby_haurwitz(mesh: Mesh, args) -> tuple[np.ndarray, str]:
    radius = np.linalg.norm(np.asarray(mesh.vertices, dtype=float), axis=1)
    if not np.allclose(radius, 1.0, rtol=0, atol=1e-6):
        raise DDGInputError(
            "--initial rossby-haurwitz: expected a unit sphere centred at the origin (vertex radii from "
            f"{radius.min():.4g} to {radius.max():.4g})"
        )
    cosine, _ = _harmonic_pair(mesh, args.degree, args.order)
    vorticity = cosine / np.abs(cosine).max()  # peak 1
    return vorticity, f"Rossby-Haurwitz wave: P_l^m(z) cos(m lon), l = {args.degree}, m = {args.order}, peak vorticity 1"


def _haurwitz_rate(flow, mesh: Mesh, basis, args) -> str:
    """The pattern's measured angular velocity about z against `-2 Omega / (l (l + 1))` (module docstring)."""
    cosine, sine = _harmonic_pair(mesh, args.degree, args.order)
    weighted = np.asarray(flow.vorticity) * np.asarray(basis.mass)
    phase = np.unwrap(np.arctan2(weighted @ sine, weighted @ cosine)) / args.order
    rate = float(np.polyfit(np.asarray(flow.times), phase, 1)[0])
    closed = -2 * args.rotation / (args.degree * (args.degree + 1))
    error = f"relative error {abs(rate / closed - 1):.2%}" if closed else f"closed form 0, measured {rate:.3g}"
    return f"measured rate {rate:.6g} rad per unit time, closed form -2 Omega / (l (l + 1)) = {closed:.6g} ({error})"


def _dye(mesh: Mesh, pattern: str) -> np.ndarray:
    """The `--dye` pattern (module docstring), values in [-1, 1]."""
    points = np.asarray(mesh.vertices, dtype=float)
    centred = points - points.mean(axis=0)
    x, y, z = (centred / np.linalg.norm(centred, axis=1).max()).T
    if pattern == "bands":
        return np.sin(5 * np.arcsin(np.clip(z, -1.0, 1.0)))
    checker = (4 * x**3 * y - 4 * x * y**3) * z  # Im((x + i y)^4) z
    return checker / np.abs(checker).max()


def _failure(flow) -> str:
    """A failed flow's outcome in words."""
    if flow.result == RESULTS.max_steps_reached:
        return "a time step's Newton solve did not converge (try a smaller --tau)"
    return "non-finite state"


def _draw_all(flow, mesh: Mesh, name: str, args) -> bool:
    """Every figure asked for; False (with the error printed) when one could not be written."""
    if args.no_plot and args.frames is None and args.animation is None:
        return True
    vorticity = np.asarray(flow.vorticity)
    dye = None if flow.dye is None else np.asarray(flow.dye)
    times = np.asarray(flow.times)
    # One colour scale for every state (over the finite values: a failed flow repeats a non-finite state),
    # symmetric about 0 for the vorticity.
    limit = float(np.abs(vorticity[np.isfinite(vorticity)]).max(initial=0.0)) or 1.0
    scales = {"vorticity": ("RdBu_r", -limit, limit)}
    if dye is not None:
        finite = dye[np.isfinite(dye)]
        scales["dye"] = ("PuOr", float(finite.min(initial=-1.0)), float(finite.max(initial=1.0)))

    def draw(figure, index: int, cells: list, colorbar: bool) -> None:
        """State `index`: the vorticity, then the dye, in the subplot `cells` `(rows, columns, position)`."""
        from ..plot import plot_mesh_function

        values = {"vorticity": vorticity[index], "dye": None if dye is None else dye[index]}
        for cell, (kind, (cmap, low, high)) in zip(cells, scales.items(), strict=False):
            axes = figure.add_subplot(*cell)
            mappable = plot_mesh_function(axes, mesh, values[kind], up=args.up, cmap=cmap, vmin=low, vmax=high)
            axes.set_title(f"{kind}, t = {times[index]:.3g}", fontsize=9)
            if colorbar:
                figure.colorbar(mappable, ax=axes, shrink=0.8)

    def single(figure, index: int) -> None:
        """One saved state, vorticity and dye side by side."""
        draw(figure, index, [(1, len(scales), 1), (1, len(scales), 2)], True)

    if not args.no_plot:
        chosen = np.unique(np.linspace(0, times.size - 1, min(_PANELS, times.size)).round().astype(int))
        figure = _figure(3.2 * len(chosen) + 1.2, 3.1 * len(scales) + 0.3)
        for column, index in enumerate(chosen.tolist()):
            # One column per state, the vorticity above the dye; colour bars beside the last column.
            cells = [(len(scales), len(chosen), row * len(chosen) + column + 1) for row in range(len(scales))]
            draw(figure, index, cells, column == len(chosen) - 1)
        figure.suptitle(f"{name}: {_title(args)}", fontsize=10)
        if not write_figure(figure, args.output, "fluid"):
            return False
    size = (4.3 * len(scales), 3.8)
    if args.frames is not None and not _write_frames(times.size, single, size, args):
        return False
    return args.animation is None or _write_animation(times.size, single, size, args)


def _title(args) -> str:
    initial = "vortex pair" if args.initial == "vortex-pair" else f"Rossby-Haurwitz wave (l = {args.degree}, m = {args.order})"
    return f"{initial}, rotation {args.rotation:g}, viscosity {args.viscosity:g}, k = {args.k}"


def _figure(width: float, height: float):
    # Imported here: matplotlib is only needed when a figure is written.
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    figure = Figure(figsize=(width, height), layout="constrained")
    FigureCanvasAgg(figure)
    return figure


def _write_frames(count: int, single, size: tuple[float, float], args) -> bool:
    """`DIR/frame_0000.png`, ... one per saved state; False (error printed) when DIR cannot be written."""
    try:
        os.makedirs(args.frames, exist_ok=True)
        for index in range(count):
            figure = _figure(*size)
            single(figure, index)
            figure.savefig(os.path.join(args.frames, f"frame_{index:04d}.png"), dpi=90)
    except OSError as error:
        print(f"ddgjax fluid: error: --frames: could not write into {args.frames!r}: {error}", file=sys.stderr)
        return False
    print(f"{count} frames written to {args.frames}")
    return True


def _write_animation(count: int, single, size: tuple[float, float], args) -> bool:
    """The saved states as a GIF through matplotlib's `PillowWriter`; False (error printed) on failure."""
    from matplotlib.animation import PillowWriter

    figure = _figure(*size)
    try:
        with PillowWriter(fps=8).saving(figure, args.animation, dpi=80) as writer:
            for index in range(count):
                figure.clear()
                single(figure, index)
                writer.grab_frame()
    except OSError as error:
        print(f"ddgjax fluid: error: --animation: could not write {args.animation!r}: {error}", file=sys.stderr)
        return False
    print(f"animation of {count} frames written to {args.animation}")
    return True
