"""Memory over a stream of meshes of different sizes (issues 22, 41): the process's growth per new size.

A user preprocessing a dataset builds the operators of many meshes, each of a new size, in one
process. Every compiled XLA program costs 1.5-4 MB however small its input, and every traced one
leaves jaxprs in JAX's trace caches, so a library that keeps either per size forever grows without
bound. For each of `--meshes` inputs of a new size, 500-5,000 vertices (seeded), this script builds,
by `--kind`:

- `surface`: a random convex-hull sphere; `ddgjax.laplacian.cotan_laplacian` and the Voronoi and
  Galerkin `mass_matrix`;
- `tet`: the Delaunay tetrahedralisation of random points in the unit ball;
  `ddgjax.volume.cotan_laplacian` and the Voronoi and Galerkin `ddgjax.volume.mass_matrix`;
- `cloud`: random points on the unit sphere; `ddgjax.pointcloud.point_cloud_laplacian` (`L` and `M`);

and, with `--path solve`, one solve of `(M + 0.01 L) x = M 1` (`--solver` any of
`ddgjax.LINEAR_SOLVERS`). It prints the resident set size every `--every` inputs and the growth per
new size fitted over the second half of the stream (after the bounded caches have filled), with the
seconds per input. Several kinds run one after the other, each in a fresh process. A reference run
with `jax.clear_caches()` after every input (`--clear`) shows the floor. ddgjax's program store is
switched off (every size compiles, as on a first run; `--store` keeps it).

    python benchmarks/memory.py                        # surfaces: L and M, 150 meshes (a few minutes)
    python benchmarks/memory.py --kind tet cloud       # tet meshes, then point clouds
    python benchmarks/memory.py --path solve           # plus one solve per mesh
"""

from __future__ import annotations

import argparse
import ctypes
import gc
import os
import subprocess
import sys
import time

import jax
import numpy as np
import psutil
import scipy.spatial

jax.config.update("jax_enable_x64", True)

import ddgjax  # noqa: E402
from ddgjax import volume  # noqa: E402
from ddgjax.laplacian import cotan_laplacian, mass_matrix  # noqa: E402
from ddgjax.pointcloud import point_cloud_laplacian  # noqa: E402
from ddgjax.solve import linear_solve  # noqa: E402

KINDS = ("surface", "tet", "cloud")


def unit_vectors(n_points: int, rng: np.random.Generator) -> np.ndarray:
    points = rng.normal(size=(n_points, 3))
    return points / np.linalg.norm(points, axis=1, keepdims=True)


def sphere(n_points: int, rng: np.random.Generator):
    """The convex hull of `n_points` random points on the unit sphere, faces oriented outward."""
    points = unit_vectors(n_points, rng)
    faces = scipy.spatial.ConvexHull(points).simplices
    corners = points[faces]
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    inward = np.einsum("ij,ij->i", normals, corners.mean(axis=1)) < 0
    faces[inward] = faces[inward][:, ::-1]
    return ddgjax.Mesh.from_arrays(points, faces)


def ball(n_points: int, rng: np.random.Generator):
    """The Delaunay tetrahedralisation of `n_points` uniform random points in the unit ball."""
    points = unit_vectors(n_points, rng) * rng.uniform(size=(n_points, 1)) ** (1 / 3)
    return volume.TetMesh.from_arrays(points, scipy.spatial.Delaunay(points).simplices)


def operators(kind: str, n_points: int, rng: np.random.Generator) -> list:
    """`[L, M, ...]` of a new input of `n_points` vertices or points (module docstring)."""
    if kind == "surface":
        mesh = sphere(n_points, rng)
        return [cotan_laplacian(mesh), mass_matrix(mesh), mass_matrix(mesh, mass="galerkin")]
    if kind == "tet":
        tet_mesh = ball(n_points, rng)
        return [volume.cotan_laplacian(tet_mesh), volume.mass_matrix(tet_mesh), volume.mass_matrix(tet_mesh, mass="galerkin")]
    return list(point_cloud_laplacian(unit_vectors(n_points, rng)))


def measure(args: argparse.Namespace) -> None:
    """One kind's stream in this process (module docstring)."""
    if not args.store:  # read at each compilation (`ddgjax._program_store`)
        os.environ["DDGJAX_COMPILATION_CACHE"] = "0"
    rng = np.random.default_rng(0)
    process_info = psutil.Process()
    rss, start = [], time.perf_counter()
    solver = f" ({args.solver})" if args.path == "solve" else ""
    print(
        f"ddgjax {ddgjax.__version__}, jax {jax.__version__}; {args.kind[0]}, path {args.path}{solver}, "
        f"{args.meshes} inputs of 500-5,000 vertices{', clear_caches' if args.clear else ''}{', malloc_trim' if args.trim else ''}"
    )
    print("input  vertices  RSS (MB)  seconds")
    for i in range(args.meshes):
        n_points = int(rng.integers(500, 5000))
        matrices = operators(args.kind[0], n_points, rng)
        jax.block_until_ready([matrix.values for matrix in matrices])
        if args.path == "solve":
            L, M = matrices[:2]
            jax.block_until_ready(linear_solve(M + 0.01 * L, M @ np.ones(n_points), solver=args.solver).value)
        del matrices
        if args.clear:
            jax.clear_caches()
        gc.collect()
        if args.trim:
            ctypes.CDLL("libc.so.6").malloc_trim(0)
        rss.append(process_info.memory_info().rss / 2**20)
        if i % args.every == 0 or i == args.meshes - 1:
            print(f"{i:5d}  {n_points:8d}  {rss[-1]:8.0f}  {time.perf_counter() - start:7.1f}", flush=True)
    rss = np.array(rss)
    half = len(rss) // 2
    slope = np.polyfit(np.arange(half, len(rss)), rss[half:], 1)[0]
    seconds = (time.perf_counter() - start) / len(rss)
    print(
        f"{args.kind[0]}: growth per new size over the second half: {slope:.2f} MB; "
        f"overall {(rss[-1] - rss[0]) / (len(rss) - 1):.2f} MB; {seconds:.2f} s per input",
        flush=True,
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--kind", nargs="+", choices=KINDS, default=["surface"], help="inputs: one or several, each in its own process"
    )
    parser.add_argument("--meshes", type=int, default=150)
    parser.add_argument("--path", choices=("lm", "solve"), default="lm")
    parser.add_argument("--solver", choices=ddgjax.LINEAR_SOLVERS, default="auto", help="linear_solve's method (--path solve)")
    parser.add_argument("--every", type=int, default=10)
    parser.add_argument("--clear", action="store_true", help="jax.clear_caches() after every input (the floor)")
    parser.add_argument("--trim", action="store_true", help="glibc malloc_trim(0) after every input (Linux)")
    parser.add_argument("--store", action="store_true", help="keep ddgjax's program store on (default: off)")
    args = parser.parse_args()
    if len(args.kind) == 1:
        measure(args)
        return
    # A fresh process per kind: one kind's programs and caches must not count in the next one's growth.
    options = ["--meshes", str(args.meshes), "--path", args.path, "--solver", args.solver, "--every", str(args.every)]
    options += ["--clear"] * args.clear + ["--trim"] * args.trim + ["--store"] * args.store
    for kind in args.kind:
        subprocess.run([sys.executable, __file__, "--kind", kind, *options], check=True)


if __name__ == "__main__":
    main()
