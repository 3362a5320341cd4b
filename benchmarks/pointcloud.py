"""Point-cloud Laplacian build: ddgjax vs robust_laplacian, and heat-distance queries vs potpourri3d.

Run: `python benchmarks/pointcloud.py [n_points]` (default 100,000 uniform samples of the unit sphere).
Prints the build time of `point_cloud_laplacian` (first call: includes compilation; warm: a new cloud
of the same size, whose triangulation has the same array shapes only by chance, so it may recompile
the replay) against `robust_laplacian.point_cloud_laplacian(P, n_neighbors=30)`, their ratio, the
host triangulation's share, and one heat-distance query with a kept solver against potpourri3d's
`PointCloudHeatSolver.compute_distance`.
"""

from __future__ import annotations

import sys
import time

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)

import potpourri3d as pp3d  # noqa: E402
import robust_laplacian  # noqa: E402

from ddgjax.pointcloud import point_cloud_heat_solver, point_cloud_laplacian, point_cloud_triangulation  # noqa: E402


def _cloud(n: int, seed: int) -> np.ndarray:
    points = np.random.default_rng(seed).normal(size=(n, 3))
    return points / np.linalg.norm(points, axis=1, keepdims=True)


def _timed(function, *args, **kwargs) -> tuple[float, object]:
    start = time.perf_counter()
    result = jax.block_until_ready(function(*args, **kwargs))
    return time.perf_counter() - start, result


def main(n: int = 100_000, heat: bool = True) -> None:
    print(f"point-cloud Laplacian, {n} points on the unit sphere, n_neighbors=30 (seconds)")
    for label, seed in (("first call", 0), ("warm, new cloud", 1), ("warm, new cloud", 2)):
        points = _cloud(n, seed)
        ours, _ = _timed(point_cloud_laplacian, points)
        host, _ = _timed(point_cloud_triangulation, points)
        peer, _ = _timed(robust_laplacian.point_cloud_laplacian, points, n_neighbors=30)
        print(
            f"  {label:16s} ddgjax {ours:7.2f} (host triangulation {host:5.2f})  robust_laplacian {peer:7.2f}  ratio {ours / peer:5.2f}"
        )
    if not heat:
        return
    points = _cloud(n, 3)
    build, solver = _timed(point_cloud_heat_solver, points)
    peer_build, peer = _timed(pp3d.PointCloudHeatSolver, points)
    solver.distance(0)
    queries = [_timed(solver.distance, i)[0] for i in range(1, 6)]
    peer_queries = [_timed(peer.compute_distance, i)[0] for i in range(1, 6)]
    print(f"heat distance, {n} points: solver build ddgjax {build:.2f}, potpourri3d {peer_build:.2f}")
    print(
        f"  per query (median of 5): ddgjax {np.median(queries) * 1e3:.1f} ms, potpourri3d {np.median(peer_queries) * 1e3:.1f} ms, "
        f"ratio {np.median(queries) / np.median(peer_queries):.2f}"
    )


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 100_000)
