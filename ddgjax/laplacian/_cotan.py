"""The cotan Laplacian, by the FEM route (hat-function gradients) and the DEC route (`d0^T *1 d0`).

Convention (DESIGN.md): `L` is the positive semidefinite weak (integrated) Laplacian,

    (L u)_i = 1/2 sum_j (cot a_ij + cot b_ij) (u_i - u_j),

so `L == -igl.cotmatrix(V, F) == gpytoolbox.cotangent_laplacian(V, F)`, and the pointwise
Laplace-Beltrami operator is `-M^{-1} L`. Both routes land on `mesh.vertex_pattern`: the edge
entries `-w_ij` are gathered from per-edge weights (no scatter), the diagonal is minus the
off-diagonal row sum (`L 1 = 0` by construction, exactly the partition of unity `sum_j grad phi_j = 0`).

Works on every triangle mesh, as libigl's does: a boundary edge has one cotangent term, a
non-manifold edge one per incident face, inconsistent orientation does not matter (cotangents are
unsigned), an unreferenced vertex has an empty (zero) row. Degenerate faces (zero area, collinear
corners) contribute nothing, with finite values and gradients (libigl gives inf / NaN there).
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Float

from .._errors import DDGInputError
from ..dec import d0, hodge1
from .._numerics import safe_div, safe_norm
from ..mesh._geometry import edge_cotan_weights_from_corner_cotangents, face_area_vectors, face_hat_gradients
from ..mesh._mesh import Mesh
from ..sparse import SparseMatrix, congruence, gather_sum

def cotan_laplacian(mesh: Mesh, *, method: str = "fem") -> SparseMatrix:
    """The cotan Laplacian `L` (PSD, weak / integrated), a `SparseMatrix` on `mesh.vertex_pattern`.

    `L_ij = -(cot a_ij + cot b_ij) / 2` for an edge `ij`, `L_ii = -sum_{j != i} L_ij`.

    - `method="fem"` (default, the fast one): Galerkin stiffness matrix of piecewise-linear hat
      functions, `L_ij = sum_f A_f <grad phi_i, grad phi_j>` with `grad phi_k = (N x e_k) / (2 A_f)`
      (`e_k` the edge vector opposite corner `k`, `N` the unit normal; `face_hat_gradients`). A
      rotation by 90 degrees in the face plane keeps dot products, so the per-face product simplifies
      to `A_f <grad phi_i, grad phi_j> = <e_i, e_j> / (4 A_f)` with `4 A_f = 2 |e_i x e_j|`: two dot
      products and one cross product per face, no normal or gradient is formed. It equals the cotan
      formula since `<e_i, e_j> / (2 A_f) = -cot(angle at the third corner)`. The per-corner values are
      gathered straight into the pattern's storage order (`Mesh.vertex_pattern_corners`) and the
      diagonal is minus the ELL row sum; the gather runs through `ddgjax.sparse.gather_sum`, whose
      transpose is a gather (no scatter-add), so `jax.grad` of an energy costs a few energy
      evaluations. Second derivatives work by reverse-over-reverse (Hessian-vector products as
      `jax.grad(lambda V: jnp.vdot(jax.grad(E)(V), v))`); forward mode (`jax.jvp`, `jax.jacfwd`) over
      the vertices does not pass through that custom reverse rule: use `method="dec"` for it.
    - `method="dec"`: `d0^T *1 d0` from `ddgjax.dec.d0` and the circumcentric `ddgjax.dec.hodge1`,
      summed by `ddgjax.sparse.congruence` (slower; a cross-check of the derivation).

    Both agree to round-off on every mesh (tests). Works under jit / grad / vmap over the vertex
    positions; see the module docstring for non-manifold, boundary and degenerate input.

    Args:
        mesh: any triangle mesh.
        method: `"fem"` or `"dec"` (keyword-only).

    Returns:
        `(nv, nv)` `SparseMatrix`; `L == -igl.cotmatrix(V, F)` (`to_igl_cotmatrix` converts).

    References: U. Pinkall, K. Polthier, "Computing discrete minimal surfaces and their conjugates"
    (1993); K. Crane, "Discrete Differential Geometry: An Applied Introduction" (2020), ch. 6.
    libigl `cotmatrix` (negated); gpytoolbox `cotangent_laplacian`.
    """
    if method == "fem":
        return _fem_stiffness(mesh)
    if method == "dec":
        return congruence(d0(mesh), hodge1(mesh).diagonal(), mesh.vertex_pattern)
    raise DDGInputError(f"method: expected 'fem' or 'dec', got {method!r}")


def _fem_stiffness(mesh: Mesh) -> SparseMatrix:
    """The FEM stiffness on `mesh.vertex_pattern`, values computed in storage order (see `cotan_laplacian`)."""
    corners = mesh.vertices[mesh.faces]
    p0, p1, p2 = corners[:, 0], corners[:, 1], corners[:, 2]
    e0, e1, e2 = p2 - p1, p0 - p2, p1 - p0  # edge opposite corner k
    dots = jnp.stack([jnp.sum(e1 * e2, axis=-1), jnp.sum(e2 * e0, axis=-1), jnp.sum(e0 * e1, axis=-1)], axis=1)
    # <e_i, e_j> / (4 A) per corner (the entry of the edge opposite it); 0 on zero-area faces.
    entries = safe_div(dots, 2.0 * safe_norm(jnp.cross(e1, e2))[:, None])
    off_diagonal = gather_sum(entries.reshape(-1), mesh.vertex_pattern_corners, mesh.corner_pattern_slots)
    rows_off = SparseMatrix(jnp.concatenate([jnp.zeros(mesh.n_vertices, entries.dtype), off_diagonal]), mesh.vertex_pattern)
    return _with_diagonal(rows_off, -rows_off.row_sums())


def edge_stiffness_weights(mesh: Mesh) -> Float[Array, " ne"]:
    """Cotan weight of each edge from the FEM stiffness, `w_ij = -sum_f A_f <grad phi_i, grad phi_j>`, `(ne,)`.

    Equals `edge_cotan_weights` (to round-off); computed from `face_hat_gradients`.
    """
    gradients = face_hat_gradients(mesh)
    double_areas = 2.0 * safe_norm(face_area_vectors(mesh))
    # Corner k's entry is the stiffness of the edge opposite it: corners k+1 and k+2.
    products = jnp.sum(jnp.roll(gradients, -1, axis=1) * jnp.roll(gradients, -2, axis=1), axis=-1)
    # -2 A <grad phi_{k+1}, grad phi_{k+2}> = cot(alpha_k): the edge gather takes corner cotangents.
    return edge_cotan_weights_from_corner_cotangents(mesh, -double_areas[:, None] * products)


def vertex_operator(mesh: Mesh, edge_values: Float[Array, " ne"]) -> SparseMatrix:
    """Symmetric matrix on `mesh.vertex_pattern` with `edge_values` off the diagonal and 0 on it (one gather)."""
    zeros = jnp.zeros(mesh.n_vertices, edge_values.dtype)
    entries = jnp.concatenate([zeros, edge_values, edge_values])
    values = jnp.take(entries, mesh.vertex_pattern_source, mode="fill", fill_value=0)
    return SparseMatrix(values, mesh.vertex_pattern)


def _with_diagonal(matrix: SparseMatrix, diagonal: Float[Array, " nv"]) -> SparseMatrix:
    # The vertex pattern stores the diagonal first (slots 0..nv-1).
    return SparseMatrix(matrix.values.at[: diagonal.shape[0]].set(diagonal), matrix.pattern)


def laplacian_apply(mesh: Mesh, u: Float[Array, "nv *k"]) -> Float[Array, "nv *k"]:
    """Matrix-free `L u` for `u` of shape `(nv,)` or `(nv, k)` (same convention as `cotan_laplacian`).

    `(L u)_i = 1/2 sum_j (cot a_ij + cot b_ij)(u_i - u_j)`. `laplacian_apply(mesh, mesh.vertices)` is
    the integrated mean curvature normal `2 H N A_i`, the gradient of the total area (outward on a
    convex closed mesh). libigl: `-igl.cotmatrix(V, F) @ u`.
    """
    return cotan_laplacian(mesh) @ u


def dirichlet_energy(mesh: Mesh, u: Float[Array, "nv *k"]) -> Float[Array, ""]:
    """Dirichlet energy `E(u) = 1/2 u^T L u = 1/2 int |grad u|^2` of a piecewise-linear function (summed over columns).

    Differentiable in `u` (`grad_u E = L u`) and in the vertex positions. Reference: Pinkall &
    Polthier 1993.
    """
    return 0.5 * jnp.sum(u * (cotan_laplacian(mesh) @ u))
