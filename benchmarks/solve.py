"""Laplacian linear systems: sparse solvers side by side, in one process, on the same matrices.

Sections (`--sections`, comma-separated; all by default):

- **direct**: the host sparse direct solvers that install with plain pip, on the systems ddgjax
  solves. For each mesh (icospheres of ~40k, ~160k and ~650k vertices,
  `../shared/meshes/armadillo_loop1.ply`, `../shared/meshes/camelhead.off` with boundary) it builds
  with ddgjax the cotan Laplacian `L` and the Voronoi mass `M` and two SPD systems, exported with
  `.to_scipy()`:
  the implicit heat step `A = M + t L`, `t = h^2` (`h` the mean edge length), right-hand side `M r`;
  the Dirichlet problem `L_ff u = (M 1)_f`, `L` restricted to the free vertices (the boundary fixed
  on camelhead, vertex 0 on closed meshes).
  Contenders (those that import): SciPy `spsolve` / `splu` (SuperLU; COLAMD, and its symmetric mode),
  cholespy, pypardiso (MKL PARDISO; SPD Cholesky `mtype=2`, and `mtype=11`, the LU that
  `pypardiso.spsolve` uses), sparsax (CHOLMOD as XLA FFI calls: eager, jitted, in `lax.scan`, under
  `vmap`, its gradient), and pyamg-preconditioned SciPy CG to 1e-10 relative residual for reference.
  Columns: (a) factorise + solve one right-hand side; (b) one more solve with the kept
  factorisation; (c) a kept-factorisation solve of 8 right-hand sides. Every answer is checked
  against `spsolve`'s. A last table says what each backend does on matrices that are not positive
  definite (a closed mesh's singular `L`, `-L`, the indefinite `L - 3M`).

Times are min / median over repeats, in ms; calls compared with each other run interleaved, in an
order rotated each round. A call's first run is a warm-up unless it took over a second (then it
is the first sample), and a call stops repeating once its runs add up to `--budget` seconds, so a
slow solver on a big mesh runs once or twice ("(k)" after a time: k samples). Run:
`python benchmarks/solve.py [--sections direct] [--max-vertices N] [--meshes NAMES] [--systems heat]
[--skip NAMES] [--quick]`. On 2 cores the whole direct section takes over half an hour; by parts:
`--meshes "icosphere(6),camelhead"` ~10 min; `--meshes "icosphere(7)" --skip "symmetric mode"`
(SuperLU's symmetric mode takes a minute per factorisation there) ~5 min a system; the ~650k-vertex
icosphere with `--repeats 2 --budget 1 --skip "splu,values change each step"` ~5 min a system.
"""

from __future__ import annotations

import argparse
import importlib
import itertools
import os
import pathlib
import platform
import time
import warnings

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import scipy  # noqa: E402
import scipy.sparse as sp  # noqa: E402
import scipy.sparse.linalg as spla  # noqa: E402

import ddgjax  # noqa: E402
from ddgjax.io import load_mesh  # noqa: E402
from ddgjax.laplacian import cotan_laplacian, mass_matrix  # noqa: E402
from ddgjax.mesh import edge_lengths, icosphere  # noqa: E402


def optional(name):
    """The module, or None when it does not import (an optional peer)."""
    try:
        return importlib.import_module(name)
    except ImportError:
        return None


cholespy = optional("cholespy")
pypardiso = optional("pypardiso")
pyamg = optional("pyamg")
sparsax = optional("sparsax")

SHARED = pathlib.Path(__file__).resolve().parents[2] / "shared" / "meshes"


# Functions jitted here are what a user writes; they compile as the README recommends.
def jit(function, **kwargs):
    return jax.jit(function, compiler_options=ddgjax.cpu_compiler_options() or None, **kwargs)


# --- timing ------------------------------------------------------------------------------------


def timed_interleaved(calls: dict, repeats: int, budget_s: float) -> tuple[dict, dict]:
    """`({name: (min, median, samples) ms}, {name: last result})` for `{name: (fn, args)}`.

    As in `benchmarks/laplacian.py`: rounds in which every call runs once, in an order rotated
    each round, so compared calls see the same drift of this VM. Direct solvers span four orders
    of magnitude, so two additions: a call's first run is a warm-up (page faults, lazy library
    loading, JAX dispatch caches) unless it took over a second, when it counts as the first
    sample; and a call stops once its runs add up to `budget_s`, leaving at least one sample.
    """
    times = {name: [] for name in calls}
    spent = dict.fromkeys(calls, 0.0)
    results = {}
    names = list(calls)
    for round_ in range(repeats + 1):
        shift = round_ % len(names)
        for name in names[shift:] + names[:shift]:
            if len(times[name]) >= repeats or (times[name] and spent[name] > budget_s):
                continue
            fn, args = calls[name]
            start = time.perf_counter()
            results[name] = jax.block_until_ready(fn(*args))
            elapsed = time.perf_counter() - start
            spent[name] += elapsed
            if round_ > 0 or elapsed > 1.0:
                times[name].append(1e3 * elapsed)
    return {name: (min(t), float(np.median(t)), len(t)) for name, t in times.items()}, results


def warmed(calls: dict) -> dict:
    """`calls` after one run of each (compilation, first-touch costs), for `timed_interleaved` on slow calls."""
    for fn, args in calls.values():
        jax.block_until_ready(fn(*args))
    return calls


def compile_time(fn, *args):
    """Wall time in ms of compiling the jitted `fn` for these arguments, ahead of time: a first call
    would also run it (ten factorisations for a scan), and the compiled program is cached for the
    calls that follow."""
    start = time.perf_counter()
    fn.lower(*args).compile()
    return 1e3 * (time.perf_counter() - start)


def fmt(t, repeats):
    if t is None:
        return "-"
    digits = 1 if t[0] >= 1 else 3
    more = f" ({t[2]})" if t[2] < repeats else ""
    return f"{t[0]:.{digits}f} / {t[1]:.{digits}f}{more}"


def rel_err(x, ref):
    x, ref = np.asarray(x), np.asarray(ref)
    return float(np.linalg.norm(x - ref) / np.linalg.norm(ref))


# --- matrices ------------------------------------------------------------------------------------


def mesh_catalogue():
    """`[(name, vertex count, loader)]`: the meshes of issue 13, smallest icosphere first."""
    catalogue = [(f"icosphere({s})", 10 * 4**s + 2, lambda s=s: icosphere(s)) for s in (6, 7, 8)]
    for file in ("armadillo_loop1.ply", "camelhead.off"):
        path = SHARED / file
        if path.exists():
            # vertex count from the file without building the mesh twice: load once, keep it
            mesh = load_mesh(path)
            catalogue.append((path.stem, mesh.n_vertices, lambda mesh=mesh: mesh))
    return catalogue


def laplacian_systems(mesh, rng):
    """`{system name: (A, b, B, m)}`: SPD CSR matrix, one and eight right-hand sides, and the lumped
    mass of the unknowns (for the heat steps of the scan)."""
    L = cotan_laplacian(mesh).to_scipy().tocsr()
    M = mass_matrix(mesh, mass="voronoi").to_scipy().tocsr()
    m = M.diagonal()
    n = L.shape[0]
    h = float(np.mean(np.asarray(edge_lengths(mesh))))
    heat = (M + h**2 * L).tocsr()
    topology = mesh.topology
    fixed = np.asarray(topology.boundary_vertices) if not topology.is_closed else np.array([0])
    free = np.setdiff1d(np.arange(n), fixed)
    dirichlet = L[free][:, free].tocsr()
    systems = {
        f"heat M + h^2 L (h = {h:.3g})": (heat, M @ rng.standard_normal(n), M @ rng.standard_normal((n, 8)), m),
        f"Dirichlet L_ff ({fixed.size} fixed)": (
            dirichlet,
            m[free],
            (M @ rng.standard_normal((n, 8)))[free],
            m[free],
        ),
    }
    for A, *_ in systems.values():
        A.sum_duplicates()
        A.sort_indices()
    return systems


# --- direct solvers ------------------------------------------------------------------------------

# SuperLU's symmetric mode: a minimum-degree ordering of A + A^T and no row pivoting off the
# diagonal, the setting SuperLU's documentation recommends for SPD matrices.
SUPERLU_SYMMETRIC = dict(permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options=dict(SymmetricMode=True))


class Pardiso:
    """pypardiso with the analysis + factorisation redone on every `factor_solve` and kept by
    `solve` (its public API: `solve` compares the matrix with the factorised one, O(nnz))."""

    def __init__(self, A, mtype):
        self.A = sp.triu(A, format="csr") if mtype == 2 else A  # PARDISO's symmetric types read the upper triangle
        self.fresh = pypardiso.PyPardisoSolver(mtype=mtype)
        self.kept = pypardiso.PyPardisoSolver(mtype=mtype)
        self.kept.factorize(self.A)

    def factor_solve(self, b):
        self.fresh.remove_stored_factorization()  # so `solve` runs phase 13: analysis, factorisation, solve
        return self.fresh.solve(self.A, b)

    def solve(self, b):
        return self.kept.solve(self.A, b)

    def free(self):
        self.fresh.free_memory(everything=True)
        self.kept.free_memory(everything=True)


def cholespy_factor(A):
    return cholespy.CholeskySolverD(A.shape[0], A.indptr, A.indices, A.data, cholespy.MatrixType.CSR)


def cholespy_solve(solver, b):
    x = np.empty_like(b)
    solver.solve(np.require(b, requirements=["C", "W"]), x)  # nanobind refuses read-only arrays
    return x


def amg_cg(A, ml, b):
    """SciPy CG preconditioned by one pyamg V-cycle, to 1e-10 relative residual; columns in turn."""
    preconditioner = ml.aspreconditioner(cycle="V")
    columns = b.reshape(b.shape[0], -1).T
    x = np.stack([spla.cg(A, c, rtol=1e-10, atol=0.0, M=preconditioner, maxiter=1000)[0] for c in columns], axis=1)
    return x.reshape(b.shape)


class SparsaxValues:
    """Matrix values for sparsax calls that must factorise: sparsax skips the numeric factorisation
    when the values equal the last ones of the pattern (a one-slot value cache), so these calls get
    `A` scaled by 1.001 or 1.002 in turn (never the plain values, which the other calls use) and
    undo the scale on the answer, `(s A)^-1 b = A^-1 b / s`, to be checked like the others."""

    def __init__(self, Ax):
        self.scaled = [(jnp.asarray(Ax * s), s) for s in (1.001, 1.002)]
        self.turn = itertools.count()

    def next(self):
        return self.scaled[next(self.turn) % 2]


def sparsax_calls(A, b, B, m):
    """The sparsax rows of the three columns (each `{name: (fn, args)}`) and a setup for (b) / (c)."""
    n = A.shape[0]
    U = sp.triu(A, format="coo")
    Ai, Aj, Ax = jnp.asarray(U.row, jnp.int32), jnp.asarray(U.col, jnp.int32), jnp.asarray(U.data)
    bj, Bj, mj = jnp.asarray(b), jnp.asarray(B), jnp.asarray(m)
    values = SparsaxValues(U.data)
    w = jnp.asarray(np.random.default_rng(3).standard_normal(n))

    solve = jit(lambda Ai, Aj, Ax, b: sparsax.solve(Ai, Aj, Ax, b))
    solve_factor = jit(lambda token, b: sparsax.solve_factor(token, b))
    solve_columns = jit(jax.vmap(lambda Ai, Aj, Ax, b: sparsax.solve(Ai, Aj, Ax, b), in_axes=(None, None, None, 1), out_axes=1))

    def loss(Ax, b):
        return jnp.vdot(w, sparsax.solve(Ai, Aj, Ax, b))

    grad_b = jit(jax.grad(loss, argnums=1))
    grad_both = jit(jax.grad(loss, argnums=(0, 1)))
    steps = 10

    # 10 implicit heat steps u <- A^-1 (m u) in one compiled program: with A fixed (the factor is
    # reused from step to step) and with A's values changing every step (a factorisation a step).
    @jit
    def scan_fixed(Ai, Aj, Ax, m, u):
        return jax.lax.scan(lambda u, _: (sparsax.solve(Ai, Aj, Ax, m * u), None), u, None, length=steps)[0]

    @jit
    def scan_changing(Ai, Aj, Ax, m, u, scales):
        return jax.lax.scan(lambda u, s: (sparsax.solve(Ai, Aj, Ax * s, m * u), None), u, scales)[0]

    scales = jnp.asarray(1.0 + 1e-5 * np.arange(1, steps + 1))  # distinct from 1.001 / 1.002 and from each other
    compile_ms = {
        "solve": compile_time(solve, Ai, Aj, Ax, bj) + compile_time(solve, Ai, Aj, Ax, Bj),
        "grad": compile_time(grad_both, Ax, bj) + compile_time(grad_b, Ax, bj),
        "scan": compile_time(scan_fixed, Ai, Aj, Ax, mj, bj) + compile_time(scan_changing, Ai, Aj, Ax, mj, bj, scales),
        "vmap": compile_time(solve_columns, Ai, Aj, Ax, Bj),
    }

    def eager_cold(b):
        sparsax.clear_cache()  # drops the cached analysis too: ordering + factorisation + solve
        return sparsax.solve(Ai, Aj, Ax, b)

    def eager_new_values(b):
        Axs, s = values.next()
        return np.asarray(sparsax.solve(Ai, Aj, Axs, b)) * s

    def jit_new_values(b):
        Axs, s = values.next()
        return np.asarray(solve(Ai, Aj, Axs, b)) * s

    def grad_b_new_values(b):
        return grad_b(values.next()[0], b)

    def grad_both_new_values(b):
        return grad_both(values.next()[0], b)

    factor_column = {
        "sparsax.solve eager, cold (cache cleared: analysis + factor + solve)": (eager_cold, (bj,)),
        "sparsax.solve eager, new values (analysis cached)": (eager_new_values, (bj,)),
        "sparsax.solve jitted, new values (analysis cached)": (jit_new_values, (bj,)),
        "sparsax jitted grad wrt b, new values": (grad_b_new_values, (bj,)),
        "sparsax jitted grad wrt (Ax, b), new values": (grad_both_new_values, (bj,)),
        f"sparsax lax.scan of {steps}, values change each step (per step)": (
            scan_changing,
            (Ai, Aj, Ax, mj, bj, scales),
        ),
    }
    per_step_rows = {f"sparsax lax.scan of {steps}, values change each step (per step)"}

    def kept_setup():
        """After the factor column (whose cold calls clear sparsax's cache): put the plain values
        in the value cache and hold a factor token; returns the (b) and (c) rows."""
        sparsax.clear_cache()
        jax.block_until_ready(sparsax.solve(Ai, Aj, Ax, bj))
        token = jax.block_until_ready(sparsax.factor(Ai, Aj, Ax, n))
        compile_time(solve_factor, token, bj)
        compile_time(solve_factor, token, Bj)
        one = {
            "sparsax.solve_factor(token) eager": (sparsax.solve_factor, (token, bj)),
            "sparsax.solve_factor(token) jitted": (solve_factor, (token, bj)),
            "sparsax.solve eager, same values (cached factor)": (sparsax.solve, (Ai, Aj, Ax, bj)),
            "sparsax.solve jitted, same values (cached factor)": (solve, (Ai, Aj, Ax, bj)),
            "sparsax jitted grad wrt (Ax, b), same values": (grad_both, (Ax, bj)),
            f"sparsax lax.scan of {steps}, fixed A (per step)": (scan_fixed, (Ai, Aj, Ax, mj, bj)),
        }
        eight = {
            "sparsax.solve_factor(token) eager": (sparsax.solve_factor, (token, Bj)),
            "sparsax.solve_factor(token) jitted": (solve_factor, (token, Bj)),
            "sparsax.solve eager, same values (cached factor)": (sparsax.solve, (Ai, Aj, Ax, Bj)),
            "sparsax.solve jitted, same values (cached factor)": (solve, (Ai, Aj, Ax, Bj)),
            "sparsax jitted vmap over the 8 columns, same values": (solve_columns, (Ai, Aj, Ax, Bj)),
        }
        return one, eight, {f"sparsax lax.scan of {steps}, fixed A (per step)"}

    def check_gradient(x_ref, reference_solve):
        """The gradient's error against the adjoint computed with another solver: d/db = A^-1 w,
        d/dAx_ij = -(v_i x_j + v_j x_i) (i < j), -v_i x_i (i = j)."""
        g_Ax, g_b = grad_both(Ax, bj)
        v = reference_solve(np.asarray(w))
        r, c = U.row, U.col
        expected = -np.where(r == c, v[r] * x_ref[r], v[r] * x_ref[c] + v[c] * x_ref[r])
        return rel_err(g_b, v), rel_err(g_Ax, expected)

    return factor_column, kept_setup, per_step_rows, compile_ms, check_gradient


SPSOLVE = "scipy spsolve (SuperLU, COLAMD)"
SPLU = "scipy splu + solve (COLAMD)"
SPLU_SYMMETRIC = "scipy splu + solve (symmetric mode, MMD(A+A^T))"
CHOLESPY = "cholespy (CHOLMOD simplicial, METIS)"
PARDISO = {2: "pypardiso mtype=2 (SPD Cholesky)", 11: "pypardiso mtype=11 (LU, pypardiso.spsolve's default)"}
AMG_CG = "pyamg SA setup + CG to 1e-10 (reference)"


def bench_direct_system(A, b, B, m, repeats, budget_s, skip=()):
    """`(rows, notes)`: rows `{name: {"a"|"b"|"c": timing, "err": max relative error}}`. Rows whose
    name contains a string of `skip` are left out (spsolve, the reference, never is)."""

    def wanted(name):
        return name == SPSOLVE or not any(key in name for key in skip)

    csc = A.tocsc()
    rows = {}
    errors = {}

    def run(column, calls, reference, per_step=()):
        """Time the wanted calls of one column; record times (per step for scans) and errors."""
        timings, results = timed_interleaved({k: v for k, v in calls.items() if wanted(k)}, repeats, budget_s)
        for name, t in timings.items():
            rows.setdefault(name, {})[column] = (t[0] / 10, t[1] / 10, t[2]) if name in per_step else t
        if reference is None:
            reference = np.asarray(results[SPSOLVE])
        for name, x in results.items():
            # a gradient is not a solution, a scan not one solve: those are checked apart
            if "grad" not in name and name not in per_step:
                errors[name] = max(errors.get(name, 0.0), rel_err(x, reference))
        return reference, results

    # --- (a) factorise + solve one right-hand side ------------------------------------------
    factor_column = {
        SPSOLVE: (spla.spsolve, (A, b)),
        SPLU: (lambda b: spla.splu(csc).solve(b), (b,)),
        SPLU_SYMMETRIC: (lambda b: spla.splu(csc, **SUPERLU_SYMMETRIC).solve(b), (b,)),
    }
    if cholespy is not None:
        factor_column[CHOLESPY] = (lambda b: cholespy_solve(cholespy_factor(A), b), (b,))
    pardiso = {}
    if pypardiso is not None:
        pardiso = {PARDISO[mtype]: Pardiso(A, mtype) for mtype in PARDISO if wanted(PARDISO[mtype])}
        for name, solver in pardiso.items():
            factor_column[name] = (solver.factor_solve, (b,))
    if pyamg is not None:
        factor_column[AMG_CG] = (lambda b: amg_cg(A, pyamg.smoothed_aggregation_solver(A), b), (b,))
    notes = []
    use_sparsax = sparsax is not None and wanted("sparsax")
    per_step = set()
    if use_sparsax:
        sx_factor, sx_kept, per_step, compile_ms, check_gradient = sparsax_calls(A, b, B, m)
        factor_column.update(sx_factor)
        notes.append("sparsax compile (ahead of time, ms): " + ", ".join(f"{k} {v:.0f}" for k, v in compile_ms.items()))
    x_ref, _ = run("a", factor_column, None, per_step)

    # --- (b) and (c): solves with the kept factorisation --------------------------------------
    one = {}
    for name, options in ((SPLU, {}), (SPLU_SYMMETRIC, SUPERLU_SYMMETRIC)):
        if wanted(name):
            one[name] = (spla.splu(csc, **options).solve, (b,))
    if cholespy is not None and wanted(CHOLESPY):
        chol = cholespy_factor(A)
        one[CHOLESPY] = (lambda b: cholespy_solve(chol, b), (b,))
    # the solver the gradient and the scan are checked with: SuperLU where it runs, else cholespy
    reference = next(iter(one), None)
    reference_solve = one[reference][0] if reference else lambda b: spla.spsolve(A, b)
    reference = reference or SPSOLVE
    for name, solver in pardiso.items():
        one[name] = (solver.solve, (b,))
    if pyamg is not None:
        ml = pyamg.smoothed_aggregation_solver(A)
        one[AMG_CG] = (lambda b: amg_cg(A, ml, b), (b,))
    eight = {name: (fn, (B,)) for name, (fn, _) in one.items()}
    eight[SPSOLVE] = (spla.spsolve, (A, B))
    kept_per_step = set()
    if use_sparsax:
        sx_one, sx_eight, kept_per_step = sx_kept()
        one.update(sx_one)
        eight.update(sx_eight)
    _, results = run("b", one, x_ref, kept_per_step)
    for name in kept_per_step & set(results):
        u = np.asarray(b)
        for _ in range(10):
            u = reference_solve(m * u)
        errors[name] = rel_err(results[name], u)  # against 10 steps with the reference solver
    del results
    run("c", eight, None)
    if use_sparsax:
        e_b, e_Ax = check_gradient(x_ref, reference_solve)
        notes.append(f"sparsax gradient vs an adjoint solve with {reference}: rel. err d/db {e_b:.1e}, d/dAx {e_Ax:.1e}")

        def ratio(name, column, base, base_column):
            if name in rows and base in rows:
                return f"{rows[name][column][0] / rows[base][base_column][0]:.2f}"
            return "n/a"

        fwd_new, fwd_same = (
            "sparsax.solve jitted, new values (analysis cached)",
            "sparsax.solve jitted, same values (cached factor)",
        )
        notes.append(
            "sparsax gradient / forward (min times): new values: wrt b "
            f"{ratio('sparsax jitted grad wrt b, new values', 'a', fwd_new, 'a')}, wrt (Ax, b) "
            f"{ratio('sparsax jitted grad wrt (Ax, b), new values', 'a', fwd_new, 'a')}; same values (factor cached): "
            f"wrt (Ax, b) {ratio('sparsax jitted grad wrt (Ax, b), same values', 'b', fwd_same, 'b')}"
        )
        sparsax.clear_cache()
    for solver in pardiso.values():
        solver.free()
    for name in rows:
        rows[name]["err"] = errors.get(name)
    return rows, notes


def failure_modes():
    """`{backend: {case: outcome}}` on an icosphere(3) (642 vertices): a closed mesh's singular `L`
    with a generic right-hand side and with a compatible one (mean zero), `-L`, and `L - 3M`
    (indefinite and nonsingular: the sphere's eigenvalues 0, 2 and 6 straddle 3)."""
    mesh = icosphere(3)
    L = cotan_laplacian(mesh).to_scipy().tocsr()
    M = mass_matrix(mesh).to_scipy().tocsr()
    b = M @ np.random.default_rng(0).standard_normal(L.shape[0])
    cases = {
        "L (singular), generic b": (L, b),
        "L (singular), b with mean 0": (L, b - b.mean()),
        "-L": ((-L).tocsr(), b),
        "L - 3M (indefinite)": ((L - 3 * M).tocsr(), b),
    }

    def sparsax_args(A):
        U = sp.triu(A, format="coo")
        return jnp.asarray(U.row, jnp.int32), jnp.asarray(U.col, jnp.int32), jnp.asarray(U.data)

    backends = {
        "scipy spsolve": lambda A, b: spla.spsolve(A, b),
        "scipy splu (COLAMD)": lambda A, b: spla.splu(A.tocsc()).solve(b),
        "scipy splu (symmetric mode)": lambda A, b: spla.splu(A.tocsc(), **SUPERLU_SYMMETRIC).solve(b),
    }
    if cholespy is not None:
        backends["cholespy"] = lambda A, b: cholespy_solve(cholespy_factor(A), b)
    if pypardiso is not None:
        backends["pypardiso mtype=2"] = lambda A, b: pypardiso.PyPardisoSolver(mtype=2).solve(sp.triu(A, format="csr"), b)
        backends["pypardiso mtype=11"] = lambda A, b: pypardiso.PyPardisoSolver(mtype=11).solve(A, b)
    if sparsax is not None:
        backends["sparsax.solve eager"] = lambda A, b: sparsax.solve(*sparsax_args(A), b)
        backends["sparsax.solve jitted"] = lambda A, b: jax.jit(sparsax.solve)(*sparsax_args(A), b)
        backends["sparsax.factor + solve_factor"] = lambda A, b: sparsax.solve_factor(
            sparsax.factor(*sparsax_args(A), A.shape[0]), b
        )

        def in_scan(A, b):
            # a 3-step scan whose second step gets the bad matrix (steps 1 and 3: M + L, SPD)
            Ai, Aj, bad = sparsax_args(A)
            good_i, good_j, good = sparsax_args((M + L).tocsr())
            if not (np.array_equal(Ai, good_i) and np.array_equal(Aj, good_j)):
                return "skipped: pattern differs from M + L's"
            stack = jnp.stack([good, bad, good])
            body = lambda u, Ax: (sparsax.solve(Ai, Aj, Ax, u), None)
            u = np.asarray(jax.jit(lambda u, s: jax.lax.scan(body, u, s)[0])(jnp.asarray(b), stack))
            # three steps, not one solve: no residual to report, only whether anything signalled
            finite = "finite" if np.isfinite(u).all() else "NaN/inf"
            return f"no error; the scan returns {finite} values, max|u| {np.abs(u).max():.0e}"

        backends["sparsax.solve in lax.scan (bad 2nd step)"] = in_scan
    if pyamg is not None:

        def cg(A, b):
            x, info = spla.cg(A, b, rtol=1e-10, atol=0.0, M=pyamg.smoothed_aggregation_solver(A).aspreconditioner(), maxiter=1000)
            return f"info={info} ({'converged' if info == 0 else 'not converged'}), " + describe(A, b, x)

        backends["pyamg SA + CG"] = cg

    def describe(A, b, x):
        x = np.asarray(x)
        if not np.isfinite(x).all():
            return f"NaN/inf in {np.count_nonzero(~np.isfinite(x))} of {x.size} entries, no error"
        residual = np.linalg.norm(A @ x - b) / np.linalg.norm(b)
        return f"finite, rel. residual {residual:.0e}, max|x| {np.abs(x).max():.0e}"

    outcomes = {}
    for backend, fn in backends.items():
        outcomes[backend] = {}
        for case, (A, b) in cases.items():
            A.sort_indices()
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    x = fn(A, b)
                    x = jax.block_until_ready(x)
                outcome = x if isinstance(x, str) else describe(A, b, x)
            except Exception as error:  # the point of this table: what each backend raises
                message = " ".join(str(error).split())
                outcome = f"raises {type(error).__name__}: {message[:90]}"
            outcomes[backend][case] = outcome
    return outcomes


def section_direct(args):
    print("\n# direct solvers")
    # pypardiso runs MKL's OpenMP threads; sparsax >= 0.10's wheels link a threaded OpenBLAS, which on
    # this busy 2-core VM made its factorisations 10-80x slower than with OPENBLAS_NUM_THREADS=1
    threads = ", ".join(
        f"{k}={os.environ.get(k, 'unset')}" for k in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")
    )
    versions = {
        "scipy": scipy.__version__,
        "cholespy": _dist_version("cholespy"),
        "pypardiso": _dist_version("pypardiso"),
        "mkl": _dist_version("mkl"),
        "sparsax": _dist_version("sparsax"),
        "pyamg": _dist_version("pyamg"),
        "scikit-sparse": _dist_version("scikit-sparse"),
    }
    print("versions: " + ", ".join(f"{k} {v}" for k, v in versions.items()) + f"; threads: {threads}")
    print(f"scipy.sparse.linalg.cholesky: {'present' if hasattr(spla, 'cholesky') else 'absent in this SciPy'}")
    rng = np.random.default_rng(0)
    summary = {}
    for name, nv, load in mesh_catalogue():
        if nv > args.max_vertices or (args.meshes and not any(key in name for key in args.meshes)):
            continue
        mesh = load()
        for system, (A, b, B, m) in laplacian_systems(mesh, rng).items():
            if args.systems and not any(key.lower() in system.lower() for key in args.systems):
                continue
            title = f"{name}, {system}: n = {A.shape[0]}, nnz = {A.nnz}"
            print(f"\n## {title}  (min / median ms)", flush=True)
            start = time.perf_counter()
            # more samples where a call takes milliseconds: this VM's noise needs them
            repeats = args.repeats * (3 if A.shape[0] < 100_000 else 1)
            rows, notes = bench_direct_system(A, b, B, m, repeats, args.budget, args.skip)
            header = f"  {'':70s} {'(a) factor + solve':>22s} {'(b) kept, 1 rhs':>20s} {'(c) kept, 8 rhs':>20s}  max rel. err vs spsolve"
            print(header)
            for row, cells in rows.items():
                err = cells.get("err")
                print(
                    f"  {row:70s} {fmt(cells.get('a'), repeats):>22s} {fmt(cells.get('b'), repeats):>20s} "
                    f"{fmt(cells.get('c'), repeats):>20s}  {'-' if err is None else f'{err:.1e}'}"
                )
            print("  (c) for spsolve includes the factorisation: it keeps none. Per-step rows divide a 10-step scan by 10.")
            for note in notes:
                print("  " + note)
            print(f"  [this system took {time.perf_counter() - start:.0f} s]", flush=True)
            summary[title] = rows
    print_summary(summary)
    if not args.skip_failures:
        print("\n## matrices that are not positive definite: icosphere(3), 642 vertices")
        for backend, outcomes in failure_modes().items():
            print(f"  {backend}")
            for case, outcome in outcomes.items():
                print(f"    {case:30s} {outcome}")


def print_summary(summary):
    """Per column, each contender's min time over the fastest row's (among the rows that solve
    the same problem: plain solvers, not gradients or scans)."""
    if not summary:
        return
    print("\n## summary: min time / fastest min time, per matrix (a: factor + solve; b: kept solve, 1 rhs; c: kept, 8 rhs)")
    for title, rows in summary.items():
        print(f"  {title}")
        for column in "abc":
            plain = {
                name: cells[column][0]
                for name, cells in rows.items()
                if column in cells and "grad" not in name and "scan" not in name
            }
            if column == "c":
                plain.pop("scipy spsolve (SuperLU, COLAMD)", None)
            if not plain:
                continue
            fastest = min(plain.values())
            ranked = sorted(plain.items(), key=lambda item: item[1])
            print(f"    ({column}) fastest {fastest:.1f} ms: " + "; ".join(f"{name} {t / fastest:.2f}" for name, t in ranked))


# --- differentiation, optimistix, CG, scans --------------------------------------------------------


def selected_meshes(args, default=("icosphere(6)", "camelhead")):
    """The catalogue's meshes these sections run on: `--meshes`, else `default`, within `--max-vertices`."""
    keys = args.meshes or default
    for name, nv, load in mesh_catalogue():
        if nv <= args.max_vertices and any(key in name for key in keys):
            yield name, load()


def mean_edge_length(mesh):
    return float(np.mean(np.asarray(edge_lengths(mesh))))


def section_gradients(args):
    """The backward pass of a solve, with respect to `b` and to the vertex positions, against the forward solve."""

    print("\n# backward pass against the forward factor + solve (ddgjax linear_solve, method 'auto')")
    print("  loss = |x|^2 / 2 with (M + t L) x = b, t = h^2; values change every call (a new factorisation each time)")
    for name, mesh in selected_meshes(args):
        _gradients_on(name, mesh, args)


def _gradients_on(name, mesh, args):
    from ddgjax.solve import linear_solve
    from ddgjax.sparse import SparseMatrix

    t = mean_edge_length(mesh) ** 2
    heat = lambda V: mass_matrix(mesh.with_vertices(V)) + t * cotan_laplacian(mesh.with_vertices(V))
    A = heat(mesh.vertices)
    pattern = A.pattern
    b = A @ jnp.asarray(np.random.default_rng(0).standard_normal(mesh.n_vertices))
    solve = lambda values, b: linear_solve(SparseMatrix(values, pattern, symmetric=True, positive_semidefinite=True), b).value
    loss = lambda x: 0.5 * jnp.sum(x * x)
    forward = jit(lambda values, b: loss(solve(values, b)))
    backward_b = jit(jax.value_and_grad(lambda values, b: loss(solve(values, b)), argnums=1))
    backward_values = jit(jax.value_and_grad(lambda values, b: loss(solve(values, b)), argnums=(0, 1)))
    forward_V = jit(lambda V: loss(linear_solve(heat(V), b).value))
    backward_V = jit(jax.value_and_grad(lambda V: loss(linear_solve(heat(V), b).value)))
    values = [A.values * s for s in (1.001, 1.002)]  # sparsax skips a factorisation of the values it saw last
    vertices = [mesh.vertices * s for s in (1.001, 1.002)]
    turn = itertools.count()
    pick = lambda options: options[next(turn) % 2]
    calls = {
        "forward: factor + solve": (lambda: forward(pick(values), b), ()),
        "value and gradient in b": (lambda: backward_b(pick(values), b), ()),
        "value and gradient in b and the matrix values": (lambda: backward_values(pick(values), b), ()),
        "forward from vertex positions (assembly + solve)": (lambda: forward_V(pick(vertices)), ()),
        "value and gradient in the vertex positions": (lambda: backward_V(pick(vertices)), ()),
    }
    times, _ = timed_interleaved(warmed(calls), args.repeats, args.budget)
    print(f"\n## {name}: n = {mesh.n_vertices}  (min / median ms; ratio to its forward)")
    for row, reference in (
        ("forward: factor + solve", None),
        ("value and gradient in b", "forward: factor + solve"),
        ("value and gradient in b and the matrix values", "forward: factor + solve"),
        ("forward from vertex positions (assembly + solve)", None),
        ("value and gradient in the vertex positions", "forward from vertex positions (assembly + solve)"),
    ):
        ratio = "" if reference is None else f"{times[row][0] / times[reference][0]:.2f}x"
        print(f"  {row:58s} {fmt(times[row], args.repeats):>22s} {ratio:>8s}")


def section_optimistix(args):
    """Quadratic energies minimised by optimistix and by `ddgjax.optim.minimize_energy`, against the direct solve."""

    print("\n# optimistix route: argmin of a quadratic energy, against the direct solve (assemble, factor, solve)")
    print("  screened: 1/2 u^T (L + s M) u - u^T M rho, s = 1 / h^2 (direct: linear_solve(L + s M, M rho))")
    print("  dirichlet: 1/2 u^T L u with u = g fixed on the boundary (camelhead) or where |z| > 0.8 (closed meshes)")
    print("  (direct: harmonic_interpolation)")
    for name, mesh in selected_meshes(args):
        _optimistix_on(name, mesh, args)


def _optimistix_on(name, mesh, args):
    import optimistix as optx

    from ddgjax.optim import minimize_energy
    from ddgjax.pde import dirichlet_energy, harmonic_interpolation, screened_dirichlet_energy
    from ddgjax.solve import SparseCholesky, linear_solve

    L = cotan_laplacian(mesh)
    s = 1.0 / mean_edge_length(mesh) ** 2
    rng = np.random.default_rng(1)
    rho = jnp.asarray(rng.standard_normal(mesh.n_vertices))
    boundary = np.asarray(mesh.topology.boundary_vertices)
    fixed = boundary if boundary.size else np.flatnonzero(np.abs(np.asarray(mesh.vertices[:, 2])) > 0.8)
    g = jnp.asarray(rng.standard_normal(fixed.size))

    # Every route starts from the vertex positions (assembly or energy included), passed as arguments.
    def energy(u, data):
        moved = mesh.with_vertices(data[0])
        return screened_dirichlet_energy(moved, u, s) - jnp.vdot(u, mass_matrix(moved) @ data[1])

    def direct_solve(data):
        moved = mesh.with_vertices(data[0])
        M = mass_matrix(moved)
        return linear_solve(cotan_laplacian(moved) + s * M, M @ data[1]).value

    solver = SparseCholesky(L.pattern)
    answer = lambda solution: (solution.value, solution.stats["num_steps"])
    start = lambda data: jnp.zeros_like(data[1])
    root = lambda method, steps: jit(
        lambda data: answer(optx.root_find(jax.grad(energy), method, start(data), data, max_steps=steps, throw=False))
    )
    minimise = lambda method, steps: jit(
        lambda data: answer(optx.minimise(energy, method, start(data), data, max_steps=steps, throw=False))
    )
    screened = {
        "direct (linear_solve)": jit(direct_solve),
        "minimize_energy(E, mesh=mesh)": jit(lambda data: answer(minimize_energy(energy, start(data), mesh=mesh, args=(data,)))),
        "optx.root_find(grad E, Newton(SparseCholesky))": root(optx.Newton(1e-12, 1e-12, linear_solver=solver), 10),
        "optx.root_find(grad E, Chord(SparseCholesky))": root(optx.Chord(1e-12, 1e-12, linear_solver=solver), 10),
        "optx.minimise(E, LBFGS), 2000 steps at most": minimise(optx.LBFGS(1e-10, 1e-10), 2000),
        "optx.minimise(E, NonlinearCG), 2000 steps at most": minimise(optx.NonlinearCG(1e-10, 1e-10), 2000),
    }
    dirichlet = {
        "direct (harmonic_interpolation)": jit(
            lambda data: harmonic_interpolation(mesh.with_vertices(data[0]), fixed_vertices=fixed, fixed_values=data[1])
        ),
        "minimize_energy(E, mesh=mesh, fixed_vertices=...)": jit(
            lambda data: answer(
                minimize_energy(
                    lambda u, V: dirichlet_energy(mesh.with_vertices(V), u),
                    jnp.zeros(mesh.n_vertices),
                    mesh=mesh,
                    fixed_vertices=fixed,
                    fixed_values=data[1],
                    args=(data[0],),
                )
            )
        ),
    }
    for system, calls, rhs in (("screened", screened, rho), ("dirichlet", dirichlet, g)):
        # New vertex positions each call: sparsax keeps the factors of recent values (per pattern) and skips
        # their factorisation, so a cycle of two would time cache hits.
        data = [(mesh.vertices * (1 + 1e-4 * k), rhs) for k in range(1, 65)]
        turn = itertools.count()
        timed = {row: (lambda fn=fn, data=data, turn=turn: fn(data[next(turn) % len(data)]), ()) for row, fn in calls.items()}
        repeats = max(2, args.repeats // 2)
        times, _ = timed_interleaved(warmed(timed), repeats, args.budget)
        direct_row = next(iter(calls))
        reference = np.asarray(calls[direct_row](data[0]))
        print(
            f"\n## {name}, {system}: n = {mesh.n_vertices}  (min / median ms; ratio to the direct solve; steps; max error / max |u|)"
        )
        for row, fn in calls.items():
            result = fn(data[0])
            value = result if row == direct_row else result[0]
            steps = "" if row == direct_row else f"{int(result[1])} steps"
            error = float(np.abs(np.asarray(value) - reference).max() / np.abs(reference).max())
            print(
                f"  {row:52s} {fmt(times[row], repeats):>22s} {times[row][0] / times[direct_row][0]:7.2f}x "
                f"{steps:>11s}  {error:.1e}"
            )


def section_cg(args):
    """Pure-JAX CG (AMG V-cycle, Jacobi) against pyamg-preconditioned SciPy CG, to the same relative residual."""

    print("\n# conjugate gradients to |b - A x| <= 1e-10 |b|: ddgjax in JAX (jitted) against pyamg + SciPy CG on the host")
    for name, mesh in selected_meshes(args):
        _cg_on(name, mesh, args)


def _cg_on(name, mesh, args):
    from ddgjax.solve import amg_hierarchy, linear_solve
    from ddgjax.solve._amg import pyamg_solver
    from ddgjax.sparse import from_scipy

    for system, (A, b, _, _) in laplacian_systems(mesh, np.random.default_rng(0)).items():
        A_jax = from_scipy(A, positive_semidefinite=True)
        b_jax = jnp.asarray(b)
        start = time.perf_counter()
        hierarchy = jax.block_until_ready(amg_hierarchy(A_jax))
        setup_jax = 1e3 * (time.perf_counter() - start)
        start = time.perf_counter()
        ml = pyamg_solver(A)
        setup_pyamg = 1e3 * (time.perf_counter() - start)
        amg = jit(lambda A, h, b: linear_solve(A, b, solver="cg", preconditioner=h, throw=False))
        jacobi = jit(lambda A, b: linear_solve(A, b, solver="cg", max_steps=20_000, throw=False))
        calls = {
            "ddgjax cg + AMG V-cycle (hierarchy kept)": (amg, (A_jax, hierarchy, b_jax)),
            "pyamg V-cycle + scipy cg (hierarchy kept)": (amg_cg_counted, (A, ml, b)),
            "ddgjax cg + Jacobi (20000 steps at most)": (jacobi, (A_jax, b_jax)),
        }
        times, results = timed_interleaved(warmed(calls), args.repeats, args.budget)
        print(f"\n## {name}, {system}: n = {A.shape[0]}  (min / median ms; ratio to pyamg; iterations; residual)")
        for row, result in results.items():
            if row.startswith("pyamg"):
                x, steps = result
                residual = np.linalg.norm(A @ x - b) / np.linalg.norm(b)
            else:
                steps, residual = int(result.num_steps), float(result.residual)
            ratio = times[row][0] / times["pyamg V-cycle + scipy cg (hierarchy kept)"][0]
            print(f"  {row:46s} {fmt(times[row], args.repeats):>22s} {ratio:6.2f}x {steps:6d} it  {residual:.1e}")
        print(f"  hierarchy setup: ddgjax amg_hierarchy {setup_jax:.0f} ms (pyamg inside), pyamg alone {setup_pyamg:.0f} ms")


def amg_cg_counted(A, ml, b):
    """`(x, iterations)`: `amg_cg` on one right-hand side, counting the iterations."""
    count = [0]
    x, _ = spla.cg(
        A,
        b,
        rtol=1e-10,
        atol=0.0,
        M=ml.aspreconditioner(cycle="V"),
        maxiter=1000,
        callback=lambda _: count.__setitem__(0, count[0] + 1),
    )
    return x, count[0]


def section_scan(args):
    """100 implicit heat steps `(M + t L) u_{k+1} = M u_k`: one compiled `lax.scan` against the loop in SciPy."""

    print("\n# 100 implicit heat steps (M + t L) u_{k+1} = M u_k, t = h^2, factorisation made once per call")
    for name, mesh in selected_meshes(args):
        _scan_on(name, mesh, args)


def _scan_on(name, mesh, args):
    from ddgjax.solve import factorize
    from ddgjax.sparse import SparseMatrix

    A_jax = mass_matrix(mesh) + mean_edge_length(mesh) ** 2 * cotan_laplacian(mesh)
    M_jax = mass_matrix(mesh)
    A, M = A_jax.to_scipy(), M_jax.to_scipy()
    u0 = np.random.default_rng(2).standard_normal(mesh.n_vertices)
    values = [A_jax.values * s for s in (1.001, 1.002)]  # new values each call: sparsax refactors
    turn = itertools.count()

    def ddgjax_scan(method):
        @jit
        def run(values, u):
            kept = factorize(SparseMatrix(values, A_jax.pattern, symmetric=True, positive_semidefinite=True), solver=method)
            return jax.lax.scan(lambda u, _: (kept.solve(M_jax @ u).value, None), u, None, length=100)[0]

        return lambda: run(values[next(turn) % 2], jnp.asarray(u0))

    def scipy_loop(factor):
        def run():
            solve = factor(A.tocsc())
            u = u0
            for _ in range(100):
                u = solve(M @ u)
            return u

        return run

    calls = {"ddgjax factorize + scan, cholesky (CHOLMOD)": (ddgjax_scan("cholesky"), ())}
    calls["ddgjax factorize + scan, superlu"] = (ddgjax_scan("superlu"), ())
    calls["scipy splu (COLAMD) + loop"] = (scipy_loop(lambda A: spla.splu(A).solve), ())
    if cholespy is not None:
        calls["cholespy + loop"] = (
            scipy_loop(lambda A: (lambda s: lambda b: cholespy_solve(s, b))(cholespy_factor(A.tocsr()))),
            (),
        )
    times, _ = timed_interleaved(warmed(calls), max(2, args.repeats // 2), args.budget)
    fastest_peer = min(t[0] for row, t in times.items() if not row.startswith("ddgjax"))
    print(f"\n## {name}: n = {mesh.n_vertices}  (min / median ms for 100 steps; ratio to the fastest peer)")
    for row, t in times.items():
        print(f"  {row:46s} {fmt(t, max(2, args.repeats // 2)):>22s} {t[0] / fastest_peer:6.2f}x")


def section_kept(args):
    """Solves with a kept factorisation: ddgjax's `factorize(A).solve(b)` against cholespy's, and the factorisations."""

    print(
        "\n# kept factorisation of the heat step A = M + t L, t = h^2: one solve (1 and 8 right-hand sides), and the factorisation"
    )
    for name, mesh in selected_meshes(args, default=("icosphere(6)", "camelhead")):
        _kept_on(name, mesh, args)


def _kept_on(name, mesh, args):
    from ddgjax.solve import factorize
    from ddgjax.solve._linear import cholmod_analysis

    A_jax = mass_matrix(mesh) + mean_edge_length(mesh) ** 2 * cotan_laplacian(mesh)
    A = A_jax.to_scipy().tocsr()
    rng = np.random.default_rng(4)
    b, B = rng.standard_normal(A.shape[0]), rng.standard_normal((A.shape[0], 8))
    kept = factorize(A_jax, solver="cholesky")  # outside jit: a kept factorisation, simplicial (`cholmod_analysis`)
    with cholmod_analysis("auto"):
        supernodal = factorize(A_jax, solver="cholesky")  # what `linear_solve` makes: CHOLMOD's own choice
    solve = jit(lambda f, b: f.solve(b).value)
    calls = {
        "ddgjax factorize(A).solve(b), jitted": (solve, (kept, jnp.asarray(b))),
        "ddgjax the same, eager": (lambda: kept.solve(jnp.asarray(b)).value, ()),
        "ddgjax the same, CHOLMOD's supernodal choice (jitted)": (solve, (supernodal, jnp.asarray(b))),
        "ddgjax 8 right-hand sides, jitted": (solve, (kept, jnp.asarray(B))),
        "sparsax.solve_factor(the kept token), jitted: no residual check": (
            jit(sparsax.solve_factor),
            (kept.token, jnp.asarray(b)),
        ),
    }
    if cholespy is not None:
        factor = cholespy_factor(A)
        calls["cholespy solve"] = (cholespy_solve, (factor, b))
        calls["cholespy 8 right-hand sides"] = (cholespy_solve, (factor, B))
    scales = itertools.count(1)

    def new_values():
        return A_jax * (1.0 + 1e-6 * next(scales))  # new values: no cached numeric factor is reused

    calls["ddgjax factorize (eager, kept: simplicial)"] = (lambda: factorize(new_values(), solver="cholesky").token, ())

    def one_shot():
        with cholmod_analysis("auto"):
            return factorize(new_values(), solver="cholesky").token

    calls["ddgjax factorize, CHOLMOD's choice (linear_solve's)"] = (one_shot, ())
    if cholespy is not None:
        calls["cholespy factorisation"] = (cholespy_factor, (A,))
    times, _ = timed_interleaved(warmed(calls), args.repeats, args.budget)
    print(f"\n## {name}: n = {mesh.n_vertices}  (min / median ms; ratio to cholespy's row of the same kind)")
    for row, t in times.items():
        factorisation = row.startswith(("ddgjax factorize (", "ddgjax factorize,", "cholespy factorisation"))
        peer = (
            "cholespy factorisation"
            if factorisation
            else ("cholespy 8 right-hand sides" if "8 right" in row else "cholespy solve")
        )
        ratio = f"{t[0] / times[peer][0]:6.2f}x" if peer in times else ""
        print(f"  {row:58s} {fmt(t, args.repeats):>22s} {ratio}")


def _dist_version(name):
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(name)
    except PackageNotFoundError:
        return None


SECTIONS = {
    "direct": section_direct,
    "gradients": section_gradients,
    "optimistix": section_optimistix,
    "cg": section_cg,
    "scan": section_scan,
    "kept": section_kept,
}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sections", default=",".join(SECTIONS), help=f"comma-separated, of: {', '.join(SECTIONS)}")
    parser.add_argument("--max-vertices", type=int, default=None, help="skip meshes with more vertices")
    parser.add_argument(
        "--meshes", default=None, help="comma-separated substrings of mesh names to run (e.g. icosphere(6),camelhead)"
    )
    parser.add_argument("--systems", default=None, help="comma-separated: heat, dirichlet")
    parser.add_argument("--repeats", type=int, default=None, help="samples per call (default 5; 2 with --quick)")
    parser.add_argument(
        "--budget",
        type=float,
        default=None,
        help="seconds of runs after which a call stops repeating (default 20; 5 with --quick)",
    )
    parser.add_argument(
        "--skip", default=None, help="comma-separated substrings of contender names to leave out (e.g. splu on big meshes)"
    )
    parser.add_argument("--skip-failures", action="store_true", help="skip the non-positive-definite table")
    parser.add_argument("--quick", action="store_true", help="a smoke test: meshes up to 50k vertices, 2 repeats")
    args = parser.parse_args(argv)
    args.repeats = args.repeats or (2 if args.quick else 5)
    args.budget = args.budget or (5.0 if args.quick else 20.0)
    args.max_vertices = args.max_vertices or (50_000 if args.quick else 10**9)
    args.meshes = args.meshes.split(",") if args.meshes else None
    args.systems = args.systems.split(",") if args.systems else None
    args.skip = args.skip.split(",") if args.skip else ()
    unknown = set(args.sections.split(",")) - set(SECTIONS)
    if unknown:
        parser.error(f"unknown sections {sorted(unknown)}; known: {', '.join(SECTIONS)}")
    run_sections(SECTIONS, args)
    return 0


def mesh_sections_parser(description: str, sections: dict, meshes: str, budget: float) -> argparse.ArgumentParser:
    """The options the per-mesh benchmark scripts share (spectral.py, param.py, fields.py): `--sections`,
    `--meshes` (comma-separated), `--repeats`, `--budget`; a script adds its own, then calls `run_sections`."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--sections", default=",".join(sections), help=f"comma-separated, of: {', '.join(sections)}")
    parser.add_argument("--meshes", default=meshes, help="comma-separated: built-in shapes or file names in ../shared/meshes")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--budget", type=float, default=budget, help="seconds of runs per call, after which it stops repeating")
    return parser


def run_sections(sections: dict, args) -> None:
    """Print the machine line, then run the sections named in `args.sections` (comma-separated; shared with spectral.py)."""
    print(
        f"# machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
        f"python {platform.python_version()}, jax {jax.__version__} ({jax.default_backend()}), float64"
    )
    if isinstance(getattr(args, "meshes", None), str):
        args.meshes = args.meshes.split(",")
    for name in args.sections.split(","):
        sections[name](args)


if __name__ == "__main__":
    raise SystemExit(main())
