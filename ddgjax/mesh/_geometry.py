"""Per-element geometry of a triangle mesh: lengths, areas, angles, cotangents, normals, dual areas.

Intrinsic core, extrinsic wrapper (DESIGN.md): what depends only on edge lengths has a
`*_from_lengths_sq` core; the mesh version measures the embedding and calls it. Per-face triples
follow the libigl order: entry `k` belongs to the edge opposite corner `k`.

Degenerate faces (zero area, collinear corners) have no defined cotangent; their cotangents are set
to 0, so such a face contributes nothing to the cotan Laplacian or the circumcentric dual, and every
value and gradient stays finite (libigl returns inf / NaN there). See DESIGN.md, Numerics.

Dual cells: every function that needs the dual cell of a vertex (the dual areas here, the pointwise
curvatures, the DEC Hodge stars) takes the same keyword-only option `dual=`, one of `ddgjax.DUAL_CELLS`:

- `"voronoi"` (the default everywhere): the mixed area of Meyer et al. 2003, circumcentric on faces
  without an obtuse angle, `A/2, A/4, A/4` on obtuse ones; never negative; libigl's Voronoi mass
  matrix and the default of `ddgjax.laplacian.mass_matrix`.
- `"circumcentric"`: the DEC dual of Desbrun et al. 2005; a vertex next to an obtuse face gets a
  negative share of it, so its area can be negative.
- `"barycentric"`: a third of each incident face.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from .._compile import kernel
from .._errors import check_choice
from .._indexing import take_rows
from .._numerics import safe_atan2, safe_div, safe_norm, safe_normalize, safe_sqrt, unsigned_angle
from .._options import DUAL_CELLS
from ._mesh import Mesh


def face_vertex_positions(mesh: Mesh) -> Float[Array, "nf 3 3"]:
    """`(nf, 3, 3)` corner positions `V[F]` (one gather; everything per face starts here).

    Args:
        mesh: any triangle mesh.

    Returns:
        `(nf, 3, 3)` positions, indexed `[face, corner, coordinate]`, in the vertices' dtype.
    """
    return take_rows(mesh.vertices, mesh.faces)


def face_edge_vectors(mesh: Mesh) -> Float[Array, "nf 3 3"]:
    """Edge vectors per face, `(nf, 3, 3)`: entry `k` is `V[F[k+2]] - V[F[k+1]]`, the edge opposite corner `k`.

    Counterclockwise around a counterclockwise face (`e_0 + e_1 + e_2 = 0`). libigl / gpytoolbox have
    no per-face edge vectors; `V[F[:, [2, 0, 1]]] - V[F[:, [1, 2, 0]]]` in NumPy.

    Args:
        mesh: any triangle mesh.

    Returns:
        `(nf, 3, 3)` edge vectors, indexed `[face, opposite corner, coordinate]`, in the vertices' dtype.
    """
    corners = face_vertex_positions(mesh)
    return jnp.roll(corners, -2, axis=1) - jnp.roll(corners, -1, axis=1)


def _dot(a: list, b: list) -> Float[Array, " nf"]:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def face_geometry_from_corners(
    corners: Float[Array, "nf 3 3"],
) -> tuple[list[list[Float[Array, " nf"]]], Float[Array, "nf 3"], Float[Array, " nf"]]:
    """`(e, lengths_sq, areas)` of faces given by their corner positions `(nf, 3, 3)` (a `V[F]` gather).

    `e[k][c]` is coordinate `c` of the edge opposite corner `k`, `lengths_sq[:, k] = |e_k|^2` and
    `areas = |e_1 x e_2| / 2` (0, with a finite gradient, on a degenerate face). Coordinate by
    coordinate on `(nf,)` arrays: XLA:CPU does not vectorise reductions over a size-3 axis, and written
    as those the lengths and areas of the cotan Laplacian (`ddgjax.laplacian`) compile into one kernel
    with its per-corner values instead of several that write out `(nf, 3, 3)` intermediates
    (benchmarks/laplacian.py). The kernels that gather their corners themselves (the Dirichlet
    energy's gradient, `ddgjax.batch`) share it through `ddgjax.mesh.internal`.
    """
    edges = [[corners[:, (k + 2) % 3, c] - corners[:, (k + 1) % 3, c] for c in range(3)] for k in range(3)]
    lengths_sq = jnp.stack([_dot(edges[k], edges[k]) for k in range(3)], axis=1)
    (x1, y1, z1), (x2, y2, z2) = edges[1], edges[2]
    normal = [y1 * z2 - z1 * y2, z1 * x2 - x1 * z2, x1 * y2 - y1 * x2]
    return edges, lengths_sq, 0.5 * safe_sqrt(_dot(normal, normal))


@kernel
def face_edge_lengths_sq(mesh: Mesh) -> Float[Array, "nf 3"]:
    """Squared length of the edge opposite each corner, `(nf, 3)` (libigl `squared_edge_lengths`).

    Args:
        mesh: any triangle mesh.

    Returns:
        `(nf, 3)` squared lengths; entry `k` of a row is that of the edge opposite corner `k`.
    """
    return face_geometry_from_corners(face_vertex_positions(mesh))[1]


@kernel
def edge_lengths(mesh: Mesh) -> Float[Array, " ne"]:
    """Length of each global edge, `l_e = |p_head - p_tail|`, `(ne,)`, in `mesh.edges` order.

    Unsigned (the low -> high orientation of `mesh.edges` does not matter); a zero-length edge has
    length 0 with a zero (finite) gradient (`ddgjax._numerics.safe_norm`). Equivalents: libigl
    `igl.edge_lengths(V, F)` and gpytoolbox `halfedge_lengths(V, F)` give the same values per face
    corner, `(nf, 3)`, not per global edge (see `face_edge_lengths_sq` for that layout).

    Args:
        mesh: any triangle mesh.

    Returns:
        `(ne,)` edge lengths, in `mesh.edges` order and the vertices' dtype.
    """
    return safe_norm(take_rows(mesh.vertices, mesh.edges[:, 1]) - take_rows(mesh.vertices, mesh.edges[:, 0]))


@kernel
def face_area_vectors(mesh: Mesh) -> Float[Array, "nf 3"]:
    """Vector area of each face, `A_f N_f = (p1 - p0) x (p2 - p0) / 2`, `(nf, 3)`.

    Its length is the face area and its direction the unit normal by the right-hand rule of the
    face's vertex order (outward for counterclockwise faces seen from outside); the zero vector on a
    degenerate face. Summed over a closed, consistently oriented surface it vanishes, and
    `sum_f (A_f N_f) . p0 / 3` is the enclosed volume (`enclosed_volume`). Equivalents: libigl
    `igl.per_face_normals(V, F, ...) * igl.doublearea(V, F)[:, None] / 2`; gpytoolbox
    `per_face_normals(V, F) * doublearea(V, F)[:, None] / 2`.

    Args:
        mesh: any triangle mesh.

    Returns:
        `(nf, 3)` vector areas `A_f N_f` (length: the face area), in the vertices' dtype.
    """
    corners = face_vertex_positions(mesh)
    return 0.5 * jnp.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])


@kernel
def face_areas(mesh: Mesh) -> Float[Array, " nf"]:
    """Area of each face, `A_f = |(p1 - p0) x (p2 - p0)| / 2`, `(nf,)`, from the embedding.

    `p_k` are the face's corners (`mesh.vertices[mesh.faces[f, k]]`); the cross product is the face's
    vector area (`face_area_vectors`), so the value does not depend on the corner order or the
    orientation, and it is accurate to rounding for needle and cap triangles, where a plain Heron
    formula on the edge lengths cancels (the intrinsic core `face_areas_from_lengths_sq` uses Kahan's
    stable form; the two agree to round-off). A degenerate face (collinear or coincident corners) has area 0, and the
    gradient there is finite (zero) rather than NaN (`ddgjax._numerics.safe_norm`, the double-where
    pattern; DESIGN.md, Numerics); elsewhere the gradient in the corners is
    `grad_{p_k} A_f = N_f x e_k / 2` (`e_k` the edge opposite corner `k`, `N_f` the unit normal), the
    hat-function gradients times `A_f`. Sums to `total_area`; the Galerkin and lumped mass matrices
    are made of it (`ddgjax.laplacian.mass_matrix`).

    Args:
        mesh: any triangle mesh.

    Returns:
        `(nf,)` areas, in the vertices' dtype.

    References: U. Pinkall, K. Polthier, "Computing discrete minimal surfaces and their conjugates"
    (1993) (the area gradient); K. Crane, "Discrete Differential Geometry: An Applied Introduction"
    (2020). Equivalents: libigl `igl.doublearea(V, F) / 2`;
    gpytoolbox `doublearea(V, F) / 2`; trimesh `Trimesh.area_faces`.
    """
    return face_geometry_from_corners(face_vertex_positions(mesh))[2]


@kernel
def face_normals(mesh: Mesh) -> Float[Array, "nf 3"]:
    """Unit face normals (right-hand rule of the face order); the zero vector on zero-area faces.

    Args:
        mesh: any triangle mesh.

    Returns:
        `(nf, 3)` unit normals, in the vertices' dtype; zero rows on zero-area faces.
    """
    return safe_normalize(face_area_vectors(mesh))


def face_areas_from_lengths_sq(lengths_sq: Float[Array, "nf 3"]) -> Float[Array, " nf"]:
    """Triangle area from its squared edge lengths, by Kahan's stable form of Heron's formula.

    `A = 1/4 sqrt((a + (b + c)) (c - (a - b)) (c + (a - b)) (a + (b - c)))` with `a >= b >= c` the
    sorted lengths; accurate for needle and cap triangles where plain Heron cancels. Violations of the
    triangle inequality give area 0. Reference: W. Kahan, "Miscalculating area and angles of a
    needle-like triangle" (2014). libigl: `doublearea(l) / 2`.

    Args:
        lengths_sq: `(nf, 3)` squared length of the edge opposite each corner (`face_edge_lengths_sq`).

    Returns:
        `(nf,)` areas, in the dtype of `lengths_sq`; 0 where the lengths violate the triangle inequality.
    """
    lengths = safe_sqrt(lengths_sq)
    a = jnp.max(lengths, axis=-1)
    c = jnp.min(lengths, axis=-1)
    b = jnp.sum(lengths, axis=-1) - a - c
    product = (a + (b + c)) * (c - (a - b)) * (c + (a - b)) * (a + (b - c))
    return 0.25 * safe_sqrt(product)


def _cosine_numerators(lengths_sq: Float[Array, "nf 3"]) -> Float[Array, "nf 3"]:
    """Law-of-cosines numerator at each corner, `l_{k+1}^2 + l_{k+2}^2 - l_k^2 = 2 l_{k+1} l_{k+2} cos(alpha_k)`."""
    return jnp.roll(lengths_sq, -1, axis=-1) + jnp.roll(lengths_sq, -2, axis=-1) - lengths_sq


def corner_cotangents_from_lengths_sq(
    lengths_sq: Float[Array, "nf 3"], *, areas: Float[Array, " nf"] | None = None
) -> Float[Array, "nf 3"]:
    """Cotangent of each corner angle from the squared lengths of the opposite edges, `(nf, 3)`.

    `cot(alpha_k) = (l_{k+1}^2 + l_{k+2}^2 - l_k^2) / (4 A)` (law of cosines over twice the area).
    Zero-area faces get cotangent 0 (module policy). libigl: `cotmatrix_entries` (times 2).

    Args:
        lengths_sq: `(nf, 3)` squared length of the edge opposite each corner (`face_edge_lengths_sq`).
        areas: `(nf,)` face areas (keyword-only); `None` (default) computes them by Kahan's formula
            (`face_areas_from_lengths_sq`); the extrinsic wrappers (`corner_cotangents`,
            `ddgjax.laplacian.cotan_laplacian`) pass the cross-product area.

    Returns:
        `(nf, 3)` cotangents `cot(alpha_k)` of the corner angles; 0 on zero-area faces.
    """
    if areas is None:
        areas = face_areas_from_lengths_sq(lengths_sq)
    # Column by column (no roll, no broadcast of the areas): the cotan Laplacian's per-face arithmetic
    # then compiles into one kernel with the edge lengths (benchmarks/laplacian.py).
    columns = [lengths_sq[:, k] for k in range(3)]
    four_areas = 4.0 * areas
    return jnp.stack([safe_div(columns[(k + 1) % 3] + columns[(k + 2) % 3] - columns[k], four_areas) for k in range(3)], axis=1)


@kernel
def corner_cotangents(mesh: Mesh) -> Float[Array, "nf 3"]:
    """Cotangent of each corner angle, `(nf, 3)` (extrinsic lengths and area; see the core).

    Args:
        mesh: any triangle mesh.

    Returns:
        `(nf, 3)` cotangents of the corner angles, in the vertices' dtype; 0 on zero-area faces.
    """
    return corner_cotangents_from_lengths_sq(face_edge_lengths_sq(mesh), areas=face_areas(mesh))


def corner_angles_from_lengths_sq(lengths_sq: Float[Array, "nf 3"]) -> Float[Array, "nf 3"]:
    """Interior angle at each corner from squared edge lengths, `atan2(4A, l_{k+1}^2 + l_{k+2}^2 - l_k^2)`.

    Uses `atan2` of (twice the doubled area, law-of-cosines numerator), never `arccos`, so it is exact
    near 0 and pi with finite gradients. libigl: `internal_angles_using_squared_edge_lengths`.

    Args:
        lengths_sq: `(nf, 3)` squared length of the edge opposite each corner (`face_edge_lengths_sq`).

    Returns:
        `(nf, 3)` interior angles in radians, in `[0, pi]`; entry `k` is the angle at corner `k`.
    """
    numerators = _cosine_numerators(lengths_sq)
    # 4 A = 2 l_{k+1} l_{k+2} sin(alpha_k), the sine counterpart of the numerator at every corner.
    sines = jnp.broadcast_to(4.0 * face_areas_from_lengths_sq(lengths_sq)[:, None], numerators.shape)
    return safe_atan2(sines, numerators)


@kernel
def corner_angles(mesh: Mesh) -> Float[Array, "nf 3"]:
    """Interior angle at each corner, `(nf, 3)`, in `[0, pi]`: `atan2(|a x b|, a . b)` of the two edges leaving it.

    `a = p_{k+1} - p_k`, `b = p_{k+2} - p_k` (`ddgjax._numerics.unsigned_angle`): accurate near 0 and
    pi with finite gradients, unlike `arccos` (DESIGN.md, Numerics); 0 at a corner with a zero-length
    edge. Agrees with `corner_angles_from_lengths_sq(face_edge_lengths_sq(mesh))` to round-off.
    libigl: `internal_angles`; gpytoolbox: `tip_angles`.

    Args:
        mesh: any triangle mesh.

    Returns:
        `(nf, 3)` interior angles in radians, in the vertices' dtype; entry `k` is the angle at corner `k`.
    """
    corners = face_vertex_positions(mesh)
    return unsigned_angle(jnp.roll(corners, -1, axis=1) - corners, jnp.roll(corners, -2, axis=1) - corners)


def edge_cotan_weights_from_corner_cotangents(mesh: Mesh, cotangents: Float[Array, "nf 3"]) -> Float[Array, " ne"]:
    """`w_ij = 1/2 sum cot(opposite angles)` per global edge, gathered (no scatter) from corners.

    A boundary edge has one term, a non-manifold edge one per face.

    Args:
        mesh: the triangle mesh whose edges are weighted (only its topology is read).
        cotangents: `(nf, 3)` cotangent of each corner angle, from the embedding (`corner_cotangents`) or
            from intrinsic lengths (`corner_cotangents_from_lengths_sq`).

    Returns:
        `(ne,)` cotan weights, in `mesh.edges` order.
    """
    flat = cotangents.reshape(-1)
    slots = mesh.edge_faces * 3 + mesh.edge_face_corners
    present = mesh.edge_faces >= 0
    return 0.5 * jnp.sum(jnp.where(present, flat[jnp.where(present, slots, 0)], 0.0), axis=-1)


@kernel
def edge_cotan_weights(mesh: Mesh) -> Float[Array, " ne"]:
    """Cotan weight `w_ij = (cot a_ij + cot b_ij) / 2` of each edge, `(ne,)`.

    Equals the circumcentric dual/primal length ratio `|e*| / |e|` (the diagonal of the DEC Hodge star
    on 1-forms) and minus the off-diagonal entry of libigl's `cotmatrix`. Reference: Pinkall &
    Polthier 1993.

    Args:
        mesh: any triangle mesh.

    Returns:
        `(ne,)` cotan weights, in `mesh.edges` order and the vertices' dtype; negative across obtuse angles.
    """
    return edge_cotan_weights_from_corner_cotangents(mesh, corner_cotangents(mesh))


def scatter_corners_to_vertices(mesh: Mesh, corner_values: Float[Array, "nf 3 *d"]) -> Float[Array, "nv *d"]:
    """Sum per-corner values (scalars or vectors) into their vertices, `(nv, *d)`; unreferenced vertices get 0.

    `out_i = sum_{corners (f, k) with F[f, k] = i} corner_values[f, k]`, one `segment_sum`. NumPy
    equivalent for scalars: `np.bincount(F.ravel(), weights=corner_values.ravel(), minlength=nv)`
    (libigl and gpytoolbox have no per-corner sum; libigl's `average_onto_vertices` averages faces).

    Args:
        mesh: the triangle mesh whose faces map corners to vertices (only its topology is read).
        corner_values: `(nf, 3, *d)` one value per face corner, in the order of `mesh.faces`.

    Returns:
        `(nv, *d)` per-vertex sums, in the dtype of `corner_values`.
    """
    flat = corner_values.reshape((-1,) + corner_values.shape[2:])
    return jax.ops.segment_sum(flat, mesh.faces.reshape(-1), num_segments=mesh.n_vertices)


def corner_dual_areas_from_lengths_sq(
    lengths_sq: Float[Array, "nf 3"], *, dual: str = "voronoi", areas: Float[Array, " nf"] | None = None
) -> Float[Array, "nf 3"]:
    """Share of each face's area assigned to each of its corners, `(nf, 3)` (intrinsic core).

    With `l_k` the length of the edge opposite corner `k`, `A` the face area and
    `t_k = l_k^2 cot(alpha_k) / 8` (the area between edge `k` and the circumcentre, halved to each of
    its endpoints):

    - `"barycentric"`: `A / 3` per corner.
    - `"circumcentric"`: corner `i` gets `sum_{k != i} t_k` = `(l_j^2 cot a_j + l_k^2 cot a_k) / 8`,
      the part of the face closer to corner `i` than to the others when the circumcentre lies inside.
      For an obtuse face the circumcentre lies outside and the share of a corner next to the obtuse
      one is **negative**; the per-corner shares still sum to `A`.
    - `"voronoi"` (mixed area, Meyer et al. 2003): circumcentric on faces without an obtuse angle;
      on a face with an obtuse corner, `A / 2` to that corner and `A / 4` to the two others. Always
      nonnegative. Exactly libigl's `massmatrix(..., MASSMATRIX_TYPE_VORONOI)` rule (a right angle
      counts as non-obtuse; both rules agree there).

    `areas` defaults to Kahan's formula from the lengths. Zero-area faces give 0 shares (every dual).

    Args:
        lengths_sq: `(nf, 3)` squared length of the edge opposite each corner.
        dual: one of `"voronoi"` (default), `"circumcentric"`, `"barycentric"` (keyword-only, static;
            module docstring).
        areas: optional `(nf,)` face areas.

    Returns:
        `(nf, 3)` corner dual areas (each row sums to the face area).

    Reference: M. Meyer, M. Desbrun, P. Schroeder, A. Barr, "Discrete differential-geometry operators
    for triangulated 2-manifolds" (2003), Section 3.3 and Fig. 4.
    """
    check_choice("dual", dual, DUAL_CELLS)
    if areas is None:
        areas = face_areas_from_lengths_sq(lengths_sq)
    if dual == "barycentric":
        return jnp.broadcast_to(areas[:, None] / 3.0, lengths_sq.shape)
    # l_k^2 cot(alpha_k) / 8 = l_k^2 (l_{k+1}^2 + l_{k+2}^2 - l_k^2) / (32 A): the law-of-cosines
    # numerator is also the (sign of the) cosine, so the obtuse test needs no extra work.
    cosine_numerators = _cosine_numerators(lengths_sq)
    halves = safe_div(lengths_sq * cosine_numerators, 32.0 * areas[:, None])
    circumcentric = jnp.sum(halves, axis=-1, keepdims=True) - halves
    if dual == "circumcentric":
        return circumcentric
    obtuse = cosine_numerators < 0
    has_obtuse = jnp.any(obtuse, axis=-1, keepdims=True)
    split = jnp.where(obtuse, 0.5, 0.25) * areas[:, None]
    return jnp.where(has_obtuse, split, circumcentric)


@kernel(static_argnames=("dual",))
def corner_dual_areas(mesh: Mesh, *, dual: str = "voronoi") -> Float[Array, "nf 3"]:
    """Per-corner dual areas, `(nf, 3)`, from the embedding (see `corner_dual_areas_from_lengths_sq`).

    Args:
        mesh: any triangle mesh.
        dual: the dual cell, one of `ddgjax.DUAL_CELLS`: `"voronoi"` (default), `"circumcentric"`,
            `"barycentric"` (keyword-only, static).

    Returns:
        `(nf, 3)` corner dual areas (each row sums to the face area), in the vertices' dtype.
    """
    return corner_dual_areas_from_lengths_sq(face_edge_lengths_sq(mesh), dual=dual, areas=face_areas(mesh))


@kernel(static_argnames=("dual",))
def vertex_dual_areas(mesh: Mesh, *, dual: str = "voronoi") -> Float[Array, " nv"]:
    """Area of the dual cell of each vertex, `(nv,)`: the corner shares of its faces, summed.

    `dual="voronoi"` (default) is the mixed area of Meyer et al. 2003, `"barycentric"` a third of
    each incident face, `"circumcentric"` the (possibly negative, on obtuse meshes) circumcentric
    dual cell; see `corner_dual_areas_from_lengths_sq` for the formulas. Every dual sums to the
    total surface area. Unreferenced vertices get 0. Dividing an integrated quantity (e.g. the angle
    defect) by these areas gives the pointwise one.

    Args:
        mesh: any triangle mesh.
        dual: the dual cell, one of `ddgjax.DUAL_CELLS`: `"voronoi"` (default), `"circumcentric"`,
            `"barycentric"` (keyword-only, static).

    Returns:
        `(nv,)` dual areas, in the vertices' dtype; 0 at unreferenced vertices.

    Equivalents: `igl.massmatrix(V, F, igl.MASSMATRIX_TYPE_VORONOI / _BARYCENTRIC).diagonal()`;
    gpytoolbox `massmatrix(V, F, type="voronoi" / "barycentric").diagonal()`. Each dual is the
    diagonal of the DEC Hodge star on 0-forms of that dual (`ddgjax.dec.hodge0`).
    """
    return scatter_corners_to_vertices(mesh, corner_dual_areas(mesh, dual=dual))


_NORMAL_WEIGHTINGS = ("area", "angle", "uniform")


@kernel(static_argnames=("weighting", "normalize"))
def vertex_normals(mesh: Mesh, *, weighting: str = "area", normalize: bool = True) -> Float[Array, "nv 3"]:
    """Vertex normals, `(nv, 3)`: a weighted sum of the unit normals `N_f` of the incident faces.

    `n_i = sum_{f ni i} w_f N_f`, with `w_f` the face area `A_f` (`"area"`, default), the corner angle
    of `f` at `i` (`"angle"`, Thuermer & Wuethrich 1998) or 1 (`"uniform"`); then normalised to unit
    length unless `normalize=False`. The unnormalised area-weighted sum `sum_f A_f N_f` is the
    gradient of the enclosed volume times 3 (see `enclosed_volume`). Zero-area faces contribute
    nothing; vertices with a zero sum (unreferenced, or cancelling normals) get the zero vector.

    Args:
        mesh: any triangle mesh.
        weighting: how the faces around a vertex are weighted: `"area"` (default), `"angle"` or
            `"uniform"` (keyword-only, static; libigl's names). Not the `weights=` of ddgjax's
            vocabulary (uniform or cotan edge weights of a graph Laplacian, `ddgjax.LAPLACIAN_WEIGHTS`).
        normalize: whether to scale each sum to unit length (default `True`; keyword-only, static).

    Returns:
        `(nv, 3)` vertex normals, in the vertices' dtype; zero rows where the sum vanishes.

    Equivalent: `igl.per_vertex_normals(V, F, igl.PER_VERTEX_NORMALS_WEIGHTING_TYPE_AREA / _ANGLE /
    _UNIFORM)` (libigl returns NaN or an arbitrary vector where the sum vanishes).
    """
    check_choice("weighting", weighting, _NORMAL_WEIGHTINGS)
    area_vectors = face_area_vectors(mesh)
    if weighting == "area":
        corner_vectors = jnp.broadcast_to(area_vectors[:, None, :], (mesh.n_faces, 3, 3))
    else:
        unit = safe_normalize(area_vectors)
        weights = corner_angles(mesh) if weighting == "angle" else jnp.ones(mesh.faces.shape, unit.dtype)
        corner_vectors = weights[:, :, None] * unit[:, None, :]
    sums = scatter_corners_to_vertices(mesh, corner_vectors)
    return safe_normalize(sums) if normalize else sums


@kernel
def edge_dihedral_angles(mesh: Mesh) -> Float[Array, " ne"]:
    """Signed dihedral angle of each edge, `(ne,)`: the angle between the normals of its two faces.

    For an edge `ij` with faces `ijk` (which traverses it `i -> j`) and `jil`,
    `theta_ij = atan2(e_ij / l_ij . (N_ijk x N_jil), N_ijk . N_jil)`, in `(-pi, pi]`: positive where
    the surface bends away from its normals (convex, as everywhere on a sphere with outward normals),
    negative on saddle-like concave edges, 0 on flat ones. It is the exterior angle: 0 for a flat
    pair, not pi. Boundary and non-manifold edges get 0; on an inconsistently oriented edge the sign
    follows the first face's orientation and means nothing. Computed with `atan2` of area-weighted
    normals, so it is exact near 0 and pi, with finite gradients on degenerate faces (value 0 there).

    Args:
        mesh: any triangle mesh.

    Returns:
        `(ne,)` signed dihedral angles in radians, in `(-pi, pi]`, in `mesh.edges` order; 0 on boundary
        and non-manifold edges.

    Reference: K. Crane, "Discrete Differential Geometry: An Applied Introduction" (2020), "Discrete
    curvature II" (dihedral angle). libigl has no signed per-edge equivalent.
    """
    area_vectors = face_area_vectors(mesh)
    first, second = mesh.edge_faces[:, 0], mesh.edge_faces[:, 1]
    two_faces = second >= 0
    if mesh.edge_faces.shape[1] > 2:
        # Only non-manifold meshes pad wider; an edge with 3+ faces has no single dihedral angle.
        two_faces = two_faces & (mesh.edge_faces[:, 2] < 0)
    n0 = area_vectors[first]
    n1 = area_vectors[jnp.where(two_faces, second, first)]
    direction = mesh.face_edge_signs[first, mesh.edge_face_corners[:, 0]].astype(n0.dtype)
    edge_vectors = take_rows(mesh.vertices, mesh.edges[:, 1]) - take_rows(mesh.vertices, mesh.edges[:, 0])
    unit_edges = direction[:, None] * safe_normalize(edge_vectors)
    angles = safe_atan2(jnp.sum(unit_edges * jnp.cross(n0, n1), axis=-1), jnp.sum(n0 * n1, axis=-1))
    return jnp.where(two_faces, angles, 0.0)


@kernel
def total_area(mesh: Mesh) -> Float[Array, ""]:
    """Surface area, `sum_f A_f`, a scalar `()` (`A_f = |(p1 - p0) x (p2 - p0)| / 2`, `face_areas`).

    Its gradient with respect to the vertices is `L V`, the PSD cotan Laplacian applied to the
    positions, i.e. twice the integrated mean curvature normal (`vertex_mean_curvature_normals`):
    `grad_{p_i} A = 1/2 sum_j (cot a_ij + cot b_ij)(p_i - p_j)`. Reference: Pinkall & Polthier,
    "Computing discrete minimal surfaces and their conjugates" (1993). libigl:
    `igl.doublearea(V, F).sum() / 2`; gpytoolbox: `doublearea(V, F).sum() / 2`.

    Args:
        mesh: any triangle mesh.

    Returns:
        The total area, a scalar `()` in the vertices' dtype.
    """
    return jnp.sum(face_areas(mesh))


@kernel
def enclosed_volume(mesh: Mesh) -> Float[Array, ""]:
    """Signed volume enclosed by a closed, oriented mesh, `1/6 sum_f (V0 . (V1 x V2))` (divergence theorem).

    A scalar `()`: the sum of the signed volumes of the tetrahedra joining each face to a reference
    point. Positive for outward-oriented faces. Computed relative to the vertex centroid (held
    constant under differentiation), which leaves the value and gradient of a closed mesh unchanged
    and avoids cancellation far from the origin. On a mesh with boundary or inconsistent orientation
    the value depends on that reference point and is not a volume (no error is raised: it is a
    plain sum; `ddgjax.mesh.check_mesh` tells whether the mesh is closed and oriented). Its gradient
    is `1/3 sum_{f ni i} A_f N_f`, i.e. `vertex_normals(mesh, weighting="area", normalize=False) / 3`.
    Reference: the divergence theorem, `V = 1/3 int_S p . N dA`. libigl: `igl.volume` of the
    tetrahedra to the origin, summed; trimesh: `Trimesh.volume`.

    Args:
        mesh: a closed, consistently oriented triangle mesh (any mesh is accepted; see above).

    Returns:
        The signed enclosed volume, a scalar `()` in the vertices' dtype; positive for outward-oriented faces.
    """
    corners = face_vertex_positions(mesh) - jax.lax.stop_gradient(jnp.mean(mesh.vertices, axis=0))
    return jnp.sum(corners[:, 0] * jnp.cross(corners[:, 1], corners[:, 2])) / 6.0


@kernel
def face_hat_gradients(mesh: Mesh) -> Float[Array, "nf 3 3"]:
    """Gradient of each corner's hat function on each face, `grad phi_k = (N x e_k) / (2 A)`, `(nf, 3, 3)`.

    `e_k` is the edge vector opposite corner `k` (face order), `N` the unit normal, `A` the area;
    zero on zero-area faces. Reference: Crane 2020, section 6.2 ("the gradient of a hat function").

    Args:
        mesh: any triangle mesh.

    Returns:
        `(nf, 3, 3)` gradients, indexed `[face, corner, coordinate]` (units of 1 / length); zero on zero-area faces.
    """
    area_vectors = face_area_vectors(mesh)
    double_areas = 2.0 * safe_norm(area_vectors)
    normals = safe_div(area_vectors, double_areas[:, None] / 2.0)
    rotated = jnp.cross(normals[:, None, :], face_edge_vectors(mesh))
    return safe_div(rotated, double_areas[:, None, None])
