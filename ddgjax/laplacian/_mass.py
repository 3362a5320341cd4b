"""Mass matrices: lumped (Voronoi / mixed, barycentric) and the consistent Galerkin one."""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Float

from .._compile import kernel
from .._errors import check_choice
from ..mesh import Mesh, edge_cotan_weights_from_corner_cotangents, face_areas, vertex_dual_areas
from ..sparse import SparseMatrix, diagonal_matrix
from ._cotan import _with_diagonal, vertex_operator
from ._plan import VertexPlan, vertex_plan


def mass_matrix(mesh: Mesh, *, kind: str = "voronoi") -> SparseMatrix:
    """Mass matrix `M` (integrates piecewise-linear functions: `u^T M v ~ int u v`), symmetric positive definite.

    - `"voronoi"` (default; mixed area of Meyer et al. 2003): diagonal, `M_ii` = the vertex's mixed
      Voronoi area (`vertex_dual_areas(mesh, dual="voronoi")`), as libigl `MASSMATRIX_TYPE_VORONOI`.
    - `"barycentric"`: diagonal, a third of the incident face areas (libigl `MASSMATRIX_TYPE_BARYCENTRIC`).
    - `"galerkin"`: the consistent FEM mass matrix `M_ij = int phi_i phi_j` on the vertex pattern
      (same pattern as the cotan Laplacian, so `L + t M` is defined): `A_f / 6` on the diagonal and
      `A_f / 12` off it per face (libigl `MASSMATRIX_TYPE_FULL`; gpytoolbox `massmatrix(type="full")`).

    The lumped kinds return a diagonal `SparseMatrix` (`ddgjax.sparse.diagonal_matrix`); `L + t M`
    and `M + t L` work for every kind (a diagonal matrix adds onto the Laplacian's pattern). Every
    kind is flagged symmetric positive semidefinite (so `as_lineax_operator()` is tagged for
    `lineax.CG`) and sums to the total area; unreferenced vertices get zero rows (so `M` is then only
    semidefinite); zero-area faces contribute nothing.

    Args:
        mesh: any triangle mesh.
        kind: `"voronoi"`, `"barycentric"` or `"galerkin"` (keyword-only).

    Returns:
        `(nv, nv)` `SparseMatrix`.

    Reference: Meyer, Desbrun, Schroeder, Barr (2003); libigl `massmatrix`.
    """
    check_choice("kind", kind, ("voronoi", "barycentric", "galerkin"))
    if kind != "galerkin":
        return diagonal_matrix(vertex_dual_areas(mesh, dual=kind), positive_semidefinite=True)
    plan = vertex_plan(mesh)
    return SparseMatrix(_galerkin_values(mesh, plan), plan.pattern, symmetric=True, positive_semidefinite=True)


@kernel
def _galerkin_values(mesh: Mesh, plan: VertexPlan) -> Float[Array, " nnz"]:
    """Values of the Galerkin mass matrix on `plan.pattern` (one compiled program per mesh size)."""
    areas = face_areas(mesh)
    # Each face adds A/12 to each of its three edges (the helper halves its corner sum).
    edge_values = edge_cotan_weights_from_corner_cotangents(mesh, jnp.broadcast_to(areas[:, None] / 6.0, (areas.shape[0], 3)))
    off_diagonal = vertex_operator(plan, edge_values)
    # Row i: sum_f A_f / 6 on the diagonal equals its off-diagonal sum, 2 A_f / 12 per face.
    return _with_diagonal(off_diagonal, off_diagonal.row_sums(), positive_semidefinite=True).values
