"""Eigenpairs and heat-method distances: ddgjax side by side with SciPy, potpourri3d and libigl, one process.

Sections (`--sections`, comma-separated; all by default):

- **eigs**: the `k` (default 50) smallest eigenpairs of `L phi = lambda M phi` (cotan Laplacian,
  Voronoi mass) on the meshes of `--meshes` (default `icosphere(6)` (41k vertices) and camelhead;
  `icosphere(7)`: 164k), ddgjax's `eigenpairs` (jitted) against SciPy's
  `eigsh(L, k, M, sigma, which="LM")` on the same matrices, and the gradient of a loss of the
  eigenvalues and of one of the eigenvectors (value and gradient, jitted) against the eigensolve;
  `--subspace` adds the pure-JAX path (subspace iteration, CG preconditioned by AMG).
  Targets: eigensolve no slower than SciPy; gradient at most 2x the eigensolve.
- **heat**: one heat-method distance query with a prebuilt solver (ddgjax's `HeatDistanceSolver`
  with potpourri3d's options, jitted and eager; with ddgjax's defaults) against potpourri3d's
  `MeshHeatMethodDistanceSolver.compute_distance` (`use_robust=False`) and libigl's
  `heat_geodesics_solve`; building the solvers; ddgjax's value and gradient of a loss of the distance.
  Targets: the query within 1.2x of potpourri3d's; its gradient at most 2x the query.
  `--meshes "spot.obj,camelhead.off,icosphere(6)"` runs the issue's three meshes.

Times: min / median ms over interleaved repeats (`benchmarks/solve.py`'s `timed_interleaved`).
Run: `python benchmarks/spectral.py [--sections eigs,heat] [--meshes NAMES] [--k 50] [--repeats 5] [--subspace]`.
"""

from __future__ import annotations

import pathlib
import sys

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import scipy.sparse.linalg as spla  # noqa: E402

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from solve import fmt, jit, mesh_sections_parser, optional, run_sections, timed_interleaved, warmed  # noqa: E402

from ddgjax.geodesics import heat_distance_solver  # noqa: E402
from ddgjax.io import load_mesh  # noqa: E402
from ddgjax.laplacian import cotan_laplacian, mass_matrix  # noqa: E402
from ddgjax.mesh import icosphere  # noqa: E402
from ddgjax.solve import amg_hierarchy  # noqa: E402
from ddgjax.spectral import eigenpairs  # noqa: E402

igl = optional("igl")
pp3d = optional("potpourri3d")
SHARED = pathlib.Path(__file__).resolve().parents[2] / "shared" / "meshes"


def meshes(names):
    """`{name: mesh}`: icospheres by subdivision (`icosphere(6)`), or files in ../shared/meshes."""
    result = {}
    for name in names:
        if name.startswith("icosphere("):
            result[name] = icosphere(int(name[len("icosphere(") : -1]))
        else:
            result[name] = load_mesh(SHARED / name)
    return result


def section_eigs(args):
    print(f"\n# the {args.k} smallest eigenpairs of L phi = lambda M phi (Voronoi mass)")
    for name, mesh in meshes(args.meshes).items():
        _eigs_on(name, mesh, args)


def _eigs_on(name, mesh, args):
    L, M = cotan_laplacian(mesh).to_scipy().tocsc(), mass_matrix(mesh).to_scipy().tocsc()
    shift = -1e-8 * L.diagonal().sum() / M.diagonal().sum()
    start = np.ones(mesh.n_vertices) + np.linspace(0.0, 1.0, mesh.n_vertices)
    k = args.k
    ours = jit(lambda V: eigenpairs(mesh.with_vertices(V), k))
    weights = jnp.linspace(0.0, 1.0, mesh.n_vertices)

    def values_loss(V):
        return jnp.sum(eigenpairs(mesh.with_vertices(V), k)[0][1:] ** 2)

    def vectors_loss(V):
        values, vectors = eigenpairs(mesh.with_vertices(V), k)
        return jnp.sum(values[1:]) + jnp.sum(weights * vectors[:, 1] ** 2)

    calls = {
        "scipy eigsh (shift-invert, SuperLU)": (
            lambda: spla.eigsh(L, k=k, M=M, sigma=shift, which="LM", v0=start, tol=0.0),
            (),
        ),
        "ddgjax eigenpairs (jit)": (ours, (mesh.vertices,)),
        "ddgjax value and gradient, eigenvalue loss": (jit(jax.value_and_grad(values_loss)), (mesh.vertices,)),
        "ddgjax value and gradient, + an eigenvector": (jit(jax.value_and_grad(vectors_loss)), (mesh.vertices,)),
    }
    if args.subspace:
        # The accelerator's path on this CPU: subspace iteration, CG preconditioned by AMG (a hierarchy of L).
        hierarchy = amg_hierarchy(cotan_laplacian(mesh))
        calls["ddgjax eigenpairs, subspace + CG-AMG (pure JAX)"] = (
            jit(lambda V: eigenpairs(mesh.with_vertices(V), k, method="subspace", solver="cg", preconditioner=hierarchy)),
            (mesh.vertices,),
        )
    times, results = timed_interleaved(warmed(calls), args.repeats, args.budget)
    expected = np.sort(results["scipy eigsh (shift-invert, SuperLU)"][0])
    error = np.abs(np.asarray(results["ddgjax eigenpairs (jit)"][0]) - expected).max() / expected.max()
    reference = times["ddgjax eigenpairs (jit)"][0]
    print(
        f"\n## {name}: n = {mesh.n_vertices}  (min / median ms; ratio to ddgjax's eigensolve)  eigenvalues agree to {error:.1e}"
    )
    for row, t in times.items():
        print(f"  {row:48s} {fmt(t, args.repeats):>24s} {t[0] / reference:7.2f}x")


def section_heat(args):
    print("\n# heat-method distance: one query with a prebuilt solver (t = h^2, barycentric mass, Neumann)")
    for name, mesh in meshes(args.meshes).items():
        _heat_on(name, mesh, args)


def _heat_on(name, mesh, args):
    V, F = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    # potpourri3d's options (module docstring of ddgjax.geodesics): lumped barycentric mass, the Neumann heat flow.
    solver = heat_distance_solver(mesh, mass="barycentric", boundary="neumann")
    defaults = heat_distance_solver(mesh)
    source = np.array([0])
    query = jit(lambda solver: solver.distance(source))
    weights = jnp.linspace(0.0, 1.0, mesh.n_vertices)

    def loss(V):
        moved = heat_distance_solver(mesh.with_vertices(V), mass="barycentric", boundary="neumann")
        return jnp.sum(weights * moved.distance(source))

    calls = {
        "ddgjax HeatDistanceSolver.distance (jit)": (query, (solver,)),
        "ddgjax the same, eager": (lambda: solver.distance(source), ()),
        "ddgjax default options (jit)": (query, (defaults,)),
    }
    if pp3d is not None:
        pp_solver = pp3d.MeshHeatMethodDistanceSolver(V, F, t_coef=1.0, use_robust=False)
        calls["potpourri3d compute_distance"] = (pp_solver.compute_distance, (0,))
    if igl is not None and hasattr(igl, "heat_geodesics_precompute"):
        data = igl.HeatGeodesicsData() if hasattr(igl, "HeatGeodesicsData") else None
        if data is not None:
            t = float(np.mean(np.linalg.norm(V[F[:, 1]] - V[F[:, 0]], axis=1))) ** 2
            igl.heat_geodesics_precompute(V, F, t, data)
            calls["libigl heat_geodesics_solve"] = (lambda: igl.heat_geodesics_solve(data, np.array([0])), ())
    # The builds and gradients in a group of their own: interleaved with sub-millisecond queries, their
    # large working sets would leave the queries to run from cold caches.
    queries = calls
    calls = {}
    calls["ddgjax heat_distance_solver (build, eager)"] = (
        lambda: heat_distance_solver(mesh, mass="barycentric", boundary="neumann").heat.token,
        (),
    )
    if pp3d is not None:
        calls["potpourri3d MeshHeatMethodDistanceSolver (build)"] = (
            lambda: pp3d.MeshHeatMethodDistanceSolver(V, F, t_coef=1.0, use_robust=False),
            (),
        )
    calls["ddgjax build + query (jit)"] = (
        jit(lambda V: heat_distance_solver(mesh.with_vertices(V), mass="barycentric", boundary="neumann").distance(source)),
        (mesh.vertices,),
    )
    calls["ddgjax value and gradient (build + query)"] = (jit(jax.value_and_grad(loss)), (mesh.vertices,))
    times = {**timed_interleaved(warmed(queries), args.repeats, args.budget)[0]}
    times.update(timed_interleaved(warmed(calls), args.repeats, args.budget)[0])
    reference = times.get("potpourri3d compute_distance", times["ddgjax HeatDistanceSolver.distance (jit)"])[0]
    print(f"\n## {name}: n = {mesh.n_vertices}  (min / median ms; ratio to potpourri3d's query)")
    for row, t in times.items():
        print(f"  {row:50s} {fmt(t, args.repeats):>24s} {t[0] / reference:7.2f}x")


SECTIONS = {"eigs": section_eigs, "heat": section_heat}


def main(argv=None) -> int:
    parser = mesh_sections_parser(__doc__.splitlines()[0], SECTIONS, "icosphere(6),camelhead.off", budget=20.0)
    parser.add_argument("--k", type=int, default=50)
    parser.add_argument("--subspace", action="store_true", help="also time the pure-JAX path (subspace iteration, CG-AMG)")
    run_sections(SECTIONS, parser.parse_args(argv))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
