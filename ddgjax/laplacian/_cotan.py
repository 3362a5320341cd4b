"""The cotan Laplacian, by the FEM route (hat-function gradients) and the DEC route (`d0^T *1 d0`).

Convention (DESIGN.md): `L` is the positive semidefinite weak (integrated) Laplacian,

    (L u)_i = 1/2 sum_j (cot a_ij + cot b_ij) (u_i - u_j),

so `L == -igl.cotmatrix(V, F) == gpytoolbox.cotangent_laplacian(V, F)`, and the pointwise
Laplace-Beltrami operator is `-M^{-1} L`. Both routes land on the vertex pattern (`ddgjax.laplacian._plan`): the edge
entries `-w_ij` are gathered from per-corner values (no scatter), the diagonal is minus the
off-diagonal row sum (`L 1 = 0` by construction, exactly the partition of unity `sum_j grad phi_j = 0`).

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

from .._compile import kernel
from .._errors import DDGInputError, check_choice
from .._indexing import take_rows, take_rows_or_zero
from .._numerics import safe_div, safe_reciprocal, safe_sqrt
from ..dec import d0, hodge1
from ..mesh import Mesh, require_mesh
from ..sparse import SparseMatrix, congruence, gather_sum
from ._plan import VertexPlan, dec_plan, vertex_plan


def cotan_laplacian(mesh: Mesh, *, method: str = "fem") -> SparseMatrix:
    """The cotan Laplacian `L` (PSD, weak / integrated), a `SparseMatrix` on the vertex pattern (`ddgjax.laplacian._plan`).

    `L_ij = -(cot a_ij + cot b_ij) / 2` for an edge `ij`, `L_ii = -sum_{j != i} L_ij`.

    - `method="fem"` (default, the fast one): Galerkin stiffness matrix of piecewise-linear hat
      functions, `L_ij = sum_f A_f <grad phi_i, grad phi_j>` with `grad phi_k = (N x e_k) / (2 A_f)`
      (`e_k` the edge vector opposite corner `k`, `N` the unit normal; `face_hat_gradients`). A
      rotation by 90 degrees in the face plane keeps dot products, so the per-face product simplifies
      to `A_f <grad phi_i, grad phi_j> = <e_i, e_j> / (4 A_f)` with `4 A_f = 2 |e_i x e_j|`: two dot
      products and one cross product per face, no normal or gradient is formed. It equals the cotan
      formula since `<e_i, e_j> / (2 A_f) = -cot(angle at the third corner)`. The per-corner values are
      gathered straight into the pattern's storage order (`VertexPlan.slot_corners`) and the
      diagonal is minus the ELL row sum.
    - `method="dec"`: `d0^T *1 d0` from `ddgjax.dec.d0` and the circumcentric `ddgjax.dec.hodge1`,
      summed by `ddgjax.sparse.congruence` (a cross-check of the derivation; slower). Its product ->
      slot map is built on the host once per mesh topology and cached.

    Both agree to round-off on every mesh (tests). The result is flagged symmetric positive
    semidefinite (a Gram matrix of hat gradients, whatever the angles), so
    `cotan_laplacian(m).as_lineax_operator()` is tagged for `lineax.CG`. Works under jit / grad / jvp /
    vmap over the vertex positions; see the module docstring for non-manifold, boundary and
    degenerate input.

    Args:
        mesh: any triangle mesh.
        method: `"fem"` or `"dec"` (keyword-only).

    Returns:
        `(nv, nv)` `SparseMatrix`; `L == -igl.cotmatrix(V, F)` (`to_igl_cotmatrix` converts).

    References: U. Pinkall, K. Polthier, "Computing discrete minimal surfaces and their conjugates"
    (1993); K. Crane, "Discrete Differential Geometry: An Applied Introduction" (2020), ch. 6.
    libigl `cotmatrix` (negated); gpytoolbox `cotangent_laplacian`.
    """
    check_choice("method", method, ("fem", "dec"))
    plan = vertex_plan(mesh)
    if method == "fem":
        values = _fem_values(mesh, plan)
    else:
        values = congruence(d0(mesh), hodge1(mesh).diagonal(), plan.pattern, dec_plan(mesh)).values
    return SparseMatrix(values, plan.pattern, symmetric=True, positive_semidefinite=True)


@kernel
def _fem_values(mesh: Mesh, plan: VertexPlan) -> Float[Array, " nnz"]:
    """Values of the FEM cotan Laplacian on `plan.pattern` (one compiled program per mesh size)."""
    rows_off = _off_diagonal(plan, _edge_entries(mesh, plan))
    return _with_diagonal(rows_off, -rows_off.row_sums(), positive_semidefinite=True).values


def laplacian_apply(mesh: Mesh, u: Float[Array, "nv *k"]) -> Float[Array, "nv *k"]:
    """Matrix-free `L u` for `u` of shape `(nv,)` or `(nv, k)` (same convention as `cotan_laplacian`).

    `(L u)_i = sum_{j ~ i} w_ij (u_i - u_j)` with `w_ij = 1/2 (cot a_ij + cot b_ij)`, evaluated term by
    term: each face's corner values `-cot(alpha) / 2 = <e_i, e_j> / (4 A_f)` are gathered onto the
    directed edges `i -> j` leaving each vertex (the off-diagonal slots of the vertex pattern (`ddgjax.laplacian._plan`), which
    list them row by row), multiplied by the edge differences `u_j - u_i`, and summed per vertex. No
    matrix is assembled: no diagonal, no `SparseMatrix`. Equals `cotan_laplacian(mesh) @ u` to
    round-off. Every step is a fixed gather or a contiguous sum, no scatter-add (only the few
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
    return u if isinstance(u, jax.Array) else jnp.asarray(u)


def _apply_laplacian(mesh: Mesh, plan: VertexPlan, u: Float[Array, "nv *k"]) -> Float[Array, "nv *k"]:
    """`laplacian_apply` without the input check (see there)."""
    n = mesh.n_vertices
    shape = jnp.shape(u)
    columns = u.reshape(n, -1)
    pattern = plan.pattern
    weights = _edge_entries(mesh, plan)[:, None]  # L_ij on the off-diagonal slots nv.. (row i, column j)
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
    of the assembly would carry the per-corner values through the corner -> edge gather and back.
    Reference: Pinkall & Polthier 1993. libigl / gpytoolbox:
    `0.5 * u @ (L @ u)` with `L = -igl.cotmatrix(V, F)`.
    """
    return _compiled_energy(mesh, vertex_plan(mesh), _vertex_values(mesh, u))


@jax.custom_jvp
def _dirichlet_energy(mesh: Mesh, plan: VertexPlan, u: Float[Array, "nv *k"]) -> Float[Array, ""]:
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
    size-3 axis, which `(nf, 3, 3)` arrays with `sum(axis=-1)` / `jnp.cross` would need.
    """
    corners = [take_rows(mesh.vertices[:, c], mesh.faces) for c in range(3)]  # coordinate c of each face's corners, (nf, 3)
    points = [[corners[c][:, k] for c in range(3)] for k in range(3)]  # points[k][c], (nf,)
    edges = [[points[(k + 2) % 3][c] - points[(k + 1) % 3][c] for c in range(3)] for k in range(3)]
    return edges, _cross(edges[1], edges[2])


def _dot(a, b):
    """Dot product of 3-vectors given as coordinate lists (XLA does not vectorise size-3 reductions)."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _cross(a, b):
    return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]


def vertex_operator(plan: VertexPlan, edge_values: Float[Array, " ne"]) -> SparseMatrix:
    """Symmetric matrix on `plan.pattern` with `edge_values` off the diagonal and 0 on it (one gather)."""
    zeros = jnp.zeros(plan.pattern.shape[0], edge_values.dtype)
    entries = jnp.concatenate([zeros, edge_values, edge_values])
    values = take_rows_or_zero(entries, plan.source)
    return SparseMatrix(values, plan.pattern, symmetric=True)


def _edge_entries(mesh: Mesh, plan: VertexPlan) -> Float[Array, " n_off"]:
    """FEM stiffness `L_ij = sum_f <e_i, e_j> / (4 A_f)` on each off-diagonal slot of `plan.pattern`."""
    edges, normal = _face_edges(mesh)
    four_areas = 2.0 * safe_sqrt(_dot(normal, normal))
    # <e_i, e_j> / (4 A) per corner k (the entry of the edge opposite it); 0 on zero-area faces.
    entries = jnp.stack([safe_div(_dot(edges[(k + 1) % 3], edges[(k + 2) % 3]), four_areas) for k in range(3)], axis=1)
    return gather_sum(entries.reshape(-1), plan.slot_corners, plan.corner_slots)


def _off_diagonal(plan: VertexPlan, edge_entries: Float[Array, " n_off"]) -> SparseMatrix:
    values = jnp.concatenate([jnp.zeros(plan.pattern.shape[0], edge_entries.dtype), edge_entries])
    return SparseMatrix(values, plan.pattern, symmetric=True)


def _with_diagonal(matrix: SparseMatrix, diagonal: Float[Array, " nv"], *, positive_semidefinite: bool) -> SparseMatrix:
    # The vertex pattern stores the diagonal first (slots 0..nv-1).
    values = matrix.values.at[: diagonal.shape[0]].set(diagonal)
    return SparseMatrix(values, matrix.pattern, symmetric=True, positive_semidefinite=positive_semidefinite)
