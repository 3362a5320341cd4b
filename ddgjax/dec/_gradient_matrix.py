"""The gradient of piecewise-linear vertex functions as a sparse matrix: `dec.gradient` assembled.

`gradient_matrix(mesh)` is the `(3 nf, nv)` matrix `G` with `G u` the per-face gradient of the
piecewise-linear `u`, flattened face by face (`(G u).reshape(nf, 3) == ddgjax.dec.gradient(mesh, u)`):
its entries are the gradients `grad phi_j` of each face's hat functions (Crane 2020, "Discrete
differential geometry: an applied introduction", section 6.2). libigl: `igl.grad(V, F)` holds the same
entries with the rows ordered all x, then all y, then all z (ddgjax: row `3 f + c`).
"""

from __future__ import annotations

import weakref

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from .._compile import device_array, kernel
from ..mesh import Mesh, MeshTopology, face_hat_gradients, require_mesh
from ..sparse import SparseMatrix, SparsityPattern


def gradient_matrix(mesh: Mesh) -> SparseMatrix:
    """The `(3 nf, nv)` matrix `G` of the per-face gradient of vertex functions (module docstring).

    Differentiable in the vertex positions, under `jit` and `vmap` (one compiled program per mesh size);
    the sparsity pattern is built once per connectivity.

    Args:
        mesh: any triangle mesh.

    Returns:
        `(3 nf, nv)` `SparseMatrix`, row `3 f + c` the coordinate `c` of the gradient on face `f`.
    """
    mesh = require_mesh("mesh", mesh)
    pattern, slot = _gradient_pattern(mesh.topology)
    return SparseMatrix(_gradient_values(mesh, slot, nnz=pattern.nnz), pattern)


# Keyed by topology, which compares by content: meshes of one connectivity share one pattern.
_GRADIENT_PATTERNS: "weakref.WeakKeyDictionary[MeshTopology, tuple[SparsityPattern, Array]]" = weakref.WeakKeyDictionary()


def _gradient_pattern(topology: MeshTopology) -> tuple[SparsityPattern, Int[Array, " m"]]:
    """`(pattern, slot)` of `G` for this connectivity: entry `(f, j, c)` of `face_hat_gradients` lands in `slot`."""
    cached = _GRADIENT_PATTERNS.get(topology)
    if cached is None:
        faces = np.asarray(topology.faces)
        nf = faces.shape[0]
        rows = (3 * np.arange(nf)[:, None, None] + np.arange(3)[None, None, :]).repeat(3, axis=1)  # row 3 f + c
        cols = np.repeat(faces[:, :, None], 3, axis=2)  # column: the face's corner j
        # Host work even when called inside a caller's trace: the pattern depends on the topology only.
        with jax.ensure_compile_time_eval():
            pattern, slot = SparsityPattern.from_coo(rows.ravel(), cols.ravel(), (3 * nf, topology.n_vertices))
            cached = _GRADIENT_PATTERNS[topology] = (pattern, device_array(slot))
    return cached


@kernel(static_argnames=("nnz",))
def _gradient_values(mesh: Mesh, slot: Int[Array, " m"], *, nnz: int) -> Float[Array, " nnz"]:
    """The values of `G` on its pattern's `nnz` slots (one compiled program per mesh size)."""
    entries = face_hat_gradients(mesh)  # [f, j, c]
    return jnp.zeros(nnz, entries.dtype).at[slot].add(entries.ravel())
