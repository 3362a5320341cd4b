"""Intrinsic Delaunay Laplacian: ddgjax against robust_laplacian and libigl, in one process.

For each mesh (`../shared/meshes` camelhead, beetle, nefertiti, and an icosphere(6) whose vertices
are moved tangentially by 0.3 edge lengths, back onto the sphere, so that it has obtuse angles) it
times

- **build** from the mesh: `intrinsic_delaunay_laplacian(mesh)` (host flips, their plan, then the
  compiled replay and assembly), and L together with the barycentric mass matrix from one
  triangulation, against `robust_laplacian.mesh_laplacian(V, F, mollify_factor=0)` (which returns both)
  and `igl.intrinsic_delaunay_cotmatrix(V, F)` (L only); also from `(V, F)` with `Mesh.from_arrays`
  included, and the host flips alone;
- **rebuild** for new vertex positions with the same flips, jitted: the replayed lengths and L;
- **gradient** of `u^T L u` with respect to the vertices, through the replay (jitted).

Compile time (the first call) is reported apart. Functions jitted here compile with
`ddgjax.cpu_compiler_options()`, as the README recommends. Times are min / median over repeats, in
ms, compared calls interleaved (`benchmarks/laplacian.py`'s helpers). Run:
`python benchmarks/intrinsic.py [--repeats N]` (about two minutes).
"""

from __future__ import annotations

import argparse
import os
import platform

import jax

jax.config.update("jax_enable_x64", True)

import igl  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import robust_laplacian  # noqa: E402
from laplacian import SHARED, first_call, fmt, jit, timed, timed_interleaved  # noqa: E402

from ddgjax.io import load_mesh  # noqa: E402
from ddgjax.laplacian import intrinsic_delaunay, intrinsic_delaunay_laplacian, intrinsic_delaunay_mass_matrix  # noqa: E402
from ddgjax.mesh import Mesh, icosphere  # noqa: E402


def jittered_icosphere(subdivisions: int, amount: float = 0.3, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Icosphere vertices moved tangentially by `amount` edge lengths (normal noise), back onto the unit sphere."""
    mesh = icosphere(subdivisions)
    V = np.asarray(mesh.vertices)
    noise = np.random.default_rng(seed).standard_normal(V.shape) * amount * 1.1 / 2**subdivisions
    noise -= np.sum(noise * V, axis=1, keepdims=True) * V
    moved = V + noise
    return moved / np.linalg.norm(moved, axis=1, keepdims=True), np.asarray(mesh.faces)


def laplacian_and_mass(mesh: Mesh):
    triangulation = intrinsic_delaunay(mesh)
    L = intrinsic_delaunay_laplacian(mesh, triangulation=triangulation)
    M = intrinsic_delaunay_mass_matrix(mesh, triangulation=triangulation, mass="barycentric")
    return L.values, M.values


def bench_mesh(V: np.ndarray, F: np.ndarray, repeats: int):
    mesh = Mesh.from_arrays(V, F)
    triangulation = intrinsic_delaunay(mesh)
    compiles = {
        "build": first_call(lambda m: intrinsic_delaunay_laplacian(m).values, mesh),
        "mass": first_call(laplacian_and_mass, mesh),
    }
    F_int64 = F.astype(np.int64)
    # The same triangles with their corners rotated: a face array no living mesh has, so the
    # topology and every plan are built anew, as for a new mesh.
    F_new = np.ascontiguousarray(F[:, [1, 2, 0]])
    rows = timed_interleaved(
        {
            "robust_laplacian.mesh_laplacian (L and M)": (
                lambda V, F: robust_laplacian.mesh_laplacian(V, F, mollify_factor=0.0),
                (V, F),
            ),
            "igl.intrinsic_delaunay_cotmatrix (L)": (igl.intrinsic_delaunay_cotmatrix, (V, F_int64)),
            "ddgjax intrinsic_delaunay (host flips + plan)": (intrinsic_delaunay, (mesh,)),
            "ddgjax build L = intrinsic_delaunay_laplacian(mesh)": (lambda m: intrinsic_delaunay_laplacian(m).values, (mesh,)),
            "ddgjax build L and M (barycentric)": (laplacian_and_mass, (mesh,)),
            "ddgjax build L from (V, F), Mesh.from_arrays included": (
                lambda V, F: intrinsic_delaunay_laplacian(Mesh.from_arrays(V, F)).values,
                (V, F_new),
            ),
        },
        repeats=repeats,
    )
    # Rebuild for moved vertices, the flips kept (mesh and triangulation are jit arguments).
    moved = jnp.asarray(V * 1.01)
    lengths = jit(lambda m, t, W: t.face_lengths_sq(m.with_vertices(W)))
    rebuild = jit(lambda m, t, W: intrinsic_delaunay_laplacian(m.with_vertices(W), triangulation=t).values)
    u = jnp.asarray(np.random.default_rng(1).standard_normal(V.shape[0]))
    energy = lambda m, t, W: jnp.vdot(u, intrinsic_delaunay_laplacian(m.with_vertices(W), triangulation=t) @ u)
    gradient = jit(jax.grad(energy, argnums=2))
    compiles["rebuild"] = first_call(rebuild, mesh, triangulation, moved)
    first_call(lengths, mesh, triangulation, moved)
    compiles["gradient"] = first_call(gradient, mesh, triangulation, moved)
    rows.update(
        timed_interleaved(
            {
                "ddgjax rebuild: replayed lengths (jitted)": (lengths, (mesh, triangulation, moved)),
                "ddgjax rebuild: lengths + L (jitted)": (rebuild, (mesh, triangulation, moved)),
            },
            repeats=repeats,
        )
    )
    rows["ddgjax grad_V u^T L u (jitted)"] = timed(gradient, mesh, triangulation, moved, repeats=repeats)[0]
    return triangulation, rows, compiles


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args(argv)
    print(
        f"# machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
        f"python {platform.python_version()}, jax {jax.__version__} ({jax.default_backend()}), float64"
    )
    meshes = []
    for name in ("camelhead.off", "beetle.off", "nefertiti.obj"):
        if (SHARED / name).exists():
            mesh = load_mesh(SHARED / name)
            meshes.append((name, np.asarray(mesh.vertices), np.asarray(mesh.faces)))
    meshes.append(("icosphere(6), tangential noise 0.3", *jittered_icosphere(6)))
    for name, V, F in meshes:
        triangulation, rows, compiles = bench_mesh(V, F, args.repeats)
        print(
            f"\n## {name}: {V.shape[0]} vertices, {F.shape[0]} faces, {triangulation.n_flips} flips in "
            f"{triangulation.n_rounds} rounds  (min / median ms)"
        )
        for key, value in rows.items():
            print(f"  {key:58s} {fmt(value)}")
        print("  compile (first call, ms): " + ", ".join(f"{k} {v:.0f}" for k, v in compiles.items()))
        robust = rows["robust_laplacian.mesh_laplacian (L and M)"][0]
        build = rows["ddgjax build L = intrinsic_delaunay_laplacian(mesh)"][0]
        ratios = {
            "build L / robust": build / robust,
            "build L+M / robust": rows["ddgjax build L and M (barycentric)"][0] / robust,
            "build from (V, F) / robust": rows["ddgjax build L from (V, F), Mesh.from_arrays included"][0] / robust,
            "build L / igl": build / rows["igl.intrinsic_delaunay_cotmatrix (L)"][0],
            "robust / rebuild": robust / rows["ddgjax rebuild: lengths + L (jitted)"][0],
            "gradient / rebuild": rows["ddgjax grad_V u^T L u (jitted)"][0] / rows["ddgjax rebuild: lengths + L (jitted)"][0],
        }
        print("  ratios (min times): " + ", ".join(f"{k} {v:.2f}" for k, v in ratios.items()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
