"""Graphs of point sets: ddgjax's `knn_graph` / `epsilon_graph` against scikit-learn's, one process.

Uniform random points in the unit cube (`--sizes`, seeded). ddgjax: `knn_graph(P, n_neighbors=10)`
(edges and Gaussian weights, the weights compiled once per size before timing) and
`epsilon_graph(P, radius=r)` with `r` the radius of a ball holding 10 points on average;
scikit-learn: `kneighbors_graph(P, 10, mode="distance")` symmetrised with `maximum(A, A.T)` and
`radius_neighbors_graph(P, r, mode="distance")`, the graphs ddgjax documents as its equals (each
run's edge sets are checked equal). Min ms over `--repeats` interleaved runs. Run:
`python benchmarks/graphs.py [--sizes 10000,100000] [--repeats 5]`.
"""

from __future__ import annotations

import argparse
import functools
import time

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402
from sklearn.neighbors import kneighbors_graph, radius_neighbors_graph  # noqa: E402

from ddgjax.graph import epsilon_graph, knn_graph  # noqa: E402


def upper_edges(matrix) -> np.ndarray:
    """`(ne, 2)` the pairs `i < j` of a symmetric SciPy matrix's nonzeros, sorted (ddgjax's edge order)."""
    coo = matrix.tocoo()
    keep = coo.row < coo.col
    pairs = np.stack([coo.row[keep], coo.col[keep]], axis=1).astype(np.int64)
    return pairs[np.lexsort(pairs.T[::-1])]


def best_ms(calls: dict, repeats: int) -> dict:
    """Min wall time of each call in ms, the calls interleaved round by round."""
    times = {name: np.inf for name in calls}
    for _ in range(repeats):
        for name, call in calls.items():
            start = time.perf_counter()
            call()
            times[name] = min(times[name], 1e3 * (time.perf_counter() - start))
    return times


def symmetric_knn(points: np.ndarray):
    A = kneighbors_graph(points, 10, mode="distance")
    return A.maximum(A.T)


def compare(n: int, repeats: int) -> None:
    """One table row per graph at `n` points."""
    points = np.random.default_rng(0).uniform(size=(n, 3))
    radius = (30 / (4 * np.pi * n)) ** (1 / 3)  # a ball holding 10 points on average
    cases = {
        "knn, 10 neighbours": (
            functools.partial(knn_graph, points, n_neighbors=10),
            functools.partial(symmetric_knn, points),
        ),
        f"epsilon, radius {radius:.4f}": (
            functools.partial(epsilon_graph, points, radius=radius),
            functools.partial(radius_neighbors_graph, points, radius, mode="distance"),
        ),
    }
    for name, (ours, theirs) in cases.items():
        jax.block_until_ready(ours().edge_weights)  # compiles the weights' program for this size
        same = np.array_equal(ours().edges, upper_edges(theirs()))
        times = best_ms({"ours": functools.partial(weights_of, ours), "theirs": theirs}, repeats)
        ratio = times["ours"] / times["theirs"]
        print(f"| {n:,} | {name} | {times['ours']:.0f} | {times['theirs']:.0f} | {ratio:.2f}x | {same} |", flush=True)


def weights_of(build):
    return jax.block_until_ready(build().edge_weights)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="10000,100000")
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    print("| points | graph | ddgjax ms | scikit-learn ms | ratio | same edges |")
    print("|---|---|---|---|---|---|")
    for n in (int(size) for size in args.sizes.split(",")):
        compare(n, args.repeats)


if __name__ == "__main__":
    main()
