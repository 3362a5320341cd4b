"""Laplacian systems at scale: how the cost of one solve grows with the number of unknowns.

Three families of symmetric positive definite systems (`--families`), each at growing sizes:

- **mesh**: the heat step `A = M + 0.01 L` of icospheres (`--levels`, default 6, 7, 8: 40,962,
  163,842 and 655,362 vertices; level 9 has 2,621,442), `L` the cotan Laplacian, `M` the Voronoi
  mass, right-hand side `M r` for a random `r`. No obtuse angle: `A` is an M-matrix.
- **rough**: the same on the icospheres with every vertex moved by 0.4 mean edge lengths at random:
  obtuse triangles, positive off-diagonal entries (as on scanned meshes), the case AMG needs its
  costlier evolution strength of connection for.
- **graph**: label propagation on the symmetrised 10-nearest-neighbour graph of uniform random
  points in the unit cube (`--graph-sizes`), Gaussian weights (`ddgjax.graph.knn_graph`): the block
  `L_ff` of the graph Laplacian on the unlabelled vertices, 1 % of the vertices labelled, right-hand
  side `-L_fl y_l` for random labels `y_l` (the system `ddgjax.graph.harmonic_interpolation` solves).
  A 3-D neighbourhood graph: its Cholesky factor fills in far more than a surface's.

Every contender solves to a relative residual `|A x - b| / |b| <= 1e-8` (checked; the direct
solvers reach ~1e-14), one-shot: factorisation or preconditioner set-up included, as a user's first
solve with new values pays; the matrix is converted to each library's input format once, untimed.
Contenders: ddgjax's `linear_solve` with `solver="auto"` (the default), and with each backend named;
CHOLMOD through sparsax (`sparsax.solve`, the same library as ddgjax's `"cholesky"`) and through
cholespy; pyamg's smoothed-aggregation solver with its defaults as CG preconditioner
(`ml.solve(b, tol=1e-8, accel="cg")`). sparsax keeps the last numeric factorisation of a pattern and
skips refactoring equal values, so every call gets the matrix scaled by another factor (1.001, 1.002,
...) and its answer is checked against that. Calls run in rounds, one call of each contender per
round in an order rotated each round; ddgjax's first call (compilation) is not a sample, its time
is printed apart.

Printed: per family, a table of min seconds per contender and size, the fitted growth exponent `p`
of `time ~ n^p` (least squares on log-log over the sizes measured), and the ratio of each contender
to the fastest peer at the largest size; `--plot FILE` draws the same on log-log axes.

Run: `python benchmarks/scale.py` (~15 min on 2 cores); `--levels 6,7,8,9` adds 2.6M vertices;
`--only NAMES` runs some contenders; `--direct-max N` leaves the direct solvers out above N unknowns
on the graph family (their fill grows like n^(4/3) in 3-D; default 200,000).
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import scipy.sparse as sp  # noqa: E402
from solve import _dist_version, optional  # noqa: E402

from ddgjax.graph import graph_laplacian, knn_graph  # noqa: E402
from ddgjax.laplacian import cotan_laplacian, mass_matrix  # noqa: E402
from ddgjax.mesh import icosphere  # noqa: E402
from ddgjax.solve import linear_solve  # noqa: E402
from ddgjax.solve._linear import auto_solver  # noqa: E402
from ddgjax.sparse import from_scipy  # noqa: E402

cholespy = optional("cholespy")
pyamg = optional("pyamg")
sparsax = optional("sparsax")

TOLERANCE = 1e-8
PEERS = ("sparsax CHOLMOD", "cholespy CHOLMOD", "pyamg SA + CG")
DIRECT = ("ddgjax cholesky", "ddgjax superlu", "sparsax CHOLMOD", "cholespy CHOLMOD")


# --- systems ---------------------------------------------------------------------------------------


def heat_step_system(mesh, rng) -> tuple[sp.csr_matrix, np.ndarray]:
    """`(A, b)`: the heat step `M + 0.01 L` of `mesh` (cotan `L`, Voronoi `M`) and `M r` for a random `r`."""
    L = cotan_laplacian(mesh).to_scipy().tocsr()
    M = mass_matrix(mesh, mass="voronoi").to_scipy().tocsr()
    return (M + 0.01 * L).tocsr(), M @ rng.standard_normal(L.shape[0])


def mesh_system(level: int, rng) -> tuple[sp.csr_matrix, np.ndarray]:
    """`heat_step_system` of `icosphere(level)`."""
    return heat_step_system(icosphere(level), rng)


def jittered_mesh_system(level: int, rng, amplitude: float = 0.4) -> tuple[sp.csr_matrix, np.ndarray]:
    """`heat_step_system` of `icosphere(level)` with every vertex moved by `amplitude` times the mean edge length
    in a uniform random direction: obtuse triangles, so `L` has positive off-diagonal entries (not an M-matrix,
    as on most scanned meshes)."""
    mesh = icosphere(level)
    V, E = np.asarray(mesh.vertices), np.asarray(mesh.edges)
    h = np.linalg.norm(V[E[:, 0]] - V[E[:, 1]], axis=1).mean()
    step = rng.standard_normal(V.shape)
    return heat_step_system(mesh.with_vertices(V + amplitude * h * step / np.linalg.norm(step, axis=1, keepdims=True)), rng)


def graph_system(n: int, rng) -> tuple[sp.csr_matrix, np.ndarray]:
    """`(L_ff, -L_fl y_l)`: label propagation on the 10-NN graph of `n` random points in the unit cube."""
    points = rng.random((n, 3))
    graph = knn_graph(points, n_neighbors=10)
    L = graph_laplacian(graph.edges, edge_weights=graph.edge_weights, n_vertices=n).to_scipy().tocsr()
    labelled = rng.choice(n, size=max(1, n // 100), replace=False)
    free = np.setdiff1d(np.arange(n), labelled)
    y = rng.standard_normal(labelled.size)
    return L[free][:, free].tocsr(), -(L[free][:, labelled] @ y)


# --- contenders ------------------------------------------------------------------------------------


class System:
    """One system in every contender's input format, converted once (not timed: a user holds `A` in the
    format of the library they call); `scaled(s)` gives `s A` in each, so no value cache ever hits."""

    def __init__(self, A: sp.csr_matrix, b: np.ndarray):
        self.A, self.b = A, b
        self.ddgjax = from_scipy(A, positive_semidefinite=True)
        upper = sp.triu(A, format="coo")  # CHOLMOD reads the upper triangle
        self.upper = (jnp.asarray(upper.row, jnp.int32), jnp.asarray(upper.col, jnp.int32), jnp.asarray(upper.data))


def ddgjax_contender(method: str, **options):
    def solve(system: System, s: float):
        A = s * system.ddgjax
        return np.asarray(linear_solve(A, system.b, solver=method, rtol=TOLERANCE, **options).value)

    return solve


def sparsax_solve(system: System, s: float):
    rows, cols, values = system.upper
    return np.asarray(sparsax.solve(rows, cols, s * values, system.b))


def cholespy_solve(system: System, s: float):
    A = system.A * s
    solver = cholespy.CholeskySolverD(A.shape[0], A.indptr, A.indices, A.data, cholespy.MatrixType.CSR)
    x = np.empty_like(system.b)
    solver.solve(np.require(system.b, requirements=["C", "W"]), x)
    return x


def pyamg_solve(system: System, s: float):
    A = system.A * s
    return pyamg.smoothed_aggregation_solver(A).solve(system.b, tol=TOLERANCE, accel="cg", maxiter=1000)


def contenders() -> dict:
    found = {
        "ddgjax auto": ddgjax_contender("auto"),
        "ddgjax cholesky": ddgjax_contender("cholesky") if sparsax else None,
        "ddgjax cg + amg": ddgjax_contender("cg", preconditioner="amg"),
        "ddgjax pyamg": ddgjax_contender("pyamg"),
        "sparsax CHOLMOD": sparsax_solve if sparsax else None,
        "cholespy CHOLMOD": cholespy_solve if cholespy else None,
        "pyamg SA + CG": pyamg_solve if pyamg else None,
    }
    return {name: solve for name, solve in found.items() if solve is not None}


# --- measurement -----------------------------------------------------------------------------------


def measure(solvers: dict, system: System, repeats: int, budget_s: float) -> tuple[dict, dict]:
    """`({contender: min seconds}, {contender: first call seconds})`: rounds in which every contender solves
    once, in an order rotated each round (this VM's drift and first-touch page faults fall on all alike),
    each call with the matrix scaled anew; a contender stops once its calls add up to `budget_s`. ddgjax's
    first call (compilation) is not a sample. Every answer's relative residual is checked."""
    times = {name: [] for name in solvers}
    first, spent = {}, dict.fromkeys(solvers, 0.0)
    names, calls = list(solvers), 0
    for round_ in range(repeats + 1):
        shift = round_ % len(names)
        for name in names[shift:] + names[:shift]:
            if len(times[name]) >= repeats or spent[name] > budget_s:
                continue
            calls += 1
            s = 1.0 + 1e-3 * calls
            start = time.perf_counter()
            x = solvers[name](system, s)
            elapsed = time.perf_counter() - start
            residual = np.linalg.norm(s * (system.A @ x) - system.b) / np.linalg.norm(system.b)
            if not residual <= 2 * TOLERANCE:
                raise AssertionError(f"{name}: relative residual {residual:.2e} above {TOLERANCE:g}")
            if name.startswith("ddgjax") and name not in first:
                first[name] = elapsed
                continue
            times[name].append(elapsed)
            spent[name] += elapsed
    return {name: min(t) for name, t in times.items() if t}, first


def growth_exponent(sizes, times) -> float:
    """`p` of the least-squares fit `log t = p log n + c` (NaN with fewer than two sizes)."""
    if len(sizes) < 2:
        return float("nan")
    return float(np.polyfit(np.log(sizes), np.log(times), 1)[0])


def run_family(name, systems, solvers, args) -> dict:
    """`{contender: [(n, seconds)]}` over the systems `[(label, A, b)]`, printed as they come."""
    print(f"\n## {name}\n")
    table = {contender: [] for contender in solvers}
    for label, A, b in systems:
        n = A.shape[0]
        chosen = auto_solver(n, one_shot=True, entries_per_row=A.nnz / n)
        print(f"{label}: n = {n:,}, nnz = {A.nnz:,}; linear_solve's auto picks {chosen!r}", flush=True)
        direct = set(DIRECT) | ({"ddgjax auto"} if chosen in ("cholesky", "superlu") else set())
        running = {c: f for c, f in solvers.items() if not (name == "graph" and c in direct and n > args.direct_max)}
        for contender in solvers.keys() - running.keys():
            print(f"  {contender:18s} skipped (a direct solve, n > --direct-max {args.direct_max:,})")
        seconds, first = measure(running, System(A, b), args.repeats, args.budget)
        for contender, t in seconds.items():
            table[contender].append((n, t))
            note = f"   (first call {first[contender]:.2f} s)" if contender in first else ""
            print(f"  {contender:18s} {t:8.3f} s{note}", flush=True)
    return table


def report(name, table, plot_axes=None) -> None:
    rows = {contender: points for contender, points in table.items() if points}
    sizes = sorted({n for points in rows.values() for n, _ in points})
    largest = sizes[-1]
    at_largest = {contender: dict(points).get(largest) for contender, points in rows.items()}
    peer_best = min((t for c, t in at_largest.items() if c in PEERS and t is not None), default=None)
    print(f"\n### {name}: min seconds, growth exponent p (time ~ n^p), ratio to the fastest peer at n = {largest:,}\n")
    print("| contender | " + " | ".join(f"{n:,}" for n in sizes) + " | p | / fastest peer |")
    print("|---|" + "---|" * (len(sizes) + 2))
    for contender, points in rows.items():
        by_size = dict(points)
        cells = [f"{by_size[n]:.3f}" if n in by_size else "-" for n in sizes]
        p = growth_exponent(*zip(*points, strict=True))
        ratio = f"{at_largest[contender] / peer_best:.2f}x" if peer_best and at_largest[contender] else "-"
        print(f"| {contender} | " + " | ".join(cells) + f" | {p:.2f} | {ratio} |")
        if plot_axes is not None:
            ns, ts = zip(*points, strict=True)
            plot_axes.loglog(ns, ts, "o-" if contender.startswith("ddgjax") else "s--", label=contender)
    if plot_axes is not None:
        reference = np.array([sizes[0], sizes[-1]], float)
        base = min(t for points in rows.values() for n, t in points if n == sizes[0])
        plot_axes.loglog(reference, base * (reference / sizes[0]) ** 1.15, "k:", label="n^1.15")
        plot_axes.set(title=name, xlabel="unknowns n", ylabel="seconds (one solve, setup included)")
        plot_axes.legend(fontsize=7)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--levels", default="6,7,8", help="icosphere subdivision levels (comma-separated)")
    parser.add_argument("--graph-sizes", default="40000,160000", help="point counts of the kNN graphs (comma-separated)")
    parser.add_argument("--families", default="mesh,rough,graph", help="comma-separated: mesh, rough, graph")
    parser.add_argument("--only", default=None, help="comma-separated contender names to run (default: all found)")
    parser.add_argument("--direct-max", type=int, default=200_000, help="graph family: no direct solver above this n")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--budget", type=float, default=20.0, help="seconds of timed calls after which a contender stops")
    parser.add_argument("--plot", default=None, help="write a log-log figure of the tables to this file (docs/figures/scale.png)")
    args = parser.parse_args(argv)
    rng = np.random.default_rng(0)
    solvers = contenders()
    if args.only:
        solvers = {name: solve for name, solve in solvers.items() if name in args.only.split(",")}
    versions = ", ".join(f"{lib} {_dist_version(lib)}" for lib in ("jax", "sparsax", "cholespy", "pyamg", "scipy"))
    print(f"# machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, python {platform.python_version()}")
    print(f"# {versions}; relative residual <= {TOLERANCE:g}")
    families = args.families.split(",")
    axes = None
    if args.plot:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        figure, axes = plt.subplots(1, len(families), figsize=(6 * len(families), 4.5), squeeze=False)
        axes = axes[0]
    for index, family in enumerate(families):
        if family == "mesh":
            systems = ((f"icosphere({level})", *mesh_system(int(level), rng)) for level in args.levels.split(","))
        elif family == "rough":
            systems = (
                (f"jittered icosphere({level})", *jittered_mesh_system(int(level), rng)) for level in args.levels.split(",")
            )
        else:
            systems = ((f"10-NN graph of {n} points", *graph_system(int(n), rng)) for n in args.graph_sizes.split(","))
        table = run_family(family, systems, solvers, args)
        report(family, table, axes[index] if axes is not None else None)
    if args.plot:
        figure.tight_layout()
        figure.savefig(args.plot, dpi=120)
        print(f"\nfigure: {args.plot}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
