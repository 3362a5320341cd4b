"""`ddgjax optimize [--example willmore|catenoid|fit]`: one shape-optimisation example on built-in shapes.

- `willmore` (default): a bumpy icosphere(3) minimises its Willmore energy at fixed enclosed volume
  with Large Steps; it becomes round, the energy falls to the round icosphere's own discrete value
  (`4 pi` in the limit).
- `catenoid`: a cylinder between two unit rings (half-separation 0.5) minimises its area with the
  rings held; the profile tends to the catenoid `r = a cosh(z / a)`.
- `fit`: PyTorch3D's "deform a source mesh to fit a target" loop: an icosphere(2) fits points sampled
  from an ellipsoid by Chamfer distance plus edge, normal-consistency and Laplacian regularisers.

Prints the loss before and after with the analytic comparison and writes a figure: the shape before
and after, and the loss curve.
"""

from __future__ import annotations

import argparse
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np
import optax
import scipy.optimize

from .._errors import DDGInputError
from ..mesh import Mesh, cylinder, icosphere
from ..optim import (
    adam_uniform,
    chamfer_distance,
    enclosed_volume,
    mesh_fitting_loss,
    minimize_shape,
    sample_points,
    total_area,
    willmore_energy,
)
from ._common import add_output_argument, write_figure

EXAMPLES = ("willmore", "catenoid", "fit")
DEFAULT_STEPS = {"willmore": 300, "catenoid": 400, "fit": 300}
CATENOID_HALF_HEIGHT = 0.5  # below the critical 0.6627, where the catenoid stops existing


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `ddgjax optimize`; its action is `run`."""
    parser.add_argument("--example", choices=EXAMPLES, default="willmore", help="the example to run (default willmore)")
    parser.add_argument("--steps", type=int, default=None, help="optimiser steps (default: 300, 400 for catenoid)")
    add_output_argument(parser, "optimize")
    parser.add_argument("--no-plot", action="store_true", help="print the numbers only")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.set_defaults(run=run)


def bumpy_sphere(subdivisions: int = 3) -> Mesh:
    """icosphere(subdivisions) with its radius modulated by smooth bumps (a non-round genus-0 shape)."""
    V = np.asarray(icosphere(subdivisions, dtype=jnp.float64).vertices)
    x, y, z = V.T
    scale = 1 + 0.15 * np.sin(3 * x) * np.sin(3 * y) * np.sin(3 * z) + 0.1 * (x * x - y * y)
    return icosphere(subdivisions, dtype=jnp.float64).with_vertices(V * scale[:, None])


def run(args: argparse.Namespace) -> int:
    """Action of `ddgjax optimize`: run the example, compare with the analytic answer, draw; 2 on bad input."""
    steps = DEFAULT_STEPS[args.example] if args.steps is None else args.steps
    if steps < 1:
        print(f"ddgjax optimize: error: --steps: expected at least 1, got {steps}", file=sys.stderr)
        return 2
    try:
        began = time.perf_counter()
        start, result, rows, (label, reference) = _EXAMPLES[args.example](steps, not args.no_progress)
        seconds = time.perf_counter() - began
    except DDGInputError as error:
        print(f"ddgjax optimize: error: {error}", file=sys.stderr)
        return 2
    history = np.asarray(result.loss_history)
    rows = [
        ("example", args.example),
        ("mesh", f"{start.n_vertices} vertices, {start.n_faces} faces"),
        ("steps", f"{steps} ({seconds:.2f} s, compilation included)"),
        ("loss", f"{history[0]:.6g} -> {history[-1]:.6g}"),
        *rows,
    ]
    print("\n".join(f"{key:10s} {value}" for key, value in rows))
    if not args.no_plot and not _draw(start, result.mesh(), history, label, reference, args):
        return 2
    return 0


def _willmore(steps: int, progress: bool):
    start = bumpy_sphere()
    optimizer = adam_uniform(optax.exponential_decay(3e-2, steps, 0.01))
    result = minimize_shape(willmore_energy, start, steps=steps, optimizer=optimizer, constraint="volume", progress=progress)
    V = np.asarray(result.value)
    radii = np.linalg.norm(V - V.mean(axis=0), axis=1)
    round_value = float(willmore_energy(icosphere(3, dtype=jnp.float64)))
    rows = [
        ("target", f"4 pi = {4 * np.pi:.6g}; the round icosphere(3)'s discrete energy {round_value:.6g}"),
        ("round", f"radii spread {(radii.max() - radii.min()) / radii.mean():.2%} of the mean radius"),
        ("volume", f"{float(enclosed_volume(start)):.10g} -> {float(enclosed_volume(result.mesh())):.10g} (held)"),
    ]
    return start, result, rows, ("4 pi", 4 * np.pi)


def _catenoid(steps: int, progress: bool):
    h = CATENOID_HALF_HEIGHT
    a = scipy.optimize.brentq(lambda a: a * np.cosh(h / a) - 1, 0.6, 1.0)  # the stable (larger) root
    start = cylinder(64, 16, radius=1.0, height=2 * h, dtype=jnp.float64)
    rings = start.topology.boundary_vertices
    optimizer = adam_uniform(optax.exponential_decay(3e-2, steps, 0.01))
    result = minimize_shape(total_area, start, steps=steps, optimizer=optimizer, fixed_vertices=rings, progress=progress)
    V = np.asarray(result.value)
    error = np.abs(np.hypot(V[:, 0], V[:, 1]) - a * np.cosh(V[:, 2] / a)).max()
    area = np.pi * a * (2 * h + a * np.sinh(2 * h / a))
    rows = [
        ("target", f"catenoid r = a cosh(z / a), a = {a:.6f}: area {area:.6g}"),
        ("profile", f"max |r - a cosh(z / a)| = {error:.3g}"),
    ]
    return start, result, rows, ("the catenoid's area", area)


def _fit(steps: int, progress: bool):
    target_mesh = icosphere(4, dtype=jnp.float64)
    target_mesh = target_mesh.with_vertices(target_mesh.vertices * jnp.array([1.3, 1.0, 0.7]))
    target = sample_points(target_mesh, 2000, key=jax.random.key(1))
    loss = mesh_fitting_loss(target, n_samples=2000, edge_weight=0.05)

    start = icosphere(2, dtype=jnp.float64)
    optimizer = adam_uniform(optax.exponential_decay(5e-2, steps, 0.1))
    result = minimize_shape(loss, start, steps=steps, optimizer=optimizer, key=jax.random.key(0), progress=progress)
    reference = sample_points(target_mesh, 2000, key=jax.random.key(8))
    measure = lambda mesh: float(chamfer_distance(sample_points(mesh, 2000, key=jax.random.key(7)), reference))
    rows = [
        (
            "chamfer",
            f"{measure(start):.3g} -> {measure(result.mesh()):.3g}; between two samplings of the target {measure(target_mesh):.3g}",
        ),
    ]
    return start, result, rows, ("", None)


_EXAMPLES = {"willmore": _willmore, "catenoid": _catenoid, "fit": _fit}


def _draw(start: Mesh, final: Mesh, history: np.ndarray, label, reference, args) -> bool:
    # Imported here: matplotlib is only needed when a figure is written.
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from ..plot import plot_mesh_function

    figure = Figure(figsize=(14, 4.4), layout="constrained")
    FigureCanvasAgg(figure)
    for index, (title, mesh) in enumerate((("before", start), ("after", final))):
        axes = figure.add_subplot(1, 3, index + 1)
        V = np.asarray(mesh.vertices)
        plot_mesh_function(
            axes, mesh, V[:, 2], cmap="viridis", vmin=-1.2, vmax=1.2, shading="flat", edgecolor="0.3", linewidth=0.1
        )
        axes.set_title(title)
    axes = figure.add_subplot(1, 3, 3)
    axes.plot(np.arange(history.size), history, label="loss")
    if reference is not None:
        axes.axhline(reference, color="0.4", linestyle="--", linewidth=1, label=label)
        axes.legend()
    axes.set_yscale("log" if history.min() > 0 else "linear")
    axes.set_xlabel("step")
    axes.set_title("loss")
    figure.suptitle(f"ddgjax optimize --example {args.example}", fontsize=10)
    return write_figure(figure, args.output, "optimize")
