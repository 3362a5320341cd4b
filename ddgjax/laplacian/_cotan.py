"""The cotan Laplacian: assembly on the mesh's vertex pattern, and its matrix-free apply."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from ..mesh._geometry import edge_cotan_weights
from ..mesh._mesh import Mesh
from ..sparse import SparseMatrix


def cotan_laplacian(mesh: Mesh, *, method: str = "fem") -> SparseMatrix:
    """The PSD weak cotan Laplacian on `mesh.vertex_pattern`."""
    weights = edge_cotan_weights(mesh)
    e0, e1 = mesh.edges[:, 0], mesh.edges[:, 1]
    diagonal = jax.ops.segment_sum(weights, e0, num_segments=mesh.n_vertices) + jax.ops.segment_sum(
        weights, e1, num_segments=mesh.n_vertices
    )
    values = jnp.concatenate([diagonal, -weights, -weights])[mesh.vertex_pattern_source]
    return SparseMatrix(values, mesh.vertex_pattern)


def laplacian_apply(mesh: Mesh, u: Float[Array, "nv *k"]) -> Float[Array, "nv *k"]:
    """`L u` for `u` of shape `(nv,)` or `(nv, k)`."""
    return cotan_laplacian(mesh) @ u
