"""Poisson surface reconstruction: ddgjax.reconstruct against Open3D's `create_from_point_cloud_poisson`, one process.

`python benchmarks/reconstruct.py [--large]`: 100k points sampled from a torus at depth 8 (with `--large`, 1M points at
depth 9 too), float64 on CPU. Prints, per method, the first call (compilation included) and the min / median of the
repeats, the ratio to Open3D, and for ddgjax the gradient of a function of the indicator with respect to the points and
normals over the forward indicator solve (`jax.grad` through the screened solve).
"""

from __future__ import annotations

import argparse
import statistics
import time

import jax
import jax.numpy as jnp
import numpy as np

jax.config.update("jax_enable_x64", True)

from ddgjax.reconstruct import poisson_indicator, poisson_reconstruction  # noqa: E402


def torus_samples(n: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    u, v, w = rng.random((3, 4 * n))
    keep = w < (1.0 + 0.35 * np.cos(2 * np.pi * v)) / 1.35
    u, v = 2 * np.pi * u[keep][:n], 2 * np.pi * v[keep][:n]
    normals = np.stack([np.cos(v) * np.cos(u), np.cos(v) * np.sin(u), np.sin(v)], axis=1)
    return normals * 0.35 + np.stack([np.cos(u), np.sin(u), 0 * u], axis=1), normals


def timed(function, repeats: int):
    start = time.perf_counter()
    function()
    first = time.perf_counter() - start
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    return first, min(times), statistics.median(times)


def run(n: int, depth: int, repeats: int) -> None:
    import open3d as o3d

    points, normals = torus_samples(n)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    cloud.normals = o3d.utility.Vector3dVector(normals)
    theirs = timed(lambda: o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(cloud, depth=depth, scale=1.1), repeats)
    ours = timed(lambda: jax.block_until_ready(poisson_reconstruction(points, normals, depth=depth).value.vertices), repeats)
    grid = poisson_reconstruction(points, normals, depth=depth).grid
    p, q = jnp.asarray(points), jnp.asarray(normals)

    def indicator_sum(p, q):
        values = poisson_indicator(p, q, grid=grid, rtol=1e-4).values
        return jnp.sum(values * values)

    forward = jax.jit(indicator_sum)
    gradient = jax.jit(jax.grad(indicator_sum, argnums=(0, 1)))
    solve = timed(lambda: jax.block_until_ready(forward(p, q)), repeats)
    backward = timed(lambda: jax.block_until_ready(gradient(p, q)), repeats)
    print(f"{n} points, depth {depth} ({1 << depth}^3 grid), {jax.devices()[0].platform}:")
    print(f"  Open3D create_from_point_cloud_poisson  first {theirs[0]:.3g} s  min {theirs[1]:.3g} s  median {theirs[2]:.3g} s")
    print(
        f"  ddgjax poisson_reconstruction           first {ours[0]:.3g} s  min {ours[1]:.3g} s  median {ours[2]:.3g} s"
        f"  ({ours[1] / theirs[1]:.2f}x Open3D)"
    )
    print(f"  ddgjax indicator alone (jit)            first {solve[0]:.3g} s  min {solve[1]:.3g} s")
    print(
        f"  ddgjax gradient of the indicator (jit)  first {backward[0]:.3g} s  min {backward[1]:.3g} s  ({backward[1] / solve[1]:.2f}x forward)"
    )


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--large", action="store_true", help="also 1M points at depth 9 (~15 GB of memory)")
    parser.add_argument("--repeats", type=int, default=2)
    options = parser.parse_args()
    run(100_000, 8, options.repeats)
    if options.large:
        run(1_000_000, 9, options.repeats)
