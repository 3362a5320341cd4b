"""Cotan Laplacian: ddgjax against libigl, gpytoolbox, robust_laplacian and triangulax, in one process.

For each mesh (icospheres of growing size, `../shared/meshes/armadillo_loop1.ply`) it times

- **build**: the Laplacian from a new `(V, F)`: `cotan_laplacian(Mesh.from_arrays(V, F))`, a new mesh
  object each repeat whose connectivity no living mesh shares (NumPy topology, the Laplacian's
  storage plan, then the assembly kernel compiled once per mesh size; the compile of the first mesh
  of each size is reported separately);
- **re-assembly** for moved vertices with the topology kept (jitted), against libigl's full build;
- the Voronoi **mass matrix** for moved vertices (jitted), also compiled by a plain `jax.jit`
  (XLA:CPU's YNNPACK fusions on), with the number of `__ynn_fusion` kernels in each compiled
  program: the measured reason for `ddgjax.cpu_compiler_options()`, which ddgjax's own kernels
  compile with (a property of XLA's output, so checked here, not in the tests; the Laplacian's own
  per-face arithmetic has no short reductions left for YNNPACK to take);
- **`L @ x`** against SciPy's CSR product on the same matrix;
- **matrix-free `L u`** (`laplacian_apply`, its own fused program) against assembling `L` and
  multiplying, both from moved vertices: the measured reason for keeping the matrix-free route;
- **gradient** of the Dirichlet energy `u^T L u / 2` w.r.t. the vertices (`dirichlet_energy`, whose
  derivative is written out), against the energy itself, its gradient in `u` alone, autodiff of the
  assembled `0.5 u^T (L u)` and libigl's energy (`bench_energy`; `--energy-only` runs just these).

Functions jitted here (as a user would) compile with `ddgjax.cpu_compiler_options()`, as the README
recommends (triangulax's too). Times are min / median over repeats, in ms. Run:
`python benchmarks/laplacian.py [--max-faces N] [--energy-only]`.
"""

from __future__ import annotations

import argparse
import os
import pathlib
import platform
import time

import jax

jax.config.update("jax_enable_x64", True)

import gpytoolbox  # noqa: E402
import igl  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import robust_laplacian  # noqa: E402

import ddgjax  # noqa: E402
from ddgjax.laplacian import cotan_laplacian, dirichlet_energy, laplacian_apply, mass_matrix  # noqa: E402
from ddgjax.mesh import Mesh, icosphere  # noqa: E402

try:
    import triangulax.linops as tx_linops
    import triangulax.mesh as tx_mesh
except ImportError:  # optional peer
    tx_linops = tx_mesh = None


# Functions jitted here are what a user writes; they compile as the README recommends (the options
# ddgjax's own kernels use: XLA:CPU's YNNPACK fusions off). With a plain `jax.jit` a user-jitted
# Dirichlet energy is up to 2x slower from ~160k vertices (a YNNPACK reduction), which would also
# flatter the gradient / energy ratio (icosphere(7): 1.5x plain, 2.6x with the options).
def jit(function, **kwargs):
    return jax.jit(function, compiler_options=ddgjax.cpu_compiler_options() or None, **kwargs)


SHARED = pathlib.Path(__file__).resolve().parents[2] / "shared" / "meshes"


def timed(fn, *args, repeats=5):
    """(min, median) wall time in ms of `fn(*args)` (results blocked on), and the last result."""
    times, result = [], None
    for _ in range(repeats):
        start = time.perf_counter()
        result = jax.block_until_ready(fn(*args))
        times.append(1e3 * (time.perf_counter() - start))
    return (min(times), float(np.median(times))), result


def timed_interleaved(calls: dict, repeats: int, block: int = 1) -> dict:
    """`{name: (min, median) ms}` for `{name: (fn, args)}`: `repeats` rounds, each running every call
    `block` times in turn, each round starting with the next call.

    Calls compared against each other then see the same drift of this VM and the same aftermath of
    earlier work (a peer's lingering worker threads), which one block after another does not. A
    block of several calls lets a sub-millisecond call reach its steady state (in our runs a JAX
    call and a SciPy call right after each other were both slower than in a run of their own).
    """
    times = {name: [] for name in calls}
    names = list(calls)
    for round_ in range(repeats):
        # Rotate the order each round: a call right after another library's is slower on this VM
        # (caches, thread wake-ups), so a fixed order would always penalise the same library.
        for name in names[round_ % len(names) :] + names[: round_ % len(names)]:
            fn, args = calls[name]
            for _ in range(block):
                start = time.perf_counter()
                jax.block_until_ready(fn(*args))
                times[name].append(1e3 * (time.perf_counter() - start))
    return {name: (min(t), float(np.median(t))) for name, t in times.items()}


def first_call(fn, *args):
    """Wall time in ms of the first (compiling) call."""
    start = time.perf_counter()
    jax.block_until_ready(fn(*args))
    return 1e3 * (time.perf_counter() - start)


def fmt(t):
    digits = 1 if t[0] >= 1 else 3
    return f"{t[0]:.{digits}f} / {t[1]:.{digits}f}"


def bench_mesh(name, V, F, repeats, run_robust):
    nv, nf = V.shape[0], F.shape[0]
    rows = {}
    # --- build from a new mesh -------------------------------------------------------------
    if run_robust:
        rows["robust_laplacian.mesh_laplacian"] = timed(robust_laplacian.mesh_laplacian, V, F, repeats=1)[0]
    mesh = Mesh.from_arrays(V, F)
    # `cotan_laplacian` runs a kernel compiled once per mesh size (not per mesh object): the first
    # mesh of a size pays the compile, every later one reuses it.
    compile_ms = first_call(lambda m: cotan_laplacian(m).values, mesh)
    # The same triangles with their corners rotated: a face array no living mesh has, so each build
    # makes its own storage plan (the plan is cached per connectivity while a mesh of it is alive).
    F_new = np.ascontiguousarray(F[:, [1, 2, 0]])
    rows.update(
        timed_interleaved(
            {
                "igl.cotmatrix": (igl.cotmatrix, (V, F)),
                "gpytoolbox.cotangent_laplacian": (gpytoolbox.cotangent_laplacian, (V, F)),
                "ddgjax topology (Mesh.from_arrays)": (Mesh.from_arrays, (V, F)),
                "ddgjax cotan_laplacian(mesh) (compiled kernel)": (lambda m: cotan_laplacian(m).values, (mesh,)),
                "ddgjax build = Mesh.from_arrays + cotan_laplacian, new mesh each time": (
                    lambda V, F: cotan_laplacian(Mesh.from_arrays(V, F)).values,
                    (V, F_new),
                ),
            },
            repeats=repeats,
        )
    )
    if tx_mesh is not None:
        try:

            def tx_build(V, F):
                hemesh = tx_mesh.HeMesh.from_triangles(nv, jnp.asarray(F))
                return tx_linops.cotan_laplace_sparse(jnp.asarray(V), hemesh).data

            rows["triangulax HeMesh + cotan_laplace_sparse (eager)"] = timed(tx_build, V, F, repeats=max(1, repeats // 2))[0]
        except Exception as error:  # report, do not abort the whole table
            rows["triangulax build"] = f"failed: {type(error).__name__}"
    # --- re-assembly for moved vertices --------------------------------------------------------
    # The mesh is a jit argument (its integer arrays are leaves), never a baked-in constant.
    reassemble = jit(lambda m, W: cotan_laplacian(m.with_vertices(W)).values)
    moved = jnp.asarray(V * 1.01)
    reassemble_compile = first_call(reassemble, mesh, moved)
    mass = jit(lambda m, W: mass_matrix(m.with_vertices(W)).values)
    plain_mass = jax.jit(lambda m, W: mass_matrix(m.with_vertices(W)).values)
    for fn in (mass, plain_mass):
        first_call(fn, mesh, moved)
    rows.update(
        timed_interleaved(
            {
                "ddgjax re-assembly (moved vertices, jitted)": (reassemble, (mesh, moved)),
                "ddgjax Voronoi mass matrix (moved vertices, jitted)": (mass, (mesh, moved)),
                "ddgjax Voronoi mass matrix, plain jax.jit (YNNPACK on)": (plain_mass, (mesh, moved)),
            },
            repeats=repeats,
        )
    )
    fusions = {
        name: compiled.lower(mesh, moved).compile().as_text().count("__ynn_fusion")
        for name, compiled in (("with cpu_compiler_options()", mass), ("plain jax.jit", plain_mass))
    }
    # gather_sum's fusion boundaries (conditionals XLA cannot fuse across) must survive when a user's jit
    # closes over the mesh, so that its storage plan is a constant: count them both ways.
    closed_over = jit(lambda W: cotan_laplacian(mesh.with_vertices(W)).values)
    fusions["conditionals, mesh as argument"] = reassemble.lower(mesh, moved).compile().as_text().count("conditional(")
    fusions["conditionals, mesh closed over"] = closed_over.lower(moved).compile().as_text().count("conditional(")
    # --- L @ x -------------------------------------------------------------------------------
    L = cotan_laplacian(mesh)
    csr = L.to_scipy()
    x = np.random.default_rng(0).standard_normal(nv)
    matvec = jit(lambda A, x: A @ x)
    xj = jnp.asarray(x)
    matvec_compile = first_call(matvec, L, xj)
    first_call(L.__matmul__, xj)  # outside jit `L @ x` runs one compiled product too (cached per shape and layout)
    rows.update(
        timed_interleaved(
            {
                "scipy CSR L @ x": (csr.dot, (x,)),
                "ddgjax L @ x (jitted)": (matvec, (L, xj)),
                "ddgjax L @ x (eager, no user jit)": (L.__matmul__, (xj,)),
            },
            repeats=4,
            block=repeats,
        )
    )
    # The same product repeated inside one jitted loop (as an iterative solver runs it), against a
    # Python loop of SciPy products: per product, without the per-call dispatch (~50 us for a jitted
    # call with a SparseMatrix argument, which dominates below ~50k faces).
    products = 100
    loop = jit(lambda A, x: jax.lax.fori_loop(0, products, lambda _, y: y + 1e-6 * (A @ y), x))
    first_call(loop, L, xj)

    def scipy_loop(x):
        for _ in range(products):
            x = x + 1e-6 * csr.dot(x)
        return x

    rows["scipy CSR L @ x, loop of 100 (per product)"] = tuple(v / products for v in timed(scipy_loop, x, repeats=repeats)[0])
    rows["ddgjax L @ x, jitted loop of 100 (per product)"] = tuple(v / products for v in timed(loop, L, xj, repeats=repeats)[0])
    X3 = np.random.default_rng(1).standard_normal((nv, 3))
    rows["scipy CSR L @ X (k=3)"] = timed(csr.dot, X3, repeats=2 * repeats)[0]
    rows["ddgjax L @ X (k=3)"] = timed(matvec, L, jnp.asarray(X3), repeats=2 * repeats)[0]
    energy_rows, gradient_compile = bench_energy(mesh, V, repeats)
    rows.update(energy_rows)
    u = jnp.asarray(np.random.default_rng(2).standard_normal(nv))  # the energy's u (bench_energy)
    # The matrix-free routes against the assembled matrix they equal (tests check the values).
    apply = jit(lambda m, W: laplacian_apply(m.with_vertices(W), u))
    assembled_apply = jit(lambda m, W: cotan_laplacian(m.with_vertices(W)) @ u)
    for fn in (apply, assembled_apply):
        first_call(fn, mesh, moved)
    rows.update(
        timed_interleaved(
            {
                "ddgjax laplacian_apply(moved, u) (matrix-free, jitted)": (apply, (mesh, moved)),
                "ddgjax cotan_laplacian(moved) @ u (assembled, jitted)": (assembled_apply, (mesh, moved)),
            },
            repeats=repeats,
        )
    )
    if tx_linops is not None:
        hemesh = tx_mesh.HeMesh.from_triangles(nv, jnp.asarray(F))
        tx_apply = jit(lambda h, W, u: tx_linops.compute_cotan_laplace(W, h, u))
        first_call(tx_apply, hemesh, moved, u)
        rows["triangulax matrix-free L u (jitted, incl. geometry)"] = timed(tx_apply, hemesh, moved, u, repeats=repeats)[0]
        tx_grad = jit(jax.grad(lambda h, W: -0.5 * u @ tx_linops.compute_cotan_laplace(W, h, u), argnums=1))
        first_call(tx_grad, hemesh, moved)
        rows["triangulax grad_V energy (jitted)"] = timed(tx_grad, hemesh, moved, repeats=repeats)[0]
    compiles = {"assembly": compile_ms, "re-assembly": reassemble_compile, "L @ x": matvec_compile, "grad": gradient_compile}
    return nv, nf, rows, compiles, fusions


def bench_energy(mesh, V, repeats):
    """Rows of the Dirichlet energy `u^T L u / 2` and its gradients (jitted, moved vertices), and the gradient's compile time.

    Interleaved in one loop: the energy, its gradient in the vertex positions (`dirichlet_energy`'s
    written-out derivative), its gradient in `u` alone (which skips the former), autodiff of the
    assembled `0.5 u^T (L u)`, and libigl's energy (`cotmatrix` build and product) for scale.
    """
    u_host = np.random.default_rng(2).standard_normal(V.shape[0])
    u = jnp.asarray(u_host)
    moved_host = V * 1.01
    moved = jnp.asarray(moved_host)
    energy = jit(lambda m, W: dirichlet_energy(m.with_vertices(W), u))
    gradient = jit(jax.grad(lambda m, W: dirichlet_energy(m.with_vertices(W), u), argnums=1))
    gradient_u = jit(jax.grad(lambda m, w: dirichlet_energy(m.with_vertices(moved), w), argnums=1))
    assembled_gradient = jit(jax.grad(lambda m, W: 0.5 * jnp.vdot(u, cotan_laplacian(m.with_vertices(W)) @ u), argnums=1))
    first_call(energy, mesh, moved)
    gradient_compile = first_call(gradient, mesh, moved)
    for fn, args in ((gradient_u, (mesh, u)), (assembled_gradient, (mesh, moved))):
        first_call(fn, *args)
    F = np.asarray(mesh.faces)

    def igl_energy(W):
        return -0.5 * u_host @ (igl.cotmatrix(W, F) @ u_host)

    rows = timed_interleaved(
        {
            "ddgjax energy u^T L u / 2 (jitted)": (energy, (mesh, moved)),
            "ddgjax grad_V energy (jitted)": (gradient, (mesh, moved)),
            "ddgjax grad_u energy (jitted)": (gradient_u, (mesh, u)),
            "ddgjax grad_V 0.5 u^T (L u), autodiff of the assembly": (assembled_gradient, (mesh, moved)),
            "libigl energy -u^T cotmatrix u / 2 (build + product)": (igl_energy, (moved_host,)),
        },
        repeats=repeats,
    )
    return rows, gradient_compile


def energy_ratios(rows):
    """The energy section's ratios (min times)."""
    closed = rows["ddgjax grad_V energy (jitted)"][0]
    return {
        "grad / energy": closed / rows["ddgjax energy u^T L u / 2 (jitted)"][0],
        "autodiff / closed-form grad": rows["ddgjax grad_V 0.5 u^T (L u), autodiff of the assembly"][0] / closed,
    }


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--max-faces", type=int, default=1_310_720, help="skip meshes with more faces")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--robust-max-faces", type=int, default=400_000, help="robust_laplacian is slow; skip beyond")
    parser.add_argument("--energy-only", action="store_true", help="only the Dirichlet energy and its gradients")
    args = parser.parse_args(argv)
    print(
        f"# machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
        f"python {platform.python_version()}, jax {jax.__version__} ({jax.default_backend()}), float64"
    )
    meshes = []
    for s in range(4, 9):
        if 20 * 4**s <= args.max_faces:
            ico = icosphere(s)
            meshes.append((f"icosphere({s})", np.asarray(ico.vertices), np.asarray(ico.faces)))
    armadillo = SHARED / "armadillo_loop1.ply"
    if armadillo.exists():
        V, F = igl.read_triangle_mesh(str(armadillo))
        if F.shape[0] <= args.max_faces:
            meshes.append(("armadillo_loop1", V, F))
    for name, V, F in meshes:
        # Small meshes take well under a millisecond per call: more repeats for a stable minimum.
        repeats = args.repeats * (4 if F.shape[0] < 100_000 else 1)
        if args.energy_only:
            rows, gradient_compile = bench_energy(Mesh.from_arrays(V, F), V, repeats)
            print(f"\n## {name}: {V.shape[0]} vertices, {F.shape[0]} faces  (min / median ms)")
            for key, value in rows.items():
                print(f"  {key:55s} {fmt(value)}")
            print(f"  compile (first call, ms): grad {gradient_compile:.0f}")
            print("  ratios (min times): " + ", ".join(f"{k} {v:.2f}" for k, v in energy_ratios(rows).items()))
            continue
        nv, nf, rows, compiles, fusions = bench_mesh(name, V, F, repeats, F.shape[0] <= args.robust_max_faces)
        print(f"\n## {name}: {nv} vertices, {nf} faces  (min / median ms)")
        for key, value in rows.items():
            print(f"  {key:55s} {value if isinstance(value, str) else fmt(value)}")
        print("  compile (first call, ms): " + ", ".join(f"{k} {v:.0f}" for k, v in compiles.items()))
        print(
            "  compiled structure (__ynn_fusion kernels of the mass matrix; gather_sum's boundaries, equal counts expected): "
            + ", ".join(f"{k} {v}" for k, v in fusions.items())
        )
        igl_ms = rows["igl.cotmatrix"][0]
        ratios = {
            "build / igl": rows["ddgjax build = Mesh.from_arrays + cotan_laplacian, new mesh each time"][0] / igl_ms,
            "igl / re-assembly": igl_ms / rows["ddgjax re-assembly (moved vertices, jitted)"][0],
            "L@x / scipy": rows["ddgjax L @ x (jitted)"][0] / rows["scipy CSR L @ x"][0],
            "eager L@x / scipy": rows["ddgjax L @ x (eager, no user jit)"][0] / rows["scipy CSR L @ x"][0],
            "L@x in loop / scipy": rows["ddgjax L @ x, jitted loop of 100 (per product)"][0]
            / rows["scipy CSR L @ x, loop of 100 (per product)"][0],
            "L@X(k=3) / scipy": rows["ddgjax L @ X (k=3)"][0] / rows["scipy CSR L @ X (k=3)"][0],
            "plain jit / tuned mass": rows["ddgjax Voronoi mass matrix, plain jax.jit (YNNPACK on)"][0]
            / rows["ddgjax Voronoi mass matrix (moved vertices, jitted)"][0],
            "assembled / matrix-free L u": rows["ddgjax cotan_laplacian(moved) @ u (assembled, jitted)"][0]
            / rows["ddgjax laplacian_apply(moved, u) (matrix-free, jitted)"][0],
            **energy_ratios(rows),
        }
        print("  ratios (min times): " + ", ".join(f"{k} {v:.2f}" for k, v in ratios.items()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
