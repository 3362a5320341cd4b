"""Poisson surface reconstruction: ddgjax.reconstruct against Open3D's `create_from_point_cloud_poisson`, one process.

`python benchmarks/reconstruct.py [--large]`: 100k points sampled from a torus at depth 8 (with `--large`, 1M points at
depth 9 too), on the default device, against Open3D and, when it is installed (`pip install pymeshlab`), MeshLab's
screened Poisson. Prints, per method, the first call (compilation included) and the min / median of the repeats, the
mean distance of the mesh's vertices to the torus over its bounding-box diagonal, the ratio to Open3D, ddgjax from float64 and from float32 input (the grids take the points' dtype), and for
ddgjax the gradient of a function of the indicator with respect to the points and normals over the forward indicator
solve (`jax.grad` through the screened solve), in float64.
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

MAJOR, MINOR = 1.0, 0.35


def torus_distance(vertices) -> float:
    """The mean distance of `vertices` to the torus, over its bounding-box diagonal."""
    vertices = np.asarray(vertices, dtype=np.float64)
    ring = np.hypot(np.hypot(vertices[:, 0], vertices[:, 1]) - MAJOR, vertices[:, 2])
    return float(np.mean(np.abs(ring - MINOR)) / np.linalg.norm([2 * (MAJOR + MINOR), 2 * (MAJOR + MINOR), 2 * MINOR]))


def meshlab_poisson(points, normals, depth: int):
    """MeshLab's screened Poisson (pymeshlab, its defaults but the depth and Open3D's scale), or `None` without it."""
    try:
        import pymeshlab
    except ImportError:
        return None
    meshes = pymeshlab.MeshSet()
    meshes.add_mesh(pymeshlab.Mesh(vertex_matrix=points, v_normals_matrix=normals))
    meshes.generate_surface_reconstruction_screened_poisson(depth=depth, scale=1.1)
    return meshes.current_mesh().vertex_matrix()


def torus_samples(n: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    u, v, w = rng.random((3, 4 * n))
    keep = w < (MAJOR + MINOR * np.cos(2 * np.pi * v)) / (MAJOR + MINOR)
    u, v = 2 * np.pi * u[keep][:n], 2 * np.pi * v[keep][:n]
    normals = np.stack([np.cos(v) * np.cos(u), np.cos(v) * np.sin(u), np.sin(v)], axis=1)
    return normals * MINOR + MAJOR * np.stack([np.cos(u), np.sin(u), 0 * u], axis=1), normals


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


def run(n: int, depth: int, repeats: int, gradient: bool = True) -> None:
    import open3d as o3d

    points, normals = torus_samples(n)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    cloud.normals = o3d.utility.Vector3dVector(normals)
    theirs = timed(lambda: o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(cloud, depth=depth, scale=1.1), repeats)
    open3d_vertices = np.asarray(
        o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(cloud, depth=depth, scale=1.1)[0].vertices
    )
    meshlab = timed(lambda: meshlab_poisson(points, normals, depth), repeats)
    meshlab_vertices = meshlab_poisson(points, normals, depth)
    ours = timed(lambda: jax.block_until_ready(poisson_reconstruction(points, normals, depth=depth).value.vertices), repeats)
    single = points.astype(np.float32), normals.astype(np.float32)
    ours_single = timed(lambda: jax.block_until_ready(poisson_reconstruction(*single, depth=depth).value.vertices), repeats)
    reconstruction = poisson_reconstruction(points, normals, depth=depth)
    grid = reconstruction.grid
    p, q = jnp.asarray(points), jnp.asarray(normals)

    def indicator_sum(p, q):
        values = poisson_indicator(p, q, grid=grid, rtol=1e-3).values
        return jnp.sum(values * values)

    forward = jax.jit(indicator_sum)
    backward_pass = jax.jit(jax.grad(indicator_sum, argnums=(0, 1)))
    solve = timed(lambda: jax.block_until_ready(forward(p, q)), repeats)
    backward = timed(lambda: jax.block_until_ready(backward_pass(p, q)), repeats) if gradient else None
    print(f"{n} points, depth {depth} ({1 << depth}^3 grid), {jax.devices()[0].platform}:")
    print(
        f"  Open3D create_from_point_cloud_poisson  first {theirs[0]:.3g} s  min {theirs[1]:.3g} s  median {theirs[2]:.3g} s"
        f"  distance {torus_distance(open3d_vertices):.2e}"
    )
    if meshlab_vertices is not None:
        print(
            f"  MeshLab screened Poisson (pymeshlab)    first {meshlab[0]:.3g} s  min {meshlab[1]:.3g} s  median {meshlab[2]:.3g} s"
            f"  distance {torus_distance(meshlab_vertices):.2e}  ({meshlab[1] / theirs[1]:.2f}x Open3D)"
        )
    print(
        f"  ddgjax poisson_reconstruction           first {ours[0]:.3g} s  min {ours[1]:.3g} s  median {ours[2]:.3g} s"
        f"  distance {torus_distance(reconstruction.value.vertices):.2e}  ({ours[1] / theirs[1]:.2f}x Open3D)"
    )
    print(
        f"  ddgjax poisson_reconstruction, float32  first {ours_single[0]:.3g} s  min {ours_single[1]:.3g} s"
        f"  median {ours_single[2]:.3g} s  ({ours_single[1] / theirs[1]:.2f}x Open3D)"
    )
    print(f"  ddgjax indicator alone (jit)            first {solve[0]:.3g} s  min {solve[1]:.3g} s")
    if backward is not None:
        print(
            f"  ddgjax gradient of the indicator (jit)  first {backward[0]:.3g} s  min {backward[1]:.3g} s"
            f"  ({backward[1] / solve[1]:.2f}x forward)"
        )


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument(
        "--large",
        action="store_true",
        help="also 1M points at depth 9 (~13 GB of memory; its gradient, ~2x that, with --large-gradient)",
    )
    parser.add_argument("--large-gradient", action="store_true", help="also the gradient at depth 9")
    parser.add_argument("--repeats", type=int, default=2)
    options = parser.parse_args()
    run(100_000, 8, options.repeats)
    if options.large:
        run(1_000_000, 9, options.repeats, gradient=options.large_gradient)
