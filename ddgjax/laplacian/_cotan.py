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

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.custom_derivatives import SymbolicZero
from jaxtyping import Array, Float

from .._compile import device_array, kernel
from .._errors import DDGInputError
from .._indexing import take_rows
from .._numerics import safe_div
from ..mesh import Mesh, corner_cotangents_from_lengths_sq, face_areas, face_edge_lengths_sq, require_mesh
from ..mesh.internal import degenerate_faces, face_geometry_from_corners
from ..sparse import SparseMatrix, gather_sum
from ._lengths import laplacian_values, off_diagonal_entries, psd_matrix
from ._plan import TriangulationPlan, vertex_plan


def cotan_laplacian(mesh: Mesh) -> SparseMatrix:
    r"""The cotan Laplacian `L` (PSD, weak / integrated), a `SparseMatrix` on the mesh's vertex pattern.

    $$L_{ij} = -\tfrac12 (\cot\alpha_{ij} + \cot\beta_{ij}) \quad \text{for an edge } ij, \qquad L_{ii} = -\sum_{j \ne i} L_{ij},$$

    with the cotangents from the squared edge lengths of each face,
    $\cot\alpha_k = (\ell_{k+1}^2 + \ell_{k+2}^2 - \ell_k^2) / (4 A)$: the intrinsic core `cotan_laplacian_from_lengths_sq` applied to the mesh's
    `face_edge_lengths_sq`, on the storage plan cached for its connectivity
    (`ddgjax.laplacian._plan`), with the face areas from the embedding (`|e_1 x e_2| / 2`, as
    `ddgjax.mesh.corner_cotangents` takes them). It is the Galerkin stiffness matrix of
    piecewise-linear hat functions, $L_{ij} = \int \langle \nabla\phi_i, \nabla\phi_j \rangle \, dA$, and equals the DEC
    `d0^T *1 d0` (`ddgjax.dec`) to round-off (tests). The per-corner values are gathered straight
    into the pattern's storage order and the diagonal is minus the off-diagonal row sum, so
    $L \mathbf{1} = 0$ exactly.

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

    Examples:
        >>> import jax.numpy as jnp
        >>> import ddgjax
        >>> L = ddgjax.laplacian.cotan_laplacian(ddgjax.mesh.icosphere(2))
        >>> L.shape, L.symmetric, L.positive_semidefinite
        ((162, 162), True, True)
        >>> bool(jnp.allclose(L @ jnp.ones(162), 0.0))  # constants are in the kernel
        True
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


def laplacian_apply(mesh: Mesh, u: Float[Array, "nv *k"], /) -> Float[Array, "nv *k"]:
    r"""Matrix-free `L u` for `u` of shape `(nv,)` or `(nv, k)` (same convention as `cotan_laplacian`).

    $$\sum_j L_{ij} u_j = \sum_{j \sim i} w_{ij} (u_i - u_j), \qquad w_{ij} = \tfrac12 (\cot\alpha_{ij} + \cot\beta_{ij}),$$

    evaluated term by term: the off-diagonal entries `cotan_laplacian` assembles (each corner's `-cot(alpha) / 2` from
    the squared edge lengths, gathered onto the directed edges `i -> j` leaving each vertex: the
    off-diagonal slots of the vertex pattern, which list them row by row) are multiplied by the edge
    differences `u_j - u_i` and summed per vertex. No diagonal and no `SparseMatrix` are formed, one
    fused program instead of an assembly and a product. Equals `cotan_laplacian(mesh) @ u` to
    round-off (tests). Every step is a fixed gather or a contiguous sum, no scatter-add (only the few
    directed edges of high-degree vertices that overflow the pattern's ELL width go through a
    sorted `segment_sum`), so the result is also bitwise reproducible on GPU. The corner -> edge
    gather is `ddgjax.sparse.gather_sum`, whose transpose is a gather: differentiable in `u` and in
    the vertex positions, forward and reverse mode, under jit and vmap.

    `laplacian_apply(mesh, mesh.vertices)` is the integrated mean curvature normal $2 H N A_i$, the
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
    # L_ij on the off-diagonal slots nv.. (row i, column j): the entries `cotan_laplacian` assembles.
    return apply_slot_weights(off_diagonal_entries(face_edge_lengths_sq(mesh), plan, face_areas(mesh)), plan, u)


def apply_slot_weights(weights: Float[Array, " n_off"], plan: eqx.Module, u: Float[Array, "nv *k"]) -> Float[Array, "nv *k"]:
    """`sum_j W_ij (u_j - u_i)` per vertex `i`, `W` given on the off-diagonal slots of `plan.pattern` (ELL, then the COO tail).

    `plan` is any plan with a vertex `pattern` and `n_vertices` (a `TriangulationPlan`, `ddgjax.volume`'s
    tet plan, through `ddgjax.laplacian.internal`)."""
    n = plan.n_vertices
    shape = jnp.shape(u)
    columns = u.reshape(n, -1)
    pattern = plan.pattern
    weights = weights[:, None]
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


def dirichlet_energy(mesh: Mesh, u: Float[Array, "nv *k"], /) -> Float[Array, ""]:
    r"""Dirichlet energy `E(u) = 1/2 u^T L u = 1/2 int |grad u|^2` of a piecewise-linear function (summed over columns).

    $$E(u) = \tfrac12 u^\top L u = \tfrac12 \int \lVert \nabla u \rVert^2 \, dA$$

    `u` of shape `(nv,)` or `(nv, k)`. Differentiable in `u` ($\nabla_u E = L u$) and in the vertex
    positions, in forward and reverse mode and to second order (Hessian-vector products by
    forward-over-reverse, as optimistix / lineax Newton operators use them). The derivative in the
    vertex positions is written out (`_vertex_gradient`, a custom JVP): per face three scalars, the
    energy's derivatives in its squared edge lengths, applied to the positions through the
    Laplacian's own fixed gathers, so the reverse pass has no scatter-add and costs about two
    energies (benchmarks/laplacian.py). A derivative in `u` alone does not compute it. Checked
    against autodiff of `0.5 * u @ (cotan_laplacian(mesh) @ u)`, central differences and libigl (tests).

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


def _dirichlet_energy_jvp(primals, tangents):
    """`dE = <L u, du> + <grad_V E, dV>` (`_vertex_gradient`; linear in the tangents, so reverse mode needs no scatter).

    Symbolic zeros: a derivative in `u` alone (`grad_u E`, Hessian-vector products of a Newton solve
    in `u`) skips the vertex gradient, a derivative in the positions alone skips `<L u, du>`.
    """
    mesh, plan, u = primals
    d_mesh, _, d_u = tangents  # the plan is integer data: no tangent
    applied = _apply_laplacian(mesh, plan, u)
    energy = 0.5 * jnp.sum(u * applied)
    d_energy = jnp.zeros_like(energy)
    if not isinstance(d_u, SymbolicZero):
        d_energy = d_energy + jnp.sum(applied * d_u)
    if not isinstance(d_mesh.vertices, SymbolicZero):
        d_energy = d_energy + jnp.sum(_vertex_gradient(mesh, plan, u) * d_mesh.vertices)
    return energy, d_energy


_dirichlet_energy.defjvp(_dirichlet_energy_jvp, symbolic_zeros=True)


#: Faces per chunk of the gradient's per-face pass: its gathers (~6 MB in float64) stay reusable scratch memory.
FACES_PER_CHUNK = 1 << 16


def _vertex_gradient(mesh: Mesh, plan: TriangulationPlan, u: Float[Array, "nv *k"]) -> Float[Array, "nv 3"]:
    """`grad_V E` of `E = 1/2 u^T L u` in closed form: `sum_{j ~ i} 2 mu_ij (p_i - p_j)`, `mu_ij = dE / d l_ij^2`.

    `E` depends on the positions through the squared edge lengths only, so its gradient is a
    Laplacian-like operator applied to the positions, with weights `mu_ij` summed over the faces of
    the edge `ij`. Per face, with `d_k = u_{k+1} - u_{k+2}` the difference along the edge opposite
    corner `k`, `E_f = 1/4 sum_k cot_k d_k^2`, `cot_k = (l_{k+1}^2 + l_{k+2}^2 - l_k^2) / (4 A)` and
    `dA / d l_k^2 = cot_k / 4` (Heron), so

        dE_f / d l_m^2 = (D - 2 d_m^2 - cot_m S) / (16 A),   D = sum_k d_k^2,  S = sum_k cot_k d_k^2 = 4 E_f.

    These per-corner scalars land on the off-diagonal slots of the vertex pattern through the fixed
    gather that assembles `L` (`off_diagonal_entries`' `gather_sum`) and act on the positions as
    `laplacian_apply` acts on `u`: no scatter-add, no per-face 3-vectors. (The per-corner
    form `A T grad phi_j` of the energy-momentum tensor needs nine outputs per face, which XLA:CPU
    computes in nine kernels that each recompute the face's geometry.) The per-face pass runs over
    chunks of `FACES_PER_CHUNK` faces (`lax.map`): XLA materialises the `V[F]` and `u[F]` gathers, and
    a program whose scratch memory passes glibc's 32 MiB `mmap` threshold gets fresh pages, faulted
    in on every call; in chunks it stays below from ~150k to ~400k faces and touches 2.5x fewer bytes
    beyond (benchmarks/README.md). Zero-area faces contribute 0, with finite derivatives (`safe_div`,
    as their cotangents). The edge form carries each face's in-plane gradient through its edge
    vectors, which loses digits in proportion to a sliver's aspect ratio: ~1e-13 of the largest
    entry on nefertiti (tests). Columns of a `(nv, k)` `u` add up.

    Reference: M. Meyer, M. Desbrun, P. Schroeder, A. Barr (2003) (cotangents and their derivatives
    through the edge lengths); K. Crane, "Discrete Differential Geometry: An Applied Introduction"
    (2020), ch. 6.
    """
    vertices, faces = mesh.vertices, mesh.faces
    n_chunks = faces.shape[0] // FACES_PER_CHUNK
    if n_chunks < 2:
        weights = _corner_weights(vertices, u, faces)
    else:
        split = n_chunks * FACES_PER_CHUNK
        chunks = faces[:split].reshape(n_chunks, FACES_PER_CHUNK, 3)
        weights = jax.lax.map(lambda chunk: _corner_weights(vertices, u, chunk), chunks).reshape(split, 3)
        if split < faces.shape[0]:
            weights = jnp.concatenate([weights, _corner_weights(vertices, u, faces[split:])])
    slot_weights = gather_sum(weights.reshape(-1), plan.slot_corners, plan.corner_slots)
    return apply_slot_weights(slot_weights, plan, vertices)


def _corner_weights(vertices: Float[Array, "nv 3"], u: Float[Array, "nv *k"], faces) -> Float[Array, "nf 3"]:
    """`-2 dE_f / d l_m^2` per face and corner `m` (`_vertex_gradient`): the slot weight `W_ij` of `apply_slot_weights`.

    Coordinate by coordinate on `(nf,)` arrays from one `V[F]` gather, as `face_edge_lengths_sq` and
    `face_areas` compute them (XLA:CPU does not vectorise reductions over a size-3 axis).
    """
    _, lengths_sq, areas = face_geometry_from_corners(take_rows(vertices, faces))
    return dirichlet_energy_length_weights(lengths_sq, areas, take_rows(u, faces))


def dirichlet_energy_length_weights(
    lengths_sq: Float[Array, "nf 3"], areas: Float[Array, " nf"], corner_values: Float[Array, "nf 3 *k"]
) -> Float[Array, "nf 3"]:
    """`-2 dE_f / d l_m^2` of each face's Dirichlet energy, per corner `m` (`_vertex_gradient` derives it).

    With `d_k = u_{k+1} - u_{k+2}`, `D = sum_k d_k^2`, `S = sum_k cot_k d_k^2`: `(cot_m S + 2 d_m^2 - D) / (8 A)`;
    0 on a zero-area face, with finite derivatives. Columns of `corner_values` `(nf, 3, k)` add up.
    Shared with `ddgjax.batch` through `ddgjax.laplacian.internal`.
    """
    cotangents = corner_cotangents_from_lengths_sq(lengths_sq, areas=areas)
    differences = [corner_values[:, (k + 1) % 3] - corner_values[:, (k + 2) % 3] for k in range(3)]
    squares = [d * d if corner_values.ndim == 2 else jnp.sum(d * d, axis=-1) for d in differences]  # columns add up
    total = squares[0] + squares[1] + squares[2]
    weighted = cotangents[:, 0] * squares[0] + cotangents[:, 1] * squares[1] + cotangents[:, 2] * squares[2]
    eight_areas = 8.0 * areas
    return jnp.stack([safe_div(cotangents[:, m] * weighted + 2.0 * squares[m] - total, eight_areas) for m in range(3)], axis=1)
