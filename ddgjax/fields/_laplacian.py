"""The connection Laplacian of n-direction fields: a complex Hermitian matrix on the vertex pattern.

    E(u) = sum_{edges ij} w_ij |u_j - exp(i n rho_ij) u_i|^2 = u^H A u,
    A_ii = sum_j w_ij,    A_ij = -w_ij exp(i n rho_ji) = -w_ij exp(-i n rho_ij),

with `w_ij = (cot a_ij + cot b_ij) / 2` the cotan weights and `rho_ij` the transport angle from `i`
to `j` (`ddgjax.fields._connection`). For `n = 0` (or a flat connection) it is the cotan Laplacian.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Complex, Float

from .._compile import kernel
from .._errors import DDGInputError
from .._indexing import take_rows_or_zero
from .._options import LUMPED_MASS_MATRICES, check_mass
from ..laplacian import TriangulationPlan, mass_matrix
from ..laplacian.internal import vertex_plan
from ..mesh import Mesh, edge_cotan_weights
from ..sparse import SparseMatrix, diagonal_matrix
from ._connection import check_boundary_scaling, connection_angles, plan_of
from ._plan import FieldPlan

"""The `mass=` values of tangent fields: the lumped ones (`connection_mass_matrix`)."""


def check_degree(n) -> int:
    """`n` if it is an integer `>= 1` (the number of directions), else `DDGInputError`."""
    if isinstance(n, (bool, np.bool_)) or not isinstance(n, (int, np.integer)) or n < 1:
        raise DDGInputError(f"n: expected the number of directions, an integer >= 1 (1 vector, 2 line, 4 cross field), got {n!r}")
    return int(n)


@kernel(static_argnames=("boundary_scaling",))
def _values(
    mesh: Mesh,
    field: FieldPlan,
    vertex: TriangulationPlan,
    n: Float[ArrayLike, ""],
    edge_weights: Float[Array, " ne"] | None,
    *,
    boundary_scaling: str,
) -> Complex[Array, " nnz"]:
    # `n` is traced, not static: one program per mesh size serves every n.
    transport = connection_angles(mesh, field, boundary_scaling=boundary_scaling).transport
    weights = edge_cotan_weights(mesh) if edge_weights is None else edge_weights
    rotations = jnp.exp(-1j * n * transport)
    low_high = -weights * rotations
    diagonal = jax.ops.segment_sum(jnp.repeat(weights, 2), mesh.edges.reshape(-1), num_segments=mesh.n_vertices)
    entries = jnp.concatenate([diagonal.astype(low_high.dtype), low_high, jnp.conj(low_high)])
    return take_rows_or_zero(entries, vertex.source)


def connection_laplacian(mesh: Mesh, *, n: int = 1, boundary_scaling: str = "geodesic") -> SparseMatrix:
    r"""The connection Laplacian `A` of `n`-direction fields, a complex Hermitian `SparseMatrix` on the vertex pattern.

    $$u^H A u = \sum_{ij} w_{ij} \lvert u_j - e^{i n \rho_{ij}} u_i \rvert^2$$

    (module docstring): the smoothness energy of
    the field whose value at vertex `i` is `u_i`, the `n`-th power of its directions in `i`'s polar
    coordinates (`ddgjax.fields._connection`). Entries: `A_ii = sum_j w_ij`,
    `A_ij = -w_ij exp(-i n rho_ij)` with `rho_ij` the transport from `i` to `j` (equivalently
    `-w_ij exp(i n rho_ji)`), so `A` is Hermitian. Flagged `hermitian` and `positive_semidefinite`:
    a sum of squares when every `w_ij >= 0` (Delaunay meshes); with negative cotan weights on a curved
    mesh it can have eigenvalues slightly below 0 (as geometry-central's). Weak (integrated), like
    the cotan Laplacian: pair it with a mass matrix (`connection_mass_matrix`).

    Differentiable in the vertex positions (jit / grad / vmap) through the values. Needs a
    manifold, consistently oriented mesh (`MeshDataError` otherwise).

    Args:
        mesh: the mesh.
        n: number of directions (1 vector field, 2 line field, 4 cross field), keyword-only.
        boundary_scaling: `"geodesic"` (default, as geometry-central) or `"unscaled"` (`ddgjax.fields._connection`).

    Returns:
        `(nv, nv)` complex `SparseMatrix`.

    Reference: Knoeppel, Crane, Pinkall, Schroeder, "Globally optimal direction fields" (2013),
    section 5.3. potpourri3d: `MeshVectorHeatSolver(V, F, use_intrinsic_delaunay=False)
    .get_connection_laplacian()` (n = 1, in its own tangent bases: equal up to a diagonal unitary
    change of basis); geometry-central `vertexConnectionLaplacian`.
    """
    n = check_degree(n)
    check_boundary_scaling(boundary_scaling)
    return planned_connection_laplacian(mesh, plan_of(mesh), vertex_plan(mesh), float(n), boundary_scaling=boundary_scaling)


def planned_connection_laplacian(
    mesh: Mesh,
    field: FieldPlan,
    vertex: TriangulationPlan,
    n: Float[ArrayLike, ""],
    *,
    boundary_scaling: str,
    edge_weights: Float[Array, " ne"] | None = None,
) -> SparseMatrix:
    """`connection_laplacian` from its host plans, unchecked: callable inside a kernel (whose mesh has no topology).

    `edge_weights` `(ne,)` replace the cotan weights `w_ij` (the mesh's edge order): the intrinsic Delaunay
    Laplacian's weights of the mesh's edges (`>= 0`, finite on degenerate faces; 0 on an edge flipped away)
    give the robust connection Laplacian of the vector and signed heat methods.
    """
    values = _values(mesh, field, vertex, n, edge_weights, boundary_scaling=boundary_scaling)
    return SparseMatrix(values, vertex.pattern, hermitian=True, positive_semidefinite=True)


def connection_mass_matrix(mesh: Mesh, *, mass: str = "voronoi") -> SparseMatrix:
    """The lumped mass matrix of tangent fields at vertices: `mass_matrix(mesh, mass=mass)`, `(nv, nv)`, real diagonal.

    `u^H M u` is the squared `L2` norm of a vertex field. Only the lumped kinds (`"voronoi"`,
    `"barycentric"`); `"galerkin"` is refused (`DDGInputError`): the consistent mass of tangent fields
    couples neighbouring vertices, whose vectors live in different tangent planes, so its off-diagonal
    entries would need the transport (`exp(i n rho_ij)`) too, which the scalar Galerkin mass does not have.

    Args:
        mesh: the mesh.
        mass: `"voronoi"` (default) or `"barycentric"` (`LUMPED_MASS_MATRICES`; keyword-only).

    Returns:
        `(nv, nv)` real diagonal `SparseMatrix` of the vertex dual areas.
    """
    check_mass(mass, LUMPED_MASS_MATRICES)
    return mass_matrix(mesh, mass=mass)


@kernel  # eagerly one kept program, not one compilation per operation
def real_form(matrix: SparseMatrix, plan: FieldPlan) -> SparseMatrix:
    """`[[Re A, -Im A], [Im A, Re A]]`, `(2 nv, 2 nv)`, real symmetric, of a Hermitian `A` on the vertex pattern.

    `x^T R x = u^H A u` for `x = [Re u; Im u]`; every eigenvalue of `A` appears twice in `R`, with
    eigenvectors `[Re u; Im u]` and `[-Im u; Re u]` (`i u`). On a host-built pattern (`FieldPlan`),
    one gather of the values.
    """
    values = matrix.values
    stacked = jnp.concatenate([values.real, values.imag, -values.imag])
    real_values = take_rows_or_zero(stacked, plan.real_source)
    return SparseMatrix(real_values, plan.real_pattern, symmetric=True, positive_semidefinite=matrix.positive_semidefinite)


@kernel
def real_form_diagonal(diagonal: Float[Array, " nv"]) -> SparseMatrix:
    """The real form of a real diagonal matrix: the diagonal twice, `(2 nv, 2 nv)`."""
    return diagonal_matrix(jnp.concatenate([diagonal, diagonal]), positive_semidefinite=True)
