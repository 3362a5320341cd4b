"""Mass matrices of a mesh: lumped (Voronoi / mixed, barycentric) and the consistent Galerkin one."""

from __future__ import annotations

from jaxtyping import Array, Float

from .._compile import kernel
from .._options import check_mass
from ..mesh import Mesh, face_areas, vertex_dual_areas
from ..sparse import SparseMatrix, diagonal_matrix
from ._lengths import galerkin_values, psd_matrix
from ._plan import TriangulationPlan, vertex_plan


def mass_matrix(mesh: Mesh, *, mass: str = "voronoi") -> SparseMatrix:
    r"""Mass matrix `M` (integrates piecewise-linear functions: `u^T M v ~ int u v`), symmetric positive definite.

    $$u^\top M v \approx \int u\, v \, dA, \qquad \sum_{ij} M_{ij} = \text{area}$$

    `mass` is one of `ddgjax.MASS_MATRICES`:

    - `"voronoi"` (default; mixed area of Meyer et al. 2003): diagonal, `M_ii` = the vertex's mixed
      Voronoi area (`vertex_dual_areas(mesh, dual="voronoi")`), as libigl `MASSMATRIX_TYPE_VORONOI`.
    - `"barycentric"`: diagonal, a third of the incident face areas (libigl `MASSMATRIX_TYPE_BARYCENTRIC`).
    - `"galerkin"`: the consistent FEM mass matrix $M_{ij} = \int \phi_i \phi_j \, dA$ on the vertex pattern
      (same pattern as the cotan Laplacian, so `L + t M` is defined): $A_f / 6$ on the diagonal and
      $A_f / 12$ off it per face (libigl `MASSMATRIX_TYPE_FULL`; gpytoolbox `massmatrix(type="full")`).

    Each is the intrinsic core (`mass_matrix_from_lengths_sq`: corner shares of the face areas from
    the squared edge lengths) on the mesh, with the face areas from the embedding. The lumped
    matrices are diagonal `SparseMatrix`es (`ddgjax.sparse.diagonal_matrix`); `L + t M` and
    `M + t L` work for every choice (a diagonal matrix adds onto the Laplacian's pattern). Every one
    is flagged symmetric positive semidefinite (so `as_lineax_operator()` is tagged for
    `lineax.CG`) and sums to the total area; unreferenced vertices get zero rows (so `M` is then
    only semidefinite); zero-area faces contribute nothing.

    Args:
        mesh: any triangle mesh.
        mass: `"voronoi"`, `"barycentric"` or `"galerkin"` (keyword-only).

    Returns:
        `(nv, nv)` `SparseMatrix`.

    Reference: Meyer, Desbrun, Schroeder, Barr (2003); libigl `massmatrix`; gpytoolbox `massmatrix`.

    Examples:
        >>> import jax.numpy as jnp
        >>> import ddgjax
        >>> sphere = ddgjax.mesh.icosphere(2)
        >>> M = ddgjax.laplacian.mass_matrix(sphere, mass="barycentric")
        >>> M.shape, bool(jnp.isclose(M.diagonal().sum(), ddgjax.mesh.total_area(sphere)))
        ((162, 162), True)
    """
    check_mass(mass)
    if mass != "galerkin":
        return diagonal_matrix(vertex_dual_areas(mesh, dual=mass), positive_semidefinite=True)
    plan = vertex_plan(mesh)
    return psd_matrix(_galerkin_values(mesh, plan), plan)


@kernel
def _galerkin_values(mesh: Mesh, plan: TriangulationPlan) -> Float[Array, " nnz"]:
    """Values of the Galerkin mass matrix on `plan.pattern` (one compiled program per mesh size)."""
    return galerkin_values(face_areas(mesh), plan)
