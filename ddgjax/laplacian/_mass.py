"""Mass matrices."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from ..mesh._mesh import Mesh
from ..sparse import SparseMatrix, SparsityPattern


def mass_matrix(mesh: Mesh, *, kind: str = "voronoi") -> SparseMatrix:
    """Lumped mass matrix (diagonal of vertex dual areas)."""
    from ..mesh._geometry import vertex_dual_areas

    n = mesh.n_vertices
    pattern, _ = SparsityPattern.from_coo(np.arange(n), np.arange(n), (n, n))
    return SparseMatrix(vertex_dual_areas(mesh, kind), pattern)
