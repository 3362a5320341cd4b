"""Gathers of rows by indices the host guarantees: `x[index]` without JAX's index normalisation.

`x[index]` with a traced integer index first maps negative indices (`index < 0 ? index + n :
index`), a compare and select per index that XLA fuses into the gather; `jnp.take(..., mode="fill")`
does the same before its bounds check. Topology and sparsity-pattern indices are built once on the
host (DESIGN.md, two phases) and are never negative, so the gathers here are single `lax.gather`s
without that step, which makes the ELL product `L @ x` and the re-assembly of the cotan Laplacian
measurably faster from 20k faces up (benchmarks/README.md).

Both are ordinary gathers for JAX: differentiable (the transpose is a scatter-add), batchable,
any backend.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Inexact, Int


def _row_gather(x, index, mode, fill_value=None):
    index = jnp.asarray(index)
    rest = x.shape[1:]
    numbers = jax.lax.GatherDimensionNumbers(
        offset_dims=tuple(range(index.ndim, index.ndim + len(rest))), collapsed_slice_dims=(0,), start_index_map=(0,)
    )
    return jax.lax.gather(x, index[..., None], numbers, slice_sizes=(1, *rest), mode=mode, fill_value=fill_value)


def take_rows(x: Inexact[Array, "n *rest"], index: Int[ArrayLike, "..."]) -> Inexact[Array, "... *rest"]:
    """`x[index]` for indices in `[0, n)`, promised in bounds (out-of-range indices are undefined behaviour)."""
    return _row_gather(x, index, jax.lax.GatherScatterMode.PROMISE_IN_BOUNDS)


def take_rows_or_zero(x: Inexact[Array, "n *rest"], index: Int[ArrayLike, "..."]) -> Inexact[Array, "... *rest"]:
    """`x[index]` for indices `>= 0`, where an index `>= n` (padding) reads 0: `jnp.take(x, index, axis=0,
    mode="fill", fill_value=0)` for non-negative indices."""
    return _row_gather(x, index, jax.lax.GatherScatterMode.FILL_OR_DROP, fill_value=0)
