"""A fixed gather-and-sum whose reverse mode is a gather too (no scatter-add)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, Int


@jax.custom_vjp
def gather_sum(
    x: Float[Array, " n"], index: Int[Array, "m k"], transpose_index: Int[Array, "n j"]
) -> Float[Array, " m"]:
    """`y[s] = sum_k x[index[s, k]]` (out-of-range indices read 0), differentiated by gathers.

    JAX transposes a gather into a scatter-add, which is the slow operation on CPU (a serial loop).
    Here the pattern is fixed, so the transpose is another fixed gather: `transpose_index[c]` lists
    every `s` with `c` among `index[s, :]` (each pair once, padded with an out-of-range index), and
    `x_bar[c] = sum_j y_bar[transpose_index[c, j]]`. The caller guarantees that the two index arrays
    describe the same incidence (built together on the host, e.g. `Mesh.vertex_pattern_corners` and
    `Mesh.corner_pattern_slots`).

    Reverse mode, `jit` and `vmap` work; forward mode (`jax.jvp`, `jax.jacfwd`) does not pass through
    a `custom_vjp` (JAX limitation), so callers keep a plain-gather path for it.
    """
    return jnp.take(x, index, axis=0, mode="fill", fill_value=0).sum(axis=1)


def _gather_sum_fwd(x, index, transpose_index):
    return gather_sum(x, index, transpose_index), (index, transpose_index)


def _gather_sum_bwd(residuals, cotangent):
    index, transpose_index = residuals
    x_bar = jnp.take(cotangent, transpose_index, axis=0, mode="fill", fill_value=0).sum(axis=1)
    return x_bar, None, None


gather_sum.defvjp(_gather_sum_fwd, _gather_sum_bwd)
