"""Tetrahedral meshes: ddgjax.volume's operators and solves against libigl and SciPy, one process, same inputs.

On Kuhn-subdivided cubes (`ddgjax.volume.tet_box(n)`: `6 n^3` congruent tets; n = 26, 40 give ~105k and
~384k tets) and the built-in ball:

- **build**: `TetMesh.from_arrays` (host topology: edges, triangles, incidences, orientation), once
  per connectivity; libigl has no mesh object, so its nearest work, `igl.edges(T)` plus
  `igl.boundary_facets(T)`, is shown beside it.
- **assembly**: the cotan Laplacian and the Voronoi / barycentric mass matrix. ddgjax's first call
  (the storage plan built and cached, a program compiled) apart; then the call a shape optimisation
  makes, new positions into the fixed pattern (`jax.jit` of the values), against `-igl.cotmatrix(V, T)`
  and `igl.massmatrix(V, T, type)` (answers compared).
- **solve**: `-Delta u = 1` with `u = 0` on the boundary: `ddgjax.pde.solve_poisson(tet_mesh, -1,
  fixed_vertices=boundary)` (its default solver choice) against libigl's matrices solved by SciPy's
  `spsolve` on the free block, and libigl's own `min_quad_with_fixed` (a sparse Cholesky of the free
  block), the matrices' build included in all three; and the gradient of `sum(u)` in the vertex positions (implicit differentiation), which no
  peer offers.

Times: min / median ms over interleaved repeats (`benchmarks/solve.py`'s `timed_interleaved`). Run:
`python benchmarks/volume.py [--sections build,assembly,solve] [--sizes 26,40] [--repeats 5]` (~4 min on 2 cores).
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import time

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import scipy.sparse.linalg as spla  # noqa: E402

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from solve import fmt, jit, optional, rel_err, run_sections, timed_interleaved  # noqa: E402

from ddgjax import volume  # noqa: E402
from ddgjax.pde import solve_poisson  # noqa: E402

igl = optional("igl")


def boxes(args):
    for n in args.sizes:
        start = time.perf_counter()
        tet_mesh = volume.tet_box(n)
        yield f"tet_box({n})", tet_mesh, 1e3 * (time.perf_counter() - start)


def header(name, tet_mesh):
    print(f"\n## {name}: {tet_mesh.n_vertices} vertices, {tet_mesh.n_tets} tets")


def section_build(args):
    print("\n# build: TetMesh.from_arrays (host topology) | igl.edges + igl.boundary_facets; ms")
    for name, tet_mesh, _ in boxes(args):
        V, T = np.asarray(tet_mesh.vertices), np.asarray(tet_mesh.tets)
        calls = {"ddgjax from_arrays": (volume.TetMesh.from_arrays, (V, T))}
        if igl is not None:
            calls["igl edges + boundary_facets"] = (lambda T: (igl.edges(T), igl.boundary_facets(T)), (T.astype(np.int64),))
        times, _ = timed_interleaved(calls, args.repeats, args.budget)
        header(name, tet_mesh)
        for call, t in times.items():
            print(f"  {call:32s} {fmt(t, args.repeats)}")


def section_assembly(args):
    print("\n# assembly: L and M (ms, min / median); ratio = ddgjax / libigl")
    for name, tet_mesh, _ in boxes(args):
        header(name, tet_mesh)
        for mass, igl_type in (("voronoi", "VORONOI"), ("barycentric", "BARYCENTRIC")):
            _assembly_on(tet_mesh, mass, igl_type, args)


def _assembly_on(tet_mesh, mass, igl_type, args):
    T = np.asarray(tet_mesh.tets).astype(np.int64)
    start = time.perf_counter()
    jax.block_until_ready((volume.cotan_laplacian(tet_mesh).values, volume.mass_matrix(tet_mesh, mass=mass).values))
    first = 1e3 * (time.perf_counter() - start)

    @jit
    def values(vertices):
        moved = tet_mesh.with_vertices(vertices)
        return volume.cotan_laplacian(moved).values, volume.mass_matrix(moved, mass=mass).values

    moved = tet_mesh.vertices * 1.01
    jax.block_until_ready(values(moved))
    calls = {"ddgjax (jit, new positions)": (values, (moved,))}
    if igl is not None:
        igl_mass = getattr(igl, f"MASSMATRIX_TYPE_{igl_type}")
        calls["libigl"] = (lambda V: (-igl.cotmatrix(V, T), igl.massmatrix(V, T, igl_mass)), (np.asarray(moved),))
    times, results = timed_interleaved(calls, args.repeats, args.budget)
    line = f"  mass={mass:12s} ddgjax first call {first:.0f} ms; " + "; ".join(
        f"{k} {fmt(t, args.repeats)}" for k, t in times.items()
    )
    if igl is not None:
        moved_mesh = tet_mesh.with_vertices(moved)
        L, M = volume.cotan_laplacian(moved_mesh).to_scipy(), volume.mass_matrix(moved_mesh, mass=mass).to_scipy()
        L_igl, M_igl = results["libigl"]
        ratio = times["ddgjax (jit, new positions)"][0] / times["libigl"][0]
        line += (
            f"; ratio {ratio:.3g}x; max rel diff L {abs(L - L_igl).max() / abs(L_igl).max():.1e}, "
            f"M {abs(M - M_igl).max() / abs(M_igl).max():.1e}"
        )
    print(line)


def section_solve(args):
    print("\n# solve: -Delta u = 1, u = 0 on the boundary (ms, min / median, matrices built inside)")
    for name, tet_mesh, _ in boxes(args):
        header(name, tet_mesh)
        _solve_on(tet_mesh, args)


def _solve_on(tet_mesh, args):
    V, T = np.asarray(tet_mesh.vertices), np.asarray(tet_mesh.tets).astype(np.int64)
    boundary = tet_mesh.topology.boundary_vertices
    free = np.setdiff1d(np.arange(tet_mesh.n_vertices), boundary)
    rho = -jnp.ones(tet_mesh.n_vertices)

    def ddgjax_solve(vertices):
        return solve_poisson(tet_mesh.with_vertices(vertices), rho, fixed_vertices=boundary)

    def scipy_solve(V):
        L = (-igl.cotmatrix(V, T)).tocsr()
        M = igl.massmatrix(V, T, igl.MASSMATRIX_TYPE_VORONOI)
        u = np.zeros(V.shape[0])
        u[free] = spla.spsolve(L[free][:, free].tocsc(), M.diagonal()[free])
        return u

    def igl_solve(V):
        L = (-igl.cotmatrix(V, T)).tocsc()
        M = igl.massmatrix(V, T, igl.MASSMATRIX_TYPE_VORONOI)
        linear = -M.diagonal()[:, None]  # minimises u^T L u / 2 - u^T M 1: L u = M 1
        return igl.min_quad_with_fixed(L, linear, boundary.astype(np.int64), np.zeros((boundary.size, 1)))[:, 0]

    calls = {"ddgjax solve_poisson": (ddgjax_solve, (tet_mesh.vertices,))}
    if igl is not None:
        calls["libigl + scipy spsolve"] = (scipy_solve, (V,))
        calls["libigl min_quad_with_fixed"] = (igl_solve, (V,))
    times, results = timed_interleaved(calls, args.repeats, args.budget)
    for call, t in times.items():
        print(f"  {call:28s} {fmt(t, args.repeats)}")
    if igl is not None:
        ratio = times["ddgjax solve_poisson"][0] / times["libigl + scipy spsolve"][0]
        difference = rel_err(results["ddgjax solve_poisson"], results["libigl + scipy spsolve"])
        print(f"  ratio {ratio:.3g}x; relative difference {difference:.1e}")
        ratio = times["ddgjax solve_poisson"][0] / times["libigl min_quad_with_fixed"][0]
        difference = rel_err(results["ddgjax solve_poisson"], results["libigl min_quad_with_fixed"])
        print(f"  against min_quad_with_fixed: ratio {ratio:.3g}x; relative difference {difference:.1e}")
    gradient = jax.grad(lambda vertices: jnp.sum(ddgjax_solve(vertices)))
    gradient_times, _ = timed_interleaved({"gradient": (gradient, (tet_mesh.vertices,))}, args.repeats, args.budget)
    print(f"  gradient of sum(u) in the positions: {fmt(gradient_times['gradient'], args.repeats)}")


SECTIONS = {"build": section_build, "assembly": section_assembly, "solve": section_solve}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sections", default=",".join(SECTIONS))
    parser.add_argument("--sizes", default="26,40", help="comma-separated n of tet_box(n) (6 n^3 tets)")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--budget", type=float, default=10.0)
    args = parser.parse_args()
    args.sizes = [int(n) for n in args.sizes.split(",")]
    run_sections(SECTIONS, args)


if __name__ == "__main__":
    raise SystemExit(main())
