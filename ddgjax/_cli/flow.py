"""`ddgjax flow`: the reading report's Figure 3, three discrete curve-shortening flows of one polygon.

The same non-convex polygon is evolved by the flows of `kappa^A`, `kappa^B` and `kappa^D` (and
`kappa^C` on request). The figure shows overlaid snapshots of each flow side by side, and below them
what each flow keeps: `kappa^A` its total curvature `2 pi`, `kappa^B` the vertex centroid, and
`kappa^D` drives the polygon to a cyclic one. A table of every invariant at the start and the end of
each flow is printed. The figure uses matplotlib's object API with the Agg canvas (no display, no
change to pyplot's global backend) and the snapshot panels of `ddgjax.plot.plot_flow`.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from tqdm.auto import tqdm

from .._errors import DDGInputError
from ..curves import (
    RESULTS,
    Curve,
    CurveFlowResult,
    curvature,
    curve_shortening_flow,
    edge_lengths,
    enclosed_area,
    figure3_polygon,
    flower,
    length,
    load_polygon,
    random_polygon,
    regular_polygon,
    star,
)
from ._common import add_output_argument, positive, write_figure

SHAPES = ("figure3", "flower", "star", "random", "regular")
# One colour per kind, the same in every panel.
COLORS = {"A": "tab:blue", "B": "tab:orange", "C": "tab:green", "D": "tab:red"}
CURVATURE_NAMES = {"A": r"\theta", "B": r"2\sin(\theta/2)", "C": r"2\tan(\theta/2)", "D": r"1/R"}
# Logarithmic panels show an exact 0 at this level (below double-precision rounding of O(1) values).
LOG_FLOOR = 1e-17


def _kinds(text: str) -> list[str]:
    """argparse type for `--kinds`: comma-separated distinct letters among A, B, C, D."""
    kinds = [kind.strip().upper() for kind in text.split(",") if kind.strip()]
    bad = [kind for kind in kinds if kind not in COLORS]
    if not kinds or bad or len(set(kinds)) != len(kinds):
        raise argparse.ArgumentTypeError(f"expected distinct letters among A, B, C, D separated by commas, got {text!r}")
    return kinds


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the options of `ddgjax flow` to `parser` and make `run_flow` its action."""
    parser.formatter_class = argparse.ArgumentDefaultsHelpFormatter
    parser.add_argument(
        "--shape",
        default="figure3",
        help="initial polygon: one of " + ", ".join(SHAPES) + " (built-in, counterclockwise), or the path of a "
        ".npy file of shape (n, 2) or a CSV / text file of 'x,y' lines (optional header); a clockwise file is reversed",
    )
    parser.add_argument(
        "--vertices",
        type=positive(int),
        default=64,
        help="number of vertices of the flower, random and regular shapes; the 5-tip star gets the nearest multiple of "
        "10 (its 10 straight edges are split into equal segments)",
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of --shape random")
    parser.add_argument(
        "--kinds",
        type=_kinds,
        default="A,B,D",
        help="flows to run, comma-separated among A (theta), B (2 sin(theta/2)), C (2 tan(theta/2)), D (1/R)",
    )
    parser.add_argument(
        "--tau",
        type=positive(float),
        default=None,
        help="time step of the pointwise D flow (flow time); the integrated flows A, B, C step by tau / h, h the initial "
        "mean edge length, so that every flow covers the same flow time. Default: (shortest edge)^2 / 4, the explicit "
        "stability bound, and without rescaling at most 60%% of the time |area| / (2 pi) a smooth flow takes to shrink "
        "the curve to a point, spread over --steps",
    )
    parser.add_argument("--steps", type=positive(int), default=3000, help="number of time steps of every flow")
    parser.add_argument(
        "--save-every",
        type=positive(int),
        default=None,
        help="save the state every this many steps (must divide --steps); default: about 100 saved states",
    )
    parser.add_argument(
        "--method",
        choices=("explicit", "semi-implicit"),
        default="explicit",
        help="explicit: the report's iteration p += tau kappa N; semi-implicit: (I - tau L) p_new = p, stable for large tau",
    )
    parser.add_argument(
        "--rescale",
        choices=("area", "length", "none"),
        default="area",
        help="after each step scale the curve about its vertex centroid back to its initial area or length, so the "
        "limit shape shows (none: watch it shrink)",
    )
    parser.add_argument("--snapshots", type=positive(int), default=6, help="snapshots overlaid in each flow's panel")
    add_output_argument(parser, "flow")
    parser.add_argument("--no-plot", action="store_true", help="print the table only, write no figure")
    parser.add_argument("--progress", action="store_true", help="show a progress bar over the steps of each flow (for long runs)")
    parser.set_defaults(run=run_flow)


def _initial_curve(args):
    """The polygon named by `--shape`, counterclockwise, with a description for the title."""
    builders = {
        "figure3": figure3_polygon,
        "flower": lambda: flower(args.vertices),
        "star": lambda: star(subdivisions=max(1, round(args.vertices / 10))),
        "random": lambda: random_polygon(args.vertices, key=args.seed),
        "regular": lambda: regular_polygon(args.vertices),
    }
    if args.shape in builders:
        curve = builders[args.shape]()
        name = f"{args.shape} polygon" + (f" (seed {args.seed})" if args.shape == "random" else "")
        return curve, name
    if not os.path.isfile(args.shape):
        raise DDGInputError(f"--shape: expected one of {', '.join(SHAPES)} or an existing .npy / CSV file, got {args.shape!r}")
    curve = load_polygon(args.shape)
    name = os.path.basename(args.shape)
    if float(enclosed_area(curve)) < 0:
        # The flows and the sign conventions assume counterclockwise order (positive turning angles).
        print(f"note: {name} is clockwise; reversing it to counterclockwise")
        curve = curve.with_points(curve.points[::-1])
    return curve, name


def _time_step(curve, args) -> float:
    """`--tau`, or the default documented in its help."""
    if args.tau is not None:
        return args.tau
    tau = float(edge_lengths(curve).min()) ** 2 / 4
    if args.rescale == "none":
        tau = min(tau, 0.6 * abs(float(enclosed_area(curve))) / (2 * math.pi) / args.steps)
    return tau


def _save_every(args) -> int:
    """`--save-every`, or the largest divisor of `--steps` that saves at least 100 states."""
    if args.save_every is not None:
        return args.save_every
    return next(d for d in range(max(1, args.steps // 100), 0, -1) if args.steps % d == 0)


class FlowRun(NamedTuple):
    """One flow of the demo: the library's result and what the table and figure derive from it."""

    result: CurveFlowResult
    own_total_curvature: np.ndarray  # (s,) sum of this kind's integrated curvature
    tau: float  # the step handed to curve_shortening_flow
    times: np.ndarray  # (s,) shared flow time (steps x the D-flow step)


def _own_total_curvature(points, kind: str) -> np.ndarray:
    """Integrated total curvature `sum_i kappa^kind_i` of every saved state (`kind`'s own, not `sum theta`)."""
    return np.asarray(jax.vmap(lambda p: jnp.sum(curvature(Curve(p), kind=kind, pointwise=False)))(points))


def _run_flows(curve, kinds, tau, args):
    """Run every flow; returns `{kind: FlowRun}` and the wall time in seconds."""
    mean_edge = float(length(curve)) / curve.n_points
    save_every = _save_every(args)
    rescale = None if args.rescale == "none" else args.rescale
    runs = {}
    start = time.perf_counter()
    for kind in tqdm(kinds, desc="flows", unit="flow", disable=None):
        # kappa^A, B, C are integrated (~ curvature x edge length): dividing tau by the mean edge makes
        # their steps move the curve as far as the pointwise kappa^D step, so all share one flow time.
        kind_tau = tau if kind == "D" else tau / mean_edge
        result = curve_shortening_flow(
            curve,
            kind=kind,
            tau=kind_tau,
            steps=args.steps,
            save_every=save_every,
            method=args.method,
            rescale=rescale,
            progress=args.progress,
            throw=False,  # a failed run is reported in the table and the warnings, not raised
        )
        times = tau * np.asarray(result.steps, dtype=float)
        runs[kind] = FlowRun(result, _own_total_curvature(result.points, kind), kind_tau, times)
    return runs, time.perf_counter() - start


def _table(runs) -> list[str]:
    """Lines of the start / end table of every invariant of every flow."""
    header = f"{'flow':<5}{'tau':>10}  {'quantity':<26}{'start':>22}{'end':>22}{'change':>12}"
    lines = [header, "-" * len(header)]
    for kind, (result, own_total, kind_tau, _) in runs.items():
        centroid = np.asarray(result.centroid)
        simple = np.asarray(result.is_simple)
        rows = [
            (f"total curvature sum kappa^{kind}", own_total[0], own_total[-1], own_total[-1] - own_total[0]),
            ("centroid (x, y)", centroid[0], centroid[-1], np.linalg.norm(centroid[-1] - centroid[0])),
            ("cyclic residual", *_ends(result.cyclic_residual)),
            ("length", *_ends(result.length)),
            ("area", *_ends(result.area)),
            ("isoperimetric ratio", *_ends(result.isoperimetric_ratio)),
        ]
        for index, (name, first, last, change) in enumerate(rows):
            prefix = f"{kind:<5}{kind_tau:>10.3g}  " if index == 0 else " " * 17
            lines.append(f"{prefix}{name:<26}{_cell(first):>22}{_cell(last):>22}{change:>+12.2e}")
        failure, step = _failure(result), int(result.first_failure_step)
        throughout = {"": "yes", "self_intersection": f"no (step {step})", "nonfinite": f"no (non-finite, step {step})"}[failure]
        lines.append(" " * 17 + f"{'simple (at every step)':<26}{_yes(simple[0]):>22}{throughout:>22}")
    return lines


def _ends(values):
    values = np.asarray(values)
    return values[0], values[-1], values[-1] - values[0]


def _cell(value) -> str:
    value = np.asarray(value)
    return "(" + ", ".join(f"{v:+.5f}" for v in value) + ")" if value.ndim else f"{float(value):.10g}"


def _yes(flag) -> str:
    return "yes" if bool(flag) else "no"


def _failure(result: CurveFlowResult) -> str:
    """How the flow failed, `"nonfinite"` or `"self_intersection"` (`RESULTS` names), or `""` if it did not."""
    return next((name for name in ("nonfinite", "self_intersection") if bool(result.result == getattr(RESULTS, name))), "")


def _warnings(runs) -> tuple[list[str], bool]:
    """Self-intersection and divergence messages, and whether any flow diverged (ended with non-finite points)."""
    messages, diverged = [], False
    advice = "lower --tau or use --method semi-implicit"
    for kind, (result, *_) in runs.items():
        failure, step = _failure(result), int(result.first_failure_step)
        # `result` is the first failure's; a flow that tangled first may still blow up later.
        blew_up = not np.isfinite(np.asarray(result.value)).all()
        diverged |= blew_up
        if failure == "nonfinite":
            messages.append(f"flow {kind}: non-finite points by step {step}: {advice}")
        elif failure == "self_intersection":
            later = f", and its points were non-finite by the end: {advice}" if blew_up else ""
            messages.append(
                f"flow {kind}: the curve self-intersected at step {step} (none of the flows guarantees simplicity){later}"
            )
    return messages, diverged


def _figure(runs, name, args, tau):
    """The Figure 3 reproduction: snapshot panels on top, invariant panels below."""
    # Imported here: matplotlib is only needed when a figure is written (not for --no-plot or --help).
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from ..plot import plot_flow

    kinds = list(runs)
    # Every flow runs the same steps and saves, so the snapshot indices and times are shared.
    times = runs[kinds[0]].times
    figure = Figure(figsize=(16, 8.8), layout="constrained")
    FigureCanvasAgg(figure)
    grid = figure.add_gridspec(2, 12, height_ratios=[1.25, 1])
    width = 12 // len(kinds)
    for column, kind in enumerate(kinds):
        axes = figure.add_subplot(grid[0, column * width : (column + 1) * width])
        chosen = plot_flow(axes, runs[kind].result, snapshots=args.snapshots, color=COLORS[kind])
        axes.set_title(rf"$\kappa^{kind} = {CURVATURE_NAMES[kind]}$ flow  ($\tau$ = {runs[kind].tau:.3g})")
        axes.tick_params(labelsize=8)
    snapshot_times = ", ".join(f"{t:.3g}" for t in times[chosen[1:]])
    panels = [
        (
            r"total curvature $|\Sigma_i\,\kappa_i(t) - \Sigma_i\,\kappa_i(0)|$",
            True,
            lambda kind: np.abs(runs[kind].own_total_curvature - runs[kind].own_total_curvature[0]),
            r"A keeps $\Sigma_i\,\kappa^A_i = 2\pi$",
        ),
        (
            r"centroid drift $|c(t) - c(0)|$",
            True,
            lambda kind: np.linalg.norm(
                np.asarray(runs[kind].result.centroid) - np.asarray(runs[kind].result.centroid)[0], axis=1
            ),
            "B keeps the vertex centroid",
        ),
        (
            r"cyclic residual $\mathrm{std}_i |p_i - c| \,/\, \mathrm{mean}_i |p_i - c|$",
            True,
            lambda kind: np.asarray(runs[kind].result.cyclic_residual),
            "D tends to a cyclic polygon",
        ),
        (
            r"isoperimetric ratio $4\pi |A| / L^2$",
            False,
            lambda kind: np.asarray(runs[kind].result.isoperimetric_ratio),
            "1 for a circle",
        ),
    ]
    for column, (label, logarithmic, values, note) in enumerate(panels):
        axes = figure.add_subplot(grid[1, 3 * column : 3 * column + 3])
        for kind in kinds:
            series = values(kind)
            if logarithmic:
                series = np.maximum(series, LOG_FLOOR)
            axes.plot(
                times[1:] if logarithmic else times, series[1:] if logarithmic else series, color=COLORS[kind], label=kind, lw=1.6
            )
        if logarithmic:
            axes.set_yscale("log")
        axes.set_title(f"{label}\n({note})", fontsize=10)
        axes.set_xlabel("flow time t")
        axes.legend(fontsize=8)
        axes.grid(alpha=0.3)
        axes.tick_params(labelsize=8)
    rescale = "" if args.rescale == "none" else f", rescaled to constant {args.rescale}"
    figure.suptitle(
        f"Discrete curve-shortening flows of the {name} ({runs[kinds[0]].result.points.shape[1]} vertices): "
        f"{args.steps} {args.method} steps to t = {tau * args.steps:.3g}{rescale}\n"
        f"snapshots at t = 0 (black, dashed), {snapshot_times} (darkest; dots: its vertices); black line: vertex centroid "
        f"path from + to x; logarithmic panels show an exact 0 at {LOG_FLOOR:g}",
        fontsize=12,
    )
    return figure


def run_flow(args: argparse.Namespace) -> int:
    """Action of `ddgjax flow`: run the flows, print the table, write the figure; 0 on success."""
    try:
        curve, name = _initial_curve(args)
        tau = _time_step(curve, args)
        runs, seconds = _run_flows(curve, args.kinds, tau, args)
    except DDGInputError as error:
        print(f"ddgjax flow: error: {error}", file=sys.stderr)
        return 2
    rescale = "no rescaling" if args.rescale == "none" else f"rescaled to constant {args.rescale}"
    print(
        f"{name}, {curve.n_points} vertices: {args.steps} {args.method} steps of flow time {tau:.3g} "
        f"(t = {tau * args.steps:.3g}), {rescale}; flows ran in {seconds:.2f} s (compilation included)"
    )
    print("\n".join(_table(runs)))
    messages, diverged = _warnings(runs)
    for message in messages:
        print(f"warning: {message}")
    if not args.no_plot:
        figure = _figure(runs, name, args, tau)
        if not write_figure(figure, args.output, "flow"):
            return 2
    return 1 if diverged else 0
