"""Geometry of a tetrahedral mesh: volumes, lengths, dihedral angles, cotan weights, hat-function gradients.

Intrinsic core, extrinsic wrapper (DESIGN.md): what depends only on the six squared edge lengths of a
tet has a `*_from_lengths_sq` form on `(nt, 6)` arrays in the local edge order `TET_EDGES`
(`(3,0), (3,1), (3,2), (1,2), (2,0), (0,1)`, libigl's `edge_lengths` order, edge `k` opposite edge
`k + 3 (mod 6)`); the `TetMesh` versions feed it the embedding's lengths and volumes.

The core is the Gram matrix of the edge vectors from local vertex 0, `G_ab = (l_0a^2 + l_0b^2 -
l_ab^2) / 2` (`a, b` in 1..3), whose determinant is `36 V^2` and whose adjugate gives every
`grad phi_i . grad phi_j` of the linear hat functions: with `P = [-1 | I]` (3 x 4),

    V grad phi_i . grad phi_j = (P^T adj(G) P)_ij / (36 V),

so the cotan weight of edge `ij`, `w_ij = -V grad phi_i . grad phi_j = l_kl cot(theta_kl) / 6`
(`theta_kl` the dihedral angle at the opposite edge `kl`), is a polynomial in the squared lengths over
`36 V`, and `theta_kl = atan2(6 V l_kl, 36 V w_ij)` needs no division at all. Degenerate tets (zero
volume) give zero weights and finite values and gradients (`safe_div`).

The `TetMesh` functions are compiled kernels (`ddgjax._compile.kernel`): called eagerly they run one
program per mesh size, as `ddgjax.mesh`'s geometry does, instead of dozens of small dispatches.

Reference: Crane, "Discrete Differential Geometry: An Applied Introduction" (2020), the cotan
formula in 3-D; Jacobson, "Algorithms and interfaces for real-time deformation of 2D and 3D shapes"
(2013), the tet cotangent weights; libigl `cotmatrix_entries`, `tet_dihedral_angles`, `volume`.
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Float

from .._compile import kernel
from .._indexing import take_rows
from .._numerics import safe_atan2, safe_div, safe_norm, safe_sqrt
from ._tet_mesh import TetMesh, require_tet_mesh
from ._topology import TET_EDGES, TET_TRIANGLES


@kernel
def tet_corner_positions(tet_mesh: TetMesh) -> Float[Array, "nt 4 3"]:
    """`(nt, 4, 3)` the positions of each tet's four vertices (libigl `V[T]`).

    Args:
        tet_mesh: the tet mesh.

    Returns:
        `(nt, 4, 3)` array in the vertices' dtype: row `t` holds `vertices[tets[t]]`.
    """
    tet_mesh = require_tet_mesh("tet_mesh", tet_mesh)
    return take_rows(tet_mesh.vertices, tet_mesh.tets)


@kernel
def tet_signed_volumes(tet_mesh: TetMesh) -> Float[Array, " nt"]:
    """`(nt,)` signed volumes `det(b - a, c - a, d - a) / 6`: positive for the orientation `from_arrays` gives.

    A tet that a move of the vertices turned inside out gets a negative volume. libigl: `igl.volume(V, T)`
    (opposite sign convention).

    Args:
        tet_mesh: the tet mesh.

    Returns:
        `(nt,)` float array of signed volumes, negative for inverted tets.
    """
    p = tet_corner_positions(tet_mesh)
    e1, e2, e3 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0], p[:, 3] - p[:, 0]
    return jnp.sum(e1 * jnp.cross(e2, e3), axis=-1) / 6.0


@kernel
def tet_volumes(tet_mesh: TetMesh) -> Float[Array, " nt"]:
    """`(nt,)` unsigned tet volumes `|det(b - a, c - a, d - a)| / 6`; `sum` is the solid's volume.

    libigl: `abs(igl.volume(V, T))`. Zero for a flat tet (finite gradients: the derivative of `|x|` at 0 is taken as 0).

    Args:
        tet_mesh: the tet mesh.

    Returns:
        `(nt,)` float array of nonnegative volumes.
    """
    return jnp.abs(tet_signed_volumes(tet_mesh))


@kernel
def tet_edge_lengths_sq(tet_mesh: TetMesh) -> Float[Array, "nt 6"]:
    """`(nt, 6)` squared lengths of each tet's edges in the local order `TET_EDGES` (libigl `edge_lengths(V, T)**2`).

    Args:
        tet_mesh: the tet mesh.

    Returns:
        `(nt, 6)` float array of squared lengths, column `k` the local edge `TET_EDGES[k]`.
    """
    p = tet_corner_positions(tet_mesh)
    vectors = p[:, TET_EDGES[:, 1]] - p[:, TET_EDGES[:, 0]]
    return jnp.sum(vectors * vectors, axis=-1)


@kernel
def edge_lengths(tet_mesh: TetMesh) -> Float[Array, " ne"]:
    """`(ne,)` lengths `|p_head - p_tail|` of the global edges `tet_mesh.edges` (low -> high, sorted).

    Zero-length edges have zero gradient (`safe_norm`). libigl: `igl.edge_lengths` per tet; per global edge,
    `np.linalg.norm(V[E[:, 1]] - V[E[:, 0]], axis=1)` with `E = igl.edges(T)`.

    Args:
        tet_mesh: the tet mesh.

    Returns:
        `(ne,)` float array, entry `e` the length of `tet_mesh.edges[e]`.
    """
    tet_mesh = require_tet_mesh("tet_mesh", tet_mesh)
    vectors = take_rows(tet_mesh.vertices, tet_mesh.edges[:, 1]) - take_rows(tet_mesh.vertices, tet_mesh.edges[:, 0])
    return safe_norm(vectors)


@kernel
def triangle_areas(tet_mesh: TetMesh) -> Float[Array, " ntri"]:
    """`(ntri,)` areas `|(q - p) x (r - p)| / 2` of the global triangles `tet_mesh.triangles` (interior and boundary).

    Finite gradients on collinear triangles (`safe_norm`). libigl: `igl.face_areas(V, T)` per tet
    (its four faces), `igl.doublearea(V, F) / 2` on a triangle list.

    Args:
        tet_mesh: the tet mesh.

    Returns:
        `(ntri,)` float array, entry `f` the area of `tet_mesh.triangles[f]`.
    """
    tet_mesh = require_tet_mesh("tet_mesh", tet_mesh)
    p = take_rows(tet_mesh.vertices, tet_mesh.triangles)
    return 0.5 * safe_norm(jnp.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]))


def _gram_adjugate(lengths_sq: Float[Array, "nt 6"]) -> tuple[Float[Array, " nt"], Float[Array, "nt 6"]]:
    """`(det G, N)`: the Gram determinant `36 V^2` and `N_k = 36 V w_k`, the cotan weight numerators per local edge."""
    l30, l31, l32, l12, l20, l01 = (lengths_sq[:, k] for k in range(6))
    g11, g22, g33 = l01, l20, l30
    g12 = 0.5 * (l01 + l20 - l12)
    g13 = 0.5 * (l01 + l30 - l31)
    g23 = 0.5 * (l20 + l30 - l32)
    a11, a22, a33 = g22 * g33 - g23 * g23, g11 * g33 - g13 * g13, g11 * g22 - g12 * g12
    a12, a13, a23 = g13 * g23 - g12 * g33, g12 * g23 - g13 * g22, g12 * g13 - g11 * g23
    determinant = g11 * a11 + g12 * a12 + g13 * a13
    # w_ij = -(P^T adj(G) P)_ij / (36 V); for (0, a) that is the row sum a of adj(G).
    numerators = jnp.stack([a13 + a23 + a33, -a13, -a23, -a12, a12 + a22 + a23, a11 + a12 + a13], axis=1)
    return determinant, numerators


def tet_volumes_from_lengths_sq(lengths_sq: Float[Array, "nt 6"]) -> Float[Array, " nt"]:
    """`(nt,)` volumes from the six squared edge lengths (Cayley-Menger: `V = sqrt(det G) / 6`; 0 where no tet exists).

    `G` is the Gram matrix of the edge vectors from local vertex 0 (module docstring); lengths that no
    Euclidean tet has (`det G < 0`) give 0, with finite gradients. Reference: L. M. Blumenthal, *Theory
    and Applications of Distance Geometry* (1953), the Cayley-Menger determinant. libigl: the C++
    `igl::volume(L, vol)` overload from edge lengths (not in the Python bindings).

    Args:
        lengths_sq: `(nt, 6)` squared edge lengths of each tet in the local order `TET_EDGES`.

    Returns:
        `(nt,)` float array of nonnegative volumes (0 where the lengths admit no tet).
    """
    determinant, _ = _gram_adjugate(lengths_sq)
    return safe_sqrt(jnp.maximum(determinant, 0.0)) / 6.0


def tet_cotan_weights_from_lengths_sq(
    lengths_sq: Float[Array, "nt 6"], *, volumes: Float[Array, " nt"] | None = None
) -> Float[Array, "nt 6"]:
    """`(nt, 6)` the cotan weight of each local edge: `w_ij = l_kl cot(theta_kl) / 6 = -int_t grad phi_i . grad phi_j`.

    `theta_kl` is the dihedral angle at the opposite edge `kl` (local edge `k + 3 mod 6`). Summed over
    the tets of an edge this is minus the off-diagonal entry of the cotan Laplacian (`cotan_laplacian`).
    Negative where the opposite dihedral angle is obtuse. A zero-volume tet gives 0 (finite gradients).

    Reference: module docstring. libigl: `cotmatrix_entries(V, T)` (its tet edge order is the same).

    Args:
        lengths_sq: `(nt, 6)` squared edge lengths of each tet in the local order `TET_EDGES`.
        volumes: `(nt,)` tet volumes (keyword-only); default `None`: `tet_volumes_from_lengths_sq(lengths_sq)`.

    Returns:
        `(nt, 6)` float array of cotan weights `w_ij`, column `k` the local edge `TET_EDGES[k]`.
    """
    determinant, numerators = _gram_adjugate(lengths_sq)
    if volumes is None:
        volumes = safe_sqrt(jnp.maximum(determinant, 0.0)) / 6.0
    return safe_div(numerators, 36.0 * volumes[:, None])


@kernel
def tet_cotan_weights(tet_mesh: TetMesh) -> Float[Array, "nt 6"]:
    """`(nt, 6)` `tet_cotan_weights_from_lengths_sq` on the embedding (volumes `tet_volumes`, as libigl takes them).

    Args:
        tet_mesh: the tet mesh.

    Returns:
        `(nt, 6)` float array of cotan weights, column `k` the local edge `TET_EDGES[k]`.
    """
    return tet_cotan_weights_from_lengths_sq(tet_edge_lengths_sq(tet_mesh), volumes=tet_volumes(tet_mesh))


def tet_dihedral_angles_from_lengths_sq(lengths_sq: Float[Array, "nt 6"]) -> Float[Array, "nt 6"]:
    """`(nt, 6)` interior dihedral angle at each local edge, in `[0, pi]`, from the squared edge lengths alone.

    `theta_m = atan2(6 V l_m, 36 V w_k)` with `k` the edge opposite `m` (module docstring): no
    division, so finite values and gradients on flat tets too. The six angles of a regular tet are
    `arccos(1/3)`. libigl: `dihedral_angles_intrinsic(L, A)` (another edge order; tests map it).

    Args:
        lengths_sq: `(nt, 6)` squared edge lengths of each tet in the local order `TET_EDGES`.

    Returns:
        `(nt, 6)` float array of angles in radians, in `[0, pi]`, column `k` at the local edge `TET_EDGES[k]`.
    """
    determinant, numerators = _gram_adjugate(lengths_sq)
    volumes = safe_sqrt(jnp.maximum(determinant, 0.0)) / 6.0
    opposite = jnp.roll(numerators, 3, axis=1)  # the weight numerator of the edge opposite each edge
    return safe_atan2(6.0 * volumes[:, None] * safe_sqrt(lengths_sq), opposite)


@kernel
def tet_dihedral_angles(tet_mesh: TetMesh) -> Float[Array, "nt 6"]:
    """`(nt, 6)` interior dihedral angle at each local edge of each tet, in `[0, pi]`.

    `tet_dihedral_angles_from_lengths_sq` on the embedding's squared edge lengths (local order `TET_EDGES`):
    `theta_m = atan2(6 V l_m, 36 V w_k)`, finite with finite gradients on flat tets. libigl:
    `igl.tet_dihedral_angles(V, T)[0]` (the same order; tests).

    Args:
        tet_mesh: the tet mesh.

    Returns:
        `(nt, 6)` float array of angles in radians, in `[0, pi]`, column `k` at the local edge `TET_EDGES[k]`.
    """
    return tet_dihedral_angles_from_lengths_sq(tet_edge_lengths_sq(tet_mesh))


@kernel
def tet_hat_gradients(tet_mesh: TetMesh) -> Float[Array, "nt 4 3"]:
    """`(nt, 4, 3)` the constant gradient of each vertex's hat function in each tet: `grad phi_k = -N_k / (6 V)`.

    `N_k = (p_1 - p_0) x (p_2 - p_0)` over local triangle `k` (`TET_TRIANGLES`, opposite vertex `k`),
    twice its outward area vector, `V` the signed volume; the four gradients sum to zero and
    `grad u = sum_k u_k grad phi_k` is the gradient of a piecewise-linear function (`gradient`).
    Zero on a zero-volume tet (finite gradients). libigl: `igl.grad(V, T)`.

    Args:
        tet_mesh: the tet mesh.

    Returns:
        `(nt, 4, 3)` float array, `[t, k]` the gradient of local vertex `k`'s hat function in tet `t`.
    """
    p = tet_corner_positions(tet_mesh)
    corners = p[:, TET_TRIANGLES]  # (nt, 4, 3, 3)
    normals = jnp.cross(corners[:, :, 1] - corners[:, :, 0], corners[:, :, 2] - corners[:, :, 0])
    return safe_div(-normals, 6.0 * tet_signed_volumes(tet_mesh)[:, None, None])
