"""Approximate Cholesky (approximate Gaussian elimination) as a CG preconditioner, against pyamg's SA V-cycle.

What is measured: on the same SDDM systems as `benchmarks/scale.py` (the heat step `M + 0.01 L` of
icospheres, the label-propagation block `L_ff` of 10-NN graphs in the unit cube), with the same
right-hand side, a one-shot solve to a relative residual `|A x - b| / |b| <= 1e-8` by

- **approxchol**: a randomised approximate factorisation `A ~ L D L^T` (factor seconds, fill), then
  PCG preconditioned by `(L D L^T)^{-1}` (iterations, solve seconds);
- **pyamg**: `ml = pyamg.smoothed_aggregation_solver(A)` (setup seconds, operator complexity), then
  `ml.solve(b, tol=1e-8, accel="cg")`, i.e. CG preconditioned by one SA V-cycle.

The algorithm (Kyng & Sachdeva 2016; the sampling as in `approxchol` of Laplacians.jl, Gao, Kyng &
Spielman 2023). An SDDM matrix `A` (symmetric, `A_ij <= 0` for `i != j`, `A_ii >= sum_{j != i} |A_ij|`)
is the Laplacian of a graph on `n + 1` vertices restricted to the first `n`: edge `(i, j)` of weight
`-A_ij`, and an edge `(i, g)` to a ground vertex `g = n` of weight `e_i = A_ii - sum_{j != i} |A_ij|`
(the excess diagonal). Eliminating vertex `v` with star weights `w_1..w_d` to neighbours `u_1..u_d`
(multi-edges merged), `W = sum_k w_k`, splits the Laplacian exactly as

    L_G = W l l^T + (L_G - star(v) + clique(v)),  l = e_v - sum_k (w_k / W) e_{u_k},
    clique(v) = sum_{i<k} (w_i w_k / W) (e_{u_i} - e_{u_k}) (e_{u_i} - e_{u_k})^T.

The clique has `d (d - 1) / 2` edges; instead, with the weights sorted ascending and
`S_i = sum_{k > i} w_k`, each neighbour `i < d` adds ONE edge `(u_i, u_j)`, `j > i` drawn with
probability `w_j / S_i`, of weight `w_i S_i / W`. Its expectation is `(w_j / S_i) (w_i S_i / W) =
w_i w_j / W`, the clique edge's, so the sampled clique equals the true clique in expectation.
As we read Gao-Kyng-Spielman (`approxchol` of Laplacians.jl), they write the step as a sequence
over `i` with a shrinking star: `f = c w_i / D`, new weight `f (1 - f) D`, then `c <- c (1 - f)`,
`D <- D (1 - f)^2` (from `c = 1`, `D = W`); by induction `c = S_{i-1} / W`, `D = S_{i-1}^2 / W`, so
the new weight is `w_i S_i / W` again: the same sampled Schur complement (their factor stores the
step as `d - 1` elementary column operations rather than one normalised star; not checked to give
the same preconditioner). An elimination removes the `d` (multi-)edges of the
star and adds at most `d - 1`, so the live graph never grows beyond `nnz(A)` (memory is fixed), but
the factor keeps every star: its size is the sum of the merged degrees at elimination, which is
why its fill ratio exceeds 1. Column `v` of the unit lower-triangular `L` is `l` without its ground
entry, `D_v = W`; `g` is eliminated last and dropped, so `L D L^T` approximates `A` itself.
Order: dynamic minimum degree (the vertex with the fewest live multi-edges next, ties by vertex
index, which keeps a mesh's memory locality; `--random-ties` breaks them at random), as Laplacians.jl's
`approxchol` does with its degree priority queue. The elimination and both triangular solves are
compiled with numba over flat arrays (doubly linked half-edge lists, a free list of edge slots,
degree buckets; the factor's rows renumbered to elimination positions so the solves sweep memory
in order); PCG is NumPy with scipy's sparse product. BLAS is
held to one thread (OPENBLAS_NUM_THREADS=1 unless set) for both CGs: on a shared 2-core machine
a threaded dot product spins for milliseconds.

If `A` is not SDDM (a positive off-diagonal: the cotan Laplacian has `L_ij = -(cot a + cot b) / 2`,
positive when the two angles opposite edge `ij` sum past pi, which a mesh with obtuse angles can
have; or a row not diagonally dominant), its graph has negative weights and the method does not
apply: sampling probabilities `w_j / S_i` and pivots `W` are no longer guaranteed positive. The
script counts such entries and then factors the SDDM surrogate (the nonpositive off-diagonals of
`A`, each row grounded with `max(0, A_ii - sum_{j != i} |A_ij|)`); PCG with that preconditioner
stays correct (it is SPD) but its iteration count is no longer backed by the theory. `--jitter` adds
such a system: icosphere(6) with its vertices moved at random (obtuse triangles), `M + 0.01 L`.

References: R. Kyng, S. Sachdeva, "Approximate Gaussian elimination for Laplacians - fast, sparse,
and simple", FOCS 2016; Y. Gao, R. Kyng, D. A. Spielman, "Robust and practical solution of Laplacian
equations by approximate elimination", arXiv:2303.00709 (2023); pyamg (Bell, Olson, Schroder).

Needs numba (not a ddgjax dependency): `pip install numba`. Run from `benchmarks/`:
`python approxchol.py` (icosphere levels 6, 7, 8; graphs of 40,000 and 160,000 points);
`--levels`, `--graph-sizes`, `--repeats`, `--jitter`, `--random-ties` change that. Printed: one
markdown table, min seconds of `--repeats` interleaved runs after a warm-up that compiles the numba
kernels (its time printed apart).

Conclusion (one run, load ~2.5 on 2 cores, min of 2; benchmarks/README.md, "Laplacian systems at
scale"): it does not pay here, so ddgjax does not implement it. Against pyamg's set-up + CG, a one-shot
solve takes 1.7-2.4x on the icosphere heat steps and 1.07-1.28x on the 10-NN graphs up to 634k
unknowns: the sequential factorisation alone costs 2.0-2.2x pyamg's set-up (~1 us per edge), the
factor holds 1.7x `nnz(A)` (pyamg's operator complexity: 1.07-1.16) and PCG needs 1.8-2.5x the
iterations (32 against 13 at 655k), each 2-4x cheaper. Cotan Laplacians of meshes with obtuse
triangles are not SDDM, where the method has no guarantee at all; AMG serves both.
"""

from __future__ import annotations

import os

# one BLAS thread: on a shared 2-core machine a threaded OpenBLAS dot of 1e5 entries spins for milliseconds, in both CGs
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import sys
import time

try:
    import numba
    from numba import njit
except ImportError:
    sys.exit("benchmarks/approxchol.py needs numba (not a ddgjax dependency): pip install numba")

import numpy as np
import scipy.sparse as sp

try:
    import pyamg
except ImportError:
    sys.exit("benchmarks/approxchol.py needs pyamg: pip install pyamg")

from scale import graph_system, jittered_mesh_system, mesh_system  # the same systems as benchmarks/scale.py

TOLERANCE = 1e-8


# --- SDDM check and graph -------------------------------------------------------------------------


def sddm_graph(A: sp.csr_matrix) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict]:
    """Edges `(u, v, w)` (int64, int64, float64; `u < v`) of the graph whose Laplacian restricted to
    `0..n-1` is `A`: `w = -A_uv` off the diagonal, `(i, n, e_i)` to the ground for the excess
    diagonal `e_i = A_ii - sum_{j != i} |A_ij| > 0`. Also a report of how far `A` is from SDDM; a
    positive off-diagonal is dropped and a negative excess clipped to 0 (the SDDM surrogate)."""
    n = A.shape[0]
    asym = abs(A - A.T).max() / abs(A).max()
    lower = sp.tril(A, k=-1).tocoo()
    diag = A.diagonal()
    off_abs = np.asarray(abs(A).sum(axis=1)).ravel() - np.abs(diag)
    excess = diag - off_abs
    # roundoff in the row sums of a Laplacian block leaves excesses of either sign around 1e-16 A_ii
    tiny = 1e-12 * np.abs(diag)
    report = {
        "asymmetry": float(asym),
        "positive_offdiag": int((lower.data > 0).sum()),
        "not_dominant_rows": int((excess < -tiny).sum()),
        "min_excess_over_diag": float((excess / diag).min()),
    }
    keep = lower.data < 0
    u, v, w = lower.col[keep], lower.row[keep], -lower.data[keep]
    grounded = np.flatnonzero(excess > tiny)
    u = np.concatenate([u, grounded]).astype(np.int64)
    v = np.concatenate([v, np.full(grounded.size, n)]).astype(np.int64)
    w = np.concatenate([w, excess[grounded]]).astype(np.float64)
    return u, v, w, report


# --- approximate elimination (numba) --------------------------------------------------------------


@njit(cache=False)
def _link(h, x, head, hnext, hprev, deg):
    hprev[h] = -1
    hnext[h] = head[x]
    if head[x] != -1:
        hprev[head[x]] = h
    head[x] = h
    deg[x] += 1


@njit(cache=False)
def _unlink(h, x, head, hnext, hprev, deg):
    if hprev[h] != -1:
        hnext[hprev[h]] = hnext[h]
    else:
        head[x] = hnext[h]
    if hnext[h] != -1:
        hprev[hnext[h]] = hprev[h]
    deg[x] -= 1


@njit(cache=False)
def _bucket_insert(x, key, bhead, bnext, bprev, bkey):
    bkey[x] = key
    bprev[x] = -1
    bnext[x] = bhead[key]
    if bhead[key] != -1:
        bprev[bhead[key]] = x
    bhead[key] = x


@njit(cache=False)
def _bucket_remove(x, bhead, bnext, bprev, bkey):
    if bprev[x] != -1:
        bnext[bprev[x]] = bnext[x]
    else:
        bhead[bkey[x]] = bnext[x]
    if bnext[x] != -1:
        bprev[bnext[x]] = bprev[x]


@njit(cache=False)
def _approx_factor(n, eu, ev, ew, seed, random_ties):
    """Approximate elimination of vertices `0..n-1` of the graph `(eu, ev, ew)` on `n + 1` vertices
    (vertex `n` the ground, never eliminated). Returns `(perm, colptr, rows, vals, d)`: column `k` of
    the unit lower-triangular factor eliminates vertex `perm[k]`, its entries `rows/vals[colptr[k]:
    colptr[k+1]]` (original indices), `d[v]` the pivot of vertex `v`. Edge slot `p` is the half-edge
    pair `(2p, 2p+1)`; half-edge `h` lies in the list of vertex `hnbr[h ^ 1]` and points to `hnbr[h]`."""
    # numba compiles only the legacy global generator (seeded per thread), not np.random.Generator
    np.random.seed(seed)  # noqa: NPY002
    npairs = eu.size
    hnbr = np.empty(2 * npairs, np.int64)
    hnext = np.empty(2 * npairs, np.int64)
    hprev = np.empty(2 * npairs, np.int64)
    pw = ew.copy()
    head = np.full(n + 1, -1, np.int64)
    deg = np.zeros(n + 1, np.int64)
    for p in range(npairs):
        hnbr[2 * p] = ev[p]
        hnbr[2 * p + 1] = eu[p]
        _link(2 * p, eu[p], head, hnext, hprev, deg)
        _link(2 * p + 1, ev[p], head, hnext, hprev, deg)
    free = np.empty(npairs, np.int64)
    nfree = 0
    # degree buckets (doubly linked, LIFO), keys clamped: the order among very high degrees does not matter
    nkeys = 1024
    bhead = np.full(nkeys, -1, np.int64)
    bnext = np.empty(n, np.int64)
    bprev = np.empty(n, np.int64)
    bkey = np.empty(n, np.int64)
    insertion = np.random.permutation(n) if random_ties else np.arange(n)[::-1]  # noqa: NPY002
    for i in insertion:
        _bucket_insert(i, min(deg[i], nkeys - 1), bhead, bnext, bprev, bkey)
    minkey = 0
    slot = np.full(n + 1, -1, np.int64)
    cap = 64
    nb = np.empty(cap, np.int64)
    wt = np.empty(cap, np.float64)
    cum = np.empty(cap, np.float64)
    perm = np.empty(n, np.int64)
    colptr = np.zeros(n + 1, np.int64)
    fcap = npairs + n
    rows = np.empty(fcap, np.int64)
    vals = np.empty(fcap, np.float64)
    d = np.zeros(n, np.float64)
    nnz = 0
    k = 0
    while k < n:
        while bhead[minkey] == -1:
            minkey += 1
        v = bhead[minkey]
        _bucket_remove(v, bhead, bnext, bprev, bkey)
        perm[k] = v
        # gather the star of v, merging multi-edges, and free its edge slots
        m = 0
        h = head[v]
        while h != -1:
            x = hnbr[h]
            _unlink(h ^ 1, x, head, hnext, hprev, deg)
            free[nfree] = h >> 1
            nfree += 1
            if slot[x] == -1:
                if m == cap:
                    cap *= 2
                    nb2 = np.empty(cap, np.int64)
                    wt2 = np.empty(cap, np.float64)
                    nb2[:m] = nb[:m]
                    wt2[:m] = wt[:m]
                    nb, wt, cum = nb2, wt2, np.empty(cap, np.float64)
                slot[x] = m
                nb[m] = x
                wt[m] = pw[h >> 1]
                m += 1
            else:
                wt[slot[x]] += pw[h >> 1]
            h = hnext[h]
        head[v] = -1
        deg[v] = 0
        for i in range(m):
            slot[nb[i]] = -1
        # weights ascending: insertion sort in place for the usual short stars, argsort for long ones
        if m <= 32:
            for i in range(1, m):
                wi, ui = wt[i], nb[i]
                t = i - 1
                while t >= 0 and wt[t] > wi:
                    wt[t + 1], nb[t + 1] = wt[t], nb[t]
                    t -= 1
                wt[t + 1], nb[t + 1] = wi, ui
        else:
            order = np.argsort(wt[:m])
            nb[:m] = nb[:m][order]
            wt[:m] = wt[:m][order]
        us, ws = nb, wt
        total = 0.0
        for i in range(m):
            total += ws[i]
            cum[i] = total
        # sampled clique: neighbour i joins one later neighbour j ~ w_j, with weight w_i S_i / W
        suffix = 0.0
        for i in range(m - 2, -1, -1):
            suffix += ws[i + 1]
            r = cum[i] + np.random.random() * suffix  # noqa: NPY002
            j = np.searchsorted(cum[:m], r, side="right")
            j = min(max(j, i + 1), m - 1)
            p = free[nfree - 1]
            nfree -= 1
            pw[p] = ws[i] * suffix / total
            hnbr[2 * p] = us[j]
            hnbr[2 * p + 1] = us[i]
            _link(2 * p, us[i], head, hnext, hprev, deg)
            _link(2 * p + 1, us[j], head, hnext, hprev, deg)
        # column of the factor: the normalised star, without the ground
        if nnz + m > fcap:
            fcap = 2 * (nnz + m)
            rows2 = np.empty(fcap, np.int64)
            vals2 = np.empty(fcap, np.float64)
            rows2[:nnz] = rows[:nnz]
            vals2[:nnz] = vals[:nnz]
            rows, vals = rows2, vals2
        for i in range(m):
            if us[i] != n:
                rows[nnz] = us[i]
                vals[nnz] = -ws[i] / total
                nnz += 1
                key = min(deg[us[i]], nkeys - 1)
                if key != bkey[us[i]]:
                    _bucket_remove(us[i], bhead, bnext, bprev, bkey)
                    _bucket_insert(us[i], key, bhead, bnext, bprev, bkey)
                    minkey = min(minkey, key)
        d[v] = total if total > 0 else 1.0
        k += 1
        colptr[k] = nnz
    # rows renumbered to elimination positions: the triangular solves then sweep a permuted vector in order
    position = np.empty(n, np.int64)
    position[perm] = np.arange(n)
    return perm, colptr, position[rows[:nnz]], vals[:nnz].copy(), d[perm]


@njit(cache=False)
def _ldl_solve(perm, colptr, rows, vals, d, b):
    """`x = (L D L^T)^{-1} b`, all in elimination positions (`rows`, `d` permuted by `perm`): forward
    substitution by columns, the diagonal, backward substitution by columns."""
    n = perm.size
    y = b[perm]
    for k in range(n):
        yk = y[k]
        for t in range(colptr[k], colptr[k + 1]):
            y[rows[t]] -= vals[t] * yk
        y[k] = yk / d[k]
    for k in range(n - 1, -1, -1):
        s = y[k]
        for t in range(colptr[k], colptr[k + 1]):
            s -= vals[t] * y[rows[t]]
        y[k] = s
    x = np.empty(n)
    x[perm] = y
    return x


class ApproxChol:
    """`L D L^T ~ A` for an SDDM (or surrogate) `A`; `solve(b)` applies `(L D L^T)^{-1}`."""

    def __init__(self, A: sp.csr_matrix, seed: int = 0, random_ties: bool = False):
        u, v, w, self.report = sddm_graph(A)
        self.n = A.shape[0]
        self.perm, self.colptr, self.rows, self.vals, self.d = _approx_factor(self.n, u, v, w, seed, random_ties)
        # fill: the factor's lower triangle (unit diagonal counted) against A's lower triangle
        self.fill = (self.rows.size + self.n) / sp.tril(A).nnz

    def solve(self, b: np.ndarray) -> np.ndarray:
        return _ldl_solve(self.perm, self.colptr, self.rows, self.vals, self.d, b)


def pcg(A: sp.csr_matrix, b: np.ndarray, precondition, tol: float = TOLERANCE, maxiter: int = 2000):
    """Preconditioned CG from `x = 0` until `|A x - b| <= tol |b|` (the recurrence residual, confirmed
    by the true one): `(x, iterations)`."""
    x = np.zeros_like(b)
    r = b.copy()
    z = precondition(r)
    p = z.copy()
    rz = r @ z
    bound = tol * np.linalg.norm(b)
    for it in range(1, maxiter + 1):
        Ap = A @ p
        alpha = rz / (p @ Ap)
        x += alpha * p
        r -= alpha * Ap
        if np.linalg.norm(r) <= bound and np.linalg.norm(b - A @ x) <= bound:
            return x, it
        z = precondition(r)
        rz, rz_old = r @ z, rz
        p = z + (rz / rz_old) * p
    return x, maxiter


# --- contenders -----------------------------------------------------------------------------------


def run_approxchol(A, b, seed, random_ties=False):
    t0 = time.perf_counter()
    factor = ApproxChol(A, seed=seed, random_ties=random_ties)
    t1 = time.perf_counter()
    x, iters = pcg(A, b, factor.solve)
    t2 = time.perf_counter()
    return {"setup": t1 - t0, "solve": t2 - t1, "iters": iters, "fill": factor.fill, "x": x, "sddm": factor.report}


def run_pyamg(A, b, seed):
    t0 = time.perf_counter()
    ml = pyamg.smoothed_aggregation_solver(A)
    t1 = time.perf_counter()
    res: list[float] = []
    x = ml.solve(b, tol=TOLERANCE, accel="cg", maxiter=1000, residuals=res)
    t2 = time.perf_counter()
    return {"setup": t1 - t0, "solve": t2 - t1, "iters": len(res) - 1, "fill": ml.operator_complexity(), "x": x}


def check(A, b, x, name):
    residual = np.linalg.norm(A @ x - b) / np.linalg.norm(b)
    if not residual <= TOLERANCE:
        print(f"  WARNING {name}: relative residual {residual:.2e} above {TOLERANCE:g}", flush=True)
    return residual


def best(runs):
    """The run of least total time, with the iteration counts of all runs."""
    run = min(runs, key=lambda r: r["setup"] + r["solve"])
    iters = sorted({r["iters"] for r in runs})
    return run, "/".join(str(i) for i in iters)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--levels", default="6,7,8")
    parser.add_argument("--graph-sizes", default="40000,160000")
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--random-ties", action="store_true", help="break minimum-degree ties at random")
    parser.add_argument("--jitter", type=float, default=0.0, help="add icosphere(6) jittered by this fraction of an edge")
    args = parser.parse_args(argv)
    print(f"# numba {numba.__version__}, pyamg {pyamg.__version__}, numpy {np.__version__}; load {os.getloadavg()}")
    rng = np.random.default_rng(0)

    # warm-up: compile the numba kernels on a small system
    A0, b0 = mesh_system(3, rng)
    t0 = time.perf_counter()
    run_approxchol(A0, b0, 0)
    t1 = time.perf_counter()
    run_approxchol(A0, b0, 1)
    t2 = time.perf_counter()
    print(f"# numba compile (first call minus second on icosphere(3)): {(t1 - t0) - (t2 - t1):.2f} s")

    systems = [
        (f"mesh L{lv}", lambda lv=lv: mesh_system(lv, rng)) for lv in map(int, args.levels.split(",") if args.levels else [])
    ]
    systems += [
        (f"graph {n}", lambda n=n: graph_system(n, rng))
        for n in map(int, args.graph_sizes.split(",") if args.graph_sizes else [])
    ]
    if args.jitter:
        systems.append((f"mesh L6 jitter {args.jitter:g}", lambda: jittered_mesh_system(6, rng, args.jitter)))
    rows = []
    for name, build in systems:
        A, b = build()
        n = A.shape[0]
        ac_runs, amg_runs = [], []
        for rep in range(args.repeats):
            ac_runs.append(run_approxchol(A, b, rep, args.random_ties))
            amg_runs.append(run_pyamg(A, b, rep))
        for r in ac_runs:
            r["res"] = check(A, b, r.pop("x"), f"{name} approxchol")
        for r in amg_runs:
            r["res"] = check(A, b, r.pop("x"), f"{name} pyamg")
        ac, ac_it = best(ac_runs)
        amg, amg_it = best(amg_runs)
        sd = ac["sddm"]
        sddm = "SDDM" if sd["positive_offdiag"] == 0 and sd["not_dominant_rows"] == 0 else "NOT SDDM"
        print(
            f"# {name}: n={n} nnz={A.nnz} {sddm} (asymmetry {sd['asymmetry']:.1e}, positive off-diagonals "
            f"{sd['positive_offdiag']}, non-dominant rows {sd['not_dominant_rows']}, min excess/diag "
            f"{sd['min_excess_over_diag']:.2e}); residuals approxchol {max(r['res'] for r in ac_runs):.1e}, "
            f"pyamg {max(r['res'] for r in amg_runs):.1e}; load {os.getloadavg()[0]:.2f}",
            flush=True,
        )
        rows.append((name, n, ac, ac_it, amg, amg_it))
        del A, b

    print()
    print(
        "| system | n | AC factor s | AC fill | AC iters | AC solve s | AC s/iter (ms) | AC total s "
        "| AMG setup s | AMG op. cx | AMG iters | AMG solve s | AMG s/iter (ms) | AMG total s | AC / AMG |"
    )
    print("|" + "---|" * 15)
    for name, n, ac, ac_it, amg, amg_it in rows:
        tac, tamg = ac["setup"] + ac["solve"], amg["setup"] + amg["solve"]
        print(
            f"| {name} | {n:,} | {ac['setup']:.3f} | {ac['fill']:.2f} | {ac_it} | {ac['solve']:.3f} "
            f"| {1e3 * ac['solve'] / ac['iters']:.2f} | {tac:.3f} | {amg['setup']:.3f} | {amg['fill']:.2f} | {amg_it} "
            f"| {amg['solve']:.3f} | {1e3 * amg['solve'] / amg['iters']:.2f} | {tamg:.3f} | {tac / tamg:.2f} |"
        )
    print(f"\n# load at end {os.getloadavg()}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
