"""`gather_sum`: a fixed gather-and-sum whose transpose is another fixed gather (no scatter-add).

JAX transposes a gather into a scatter-add, the slow operation on CPU (a serial loop; DESIGN.md,
measured facts). When the incidence is fixed, the transpose is itself a gather over the transposed
incidence, built once on the host. `gather_sum` is a linear JAX primitive that knows this:

- forward (`jit`, eager): one fill-with-0 gather of `x` (`take_rows_or_zero`) per column of `index`, added
  up; on CPU compiled with `x` and the result on either side of a fusion boundary
  (`_materialized`), so XLA neither recomputes the producer of `x` per read nor the gather per
  consumer;
- forward mode (`jax.jvp`, `jax.jacfwd`): it is linear, so the tangent is `gather_sum` of the tangent;
- reverse mode (`jax.grad`, `jax.linear_transpose`): the transpose is `gather_sum` with the two
  index arrays swapped, so gradients, Hessian-vector products (forward-over-reverse or
  reverse-over-reverse) and any depth of nesting stay gathers;
- `vmap`: over `x` it is one call on a wider `x`; over the index arrays the batch is folded into
  the leading axis (offset indices), still one call.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax.extend.core import Primitive
from jax.interpreters import ad, batching, mlir
from jaxtyping import Array, ArrayLike, Float, Int

from .._compile import device_array
from .._errors import DDGInputError
from .._indexing import take_rows_or_zero

gather_sum_p = Primitive("ddgjax_gather_sum")


def gather_sum(
    x: Float[ArrayLike, "n *rest"], /, index: Int[ArrayLike, "m k"], transpose_index: Int[ArrayLike, "n j"]
) -> Float[Array, "m *rest"]:
    """`y[s] = sum_k x[index[s, k]]`, whose derivative in both modes is a fixed gather.

    `index[s, k] >= n` pads (reads 0); `transpose_index[c]` lists every `s` with `c` among
    `index[s, :]` (each occurrence once, padded with an index `>= m`), so that the transpose is
    `x_bar[c] = sum_j y_bar[transpose_index[c, j]]`. The caller guarantees that the two arrays
    describe the same incidence (built together on the host, e.g. `TriangulationPlan.slot_corners` and
    `TriangulationPlan.corner_slots` in `ddgjax.laplacian._plan`); negative indices are not allowed.

    Linear in `x`; works under `jit`, `grad`, `jvp`, `jacfwd`, `vmap` and nested combinations (module
    docstring). No libigl / gpytoolbox equivalent; in SciPy terms it is `S @ x` (and its transpose
    `S.T @ y_bar`) with `S` the `(m, n)` 0/1 incidence matrix given in both row-compressed forms.
    Reference: JAX documentation, "JAX internals: primitives" (linear primitives and transposition).

    Args:
        x: `(n, *rest)` values.
        index: `(m, k)` integer, rows of `S` as padded column lists.
        transpose_index: `(n, j)` integer, columns of `S` as padded row lists.

    Returns:
        `(m, *rest)`.
    """
    x = device_array(x)
    index, transpose_index = device_array(index), device_array(transpose_index)
    for name, array in (("index", index), ("transpose_index", transpose_index)):
        if array.ndim != 2 or not jnp.issubdtype(array.dtype, jnp.integer):
            raise DDGInputError(f"{name}: expected a 2-d integer array, got shape {array.shape} dtype {array.dtype}")
    if x.ndim == 0 or transpose_index.shape[0] != x.shape[0]:
        raise DDGInputError(
            f"x, transpose_index: expected x of shape (n, ...) and transpose_index (n, j) with the same n, "
            f"got {x.shape} and {transpose_index.shape}"
        )
    return gather_sum_p.bind(x, index, transpose_index)


def _gather(x, index):
    # One gather per column of `index`, added up: a single elementwise kernel (a reduction over the
    # short last axis of an `(m, k)` block becomes a separate, slower kernel on XLA's CPU backend).
    total = jnp.zeros((index.shape[0],) + x.shape[1:], x.dtype)
    for k in range(index.shape[1]):
        total = total + take_rows_or_zero(x, index[:, k])
    return total


def _impl(x, index, transpose_index):
    del transpose_index
    return _gather(x, index)


def _lower(x, index, transpose_index):
    """The compiled form: `_impl` between two fusion boundaries (`_materialized`).

    The result's boundary matters in reverse mode, where the transposed gather feeds several
    per-coordinate kernels: fused into each, it would be re-gathered once per kernel.
    """
    return _materialized(_impl(_materialized(x, index), index, transpose_index), index)


def _materialized(x, index):
    """`x`, behind a boundary that stops XLA from fusing the computation of `x` into the gather.

    Each element of `x` is read by several rows of `index` in scattered order, so a fused producer
    (e.g. the per-face cotangent formulas) would be recomputed per read, with random access to its
    own inputs, several times slower for the cotan assembly. XLA's CPU pipeline drops
    `lax.optimization_barrier` before fusion but keeps a conditional, which it cannot fuse across;
    the predicate (indices are non-negative by contract) is a run-time value, so the conditional
    stays, and the other branch (NaN, never taken for valid input) keeps XLA from merging the two.
    The predicate passes through an optimization barrier so that constant indices (an operator plan
    closed over in a user's `jit`) cannot fold it away before fusion.
    """
    if index.size == 0:
        return x
    always = jax.lax.optimization_barrier(index[0, 0]) >= 0
    return jax.lax.cond(always, lambda v: v, lambda v: jnp.full_like(v, jnp.nan), x)


def _abstract_eval(x, index, transpose_index):
    del transpose_index
    # `update` keeps x's other type information (e.g. shard_map's varying manual axes).
    return x.update(shape=(index.shape[0],) + x.shape[1:])


def _jvp(tangent, x, index, transpose_index):
    del x
    return gather_sum_p.bind(tangent, index, transpose_index)


def _transpose(cotangent, x, index, transpose_index):
    if ad.is_undefined_primal(index) or ad.is_undefined_primal(transpose_index):
        raise DDGInputError("gather_sum is linear in x only; its index arrays cannot be differentiated")
    if type(cotangent) is ad.Zero:
        return ad.Zero(x.aval), None, None
    return gather_sum_p.bind(cotangent, transpose_index, index), None, None


def _batch(args, dims):
    x, index, transpose_index = args
    x_dim, index_dim, transpose_dim = dims
    if index_dim is None and transpose_dim is None:
        # One call on a wider x: the batch axis becomes a trailing axis of the gathered rows.
        return gather_sum_p.bind(jnp.moveaxis(x, x_dim, 1), index, transpose_index), 1
    size = next(a.shape[d] for a, d in zip(args, dims) if d is not None)
    x = batching.bdim_at_front(x, x_dim, size)
    index = batching.bdim_at_front(index, index_dim, size)
    transpose_index = batching.bdim_at_front(transpose_index, transpose_dim, size)
    n, m = x.shape[1], index.shape[1]
    # Fold the batch into the leading axis: batch b's entries move to [b n, (b + 1) n); padding
    # stays past the end.
    batch = jnp.arange(size, dtype=index.dtype)[:, None, None]
    index = jnp.where(index < n, index + batch * n, size * n).reshape(size * m, -1)
    transpose_index = jnp.where(transpose_index < m, transpose_index + batch * m, size * m).reshape(size * n, -1)
    y = gather_sum_p.bind(x.reshape((size * n,) + x.shape[2:]), index, transpose_index)
    return y.reshape((size, m) + y.shape[1:]), 0


gather_sum_p.def_impl(_impl)
gather_sum_p.def_abstract_eval(_abstract_eval)
mlir.register_lowering(gather_sum_p, mlir.lower_fun(_impl, multiple_results=False))
# The fusion boundaries are for XLA's CPU backend (where they were measured). On a GPU a
# conditional reads its predicate on the host, a synchronisation per call, so other platforms get
# the plain gather.
mlir.register_lowering(gather_sum_p, mlir.lower_fun(_lower, multiple_results=False), platform="cpu")
ad.defjvp(gather_sum_p, _jvp, None, None)
ad.primitive_transposes[gather_sum_p] = _transpose
batching.primitive_batchers[gather_sum_p] = _batch
