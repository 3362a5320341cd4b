"""The cotan Laplacian of a mesh: assembled (`cotan_laplacian`), applied matrix-free (`laplacian_apply`), as an energy.

Convention (DESIGN.md): `L` is the positive semidefinite weak (integrated) Laplacian,

    (L u)_i = 1/2 sum_j (cot a_ij + cot b_ij) (u_i - u_j),

so `L == -igl.cotmatrix(V, F) == gpytoolbox.cotangent_laplacian(V, F)`, and the pointwise
Laplace-Beltrami operator is `-M^{-1} L`. Every route computes the same per-corner values, the
intrinsic core of `ddgjax.laplacian._lengths` on the mesh's squared edge lengths, gathered (no
scatter) onto the off-diagonal slots of the vertex pattern (`ddgjax.laplacian._plan`); the assembled
matrix's diagonal is minus the off-diagonal row sum (`L 1 = 0` by construction, exactly the
partition of unity `sum_j grad phi_j = 0`).

Works on every triangle mesh, as libigl's does: a boundary edge has one cotangent term, a
non-manifold edge one per incident face, inconsistent orientation does not matter (cotangents are
unsigned), an unreferenced vertex has an empty (zero) row. Degenerate faces (zero area, collinear
corners) contribute nothing, with finite values and gradients (libigl gives inf / NaN there).

Every function here is differentiable in the vertex positions in forward and reverse mode, to any
order (`jax.jvp`, `jax.jacfwd`, `jax.grad`, Hessian-vector products), under `jit` and `vmap`: the
corner -> pattern gather is `ddgjax.sparse.gather_sum`, whose transpose is a fixed gather too.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._compile import device_array, kernel
from .._errors import DDGInputError
from .._indexing import take_rows
from .._numerics import safe_reciprocal, safe_sqrt
from ..internal import degenerate_faces
from ..mesh import Mesh, face_areas, face_edge_lengths_sq, face_vertex_positions, require_mesh
from ..sparse import SparseMatrix
from ._lengths import laplacian_values, off_diagonal_entries, psd_matrix
from ._plan import TriangulationPlan, vertex_plan


def cotan_laplacian(mesh: Mesh) -> SparseMatrix:
    """The cotan Laplacian `L` (PSD, weak / integrated), a `SparseMatrix` on the mesh's vertex pattern.

    `L_ij = -(cot a_ij + cot b_ij) / 2` for an edge `ij`, `L_ii = -sum_{j != i} L_ij`, with the
    cotangents from the squared edge lengths of each face, `cot a_k = (l_{k+1}^2 + l_{k+2}^2 - l_k^2)
    / (4 A)`: the intrinsic core `cotan_laplacian_from_lengths_sq` applied to the mesh's
    `face_edge_lengths_sq`, on the storage plan cached for its connectivity
    (`ddgjax.laplacian._plan`), with the face areas from the embedding (`|e_1 x e_2| / 2`, as
    `ddgjax.mesh.corner_cotangents` takes them). It is the Galerkin stiffness matrix of
    piecewise-linear hat functions, `L_ij = int <grad phi_i, grad phi_j>`, and equals the DEC
    `d0^T *1 d0` (`ddgjax.dec`) to round-off (tests). The per-corner values are gathered straight
    into the pattern's storage order and the diagonal is minus the off-diagonal row sum, so
    `L 1 = 0` exactly.

    The result is flagged symmetric positive semidefinite (a Gram matrix of hat gradients, whatever
    the angles), so `cotan_laplacian(m).as_lineax_operator()` is tagged for `lineax.CG`, except on
    concrete positions with zero or near-zero area faces (`ddgjax.mesh.check_mesh`'s
    `zero_area_faces`, found once per mesh object): there the cotangents' rounding makes the matrix
    indefinite, so it is not flagged, and the problem-level functions refuse it and point to
    `robust=True` (the mollified intrinsic Delaunay Laplacian, PSD on every mesh). Under jit the
    positions cannot be inspected and the flag is kept. Works under jit / grad / jvp / vmap over the
    vertex positions; see the module docstring for non-manifold, boundary and degenerate input.

    Args:
        mesh: any triangle mesh.

    Returns:
        `(nv, nv)` `SparseMatrix`; `L == -igl.cotmatrix(V, F)` (`to_igl_cotmatrix` converts).

    References: U. Pinkall, K. Polthier, "Computing discrete minimal surfaces and their conjugates"
    (1993); K. Crane, "Discrete Differential Geometry: An Applied Introduction" (2020), ch. 6.
    libigl `cotmatrix` (negated); gpytoolbox `cotangent_laplacian`.
    """
    plan = vertex_plan(mesh)
    degenerate = degenerate_faces(mesh)  # None under jit
    values = _values(mesh, plan)
    if degenerate is not None and degenerate.size:
        return SparseMatrix(values, plan.pattern, symmetric=True)
    return psd_matrix(values, plan)


@kernel
def _values(mesh: Mesh, plan: TriangulationPlan) -> Float[Array, " nnz"]:
    """Values of `cotan_laplacian` on `plan.pattern` (one compiled program per mesh size)."""
    return laplacian_values(face_edge_lengths_sq(mesh), plan, areas=face_areas(mesh))


def laplacian_apply(mesh: Mesh, u: Float[Array, "nv *k"]) -> Float[Array, "nv *k"]:
    """Matrix-free `L u` for `u` of shape `(nv,)` or `(nv, k)` (same convention as `cotan_laplacian`).

    `(L u)_i = sum_{j ~ i} w_ij (u_i - u_j)` with `w_ij = 1/2 (cot a_ij + cot b_ij)`, evaluated term by
    term: the off-diagonal entries `cotan_laplacian` assembles (each corner's `-cot(alpha) / 2` from
    the squared edge lengths, gathered onto the directed edges `i -> j` leaving each vertex: the
    off-diagonal slots of the vertex pattern, which list them row by row) are multiplied by the edge
    differences `u_j - u_i` and summed per vertex. No diagonal and no `SparseMatrix` are formed, one
    fused program instead of an assembly and a product. Equals `cotan_laplacian(mesh) @ u` to
    round-off (tests). Every step is a fixed gather or a contiguous sum, no scatter-add (only the few
    directed edges of high-degree vertices that overflow the pattern's ELL width go through a
    sorted `segment_sum`), so the result is also bitwise reproducible on GPU. The corner -> edge
    gather is `ddgjax.sparse.gather_sum`, whose transpose is a gather: differentiable in `u` and in
    the vertex positions, forward and reverse mode, under jit and vmap.

    `laplacian_apply(mesh, mesh.vertices)` is the integrated mean curvature normal `2 H N A_i`, the
    gradient of the total area (outward on a convex closed mesh). Reference: Pinkall & Polthier
    (1993). libigl: `-igl.cotmatrix(V, F) @ u`; gpytoolbox: `cotangent_laplacian(V, F) @ u`.

    Args:
        mesh: any triangle mesh.
        u: `(nv,)` or `(nv, k)` values at the vertices.

    Returns:
        `L u`, the shape of `u`.
    """
    return _compiled_apply(mesh, vertex_plan(mesh), _vertex_values(mesh, u))


def _vertex_values(mesh: Mesh, u) -> Float[Array, "nv *k"]:
    """`u` as a JAX array, after checking that it has shape `(nv,)` or `(nv, k)` (shapes are known under jit too)."""
    n = require_mesh("mesh", mesh).n_vertices
    if np.ndim(u) not in (1, 2) or np.shape(u)[0] != n:
        raise DDGInputError(f"u: expected shape ({n},) or ({n}, k), got {np.shape(u)}")
    return u if isinstance(u, jax.Array) else device_array(u)


def _apply_laplacian(mesh: Mesh, plan: TriangulationPlan, u: Float[Array, "nv *k"]) -> Float[Array, "nv *k"]:
    """`laplacian_apply` without the input check (see there)."""
    n = mesh.n_vertices
    shape = jnp.shape(u)
    columns = u.reshape(n, -1)
    pattern = plan.pattern
    # L_ij on the off-diagonal slots nv.. (row i, column j): the entries `cotan_laplacian` assembles.
    weights = off_diagonal_entries(face_edge_lengths_sq(mesh), plan, face_areas(mesh))[:, None]
    ell_end = n * pattern.width
    ell_weights = weights[: ell_end - n].reshape(pattern.width - 1, n, 1)
    ell_heads = pattern.cols[n:ell_end].reshape(pattern.width - 1, n)
    # Slots of ELL block k hold row i at position i, so u_i needs no gather.
    result = jnp.zeros_like(columns)
    for k in range(pattern.width - 1):
        result = result + ell_weights[k] * (take_rows(columns, ell_heads[k]) - columns)
    if pattern.nnz > ell_end:  # the COO tail of high-degree rows, sorted by row
        rows, heads = pattern.rows[ell_end:], pattern.cols[ell_end:]
        differences = weights[ell_end - n :] * (take_rows(columns, heads) - take_rows(columns, rows))
        result = result + jax.ops.segment_sum(differences, rows, num_segments=n, indices_are_sorted=True)
    return result.reshape(shape)


_compiled_apply = kernel(_apply_laplacian)


def dirichlet_energy(mesh: Mesh, u: Float[Array, "nv *k"]) -> Float[Array, ""]:
    """Dirichlet energy `E(u) = 1/2 u^T L u = 1/2 int |grad u|^2` of a piecewise-linear function (summed over columns).

    `u` of shape `(nv,)` or `(nv, k)`. Differentiable in `u` (`grad_u E = L u`) and in the vertex
    positions, in forward and reverse mode and to second order (Hessian-vector products by
    forward-over-reverse, as optimistix / lineax Newton operators use them). The derivative in the
    vertex positions is written out per face (`_face_energy_gradients`, a custom JVP): autodiff
    of the assembly would carry the per-corner values through the corner -> edge gather and back
    (benchmarks/laplacian.py compares the two). Checked against autodiff of
    `0.5 * u @ (cotan_laplacian(mesh) @ u)` (tests).

    Args:
        mesh: any triangle mesh.
        u: `(nv,)` or `(nv, k)` values at the vertices.

    Returns:
        `()` the energy, summed over the columns of `u`.

    Reference: Pinkall & Polthier 1993. libigl / gpytoolbox:
    `0.5 * u @ (L @ u)` with `L = -igl.cotmatrix(V, F)`.
    """
    return _compiled_energy(mesh, vertex_plan(mesh), _vertex_values(mesh, u))


@jax.custom_jvp
def _dirichlet_energy(mesh: Mesh, plan: TriangulationPlan, u: Float[Array, "nv *k"]) -> Float[Array, ""]:
    return 0.5 * jnp.sum(u * _apply_laplacian(mesh, plan, u))


_compiled_energy = kernel(_dirichlet_energy)


@_dirichlet_energy.defjvp
def _dirichlet_energy_jvp(primals, tangents):
    """`dE = <L u, du> + sum_f sum_j <G_fj, dp_fj>` (`G` from `_face_energy_gradients`; linear in the tangents)."""
    mesh, plan, u = primals
    d_mesh, _, d_u = tangents  # the plan is integer data: no tangent
    applied = _apply_laplacian(mesh, plan, u)
    d_energy = jnp.sum(applied * d_u)
    gradients = _face_energy_gradients(mesh, u)
    for c in range(3):
        for j in range(3):
            # One (nf,) gather per corner and coordinate: reverse mode scatters each G[j][c] as it is
            # (stacking G into (nf, 3, 3) would make XLA concatenate, which it does not vectorise).
            d_energy = d_energy + jnp.sum(gradients[j][c] * take_rows(d_mesh.vertices[:, c], mesh.faces[:, j]))
    return 0.5 * jnp.sum(u * applied), d_energy


def _face_energy_gradients(mesh: Mesh, u: Float[Array, "nv *k"]) -> list[list[Float[Array, " nf"]]]:
    """`G[j][c]`: derivative of `E = 1/2 u^T L u` in coordinate `c` of corner `j` of each face (closed form).

    Per face `E_f = A |g|^2 / 2` with `g = sum_k u_k grad phi_k` the (constant) gradient of `u`. Moving
    the corners deforms the face affinely, and the shape derivative of a Dirichlet energy is its
    energy-momentum (Eshelby) tensor `T = |g|^2 / 2 I - g g^T` applied to the hat gradients:

        G_j = A T grad phi_j = A (|g|^2 / 2 grad phi_j - (g . grad phi_j) g).

    With `e_k = p_{k+2} - p_{k+1}` the edge opposite corner `k`, `n = e_1 x e_2 = 2 A N` and
    `w = sum_k u_k e_k` (in the face plane), `grad phi_j = n x e_j / |n|^2` and `g = n x w / |n|^2`, so

        G_j = N x (|w|^2 / 2 e_j - (w . e_j) w) / (2 |n|^2).

    `G_0 + G_1 + G_2 = 0` (translations keep `E`) and `G_j` lies in the face plane (moving a corner
    off the plane changes the edge lengths only to second order). Zero-area faces contribute 0, with
    finite derivatives; the unit normal and `1 / |n|^2` keep every factor within float32 range for
    edge lengths from 1e-8 to 1e8 (tests). Columns of a `(nv, k)` `u` add up. Checked against
    autodiff of the assembled matrix (tests). Reference: J. D. Eshelby, "The force on an elastic singularity" (1951),
    the energy-momentum tensor; M. C. Delfour, J.-P. Zolesio, "Shapes and Geometries" (2011), shape
    derivatives of the Dirichlet energy.
    """
    edges, normal = _face_edges(mesh)
    values = take_rows(u, mesh.faces)  # (nf, 3) or (nf, 3, columns)
    if u.ndim == 1:  # (nf,) arrays throughout: no reductions over a size-1 axis for XLA to keep
        per_column, column_sum = lambda x: x, lambda x: x
    else:
        per_column, column_sum = lambda x: x[:, None], lambda x: jnp.sum(x, axis=-1)
    w = [sum(values[:, k] * per_column(edges[k][c]) for k in range(3)) for c in range(3)]
    inverse_sq = safe_reciprocal(_dot(normal, normal))
    unit_normal = [normal[c] * safe_sqrt(inverse_sq) for c in range(3)]
    half_w_sq = 0.5 * column_sum(_dot(w, w))
    gradients = []
    for j in range(3):
        w_dot_e = _dot(w, [per_column(edges[j][c]) for c in range(3)])
        v = [(half_w_sq * edges[j][c] - column_sum(w_dot_e * w[c])) * (0.5 * inverse_sq) for c in range(3)]
        gradients.append(_cross(unit_normal, v))
    return gradients


def _face_edges(mesh: Mesh) -> tuple[list[list[Float[Array, " nf"]]], list[Float[Array, " nf"]]]:
    """`(edges, normal)` per face as coordinate lists: `edges[k][c]`, coordinate `c` of the edge opposite
    corner `k` (`p_{k+2} - p_{k+1}`), and `normal[c] = (e_1 x e_2)[c] = 2 A N` (counterclockwise corners).

    Coordinate by coordinate on `(nf,)` arrays: XLA's CPU backend does not vectorise reductions over a
    size-3 axis, which `(nf, 3, 3)` arrays with `sum(axis=-1)` / `jnp.cross` would need. From the one
    `V[F]` gather the edge lengths of the energy's primal read too (`face_edge_lengths_sq`).
    """
    corners = face_vertex_positions(mesh)
    edges = [[corners[:, (k + 2) % 3, c] - corners[:, (k + 1) % 3, c] for c in range(3)] for k in range(3)]
    return edges, _cross(edges[1], edges[2])


def _dot(a, b):
    """Dot product of 3-vectors given as coordinate lists (XLA does not vectorise size-3 reductions)."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _cross(a, b):
    return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
