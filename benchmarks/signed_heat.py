"""Signed heat method: one query with a kept solver, ddgjax vs potpourri3d, one process.

On an icosphere (default `icosphere(6)`, 40,962 vertices) and a loop of edges near `z = 0.1` (a
shortest edge path through eight points of that latitude, closed): ddgjax
`signed_heat_solver(mesh).distance([loop])` (the vector heat solve with the kept factorisation, the
constrained Poisson matrix factorised per query, as geometry-central does) against potpourri3d
`MeshSignedHeatSolver(V, F).compute_distance([[(v, []) for v in loop]])`, each warmed by one query
first (geometry-central factors its vector heat system lazily, on the first query). Target: ddgjax's
query within 1.2x of potpourri3d's. Prints min / median ms over interleaved repeats and the ratio of
the minima, and the two fields' largest difference relative to the mesh's diameter.

Run: `python benchmarks/signed_heat.py [--level 6] [--repeats 7]`.
"""

from __future__ import annotations

import argparse
import time

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402
import potpourri3d as pp3d  # noqa: E402
import scipy.sparse as sp  # noqa: E402
from scipy.sparse.csgraph import dijkstra  # noqa: E402

from ddgjax.geodesics import signed_heat_solver  # noqa: E402
from ddgjax.mesh import icosphere  # noqa: E402


def latitude_loop(vertices: np.ndarray, edges: np.ndarray, z0: float, waypoints: int = 8) -> list[int]:
    """A closed loop of edges through the vertices nearest `waypoints` points at height `z0`, counterclockwise about +z."""
    lengths = np.linalg.norm(vertices[edges[:, 0]] - vertices[edges[:, 1]], axis=1)
    n = vertices.shape[0]
    graph = sp.coo_matrix((lengths, (edges[:, 0], edges[:, 1])), shape=(n, n)).tocsr()
    r = np.sqrt(1 - z0**2)
    angles = 2 * np.pi * np.arange(waypoints) / waypoints
    targets = np.stack([r * np.cos(angles), r * np.sin(angles), np.full(waypoints, z0)], axis=1)
    stops = [int(np.argmin(np.linalg.norm(vertices - p, axis=1))) for p in targets]
    _, predecessors = dijkstra(graph, directed=False, indices=stops, return_predecessors=True)
    loop = [stops[0]]
    for k in range(waypoints):
        a, b = stops[k], stops[(k + 1) % waypoints]
        path = [b]
        while path[-1] != a:
            path.append(int(predecessors[k, path[-1]]))
        loop.extend(path[::-1][1:])
    return loop


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--level", type=int, default=6)
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args()

    mesh = icosphere(args.level)
    V, F = np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces)
    loop = latitude_loop(V, np.asarray(mesh.edges), 0.1)
    print(f"icosphere({args.level}): {mesh.n_vertices} vertices, loop of {len(loop) - 1} edges")

    start = time.perf_counter()
    ours = signed_heat_solver(mesh)
    build_ours = time.perf_counter() - start
    start = time.perf_counter()
    theirs = pp3d.MeshSignedHeatSolver(V, F)
    build_theirs = time.perf_counter() - start
    pp_curve = [[(int(v), []) for v in loop]]

    def query_ours():
        return jax.block_until_ready(ours.distance([loop]))

    def query_theirs():
        return theirs.compute_distance(pp_curve)

    d_ours, d_theirs = np.asarray(query_ours()), query_theirs()  # warm: compiles, lazy factorisations
    times = {"ddgjax": [], "potpourri3d": []}
    for _ in range(args.repeats):
        for name, query in (("ddgjax", query_ours), ("potpourri3d", query_theirs)):
            start = time.perf_counter()
            query()
            times[name].append(time.perf_counter() - start)
    for name, t in times.items():
        print(f"{name:12s} query: min {1e3 * min(t):7.1f} ms, median {1e3 * np.median(t):7.1f} ms")
    print(f"build (untimed by the target): ddgjax {1e3 * build_ours:.0f} ms, potpourri3d {1e3 * build_theirs:.0f} ms (lazy)")
    print(f"max |ddgjax - potpourri3d| / diameter: {np.abs(d_ours - d_theirs).max() / 2:.2e}")
    print(f"ratio ddgjax / potpourri3d per query (min): {min(times['ddgjax']) / min(times['potpourri3d']):.2f} (target <= 1.2)")


if __name__ == "__main__":
    main()
