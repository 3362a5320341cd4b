"""The cotan Laplacian and mass matrices of a tetrahedral mesh, assembled into a fixed pattern from the lengths core.

Convention (DESIGN.md, as on surfaces): `L` is the positive semidefinite weak Laplacian, the Galerkin
stiffness matrix of the linear hat functions,

    L_ij = int grad phi_i . grad phi_j = -sum_{tets of ij} l_kl cot(theta_kl) / 6,   L_ii = -sum_j L_ij,

so `L == -igl.cotmatrix(V, T)` and the pointwise Laplacian is `-M^{-1} L`. The per-tet edge weights
come from the intrinsic core (`tet_cotan_weights_from_lengths_sq`) and reach the off-diagonal slots
of the vertex pattern through one fixed gather (`ddgjax.sparse.gather_sum`, whose transpose is a
gather too), so every function here is differentiable in the vertex positions, forward and reverse,
under jit / grad / vmap, with no scatter-add. The storage plan (`TetPlan`) is host work, built once
per connectivity and cached, as `ddgjax.laplacian`'s plans are.

Degenerate tets (zero volume) contribute nothing, with finite values and gradients; a Laplacian
with obtuse dihedral angles has positive off-diagonal entries (it stays PSD: a Gram matrix).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .._compile import device_array, kernel
from .._errors import DDGInputError
from .._options import check_mass
from ..laplacian.internal import apply_slot_weights
from ..sparse import SparseMatrix, diagonal_matrix
from ._dual import vertex_dual_volumes
from ._geometry import tet_cotan_weights, tet_volumes
from ._plan import TetPlan, laplacian_values_from_weights, row_sums, slot_values, tet_plan, with_diagonal
from ._tet_mesh import TetMesh, require_tet_mesh


@kernel
def _laplacian_values(tet_mesh: TetMesh, plan: TetPlan) -> Float[Array, " nnz"]:
    return laplacian_values_from_weights(tet_cotan_weights(tet_mesh), plan)


def cotan_laplacian(tet_mesh: TetMesh) -> SparseMatrix:
    r"""The cotan Laplacian `L` of a tet mesh (PSD, weak / integrated), a `SparseMatrix` on its vertex pattern.

    $$L_{ij} = -\frac16 \sum_{t \ni ij} \ell_{kl} \cot\theta_{kl}, \qquad L_{ii} = -\sum_{j \ne i} L_{ij}$$

    over the tets of edge $ij$ ($\theta_{kl}$ the dihedral angle at
    the opposite edge $kl$; module docstring): the Galerkin stiffness matrix
    $\int \langle \nabla\phi_i, \nabla\phi_j \rangle \, dV$ of the linear hat functions, and the DEC `d0^T *1 d0`
    (`ddgjax.volume.d0`, `hodge1`). Flagged symmetric positive semidefinite (`as_lineax_operator()`
    is tagged for `lineax.CG`). One compiled program per mesh size; differentiable in the vertex
    positions.

    Args:
        tet_mesh: any tet mesh.

    Returns:
        `(nv, nv)` `SparseMatrix`; `L == -igl.cotmatrix(V, T)`.

    Reference: Crane, "Discrete Differential Geometry: An Applied Introduction" (2020), ch. 6; libigl
    `cotmatrix` (negated) on tets.

    Examples:
        >>> import jax.numpy as jnp
        >>> import ddgjax
        >>> ball = ddgjax.volume.tet_ball(4)
        >>> L = ddgjax.volume.cotan_laplacian(ball)
        >>> x = ball.vertices[:, 0]  # int |grad x|^2 = the volume
        >>> L.shape, bool(jnp.isclose(x @ (L @ x), ddgjax.volume.tet_volumes(ball).sum()))
        ((309, 309), True)
    """
    plan = tet_plan(tet_mesh)
    return SparseMatrix(_laplacian_values(tet_mesh, plan), plan.pattern, symmetric=True, positive_semidefinite=True)


@kernel
def _galerkin_values(tet_mesh: TetMesh, plan: TetPlan) -> Float[Array, " nnz"]:
    volumes = tet_volumes(tet_mesh)
    off_diagonal = slot_values(jnp.broadcast_to(volumes[:, None] / 20.0, (volumes.shape[0], 6)), plan)
    # Each vertex has three edges per tet: the row sum of V / 20 is 3 V / 20, the diagonal V / 10 = 2/3 of it.
    return with_diagonal(row_sums(off_diagonal, plan) * (2.0 / 3.0), off_diagonal)


def mass_matrix(tet_mesh: TetMesh, *, mass: str = "voronoi") -> SparseMatrix:
    r"""Mass matrix `M` of a tet mesh (`u^T M v ~ int u v dV`), symmetric positive (semi)definite.

    $$u^\top M v \approx \int u\, v \, dV, \qquad \sum_{ij} M_{ij} = \text{volume}$$

    `mass` is one of `ddgjax.MASS_MATRICES`, with the meaning each has on tetrahedra in libigl:

    - `"voronoi"` (default, as on surfaces): diagonal, the hybrid Voronoi volume of each vertex
      (`vertex_dual_volumes(tet_mesh, dual="voronoi")`; libigl `MASSMATRIX_TYPE_VORONOI`, i.e.
      `voronoi_mass`). libigl's *default* on tets is barycentric.
    - `"barycentric"`: diagonal, a quarter of the volume of each incident tet (libigl
      `MASSMATRIX_TYPE_BARYCENTRIC`, its default for tets).
    - `"galerkin"`: the consistent FEM matrix $\int \phi_i \phi_j \, dV$: $V / 10$ on the diagonal and $V / 20$
      off it per tet (libigl `MASSMATRIX_TYPE_FULL`), on the Laplacian's pattern.

    Each sums to the solid's volume (`sum(M) == sum(tet_volumes)`); unreferenced vertices get zero
    rows; zero-volume tets contribute nothing.

    Args:
        tet_mesh: any tet mesh.
        mass: `"voronoi"`, `"barycentric"` or `"galerkin"` (keyword-only).

    Returns:
        `(nv, nv)` `SparseMatrix`, flagged positive semidefinite.

    Reference: libigl `massmatrix` on tets; Meyer et al. (2003) for the hybrid Voronoi idea.

    Examples:
        >>> import jax.numpy as jnp
        >>> import ddgjax
        >>> ball = ddgjax.volume.tet_ball(4)
        >>> M = ddgjax.volume.mass_matrix(ball, mass="galerkin")
        >>> one = jnp.ones(ball.n_vertices)
        >>> M.shape, bool(jnp.isclose(one @ (M @ one), ddgjax.volume.tet_volumes(ball).sum()))
        ((309, 309), True)
    """
    check_mass(mass)
    if mass != "galerkin":
        return diagonal_matrix(vertex_dual_volumes(tet_mesh, dual=mass), positive_semidefinite=True)
    plan = tet_plan(tet_mesh)
    return SparseMatrix(_galerkin_values(tet_mesh, plan), plan.pattern, symmetric=True, positive_semidefinite=True)


def laplacian_apply(tet_mesh: TetMesh, u: Float[ArrayLike, "nv *k"], /) -> Float[Array, "nv *k"]:
    """Matrix-free `L u` for `u` of shape `(nv,)` or `(nv, k)` (the convention of `cotan_laplacian`).

    `(L u)_i = sum_{j ~ i} w_ij (u_i - u_j)`, the per-tet weights gathered onto the directed edges and
    applied to the edge differences: no diagonal and no `SparseMatrix` formed. Equals
    `cotan_laplacian(tet_mesh) @ u` to round-off. libigl: `-igl.cotmatrix(V, T) @ u`.

    Args:
        tet_mesh: the tet mesh.
        u: `(nv,)` or `(nv, k)` values at the vertices (positional-only).

    Returns:
        Float array of `u`'s shape, `L u`.
    """
    return _apply(tet_mesh, tet_plan(tet_mesh), _vertex_values("u", tet_mesh, u))


@kernel
def _apply(tet_mesh: TetMesh, plan: TetPlan, u: Float[Array, "nv *k"]) -> Float[Array, "nv *k"]:
    return apply_slot_weights(slot_values(-tet_cotan_weights(tet_mesh), plan), plan, u)


def dirichlet_energy(tet_mesh: TetMesh, u: Float[ArrayLike, "nv *k"], /) -> Float[Array, ""]:
    """Dirichlet energy `E(u) = 1/2 u^T L u = 1/2 int |grad u|^2 dV` of a piecewise-linear function (columns summed).

    Differentiable in `u` (`grad_u E = L u`) and in the vertex positions (forward and reverse mode,
    to second order). libigl: `0.5 * u @ (-igl.cotmatrix(V, T) @ u)`.

    Args:
        tet_mesh: the tet mesh.
        u: `(nv,)` or `(nv, k)` values at the vertices (positional-only).

    Returns:
        Scalar float array, summed over the columns of `u`.
    """
    u = _vertex_values("u", tet_mesh, u)
    return 0.5 * jnp.sum(u * _apply(tet_mesh, tet_plan(tet_mesh), u))


def _vertex_values(name: str, tet_mesh: TetMesh, values) -> Float[Array, "nv *k"]:
    """`values` as a float JAX array after checking its shape `(nv,)` or `(nv, k)`."""
    n = require_tet_mesh("tet_mesh", tet_mesh).n_vertices
    if np.ndim(values) not in (1, 2) or np.shape(values)[0] != n:
        raise DDGInputError(f"{name}: expected shape ({n},) or ({n}, k), got {np.shape(values)}")
    values = values if isinstance(values, jax.Array) else device_array(values)
    return values if jnp.issubdtype(values.dtype, jnp.floating) else values.astype(jnp.result_type(float))
