"""Chamfer distance: ddgjax's k-d tree search and brute force against SciPy's cKDTree, value and gradient.

Two clouds of `n` 3-D points each (normal samples, the second scaled by 1.1), `n = 5,000` and `100,000`
(`--quick`: 2,000 and 20,000). Contenders, each warm and timed interleaved in one process
(`benchmarks/solve.py`'s `timed_interleaved`, min / median ms):

- **ddgjax kdtree**: `jax.jit(chamfer_distance)` with `method="kdtree"` (the CPU default), and
  `jax.jit(jax.value_and_grad(chamfer_distance, argnums=(0, 1)))` for value + gradient;
- **ddgjax brute**: the same with `method="brute"` (chunked pairwise distances in JAX, the accelerator
  default); at 100k only one call (about 10^10 distances; `--skip-brute-above N` sets the limit);
- **cKDTree**: SciPy in NumPy: build both trees, query both ways (`workers=-1`), the mean squared
  distances; for value + gradient also the analytic gradient in NumPy,
  `dC/da_i = 2 (a_i - b_nn(i)) / na - sum_{j: nn(j) = i} 2 (b_j - a_i) / nb` (and alike for `b`),
  scattered with `np.bincount`.

Every row checks that the value and the gradient match cKDTree's (relative difference printed).
Run: `python benchmarks/chamfer.py [--quick] [--repeats 7]`.
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import time

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402
from scipy.spatial import cKDTree  # noqa: E402

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from solve import fmt, jit, run_sections, timed_interleaved, warmed  # noqa: E402

from ddgjax.optim import chamfer_distance  # noqa: E402


def scipy_chamfer(a, b):
    """Chamfer distance with SciPy's cKDTree: both trees, both queries on every core, the means of squares."""
    distance_to_b, _ = cKDTree(b).query(a, workers=-1)
    distance_to_a, _ = cKDTree(a).query(b, workers=-1)
    return np.mean(distance_to_b**2) + np.mean(distance_to_a**2)


def scipy_chamfer_and_gradient(a, b):
    """`(value, (grad_a, grad_b))` with cKDTree's nearest points and the analytic gradient in NumPy."""
    _, in_b = cKDTree(b).query(a, workers=-1)
    _, in_a = cKDTree(a).query(b, workers=-1)
    to_b, to_a = a - b[in_b], b - a[in_a]
    value = np.mean(np.sum(to_b * to_b, axis=1)) + np.mean(np.sum(to_a * to_a, axis=1))
    scatter = lambda index, rows, n: np.stack([np.bincount(index, rows[:, k], minlength=n) for k in range(rows.shape[1])], 1)
    grad_a = 2 * to_b / len(a) - 2 * scatter(in_a, to_a, len(a)) / len(b)
    grad_b = 2 * to_a / len(b) - 2 * scatter(in_b, to_b, len(b)) / len(a)
    return value, (grad_a, grad_b)


def chamfer(args):
    sizes = (2_000, 20_000) if args.quick else (5_000, 100_000)
    print("\n## Chamfer distance of two clouds of n 3-D points, ms (min / median); ratio = min / cKDTree's min")
    print(f"{'n':>8} {'contender':>22} {'value':>18} {'ratio':>7} {'value + gradient':>18} {'ratio':>7} {'max rel. diff.':>15}")
    rng = np.random.default_rng(0)
    for n in sizes:
        a, b = rng.normal(size=(n, 3)), 1.1 * rng.normal(size=(n, 3))
        ja, jb = jax.device_put(a), jax.device_put(b)
        contenders = {"ddgjax kdtree": "kdtree"}
        if n <= args.skip_brute_above:
            contenders["ddgjax brute"] = "brute"
        calls = {"cKDTree": (scipy_chamfer, (a, b)), "cKDTree + gradient": (scipy_chamfer_and_gradient, (a, b))}
        for name, method in contenders.items():
            value = jit(lambda a, b, m=method: chamfer_distance(a, b, method=m))
            both = jit(jax.value_and_grad(lambda a, b, m=method: chamfer_distance(a, b, method=m), argnums=(0, 1)))
            calls[name] = (value, (ja, jb))
            calls[name + " + gradient"] = (both, (ja, jb))
        times, results = timed_interleaved(warmed(calls), args.repeats, budget_s=10.0)
        reference, (ga, gb) = results["cKDTree + gradient"]
        print(
            f"{n:>8} {'cKDTree':>22} {fmt(times['cKDTree'], args.repeats):>18} {'1':>7} "
            f"{fmt(times['cKDTree + gradient'], args.repeats):>18} {'1':>7} {abs(results['cKDTree'] - reference) / reference:>15.1e}"
        )
        for name in contenders:
            value, (da, db) = results[name + " + gradient"]
            difference = max(
                abs(float(results[name]) - reference) / reference,
                abs(float(value) - reference) / reference,
                float(np.abs(da - ga).max() / np.abs(ga).max()),
                float(np.abs(db - gb).max() / np.abs(gb).max()),
            )
            ratio = times[name][0] / times["cKDTree"][0]
            ratio_gradient = times[name + " + gradient"][0] / times["cKDTree + gradient"][0]
            print(
                f"{n:>8} {name:>22} {fmt(times[name], args.repeats):>18} {ratio:>7.2f} "
                f"{fmt(times[name + ' + gradient'], args.repeats):>18} {ratio_gradient:>7.2f} {difference:>15.1e}"
            )
        if n > args.skip_brute_above:
            brute = jit(lambda a, b: chamfer_distance(a, b, method="brute")).lower(ja, jb).compile()
            start = time.perf_counter()
            value = float(brute(ja, jb))
            seconds = time.perf_counter() - start
            print(
                f"{n:>8} {'ddgjax brute (1 call)':>22} {1e3 * seconds:>18.0f} {1e3 * seconds / times['cKDTree'][0]:>7.0f} "
                f"{'-':>18} {'-':>7} {abs(value - reference) / reference:>15.1e}"
            )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="2,000 and 20,000 points: a smoke test")
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--skip-brute-above", type=int, default=20_000, help="time the brute force once above this many points")
    args = parser.parse_args()
    args.sections = "chamfer"
    run_sections({"chamfer": chamfer}, args)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
