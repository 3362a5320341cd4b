"""Host sparse solvers called from JAX programs: SciPy's SuperLU and pyamg-preconditioned CG.

Both run on the host through `jax.pure_callback`, so they work inside `jit`, `lax.scan` and `vmap`
(one host call per batch element) like the rest of `linear_solve`; JAX differentiates around them
(`lax.custom_linear_solve`), they are never differentiated themselves.

- `"superlu"`: SciPy's SuperLU (`scipy.sparse.linalg.splu`, COLAMD ordering), the direct solver
  of the bare install (BSD; CHOLMOD through `sparsax` is the faster one, in the `cholmod` extra).
  SuperLU's symmetric mode (minimum degree on `A + A^T`, diagonal pivots) was measured 2-30x
  slower on mesh Laplacians of 41k-164k vertices (benchmarks/README.md).
- `"pyamg"`: SciPy's conjugate gradient preconditioned by a pyamg smoothed-aggregation V-cycle
  (the hierarchy of `ddgjax.solve._amg.pyamg_solver`), for systems too large to factor.

A factorisation (the SuperLU factors, the pyamg hierarchy) is made once by `host_factor` and kept in
a bounded host cache under an integer token that the JAX program carries, as `sparsax` does for
CHOLMOD. Each solve also passes the matrix values, so a factor evicted from the cache (more than
`_CAPACITY` factors made since, e.g. a long `scan` differentiated in reverse mode) is made again
from them: an old token is slower, never wrong.

References: X. S. Li, "An overview of SuperLU" (2005); N. Bell, L. Olson & J. Schroder, "PyAMG"
(2022).
"""

from __future__ import annotations

import collections
import itertools
import threading

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from jaxtyping import Array, Int

from ..sparse import SparsityPattern
from ._amg import pyamg_solver

HOST_METHODS = ("superlu", "pyamg")

# Factors kept on the host (least recently used evicted first).
_CAPACITY = 16


class _FactorCache:
    """Host factor objects under integer tokens, least recently used evicted beyond `capacity`."""

    def __init__(self, capacity: int):
        self._items: collections.OrderedDict[int, object] = collections.OrderedDict()
        self._tokens = itertools.count()
        self._lock = threading.Lock()
        self._capacity = capacity

    def add(self, item) -> int:
        with self._lock:
            token = next(self._tokens) % np.iinfo(np.int32).max
            self._put(token, item)
            return token

    def get(self, token: int, make):
        """The item of `token`, or `make()` kept under that token when it was evicted."""
        with self._lock:
            if token in self._items:
                self._items.move_to_end(token)
                return self._items[token]
        item = make()
        with self._lock:
            self._put(token, item)
        return item

    def _put(self, token: int, item) -> None:
        self._items[token] = item
        while len(self._items) > self._capacity:
            self._items.popitem(last=False)


_CACHE = _FactorCache(_CAPACITY)


def host_factor(method: str, pattern: SparsityPattern, values) -> Int[Array, ""]:
    """Factor the symmetric positive definite matrix `values` on `pattern` on the host; its token (`int32`).

    `values` are finite (the caller replaces NaN / inf first: neither SciPy nor pyamg accepts them). A
    matrix SuperLU finds exactly singular gets token `-1` (its solves return NaN and the factorisation
    reports `RESULTS.singular`).
    """
    # The callbacks close over plain values only: a tracer (`pattern`'s arrays) held by one would keep
    # the whole traced program, and its compiled code, alive in JAX's caches (`ddgjax._compile`).
    n = pattern.shape[0]

    def factor(rows, cols, values):
        made = _make(method, rows, cols, values, n)
        return np.int32(-1 if made is None else _CACHE.add(made))

    return jax.pure_callback(
        factor, jax.ShapeDtypeStruct((), jnp.int32), pattern.rows, pattern.cols, values, vmap_method="sequential"
    )


def host_solve(method: str, pattern: SparsityPattern, values, token, rhs, rtol: float, max_steps: int):
    """`(x, (num_steps, converged, factored))` for `A x = rhs` with the host factor `token` of `A` (`host_factor`).

    `rhs` is `(n,)` or `(n, k)`; the solve runs in float64 and `x` comes back in `rhs`'s dtype.
    `num_steps` counts CG iterations (the largest over the columns; 0 for SuperLU), `converged` is
    whether every column reached `rtol` in `max_steps`, `factored` whether the factorisation succeeded.
    """
    n = pattern.shape[0]  # not `pattern` itself (`host_factor`)

    def solve(rows, cols, values, token, rhs):
        if not np.all(np.isfinite(rhs)):  # reported as `nonfinite` by the caller; pyamg's CG would not stop early
            return np.full(rhs.shape, np.nan, rhs.dtype), np.int32(0), np.bool_(True), np.bool_(True)
        made = None if token < 0 else _CACHE.get(int(token), lambda: _make(method, rows, cols, values, n))
        if made is None:
            return np.full(rhs.shape, np.nan, rhs.dtype), np.int32(0), np.bool_(False), np.bool_(False)
        rhs64 = np.asarray(rhs, np.float64)
        if method == "superlu":
            return made.solve(rhs64).astype(rhs.dtype), np.int32(0), np.bool_(True), np.bool_(True)
        columns = rhs64.reshape(rhs64.shape[0], -1).T
        solved = [_amg_cg(made, column, rtol, max_steps) for column in columns]
        x = np.stack([column for column, _, _ in solved], axis=-1).reshape(rhs.shape)
        steps = max(steps for _, steps, _ in solved)
        converged = all(converged for _, _, converged in solved)
        return x.astype(rhs.dtype), np.int32(steps), np.bool_(converged), np.bool_(True)

    shapes = (
        jax.ShapeDtypeStruct(rhs.shape, rhs.dtype),
        jax.ShapeDtypeStruct((), jnp.int32),
        jax.ShapeDtypeStruct((), jnp.bool_),
        jax.ShapeDtypeStruct((), jnp.bool_),
    )
    x, steps, converged, factored = jax.pure_callback(
        solve, shapes, pattern.rows, pattern.cols, values, token, rhs, vmap_method="sequential"
    )
    return x, (steps, converged, factored)


def _host_matrix(rows, cols, values, n: int, layout: type = sp.csc_matrix) -> sp.csc_matrix | sp.csr_matrix:
    # Repeated positions (ELL padding holds zeros) are summed by the conversion.
    return layout((np.asarray(values, np.float64), (np.asarray(rows), np.asarray(cols))), shape=(n, n))


def _make(method: str, rows, cols, values, n: int):
    """The SuperLU factors or the pyamg hierarchy of the matrix; `None` when SuperLU finds it singular."""
    if method == "pyamg":  # in the layout each library works in, so neither converts it again
        return pyamg_solver(_host_matrix(rows, cols, values, n, sp.csr_matrix))
    try:
        return spla.splu(_host_matrix(rows, cols, values, n))
    except RuntimeError:  # "Factor is exactly singular"
        return None


def _amg_cg(solver, b, rtol: float, max_steps: int):
    """`(x, num_steps, converged)`: SciPy's CG on the finest level of a pyamg solver, its V-cycle as preconditioner.

    Stops at `|b - A x| <= rtol |b|` (2-norms). pyamg's V-cycle (symmetric Gauss-Seidel smoothing)
    is symmetric positive definite, as CG needs. pyamg: `ml.solve(b, tol=rtol, accel="cg")`.
    """
    count = [0]

    def counter(_):
        count[0] += 1

    preconditioner = solver.aspreconditioner(cycle="V")
    with np.errstate(invalid="ignore", divide="ignore"):  # a breakdown (a singular A) is reported by the outcome
        x, info = spla.cg(solver.levels[0].A, b, rtol=rtol, atol=0.0, maxiter=max_steps, M=preconditioner, callback=counter)
    return x, count[0], info == 0
