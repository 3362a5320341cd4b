"""A batch of `DiffusionOperators` of meshes of different sizes: padded to bucket sizes and stacked."""

from __future__ import annotations

from collections.abc import Sequence

import jax.numpy as jnp

from .._errors import DDGInputError, check_count
from ..batch import bucket
from ..fields import TangentBases
from ._operators import DiffusionOperators


def stack_diffusion_operators(
    operators: Sequence[DiffusionOperators], *, n_vertices: int | None = None, degree: int | None = None
) -> DiffusionOperators:
    """One `DiffusionOperators` with a leading batch axis: each mesh's padded to `n_vertices` and `degree`.

    Padding: vertices get zero mass, zero eigenvector rows, zero frames, themselves as neighbours with
    zero weights; extra neighbour slots of real vertices hold the vertex itself with zero weight. So
    `jax.vmap(spectral_diffusion)` and `jax.vmap(spatial_gradients)` over the batch give each mesh's
    result on its vertices and zeros on padding (whatever the padded features are).

    Args:
        operators: one shape's `DiffusionOperators` each, all with the same `k`.
        n_vertices: the padded vertex count (default `ddgjax.batch.bucket(max nv)`); at least the largest.
        degree: the padded neighbour count (default `bucket(max d, minimum=8)`); at least the largest.

    Returns:
        `DiffusionOperators` whose arrays have shapes `(B, n_vertices, ...)`. PyTorch3D's `Meshes`
        pads to the exact maximum; DiffusionNet has no batch of shapes (batch size 1).
    """
    operators = list(operators)
    if not operators:
        raise DDGInputError("operators: expected at least one DiffusionOperators, got none")
    for index, op in enumerate(operators):
        if not isinstance(op, DiffusionOperators) or op.mass.ndim != 1:
            raise DDGInputError(f"operators: expected one shape's DiffusionOperators each, not so at position {index}")
    ks = sorted({op.values.shape[0] for op in operators})
    if len(ks) > 1:
        raise DDGInputError(f"operators: expected one number of eigenpairs k for every shape, got {ks}")
    largest = max(op.mass.shape[0] for op in operators)
    widest = max(op.gradient_neighbors.shape[1] for op in operators)
    n = bucket(largest) if n_vertices is None else check_count("n_vertices", n_vertices, minimum=largest)
    d = bucket(widest, minimum=8) if degree is None else check_count("degree", degree, minimum=widest)
    padded = [_pad(op, n, d) for op in operators]
    return DiffusionOperators(
        mass=jnp.stack([p.mass for p in padded]),
        values=jnp.stack([p.values for p in padded]),
        vectors=jnp.stack([p.vectors for p in padded]),
        frames=TangentBases(*(jnp.stack([p.frames[i] for p in padded]) for i in range(3))),
        gradient_neighbors=jnp.stack([p.gradient_neighbors for p in padded]),
        gradient_weights=jnp.stack([p.gradient_weights for p in padded]),
    )


def _pad(op: DiffusionOperators, n: int, d: int) -> DiffusionOperators:
    """`op` padded to `n` vertices and `d` neighbour slots (stack_diffusion_operators)."""
    nv, width = op.gradient_neighbors.shape
    rows = nv, n - nv

    def pad_rows(array):
        return jnp.pad(array, [(0, rows[1])] + [(0, 0)] * (array.ndim - 1))

    own = jnp.broadcast_to(jnp.arange(n, dtype=op.gradient_neighbors.dtype)[:, None], (n, d))
    neighbors = own.at[:nv, :width].set(op.gradient_neighbors)
    weights = jnp.zeros((n, d, 2), op.gradient_weights.dtype).at[:nv, :width].set(op.gradient_weights)
    return DiffusionOperators(
        mass=pad_rows(op.mass),
        values=op.values,
        vectors=pad_rows(op.vectors),
        frames=TangentBases(*(pad_rows(f) for f in op.frames)),
        gradient_neighbors=neighbors,
        gradient_weights=weights,
    )
