"""The cotan Laplacian and lumped mass matrices of a triangulation given by faces and squared edge lengths.

Intrinsic core (DESIGN.md): these operators depend on the metric only through the squared length
of the edge opposite each face corner, `(nf, 3)` in libigl order (entry `k` belongs to the edge
opposite corner `k`). Per face, with `l_k^2` those squared lengths,

    A       = Kahan's stable Heron formula (`ddgjax.mesh.face_areas_from_lengths_sq`),
    cot a_k = (l_{k+1}^2 + l_{k+2}^2 - l_k^2) / (4 A)   (`ddgjax.mesh.corner_cotangents_from_lengths_sq`),

and `L_ij = -1/2 sum (cot of the corners opposite the edges ij)`, `L_ii = -sum_{j != i} L_ij`:
the PSD weak Laplacian of DESIGN.md, `L == -igl.cotmatrix_intrinsic(l, F)`.

The faces may form a general triangulation (a Delta-complex), as intrinsic triangulations do
after edge flips: a face may repeat a vertex (its edge between the two copies is a loop) and two
vertices may be joined by several edges. A loop edge adds `w (u_i - u_i) = 0` to `L u`, so its
corner contributes nothing to `L`; parallel edges add their weights into the one matrix entry.
Both are handled by `triangulation_plan`, which finds the vertex pairs on the host once.

Degenerate faces (zero area) follow `ddgjax.mesh._geometry`: their cotangents are 0 (they add
nothing to `L`), with finite values and gradients.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int

from .._compile import kernel
from .._errors import DDGInputError, check_choice, check_count, first_indices, is_traced
from ..internal import stable_order
from ..mesh import corner_cotangents_from_lengths_sq, corner_dual_areas_from_lengths_sq
from ..sparse import SparseMatrix, SparsityPattern, diagonal_matrix, gather_sum
from ._cotan import _off_diagonal, _with_diagonal
from ._plan import VertexPlan

MASS_KINDS = ("voronoi", "barycentric")
"""The lumped mass matrices `mass_matrix_from_lengths_sq` builds (the `kind=` option)."""


class TriangulationPlan(eqx.Module):
    """Faces of a triangulation and the storage plan of its vertex-vertex operators (built on the host).

    Attributes:
        faces: `(nf, 3)` int32 vertex indices; a face may repeat a vertex (module docstring).
        vertex_plan: where per-corner values land in the `(nv, nv)` vertex pattern (`VertexPlan`:
            the pattern holds the diagonal and both directions of every pair of distinct vertices
            joined by an edge; `slot_corners` lists the corners opposite every edge of that pair).
    """

    faces: Int[Array, "nf 3"]
    vertex_plan: VertexPlan

    @property
    def n_vertices(self) -> int:
        """Number of vertices `nv` (the pattern's size; vertices used by no face included)."""
        return self.vertex_plan.pattern.shape[0]


def triangulation_plan(faces: Int[ArrayLike, "nf 3"], n_vertices: int) -> TriangulationPlan:
    """The `TriangulationPlan` of a face list (NumPy, once per connectivity, outside jit).

    Accepts what an intrinsic triangulation can hold: faces that repeat a vertex and vertex pairs
    joined by several edges (module docstring); faces need no orientation. Build it once and reuse
    it for any edge lengths on these faces.

    Args:
        faces: `(nf, 3)` non-negative integer vertex indices below `n_vertices`.
        n_vertices: number of vertices `nv` (vertices used by no face get empty rows).

    Returns:
        `TriangulationPlan`.

    Raises `DDGInputError` for traced faces, a bad shape or dtype, or indices out of range.
    """
    if is_traced(faces):
        raise DDGInputError("faces: triangulation_plan works on the host and needs a concrete array; build it outside jit")
    n_vertices = check_count("n_vertices", n_vertices)
    host = np.asarray(faces)
    if host.ndim != 2 or host.shape[1] != 3 or not np.issubdtype(host.dtype, np.integer):
        raise DDGInputError(f"faces: expected an (nf, 3) integer array, got shape {host.shape} dtype {host.dtype}")
    out_of_range = (host < 0) | (host >= n_vertices)
    if out_of_range.any():
        raise DDGInputError(
            f"faces: vertex indices must lie in [0, {n_vertices}), got out-of-range entries in faces {first_indices(out_of_range)}"
        )
    host = host.astype(np.int32)
    return TriangulationPlan(faces=jnp.asarray(host), vertex_plan=_vertex_plan_of_faces(host, n_vertices))


def _vertex_plan_of_faces(faces: np.ndarray, nv: int) -> VertexPlan:
    """`VertexPlan` of a Delta-complex: vertex pairs from the corners' opposite edges, loops left out."""
    n_corners = faces.size
    # Corner 3 f + k is opposite the edge faces[f, k+1] - faces[f, k+2].
    tails = faces[:, [1, 2, 0]].reshape(-1).astype(np.int64)
    heads = faces[:, [2, 0, 1]].reshape(-1).astype(np.int64)
    corners = np.flatnonzero(tails != heads)
    keys = np.minimum(tails, heads)[corners] * nv + np.maximum(tails, heads)[corners]
    order, sorted_keys = stable_order(keys)
    is_first = np.ones(sorted_keys.size, dtype=bool)
    is_first[1:] = sorted_keys[1:] != sorted_keys[:-1]
    pair_of_sorted = np.cumsum(is_first) - 1
    starts = np.flatnonzero(is_first)
    n_pairs = starts.size
    pairs = np.stack([sorted_keys[starts] // nv, sorted_keys[starts] % nv], axis=1)
    pattern, source = SparsityPattern.from_edges(pairs, nv)
    # The corners of each pair, padded with 3 nf (reads 0); row n_pairs is the padding slots' row.
    width = max(1, int(np.diff(np.append(starts, sorted_keys.size)).max(initial=0)))
    position = np.arange(sorted_keys.size) - starts[pair_of_sorted]
    pair_corners = np.full((n_pairs + 1, width), n_corners, dtype=np.int32)
    pair_corners[pair_of_sorted, position] = corners[order]
    off_source = source[nv:].astype(np.int64) - nv  # [low->high (n_pairs) | high->low (n_pairs) | padding]
    pair_of_slot = np.where(off_source >= n_pairs, off_source - n_pairs, off_source)
    slot_corners = pair_corners[np.minimum(pair_of_slot, n_pairs)]
    n_off = off_source.size
    slot_of_source = np.full(2 * n_pairs + 1, n_off, dtype=np.int32)
    slot_of_source[off_source] = np.arange(n_off, dtype=np.int32)
    corner_slots = np.full((n_corners, 2), n_off, dtype=np.int32)  # loop corners: padding (no slot)
    corner_pairs = np.empty(corners.size, dtype=np.int64)
    corner_pairs[order] = pair_of_sorted
    corner_slots[corners, 0] = slot_of_source[corner_pairs]
    corner_slots[corners, 1] = slot_of_source[n_pairs + corner_pairs]
    arrays = jax.device_put({"source": source, "slot_corners": slot_corners, "corner_slots": corner_slots})
    return VertexPlan(pattern=pattern, **arrays)


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
    lengths_sq = jnp.asarray(lengths_sq)
    if not jnp.issubdtype(lengths_sq.dtype, jnp.floating):
        raise DDGInputError(f"lengths_sq: expected a floating-point array, got dtype {lengths_sq.dtype}")
    return lengths_sq


def cotan_laplacian_from_lengths_sq(lengths_sq: Float[ArrayLike, "nf 3"], plan: TriangulationPlan) -> SparseMatrix:
    """The cotan Laplacian `L` (PSD, weak / integrated) of a triangulation with the given squared edge lengths.

    `L_ij = -1/2 sum cot(a)` over the corners `a` opposite the edges joining `i != j`,
    `L_ii = -sum_{j != i} L_ij`, with `cot a_k = (l_{k+1}^2 + l_{k+2}^2 - l_k^2) / (4 A)` and `A` by
    Kahan's Heron formula. A `SparseMatrix` on `plan.vertex_plan.pattern`, flagged symmetric
    positive semidefinite (a Gram matrix of hat-function gradients of the metric). Zero-area faces
    (lengths violating or attaining the triangle inequality) contribute nothing, with finite
    gradients. Loops and parallel edges: module docstring. Differentiable in `lengths_sq` in both
    modes, under jit and vmap (the corner -> pattern map is `ddgjax.sparse.gather_sum`).

    Args:
        lengths_sq: `(nf, 3)` squared length of the edge opposite each corner of `plan.faces`.
        plan: `triangulation_plan(faces, n_vertices)`.

    Returns:
        `(nv, nv)` `SparseMatrix`; `== -igl.cotmatrix_intrinsic(sqrt(lengths_sq), faces)`.

    Reference: U. Pinkall, K. Polthier (1993); A. I. Bobenko, B. A. Springborn, "A discrete
    Laplace-Beltrami operator for simplicial surfaces" (2007). libigl `cotmatrix_intrinsic` (negated).
    """
    lengths_sq = _check_lengths_sq(lengths_sq, plan)
    values = _laplacian_values(lengths_sq, plan.vertex_plan)
    return SparseMatrix(values, plan.vertex_plan.pattern, symmetric=True, positive_semidefinite=True)


@kernel
def _laplacian_values(lengths_sq: Float[Array, "nf 3"], plan: VertexPlan) -> Float[Array, " nnz"]:
    """Values of `cotan_laplacian_from_lengths_sq` on `plan.pattern` (one program per size)."""
    entries = -0.5 * corner_cotangents_from_lengths_sq(lengths_sq)
    off_diagonal = _off_diagonal(plan, gather_sum(entries.reshape(-1), plan.slot_corners, plan.corner_slots))
    return _with_diagonal(off_diagonal, -off_diagonal.row_sums(), positive_semidefinite=True).values


def mass_matrix_from_lengths_sq(
    lengths_sq: Float[ArrayLike, "nf 3"], plan: TriangulationPlan, *, kind: str = "voronoi"
) -> SparseMatrix:
    """Lumped (diagonal) mass matrix `M` of a triangulation with the given squared edge lengths.

    `M_ii = sum` over the corners at vertex `i` of that corner's share of its face's area
    (`ddgjax.mesh.corner_dual_areas_from_lengths_sq`; a face that repeats a vertex gives it both
    shares):

    - `"voronoi"` (default, as `ddgjax.laplacian.mass_matrix`): the mixed Voronoi area of Meyer et
      al. 2003 (circumcentric on faces without an obtuse angle, `A/2, A/4, A/4` on obtuse ones);
      libigl `massmatrix_intrinsic(l, F, MASSMATRIX_TYPE_VORONOI)`.
    - `"barycentric"`: a third of each incident face; libigl `MASSMATRIX_TYPE_BARYCENTRIC`, and the
      mass matrix `robust_laplacian.mesh_laplacian` returns.

    A diagonal `SparseMatrix` (`ddgjax.sparse.diagonal_matrix`) flagged symmetric positive
    semidefinite, summing to the total area; differentiable in `lengths_sq`.

    Args:
        lengths_sq: `(nf, 3)` squared length of the edge opposite each corner of `plan.faces`.
        plan: `triangulation_plan(faces, n_vertices)`.
        kind: `"voronoi"` or `"barycentric"` (keyword-only).

    Returns:
        `(nv, nv)` diagonal `SparseMatrix`.

    Reference: M. Meyer, M. Desbrun, P. Schroeder, A. Barr (2003), Section 3.3; libigl `massmatrix_intrinsic`.
    """
    check_choice("kind", kind, MASS_KINDS)
    lengths_sq = _check_lengths_sq(lengths_sq, plan)
    areas = _vertex_areas(lengths_sq, plan.faces, kind=kind, n_vertices=plan.n_vertices)
    return diagonal_matrix(areas, positive_semidefinite=True)


@kernel(static_argnames=("kind", "n_vertices"))
def _vertex_areas(
    lengths_sq: Float[Array, "nf 3"], faces: Int[Array, "nf 3"], *, kind: str, n_vertices: int
) -> Float[Array, " nv"]:
    corner_areas = corner_dual_areas_from_lengths_sq(lengths_sq, dual=kind)
    return jax.ops.segment_sum(corner_areas.reshape(-1), faces.reshape(-1), num_segments=n_vertices)
