"""Curve-shortening flow benchmark: ddgjax against a plain NumPy loop and curvey, side by side.

Run from the repository root:

    python benchmarks/curves.py            # full sizes (a few minutes on 2 CPU cores)
    python benchmarks/curves.py --quick    # smaller sizes, for a smoke test

Reports compile time and run time (min / median over repeats) separately, and ratios:
1. 10,000 explicit steps on a 1,000-vertex curve, each kind A, B, C, D: ddgjax's
   `curve_shortening_flow` (one `lax.scan`, plus the invariants of the two saved states) against a
   plain NumPy loop of the same iteration (the reading report's formulas, vectorised per step),
   and the jitted scan alone ("steps only", without the invariants). Target: >= 20x.
2. curvey's `CurveShorteningFlow` (explicit, resampling off, curvey's own finite-difference normals
   with the B curvature plugged in): per step, extrapolated to 10,000 steps.
3. A batch of curves under `jax.vmap`: vertex-steps per second.
4. The gradient of a loss on the final curve through 1,000 steps, against the forward run.
   Target: <= 3x.
5. The flows' single-threaded kernels (curves below `_SERIAL_BELOW` vertices): the A and B steps
   compiled with and without XLA:CPU's parallel task assigner, interleaved, at the user size and
   above it.
"""

from __future__ import annotations

import argparse
import functools
import os
import platform
import statistics
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

jax.config.update("jax_enable_x64", True)
sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))  # this checkout's ddgjax, installed or not

import ddgjax  # noqa: E402
from ddgjax.curves import Curve, curve_shortening_flow, flower  # noqa: E402
from ddgjax.curves._flow import _SERIAL_BELOW, _SERIAL_KERNELS, _run  # noqa: E402


def timed(function, repeats):
    """(first call seconds, min, median over `repeats` further calls)."""
    start = time.perf_counter()
    jax.block_until_ready(function())
    first = time.perf_counter() - start
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(function())
        times.append(time.perf_counter() - start)
    return first, min(times), statistics.median(times)


def interleaved(functions, repeats):
    """`{name: (min, median)}` seconds over `repeats` rounds that call each function once in turn (after one warm-up each)."""
    for function in functions.values():
        jax.block_until_ready(function())
    times = {name: [] for name in functions}
    for _ in range(repeats):
        for name, function in functions.items():
            start = time.perf_counter()
            jax.block_until_ready(function())
            times[name].append(time.perf_counter() - start)
    return {name: (min(values), statistics.median(values)) for name, values in times.items()}


def numpy_flow(points, kind, tau, steps):
    """The report's iteration `p <- p + tau kappa N`, one vectorised NumPy pass per step.

    Coordinates are separate arrays (NumPy's reductions over a size-2 axis cost ~30 us each, more
    than the arithmetic), `hypot` for lengths: the fastest plain-NumPy form we found (1.4x faster
    than the `(n, 2)` form).
    """
    x, y = np.array(points[:, 0], dtype=np.float64), np.array(points[:, 1], dtype=np.float64)
    for _ in range(steps):
        vx, vy = np.roll(x, -1) - x, np.roll(y, -1) - y  # p_{i+1} - p_i
        ux, uy = np.roll(vx, 1), np.roll(vy, 1)  # p_i - p_{i-1}
        lu, lv = np.hypot(ux, uy), np.hypot(vx, vy)
        theta = np.arctan2(ux * vy - uy * vx, ux * vx + uy * vy)
        if kind == "D":
            kappa = 2 * np.sin(theta) / np.hypot(ux + vx, uy + vy)
            tx, ty = lv**2 * ux + lu**2 * vx, lv**2 * uy + lu**2 * vy
        else:
            kappa = {"A": theta, "B": 2 * np.sin(theta / 2), "C": 2 * np.tan(theta / 2)}[kind]
            tx, ty = ux / lu + vx / lv, uy / lu + vy / lv
        scale = tau * kappa / np.hypot(tx, ty)  # normal = tangent rotated by +90 degrees
        x, y = x - scale * ty, y + scale * tx
    return np.stack([x, y], axis=1)


def curvey_seconds_per_step(points, tau, steps):
    import curvey
    from curvey.flow import CurveShorteningFlow

    def kappa_b(curve):
        return 2 * np.sin(curve.turning_angle / 2)

    flow = CurveShorteningFlow(resample_mode=None, curvature_fn=kappa_b)
    solver = flow.solver(curvey.Curve(np.asarray(points)), timestep=tau, max_step=steps, history=False)
    start = time.perf_counter()
    solver.run()
    return (time.perf_counter() - start) / steps


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small sizes, for a smoke test")
    args = parser.parse_args()
    n, steps, repeats = (200, 1000, 2) if args.quick else (1000, 10_000, 5)
    batch, batch_n, batch_steps = (64, 64, 100) if args.quick else (1024, 128, 1000)
    grad_steps = 100 if args.quick else 1000
    curve = flower(n)
    taus = {"A": 1e-4, "B": 1e-4, "C": 1e-4, "D": 1e-6}  # below the explicit limits (edge ~6e-3)

    print(
        f"# ddgjax curve benchmarks: {platform.processor() or platform.machine()}, {os.cpu_count()} CPU cores, "
        f"jax {jax.__version__} ({jax.devices()[0].platform}), float64"
    )
    print(f"\n## Explicit flow: {n} vertices x {steps} steps (flower curve)\n")
    print(
        "| kind | compile (s) | run, default (certified simplicity) min / median (ms) | run, check_simple='saved' (ms) "
        "| steps only (ms) | NumPy loop, min of 3 (ms) | speed-up: default / saved / steps only | max |diff| |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for kind, tau in taus.items():

        def run(kind=kind, tau=tau, check="certified"):
            return curve_shortening_flow(curve, kind=kind, tau=tau, steps=steps, check_simple=check).points

        def scan_only(kind=kind, tau=tau):
            # the steps alone, without the invariants of the saved states (an O(n^2) simplicity test among them)
            return _run(
                curve.points,
                jnp.asarray(tau),
                closed=True,
                kind=kind,
                method="explicit",
                rescale=None,
                steps=steps,
                save_every=steps,
                check="saved",
            )

        first, fastest, median = timed(run, repeats)
        _, fastest_saved, _ = timed(lambda: run(check="saved"), repeats)
        _, fastest_scan, _ = timed(scan_only, repeats)
        numpy_times = []
        for _ in range(3 if not args.quick else 1):  # min of three: a single run on a shared machine varies by 30%
            start = time.perf_counter()
            reference = numpy_flow(curve.points, kind, tau, steps)
            numpy_times.append(time.perf_counter() - start)
        numpy_seconds = min(numpy_times)
        difference = float(np.abs(np.asarray(run()[-1]) - reference).max())
        print(
            f"| {kind} | {first - fastest:.2f} | {1e3 * fastest:.1f} / {1e3 * median:.1f} | {1e3 * fastest_saved:.1f} "
            f"| {1e3 * fastest_scan:.1f} | {1e3 * numpy_seconds:.0f} | {numpy_seconds / fastest:.1f}x / "
            f"{numpy_seconds / fastest_saved:.1f}x / {numpy_seconds / fastest_scan:.1f}x | {difference:.1e} |"
        )

    curvey_steps = 20 if args.quick else 200
    per_step = curvey_seconds_per_step(curve.points, taus["B"], curvey_steps)
    _, fastest_b, _ = timed(lambda: curve_shortening_flow(curve, kind="B", tau=taus["B"], steps=steps).points, 1)
    print(
        f"\ncurvey CurveShorteningFlow (B curvature, curvey's normals, {curvey_steps} steps timed): "
        f"{1e6 * per_step:.0f} us/step -> {per_step * steps:.1f} s for {steps} steps; "
        f"ddgjax B {1e6 * fastest_b / steps:.1f} us/step ({per_step * steps / fastest_b:.0f}x)"
    )

    print(f"\n## Batch under vmap: {batch} curves x {batch_n} vertices x {batch_steps} steps\n")
    print("Your own `jax.jit(jax.vmap(flow))`: plain, and with `compiler_options=ddgjax.cpu_compiler_options()`.\n")
    print("| kind | jit | compile (s) | run min / median (ms) | vertex-steps / s | single curve, same size (vertex-steps / s) |")
    print("|---|---|---|---|---|---|")
    rng = np.random.default_rng(0)
    base = np.asarray(flower(batch_n).points)
    curves = jnp.asarray(base[None] * rng.uniform(0.8, 1.2, (batch, 1, 1)) + 0.01 * rng.normal(size=(batch, batch_n, 2)))
    for kind in ("A", "B"):
        _, single, _ = timed(
            lambda kind=kind: (
                curve_shortening_flow(Curve(curves[0]), kind=kind, tau=1e-4, steps=batch_steps, check_simple="saved").points
            ),
            repeats,
        )
        for label, options in (("plain", None), ("cpu_compiler_options", ddgjax.cpu_compiler_options() or None)):
            # check_simple="saved": under vmap the certified tracking's lazy test becomes an every-step test;
            # throw=False: a few noisy members are not simple (some from the start), and one would stop the batch
            batched = jax.jit(
                jax.vmap(
                    lambda P, kind=kind: curve_shortening_flow(
                        Curve(P), kind=kind, tau=1e-4, steps=batch_steps, check_simple="saved", throw=False
                    ).points[-1]
                ),
                compiler_options=options,
            )
            first, fastest, median = timed(lambda batched=batched: batched(curves), max(1, repeats // 2))
            work = batch * batch_n * batch_steps
            print(
                f"| {kind} | {label} | {first - fastest:.2f} | {1e3 * fastest:.0f} / {1e3 * median:.0f} | {work / fastest:.3g} "
                f"| {batch_n * batch_steps / single:.3g} |"
            )

    print(f"\n## Gradient through {grad_steps} steps ({n} vertices)\n")
    print("| kind | forward (ms) | gradient (ms) | ratio | compile forward / gradient (s) |")
    print("|---|---|---|---|---|")
    for kind in ("A", "B", "C", "D"):
        tau = taus[kind]

        def loss(P, kind=kind, tau=tau):
            final = curve_shortening_flow(Curve(P), kind=kind, tau=tau, steps=grad_steps, check_simple="saved").points[-1]
            return jnp.sum(final**2)

        options = ddgjax.cpu_compiler_options() or None  # as the README recommends for your own jit
        forward, gradient = jax.jit(loss, compiler_options=options), jax.jit(jax.grad(loss), compiler_options=options)
        first_f, fastest_f, _ = timed(lambda forward=forward: forward(curve.points), repeats)
        first_g, fastest_g, _ = timed(lambda gradient=gradient: gradient(curve.points), repeats)
        print(
            f"| {kind} | {1e3 * fastest_f:.1f} | {1e3 * fastest_g:.1f} | {fastest_g / fastest_f:.2f}x "
            f"| {first_f - fastest_f:.2f} / {first_g - fastest_g:.2f} |"
        )

    print(f"\n## Single-threaded kernels (the flows use them below {_SERIAL_BELOW:,} vertices)\n")
    print("The scan of `check_simple='saved'` compiled with and without XLA:CPU's parallel task assigner, called in turn.\n")
    print(
        "| vertices x steps | kind | threaded min / median (ms) | single-threaded min / median (ms) | threaded / single-threaded (median) |"
    )
    print("|---|---|---|---|---|")
    static = ("closed", "kind", "method", "rescale", "steps", "save_every", "check")
    versions = {
        label: jax.jit(
            _run.__wrapped__, static_argnames=static, compiler_options=ddgjax.cpu_compiler_options(extra=extra) or None
        )
        for label, extra in (("threaded", None), ("single-threaded", _SERIAL_KERNELS))
    }
    for size, size_steps in ((200, 1000), (20_000, 100)) if args.quick else ((1000, 10_000), (20_000, 1000), (100_000, 200)):
        points = flower(size).points
        for kind in ("A", "B"):
            settings = {
                "closed": True,
                "kind": kind,
                "method": "explicit",
                "rescale": None,
                "steps": size_steps,
                "save_every": size_steps,
                "check": "saved",
            }
            tau = jnp.asarray(1e-4 * 1000 / size)  # below the explicit limit, shorter edges for more vertices
            calls = {label: functools.partial(version, points, tau, **settings) for label, version in versions.items()}
            times = interleaved(calls, 2 * repeats)
            (fast_t, median_t), (fast_s, median_s) = times["threaded"], times["single-threaded"]
            print(
                f"| {size:,} x {size_steps:,} | {kind} | {1e3 * fast_t:.1f} / {1e3 * median_t:.1f} "
                f"| {1e3 * fast_s:.1f} / {1e3 * median_s:.1f} | {median_t / median_s:.2f}x |"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
