"""The cotan Laplacian and the mass matrices of a triangulation given by faces and squared edge lengths.

Intrinsic core (DESIGN.md): these operators depend on the metric only through the squared length
of the edge opposite each face corner, `(nf, 3)` in libigl order (entry `k` belongs to the edge
opposite corner `k`). Per face, with `l_k^2` those squared lengths,

    A       = Kahan's stable Heron formula (`ddgjax.mesh.face_areas_from_lengths_sq`),
    cot a_k = (l_{k+1}^2 + l_{k+2}^2 - l_k^2) / (4 A)   (`ddgjax.mesh.corner_cotangents_from_lengths_sq`),

and `L_ij = -1/2 sum (cot of the corners opposite the edges ij)`, `L_ii = -sum_{j != i} L_ij`:
the PSD weak Laplacian of DESIGN.md, `L == -igl.cotmatrix_intrinsic(l, F)`. Every Laplacian of
ddgjax is assembled here: `cotan_laplacian(mesh)` applies this core to the mesh's squared edge
lengths (with its areas from the embedding, as `ddgjax.mesh.corner_cotangents` does), the intrinsic
Delaunay Laplacian to the lengths of its flipped edges. The mass matrices likewise
(`mass_matrix_from_lengths_sq`; the Galerkin one depends on the face areas alone).

The faces may form a general triangulation (a Delta-complex), as intrinsic triangulations do
after edge flips: a face may repeat a vertex (its edge between the two copies is a loop) and two
vertices may be joined by several edges. A loop edge adds `w (u_i - u_i) = 0` to `L u`, so its
corner contributes nothing to `L`; parallel edges add their weights into the one matrix entry.
Both are handled by the storage plan (`triangulation_plan`, `ddgjax.laplacian._plan`).

Degenerate faces (zero area) follow `ddgjax.mesh._geometry`: their cotangents are 0 (they add
nothing to `L`), with finite values and gradients.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int

from .._compile import device_array, kernel
from .._errors import DDGInputError
from .._options import check_mass
from ..mesh import corner_cotangents_from_lengths_sq, corner_dual_areas_from_lengths_sq, face_areas_from_lengths_sq
from ..sparse import SparseMatrix, diagonal_matrix, gather_sum
from ._plan import TriangulationPlan


def _check_lengths_sq(lengths_sq, plan: TriangulationPlan):
    if not isinstance(plan, TriangulationPlan):
        raise DDGInputError(
            f"plan: expected a TriangulationPlan, got {type(plan).__name__}; build one with triangulation_plan(faces, n_vertices)"
        )
    expected = (plan.faces.shape[0], 3)
    if np.shape(lengths_sq) != expected:
        raise DDGInputError(
            f"lengths_sq: expected shape {expected} (squared length opposite each face corner), got {np.shape(lengths_sq)}"
        )
    lengths_sq = device_array(lengths_sq)
    if not jnp.issubdtype(lengths_sq.dtype, jnp.floating):
        raise DDGInputError(f"lengths_sq: expected a floating-point array, got dtype {lengths_sq.dtype}")
    return lengths_sq


def cotan_laplacian_from_lengths_sq(lengths_sq: Float[ArrayLike, "nf 3"], plan: TriangulationPlan) -> SparseMatrix:
    """The cotan Laplacian `L` (PSD, weak / integrated) of a triangulation with the given squared edge lengths.

    `L_ij = -1/2 sum cot(a)` over the corners `a` opposite the edges joining `i != j`,
    `L_ii = -sum_{j != i} L_ij`, with `cot a_k = (l_{k+1}^2 + l_{k+2}^2 - l_k^2) / (4 A)` and `A` by
    Kahan's Heron formula. A `SparseMatrix` on `plan.pattern`, flagged symmetric positive
    semidefinite (a Gram matrix of hat-function gradients of the metric). Zero-area faces
    (lengths violating or attaining the triangle inequality) contribute nothing, with finite
    gradients. Loops and parallel edges: module docstring. Differentiable in `lengths_sq` in both
    modes, under jit and vmap (the corner -> pattern map is `ddgjax.sparse.gather_sum`).
    `cotan_laplacian(mesh)` is this core on the mesh's own lengths.

    Args:
        lengths_sq: `(nf, 3)` squared length of the edge opposite each corner of `plan.faces`.
        plan: `triangulation_plan(faces, n_vertices)`.

    Returns:
        `(nv, nv)` `SparseMatrix`; `== -igl.cotmatrix_intrinsic(sqrt(lengths_sq), faces)`.

    Reference: U. Pinkall, K. Polthier (1993); A. I. Bobenko, B. A. Springborn, "A discrete
    Laplace-Beltrami operator for simplicial surfaces" (2007). libigl `cotmatrix_intrinsic` (negated).
    """
    lengths_sq = _check_lengths_sq(lengths_sq, plan)
    return psd_matrix(_laplacian_values(lengths_sq, plan), plan)


def psd_matrix(values: Float[Array, " nnz"], plan: TriangulationPlan) -> SparseMatrix:
    """A symmetric positive semidefinite `SparseMatrix` on `plan.pattern` (the Laplacian, the Galerkin mass)."""
    return SparseMatrix(values, plan.pattern, symmetric=True, positive_semidefinite=True)


def off_diagonal_entries(
    lengths_sq: Float[Array, "nf 3"], plan: TriangulationPlan, areas: Float[Array, " nf"] | None = None
) -> Float[Array, " n_off"]:
    """`L_ij = -1/2 sum cot(a)` on each off-diagonal storage slot of `plan.pattern` (one fixed gather of corners)."""
    entries = -0.5 * corner_cotangents_from_lengths_sq(lengths_sq, areas=areas)
    return gather_sum(entries.reshape(-1), plan.slot_corners, plan.corner_slots)


def laplacian_values(
    lengths_sq: Float[Array, "nf 3"], plan: TriangulationPlan, areas: Float[Array, " nf"] | None = None
) -> Float[Array, " nnz"]:
    """Values of the cotan Laplacian on `plan.pattern`; `areas` defaults to Kahan's formula (traced, not compiled here)."""
    off_diagonal = off_diagonal_entries(lengths_sq, plan, areas)
    return jnp.concatenate([-_row_sums(off_diagonal, plan), off_diagonal])


_laplacian_values = kernel(laplacian_values)


def _row_sums(off_diagonal: Float[Array, " n_off"], plan: TriangulationPlan) -> Float[Array, " nv"]:
    """Row sums of a matrix on `plan.pattern` with these off-diagonal values and a zero diagonal."""
    zeros = jnp.zeros(plan.n_vertices, off_diagonal.dtype)
    return SparseMatrix(jnp.concatenate([zeros, off_diagonal]), plan.pattern, symmetric=True).row_sums()


def mass_matrix_from_lengths_sq(
    lengths_sq: Float[ArrayLike, "nf 3"], plan: TriangulationPlan, *, mass: str = "voronoi"
) -> SparseMatrix:
    """Mass matrix `M` (`u^T M v ~ int u v`) of a triangulation with the given squared edge lengths.

    `mass` is one of `ddgjax.MASS_MATRICES`:

    - `"voronoi"` (default, as `ddgjax.laplacian.mass_matrix`): lumped, `M_ii` = the sum over the
      corners at vertex `i` of their mixed Voronoi share of the face (Meyer et al. 2003:
      circumcentric on faces without an obtuse angle, `A/2, A/4, A/4` on obtuse ones;
      `ddgjax.mesh.corner_dual_areas_from_lengths_sq`); libigl
      `massmatrix_intrinsic(l, F, MASSMATRIX_TYPE_VORONOI)`.
    - `"barycentric"`: lumped, a third of each face to each corner; libigl
      `MASSMATRIX_TYPE_BARYCENTRIC`, and the mass matrix `robust_laplacian.mesh_laplacian` returns.
    - `"galerkin"`: the consistent FEM mass matrix `M_ij = int phi_i phi_j` on `plan.pattern` (the
      Laplacian's, so `L + t M` is defined): per face `A/6` on the diagonal and `A/12` off it, so it
      depends on the face areas alone; libigl `MASSMATRIX_TYPE_FULL`. A face that repeats a vertex
      `i` integrates the sum of its two (or three) hat functions there: `M_ii` gets `A/2` (`A`).

    A face that repeats a vertex gives it each of its corners' shares. Flagged symmetric positive
    semidefinite, summing to the total area; differentiable in `lengths_sq` (jit, grad, vmap).

    Args:
        lengths_sq: `(nf, 3)` squared length of the edge opposite each corner of `plan.faces`.
        plan: `triangulation_plan(faces, n_vertices)`.
        mass: `"voronoi"`, `"barycentric"` or `"galerkin"` (keyword-only).

    Returns:
        `(nv, nv)` `SparseMatrix`: diagonal for the lumped masses, on `plan.pattern` for `"galerkin"`.

    Reference: M. Meyer, M. Desbrun, P. Schroeder, A. Barr (2003), Section 3.3; libigl `massmatrix_intrinsic`.
    """
    check_mass(mass)
    lengths_sq = _check_lengths_sq(lengths_sq, plan)
    if mass == "galerkin":
        return psd_matrix(_galerkin_from_lengths_sq(lengths_sq, plan), plan)
    areas = _vertex_areas(lengths_sq, plan.faces, mass=mass, n_vertices=plan.n_vertices)
    return diagonal_matrix(areas, positive_semidefinite=True)


@kernel(static_argnames=("mass", "n_vertices"))
def _vertex_areas(
    lengths_sq: Float[Array, "nf 3"], faces: Int[Array, "nf 3"], *, mass: str, n_vertices: int
) -> Float[Array, " nv"]:
    corner_areas = corner_dual_areas_from_lengths_sq(lengths_sq, dual=mass)
    return jax.ops.segment_sum(corner_areas.reshape(-1), faces.reshape(-1), num_segments=n_vertices)


def galerkin_values(areas: Float[Array, " nf"], plan: TriangulationPlan) -> Float[Array, " nnz"]:
    """Values of the Galerkin mass matrix on `plan.pattern` from the face areas (traced, not compiled here).

    Off the diagonal each corner gives `A/12` to the pair of its opposite edge. A row of `M` sums
    to `int phi_i = sum A/3` over the corners at `i`, and an ordinary corner's two edges carry `A/6`
    of it, so the diagonal is the off-diagonal row sum; a loop edge (both ends at `i`) carries none
    of the `A/3` it adds to `M_ii`, which is added separately.
    """
    corner_values = jnp.broadcast_to(areas[:, None] / 12.0, (areas.shape[0], 3))
    off_diagonal = gather_sum(corner_values.reshape(-1), plan.slot_corners, plan.corner_slots)
    diagonal = _row_sums(off_diagonal, plan)
    if plan.loop_corners.shape[0]:
        loop_areas = jnp.take(areas, plan.loop_corners // 3) / 3.0
        diagonal = diagonal + jax.ops.segment_sum(loop_areas, plan.loop_vertices, num_segments=plan.n_vertices)
    return jnp.concatenate([diagonal, off_diagonal])


@kernel
def _galerkin_from_lengths_sq(lengths_sq: Float[Array, "nf 3"], plan: TriangulationPlan) -> Float[Array, " nnz"]:
    return galerkin_values(face_areas_from_lengths_sq(lengths_sq), plan)
