"""Discrete curvatures of triangle meshes: angle defects, mean curvature (normals and scalar), principal curvatures.

Conventions (DESIGN.md): every function says whether it is **integrated** (a sum over the vertex's
dual cell, scale-invariant for Gaussian curvature) or **pointwise** (the integrated value divided by
the vertex dual area, `vertex_dual_areas(mesh, dual=dual)`). Names follow: the
integrated quantities are `vertex_angle_defects`, `vertex_mean_curvatures`,
`vertex_mean_curvature_normals`, `vertex_gauss_curvature_normals`; their pointwise counterparts carry
`pointwise` (`vertex_pointwise_gaussian_curvatures`, ...), and `vertex_principal_curvatures` is
pointwise. Mean curvature is `H = (k1 + k2) / 2`, positive on a sphere with outward normals; the
smooth identities behind the discrete ones are `Delta x = -2 H N` and `K = k1 k2`.

Dual areas: the pointwise functions take the keyword-only `dual=` shared by `ddgjax.mesh` and
`ddgjax.dec` (`"voronoi"`, `"circumcentric"`, `"barycentric"`; see `vertex_dual_areas`). The default
`"voronoi"` (mixed) area is never negative, so `K / A` and `H / A` keep the sign of `K` and `H` on
obtuse meshes, where the circumcentric area can vanish or turn negative.

Orientation: angle defects and the mean curvature normal from `L V` need none and work on every
mesh. The signed scalar mean curvature (and so the principal curvatures, the total mean curvature and
the Gauss curvature normal) is built from signed dihedral angles, whose sign is relative to the
faces' orientation: on a mesh without a consistent orientation (a Moebius strip, inconsistently
oriented or non-manifold edges) it is undefined, and those functions raise `MeshDataError`
(checked from the host topology, so also under jit).

References: K. Crane, "Discrete Differential Geometry: An Applied Introduction" (2020), "Discrete
curvature I and II"; M. Meyer, M. Desbrun, P. Schroeder, A. Barr, "Discrete differential-geometry
operators for triangulated 2-manifolds" (2003).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from .._compile import kernel
from .._indexing import take_rows
from .._numerics import safe_div, safe_norm, safe_sqrt
from ._geometry import (
    corner_angles,
    edge_dihedral_angles,
    edge_lengths,
    face_edge_lengths_sq,
    face_edge_vectors,
    face_normals,
    scatter_corners_to_vertices,
    vertex_dual_areas,
)
from ._mesh import Mesh


def _operation(name: str) -> str:
    return f"ddgjax.mesh.{name} (signed dihedral angles)"


@kernel
def vertex_angle_defects(mesh: Mesh) -> Float[Array, " nv"]:
    r"""Integrated Gaussian curvature: the angle defect at each vertex, `(nv,)`.

    $K_i = 2\pi - \sum_{\text{corners at } i} \theta$ at interior vertices and $\pi - \sum \theta$ at boundary
    vertices. In general

    $$K_i = 2\pi - \sum \theta - \frac{\pi}{2} \sum_{\text{edges } e \text{ at } i} (2 - c_e),$$

    with $c_e$ the number of faces of edge $e$: the same on manifolds (a boundary vertex has two one-face edges) and
    it makes discrete Gauss-Bonnet, $\sum_i K_i = 2\pi\chi$ ($\chi = V - E + F$, referenced vertices),
    an identity on **every** triangle mesh, non-manifold included. Unreferenced vertices get 0.
    Since the total is topological, its gradient with respect to the vertices is 0.

    Degenerate faces keep the identity: the angles of every face sum to $\pi$. A collinear face has
    angles $0, 0, \pi$; a corner at a zero-length edge (coincident vertices) has no angle, and the
    corners without one share what the others leave of $\pi$ (`_face_corner_angles`), so merging two
    vertices of a sphere still sums to $4\pi$.

    Converters: `igl.gaussian_curvature(V, F)` is $2\pi - \sum \theta$ everywhere, so it equals this on
    interior vertices and this minus $\pi$ on boundary vertices; `gpytoolbox.angle_defect(V, F)` is
    this on interior vertices and 0 on boundary vertices
    (`jnp.where(boundary, 0, vertex_angle_defects(mesh))`). Pointwise:
    `vertex_pointwise_gaussian_curvatures`.

    Args:
        mesh: any triangle mesh.

    Returns:
        `(nv,)` angle defects `K_i` (integrated Gaussian curvature), 0 at unreferenced vertices.

    Examples:
        >>> import jax.numpy as jnp
        >>> import ddgjax
        >>> K = ddgjax.mesh.vertex_angle_defects(ddgjax.mesh.icosphere(2))
        >>> K.shape, bool(jnp.isclose(K.sum(), 4 * jnp.pi))  # Gauss-Bonnet: 2 pi chi, chi = 2
        ((162,), True)
        >>> bool(jnp.isclose(ddgjax.mesh.vertex_angle_defects(ddgjax.mesh.torus()).sum(), 0.0))  # chi = 0
        True
    """
    angle_sums = scatter_corners_to_vertices(mesh, _face_corner_angles(mesh))
    dtype = angle_sums.dtype
    face_counts = jnp.sum(mesh.edge_faces >= 0, axis=-1).astype(dtype)
    ends = mesh.edges.reshape(-1)
    # (pi / 2)(2 - c_e) per edge endpoint; 0 on interior manifold edges.
    edge_terms = jnp.repeat(0.5 * jnp.pi * (2.0 - face_counts), 2)
    corrections = jax.ops.segment_sum(edge_terms, ends, num_segments=mesh.n_vertices)
    referenced = jax.ops.segment_sum(jnp.ones(mesh.faces.size, dtype), mesh.faces.reshape(-1), num_segments=mesh.n_vertices) > 0
    return jnp.where(referenced, 2.0 * jnp.pi - angle_sums - corrections, 0.0)


def _face_corner_angles(mesh: Mesh) -> Float[Array, "nf 3"]:
    """Corner angles `(nf, 3)` that sum to `pi` in every face, faces with coincident vertices included.

    `corner_angles` is exact wherever both edges leaving a corner have positive length. A corner at a
    zero-length edge has no angle (`atan2(0, 0)`), and `corner_angles` gives it 0: a face with two
    coincident vertices then sums to 0 and each loses `pi` of Gauss-Bonnet (a sphere with one edge
    collapsed summed to `3 x 2 pi`). Those corners share equally what the face's defined angles
    leave of `pi`: `pi/2` each at the ends of one zero-length edge (the third corner's angle is 0),
    `pi/3` each in a face collapsed to a point. Every split that sums to `pi` is a limit of the
    angles as the two vertices move apart (which one depends on the direction they move in); the
    sum at the merged point, which Gauss-Bonnet needs, is the same for all. Values and gradients
    stay finite.
    """
    angles = corner_angles(mesh)
    # Corner k lies on the edges opposite corners k+1 and k+2 (libigl order).
    zero = face_edge_lengths_sq(mesh) == 0
    undefined = jnp.roll(zero, -1, axis=1) | jnp.roll(zero, -2, axis=1)
    remainder = jnp.pi - jnp.sum(jnp.where(undefined, 0.0, angles), axis=1, keepdims=True)
    shares = jnp.maximum(jnp.sum(undefined, axis=1, keepdims=True), 1).astype(angles.dtype)
    return jnp.where(undefined, remainder / shares, angles)


@kernel(static_argnames=("dual",))
def vertex_pointwise_gaussian_curvatures(mesh: Mesh, *, dual: str = "voronoi") -> Float[Array, " nv"]:
    """Pointwise Gaussian curvature, `(nv,)`: `K_i / A_i`, the angle defect over the vertex dual area.

    `K_i = vertex_angle_defects(mesh)` (integrated), `A_i = vertex_dual_areas(mesh, dual=dual)`
    (`"voronoi"` mixed areas by default, `"circumcentric"`, `"barycentric"`). 0 where the dual area
    is 0 (unreferenced vertices). Works on every mesh. Converges at `O(h^2)` on regular meshes.
    Reference: Meyer et al. 2003. libigl tutorial:
    `igl.gaussian_curvature(V, F) / igl.massmatrix(V, F, igl.MASSMATRIX_TYPE_VORONOI).diagonal()`
    (equal on interior vertices; libigl's defect omits the boundary's `-pi`).

    Args:
        mesh: any triangle mesh.
        dual: the dual cell `A_i` divides by, one of `ddgjax.DUAL_CELLS`: `"voronoi"` (default),
            `"circumcentric"`, `"barycentric"` (keyword-only, static).

    Returns:
        `(nv,)` pointwise Gaussian curvatures (units of 1 / length^2), in the vertices' dtype.
    """
    return safe_div(vertex_angle_defects(mesh), vertex_dual_areas(mesh, dual=dual))


@kernel
def vertex_mean_curvature_normals(mesh: Mesh) -> Float[Array, "nv 3"]:
    """Integrated mean curvature normal `H N A_i`, `(nv, 3)`: half the cotan Laplacian of the positions.

    `(H N)_i = (L V)_i / 2 = 1/4 sum_j (cot a_ij + cot b_ij)(p_i - p_j)`, the discrete form of
    `Delta x = -2 H N` with `L` the PSD weak Laplacian (DESIGN.md). It is half the gradient of the
    total area, and is computed as such, face by face: `grad_{p_k} A_f = N_f x e_k / 2` (`e_k` the
    edge opposite corner `k` in face order, `N_f` the unit normal), so
    `(H N)_i = 1/4 sum_{f ni i} N_f x e_i^f`, equal to `ddgjax.laplacian.laplacian_apply(mesh, V) / 2`
    to round-off without assembling `L`. Zero-area faces contribute 0.

    Integrated; points outward on convex surfaces with outward normals. Needs no orientation (the
    product `N_f x e_k` is the same for either vertex order of a face), so it works on every mesh;
    at a boundary vertex it also contains the boundary's geodesic curvature term and is not a surface
    normal. Reference: Desbrun, Meyer, Schroeder, Barr, "Implicit fairing of irregular meshes using
    diffusion and curvature flow" (1999); Meyer et al. 2003. libigl:
    `-igl.cotmatrix(V, F) @ V / 2` (the libigl tutorial's `HN = -Minv L V` is the pointwise `2 H N`
    with the opposite sign of `L`); gpytoolbox: `cotangent_laplacian(V, F) @ V / 2`.

    Args:
        mesh: any triangle mesh (no orientation needed).

    Returns:
        `(nv, 3)` integrated mean curvature normals (units of length), in the vertices' dtype.
    """
    corner_terms = 0.25 * jnp.cross(face_normals(mesh)[:, None, :], face_edge_vectors(mesh))
    return scatter_corners_to_vertices(mesh, corner_terms)


@kernel(static_argnames=("dual",))
def vertex_pointwise_mean_curvature_normals(mesh: Mesh, *, dual: str = "voronoi") -> Float[Array, "nv 3"]:
    """Pointwise mean curvature normal `H N`, `(nv, 3)`: `vertex_mean_curvature_normals / A_i`.

    `A_i = vertex_dual_areas(mesh, dual=dual)`. Its length is `|H|` (tending to `1/r` on a sphere of
    radius r); 0 where the dual area is 0. Works on every mesh (no orientation needed). Reference:
    Meyer et al. 2003 (their mean curvature normal operator `K(x_i) = 2 H N`). libigl tutorial: `HN = -Minv @ (L @ V)` with `L = igl.cotmatrix`,
    `M` the Voronoi mass matrix, equals `2 H N` here.

    Args:
        mesh: any triangle mesh (no orientation needed).
        dual: the dual cell `A_i` divides by, one of `ddgjax.DUAL_CELLS`: `"voronoi"` (default),
            `"circumcentric"`, `"barycentric"` (keyword-only, static).

    Returns:
        `(nv, 3)` pointwise mean curvature normals `H N` (units of 1 / length), in the vertices' dtype.
    """
    return safe_div(vertex_mean_curvature_normals(mesh), vertex_dual_areas(mesh, dual=dual)[:, None])


@kernel(requires_orientation=_operation("vertex_mean_curvatures"))
def vertex_mean_curvatures(mesh: Mesh) -> Float[Array, " nv"]:
    """Integrated scalar mean curvature from dihedral angles, `(nv,)`.

    Each edge carries the integrated mean curvature `1/2 l_e theta_e` (`theta_e` the signed
    dihedral angle of `edge_dihedral_angles`: positive where convex); it is split equally between
    its two endpoints, so `H_i = 1/4 sum_{e at i} l_e theta_e` and `sum_i H_i = 1/2 sum_e l_e theta_e`
    (`total_mean_curvature`). On a cylinder of radius r this gives `integral H dA` with
    `H = 1/(2r)` exactly. Boundary edges carry 0. Signed: needs consistently oriented faces
    (`MeshDataError` otherwise; module docstring). Pointwise: `vertex_pointwise_mean_curvatures`.
    Reference: Crane 2020, "Discrete curvature II" (Steiner formula). libigl and gpytoolbox have no
    dihedral-angle mean curvature (libigl's tutorial uses the unsigned `|L V|`).

    Args:
        mesh: a consistently oriented triangle mesh (`MeshDataError` otherwise).

    Returns:
        `(nv,)` integrated mean curvatures `H_i` (units of length), in the vertices' dtype.
    """
    edge_terms = 0.25 * edge_lengths(mesh) * edge_dihedral_angles(mesh)
    return jax.ops.segment_sum(jnp.repeat(edge_terms, 2), mesh.edges.reshape(-1), num_segments=mesh.n_vertices)


@kernel(requires_orientation=_operation("total_mean_curvature"))
def total_mean_curvature(mesh: Mesh) -> Float[Array, ""]:
    """Total mean curvature `1/2 sum_e l_e theta_e`, a scalar `()` (integral of `H`; `4 pi r` on a sphere).

    On a closed mesh its gradient is the Gauss curvature normal (`vertex_gauss_curvature_normals`):
    by Schlaefli's formula `sum_e l_e d(theta_e) = 0`, only the edge lengths' variation remains.
    Signed: needs consistently oriented faces (`MeshDataError` otherwise). Reference: Crane 2020,
    "Discrete curvature II".

    Args:
        mesh: a consistently oriented triangle mesh (`MeshDataError` otherwise).

    Returns:
        The total mean curvature, a scalar `()` (units of length) in the vertices' dtype.
    """
    return 0.5 * jnp.sum(edge_lengths(mesh) * edge_dihedral_angles(mesh))


@kernel(requires_orientation=_operation("vertex_gauss_curvature_normals"))
def vertex_gauss_curvature_normals(mesh: Mesh) -> Float[Array, "nv 3"]:
    """Integrated Gauss curvature normal `K N A_i`, `(nv, 3)`: `1/2 sum_j theta_ij (p_i - p_j) / l_ij`.

    The gradient of `total_mean_curvature` on a closed mesh (Steiner / Schlaefli). It points outward
    on convex surfaces with outward normals. Crane's notes write `1/2 sum_j theta_ij e_ij / l_ij`
    with `e_ij = f_j - f_i` and state `grad H = K N` under the opposite sign of the edge vector; this
    function follows the gradient. Zero-length edges contribute 0. Signed dihedral angles: needs
    consistently oriented faces (`MeshDataError` otherwise). Reference: Crane 2020, "Discrete
    curvature II". No libigl / gpytoolbox equivalent.

    Args:
        mesh: a consistently oriented triangle mesh (`MeshDataError` otherwise).

    Returns:
        `(nv, 3)` integrated Gauss curvature normals (dimensionless), in the vertices' dtype.
    """
    vectors = take_rows(mesh.vertices, mesh.edges[:, 0]) - take_rows(mesh.vertices, mesh.edges[:, 1])
    terms = 0.5 * safe_div(edge_dihedral_angles(mesh), safe_norm(vectors))[:, None] * vectors
    n = mesh.n_vertices
    return jax.ops.segment_sum(terms, mesh.edges[:, 0], num_segments=n) - jax.ops.segment_sum(
        terms, mesh.edges[:, 1], num_segments=n
    )


@kernel(static_argnames=("dual",), requires_orientation=_operation("vertex_pointwise_mean_curvatures"))
def vertex_pointwise_mean_curvatures(mesh: Mesh, *, dual: str = "voronoi") -> Float[Array, " nv"]:
    """Pointwise signed mean curvature, `(nv,)`: `vertex_mean_curvatures / A_i`.

    `A_i = vertex_dual_areas(mesh, dual=dual)`. `H = (k1 + k2) / 2`, `1/r` on a sphere of radius r
    with outward normals; 0 where the dual area is 0. Needs consistently oriented faces
    (`MeshDataError` otherwise). Reference: Crane 2020, "Discrete curvature II". libigl's tutorial
    computes the unsigned `|H|` from `L V` instead (see `vertex_pointwise_mean_curvature_normals`).

    Args:
        mesh: a consistently oriented triangle mesh (`MeshDataError` otherwise).
        dual: the dual cell `A_i` divides by, one of `ddgjax.DUAL_CELLS`: `"voronoi"` (default),
            `"circumcentric"`, `"barycentric"` (keyword-only, static).

    Returns:
        `(nv,)` pointwise signed mean curvatures `H` (units of 1 / length), in the vertices' dtype.
    """
    return safe_div(vertex_mean_curvatures(mesh), vertex_dual_areas(mesh, dual=dual))


@kernel(static_argnames=("dual",), requires_orientation=_operation("vertex_principal_curvatures"))
def vertex_principal_curvatures(mesh: Mesh, *, dual: str = "voronoi") -> Float[Array, "nv 2"]:
    """Pointwise principal curvatures `(k1, k2)`, `(nv, 2)`, `k1 >= k2`, from `K` and `H`.

    `k1,2 = H +- sqrt(max(H^2 - K, 0))` with `vertex_pointwise_mean_curvatures` and
    `vertex_pointwise_gaussian_curvatures` (same dual areas). The discrete `H^2 - K` can be slightly
    negative (umbilic points: a sphere); it is clamped to 0 there. Away from umbilics `k1, k2`
    inherit the `O(h^2)` accuracy of `K` and `H` on regular meshes; at umbilics the square root makes
    it `O(h)`. Needs consistently oriented faces, like `H` (`MeshDataError` otherwise). Reference:
    Meyer et al. 2003, section 6. libigl's `principal_curvature` fits quadrics instead (and also
    returns directions).

    Args:
        mesh: a consistently oriented triangle mesh (`MeshDataError` otherwise).
        dual: the dual cell `A_i` divides by, one of `ddgjax.DUAL_CELLS`: `"voronoi"` (default),
            `"circumcentric"`, `"barycentric"` (keyword-only, static).

    Returns:
        `(nv, 2)` pointwise principal curvatures, column 0 `k1`, column 1 `k2 <= k1` (units of 1 / length).
    """
    h = vertex_pointwise_mean_curvatures(mesh, dual=dual)
    root = safe_sqrt(h * h - vertex_pointwise_gaussian_curvatures(mesh, dual=dual))
    return jnp.stack([h + root, h - root], axis=-1)
