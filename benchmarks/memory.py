"""Memory over a stream of meshes of different sizes (issue 22): the process's growth per new mesh.

A user preprocessing a dataset builds the operators of many meshes, each of a new size, in one
process. Every compiled XLA program costs 1.5-4 MB however small its input, so a library that keeps
one program per size forever grows without bound. This script builds, for each of `--meshes`
random convex-hull spheres of 500-5,000 vertices (seeded), the cotan Laplacian and the Voronoi and
Galerkin mass matrices (`--path lm`), and optionally one solve of `(M + 0.01 L) x = M 1`
(`--path solve`, `--solver` any of `ddgjax.LINEAR_SOLVERS`), and prints the resident set size every `--every` meshes and the growth per new
mesh fitted over the second half of the stream (after the program caches have filled), with the
seconds per mesh. A reference run with `jax.clear_caches()` after every mesh (`--clear`) shows the
floor: what remains is not compiled programs.

    python benchmarks/memory.py                 # L and M, 150 meshes (a few minutes)
    python benchmarks/memory.py --path solve    # plus one solve per mesh
"""

from __future__ import annotations

import argparse
import gc
import time

import jax
import numpy as np
import psutil
import scipy.spatial

jax.config.update("jax_enable_x64", True)

import ddgjax  # noqa: E402
from ddgjax.laplacian import cotan_laplacian, mass_matrix  # noqa: E402
from ddgjax.solve import linear_solve  # noqa: E402


def sphere(n_points: int, rng: np.random.Generator) -> ddgjax.Mesh:
    """The convex hull of `n_points` random points on the unit sphere, faces oriented outward."""
    points = rng.normal(size=(n_points, 3))
    points /= np.linalg.norm(points, axis=1, keepdims=True)
    faces = scipy.spatial.ConvexHull(points).simplices
    corners = points[faces]
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    inward = np.einsum("ij,ij->i", normals, corners.mean(axis=1)) < 0
    faces[inward] = faces[inward][:, ::-1]
    return ddgjax.Mesh.from_arrays(points, faces)


def process(mesh: ddgjax.Mesh, path: str, solver: str) -> None:
    L, M, G = cotan_laplacian(mesh), mass_matrix(mesh), mass_matrix(mesh, mass="galerkin")
    jax.block_until_ready((L.values, M.values, G.values))
    if path == "solve":
        x = linear_solve(M + 0.01 * L, M @ np.ones(mesh.n_vertices), solver=solver)
        jax.block_until_ready(x.value)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--meshes", type=int, default=150)
    parser.add_argument("--path", choices=("lm", "solve"), default="lm")
    parser.add_argument("--solver", choices=ddgjax.LINEAR_SOLVERS, default="auto", help="linear_solve's method (--path solve)")
    parser.add_argument("--every", type=int, default=10)
    parser.add_argument("--clear", action="store_true", help="jax.clear_caches() after every mesh (the floor)")
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    process_info = psutil.Process()
    rss, start = [], time.perf_counter()
    solver = f" ({args.solver})" if args.path == "solve" else ""
    print(
        f"ddgjax {ddgjax.__version__}, jax {jax.__version__}; path {args.path}{solver}, {args.meshes} meshes of 500-5,000 vertices"
    )
    print("mesh  vertices  RSS (MB)  seconds")
    for i in range(args.meshes):
        mesh = sphere(int(rng.integers(500, 5000)), rng)
        process(mesh, args.path, args.solver)
        n_vertices = mesh.n_vertices
        del mesh
        if args.clear:
            jax.clear_caches()
        gc.collect()
        rss.append(process_info.memory_info().rss / 2**20)
        if i % args.every == 0 or i == args.meshes - 1:
            print(f"{i:4d}  {n_vertices:8d}  {rss[-1]:8.0f}  {time.perf_counter() - start:7.1f}", flush=True)
    rss = np.array(rss)
    half = len(rss) // 2
    slope = np.polyfit(np.arange(half, len(rss)), rss[half:], 1)[0]
    seconds = (time.perf_counter() - start) / len(rss)
    print(
        f"growth per new mesh over the second half: {slope:.2f} MB; overall {(rss[-1] - rss[0]) / (len(rss) - 1):.2f} MB; "
        f"{seconds:.2f} s per mesh"
    )


if __name__ == "__main__":
    main()
