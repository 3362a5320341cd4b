"""The geodesic toolkit's queries with kept solvers: ddgjax vs potpourri3d, one process.

Section **vector heat**: on an icosphere (default `icosphere(6)`, 40,962 vertices), one query of each
kind with the factorisations kept, both sides warmed by one query first (geometry-central factors its
systems lazily, on the first query):

- transport: ddgjax `vector_heat_solver(mesh).transport(v, vector)` (one complex vector heat solve,
  the real form of twice the size) against potpourri3d
  `MeshVectorHeatSolver(V, F, use_intrinsic_delaunay=False).transport_tangent_vector(v, [x, y])`;
- log map: ddgjax `.log_map(v)` (the vector heat solve with two columns, the heat method's heat flow
  and Poisson solve) against potpourri3d `.compute_log_map(v, strategy="VectorHeat")` (its vector
  heat solve twice and a Poisson solve).

Target: each ddgjax query within 1.2x of potpourri3d's. Prints min / median ms over interleaved
repeats (`benchmarks/solve.py`'s `timed_interleaved`) and the ratio of the minima.

Run: `python benchmarks/geodesics_toolkit.py [--level 6] [--repeats 7]`.
"""

from __future__ import annotations

import argparse
import pathlib
import sys

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402
import potpourri3d as pp3d  # noqa: E402

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from solve import fmt, timed_interleaved  # noqa: E402

from ddgjax.geodesics import vector_heat_solver  # noqa: E402
from ddgjax.mesh import icosphere  # noqa: E402


def vector_heat(level: int, repeats: int) -> None:
    mesh = icosphere(level)
    V, F = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    source = mesh.n_vertices // 3
    ours = vector_heat_solver(mesh, mass="barycentric")
    theirs = pp3d.MeshVectorHeatSolver(V, F, t_coef=1.0, use_intrinsic_delaunay=False)
    bx, by, _ = theirs.get_tangent_frames()
    vector = 0.3 * bx[source] + 0.9 * by[source]
    pairs = {
        "transport": (
            (lambda: ours.transport(source, vector), ()),
            (lambda: theirs.transport_tangent_vector(source, [0.3, 0.9]), ()),
        ),
        "log map": (
            (lambda: ours.log_map(source), ()),
            (lambda: theirs.compute_log_map(source, strategy="VectorHeat"), ()),
        ),
    }
    print(f"vector heat, icosphere({level}): {mesh.n_vertices} vertices; min / median ms over {repeats} repeats")
    for name, (ddgjax_call, potpourri_call) in pairs.items():
        calls = {"ddgjax": ddgjax_call, "potpourri3d": potpourri_call}
        for fn, args in calls.values():  # warm: compilation, lazy factorisations
            jax.block_until_ready(fn(*args))
        times, _ = timed_interleaved(calls, repeats, budget_s=30.0)
        ratio = times["ddgjax"][0] / times["potpourri3d"][0]
        print(
            f"  {name:10s} ddgjax {fmt(times['ddgjax'], repeats)}  potpourri3d {fmt(times['potpourri3d'], repeats)}  ratio {ratio:.2f}"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--level", type=int, default=6)
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args()
    vector_heat(args.level, args.repeats)


if __name__ == "__main__":
    main()
