"""Discrete exterior calculus on tetrahedral meshes: exterior derivatives `d0`, `d1`, `d2` and diagonal Hodge stars.

Discrete k-forms are arrays of integrals over k-simplices, on the mesh's oriented simplices
(`ddgjax.volume._topology`): 0-forms `(nv,)` on vertices, 1-forms `(ne,)` on `tet_mesh.edges` (low ->
high), 2-forms `(ntri,)` on `tet_mesh.triangles` (sorted triples, oriented by that order), 3-forms
`(nt,)` on the tets (positively oriented). `d0`, `d1`, `d2` are the signed incidence matrices,
`d1 @ d0 == 0` and `d2 @ d1 == 0` exactly. They need no manifold or orientation check: every
simplex carries its own global orientation.

Hodge stars `*k` (diagonal, `|dual cell| / |primal simplex|`), `dual=` as on surfaces (`TET_DUALS`):

- `*0`: the vertex dual volumes (`vertex_dual_volumes`);
- `*1`: dual face area over edge length. Voronoi (default) and circumcentric: the summed cotan
  weight `sum_t w_ij` (`w_ij = l_kl cot(theta_kl) / 6`), so `d0^T *1 d0 == cotan_laplacian` exactly,
  as on surfaces (where the Voronoi dual differs from the circumcentric one in `*0` only). In 3-D
  this is the star of the Galerkin (FEM) Laplacian: unlike on surfaces, it is not the area of the
  circumcentric dual polygon over the edge length, tet by tet nor summed around an edge (that ratio,
  `6 x_ij / l_ij^2` in `ddgjax.volume._dual`'s notation, is never negative on a Delaunay mesh; the
  cotan weights can be). Zero where the opposite dihedral angles balance (the face diagonals of a
  Kuhn cube grid). Barycentric: per tet the two triangles (edge midpoint, centroid of a triangle
  containing the edge, tet centroid); never negative.
- `*2`: dual edge length over triangle area. Voronoi and circumcentric: the signed distances from
  the triangle's circumcentre to the circumcentres of its one or two tets, positive towards each tet
  (`beta_k 3 V / A` for the face opposite vertex `k`, `beta` the circumcentre's barycentric
  coordinates); barycentric: the distances from the triangle's centroid to its tets' centroids.
- `*3`: one over the tet volume.

Inverses (`inverse=True`) take the reciprocal entry by entry, and an exactly zero entry inverts to
zero (the pseudo-inverse of a diagonal matrix), as `ddgjax.dec` does; degenerate tets contribute 0
and keep values and gradients finite. Per-tet values reach the global edges and triangles through
fixed gathers (`ddgjax.sparse.gather_sum`, whose transpose is a gather too): no scatter-add.

Reference: Desbrun, Hirani, Leok, Marsden, *Discrete Exterior Calculus* (2005); Crane, de Goes,
Desbrun, Schroeder, *Digital Geometry Processing with Discrete Exterior Calculus* (2013).
"""

from __future__ import annotations

import weakref

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from .._compile import kernel
from .._errors import DDGInputError, check_choice
from .._indexing import take_rows
from .._numerics import safe_div, safe_norm, safe_reciprocal
from ..sparse import SparseMatrix, diagonal_matrix, gather_sum
from ..sparse.internal import incidence_matrix
from ._dual import TET_DUALS, tet_circumcenter_coordinates, vertex_dual_volumes
from ._geometry import (
    edge_lengths,
    tet_corner_positions,
    tet_cotan_weights,
    tet_edge_lengths_sq,
    tet_volumes,
    triangle_areas,
)
from ._tet_mesh import TetMesh, require_tet_mesh
from ._topology import TET_EDGES, TRIANGLE_EDGE_SIGNS, TetTopology


class TetIncidence(eqx.Module):
    """Where per-tet values land on the global simplices (host-built once per connectivity, cached).

    Local edge `6 t + k` is edge `k` of tet `t`, local triangle `4 t + k` its triangle `k`, corner
    `4 t + k` its vertex `k`; each `*_locals` array lists a global simplex's local copies, padded with
    the number of local copies (`gather_sum`'s convention). The transposes are the mesh's own
    `tet_edges`, `tet_triangles`, `tets`, flattened.
    """

    edge_locals: Int[Array, "ne w"]
    triangle_locals: Int[Array, "ntri m"]
    vertex_corners: Int[Array, "nv c"]


_INCIDENCES: "weakref.WeakKeyDictionary[TetTopology, TetIncidence]" = weakref.WeakKeyDictionary()


def tet_incidence(tet_mesh: TetMesh) -> TetIncidence:
    """The `TetIncidence` of `tet_mesh`'s connectivity (built on the host on first use, then cached)."""
    topology = require_tet_mesh("tet_mesh", tet_mesh).topology
    if topology is None:
        raise DDGInputError(
            "tet_mesh: the DEC operators need the topology, which a compiled kernel does not see; build it before"
        )
    incidence = _INCIDENCES.get(topology)
    if incidence is None:
        with jax.ensure_compile_time_eval():  # host work, even inside a caller's trace
            nt = topology.n_tets
            edge_locals = np.where(topology.edge_tets >= 0, 6 * topology.edge_tets + topology.edge_tet_edges, 6 * nt)
            tets = topology.triangle_tets
            present = tets >= 0
            local = np.argmax(
                topology.tet_triangles[np.where(present, tets, 0)] == np.arange(topology.n_triangles)[:, None, None], axis=-1
            )
            triangle_locals = np.where(present, 4 * tets + local, 4 * nt)
            arrays = jax.device_put(
                {
                    "edge_locals": edge_locals.astype(np.int32),
                    "triangle_locals": triangle_locals.astype(np.int32),
                    "vertex_corners": _vertex_corners(topology.tets, topology.n_vertices),
                }
            )
            incidence = _INCIDENCES[topology] = TetIncidence(**arrays)
    return incidence


def _vertex_corners(tets: np.ndarray, n_vertices: int) -> np.ndarray:
    """`(nv, c)` the flat corner indices `4 t + k` of each vertex, padded with `4 nt`."""
    corners = tets.reshape(-1)
    order = np.argsort(corners, kind="stable")
    counts = np.bincount(corners, minlength=n_vertices)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    slot = np.arange(corners.size) - np.repeat(starts, counts)
    table = np.full((n_vertices, max(1, int(counts.max()))), corners.size, dtype=np.int32)
    table[corners[order], slot] = order
    return table


def sum_onto_edges(tet_mesh: TetMesh, incidence: TetIncidence, values: Float[Array, "nt 6"]) -> Float[Array, " ne"]:
    """`(ne,)` per-tet edge values summed onto the global edges (one fixed gather)."""
    return gather_sum(values.reshape(-1), incidence.edge_locals, tet_mesh.tet_edges.reshape(-1, 1))


def sum_onto_triangles(tet_mesh: TetMesh, incidence: TetIncidence, values: Float[Array, "nt 4"]) -> Float[Array, " ntri"]:
    """`(ntri,)` per-tet triangle values summed onto the global triangles (one fixed gather)."""
    return gather_sum(values.reshape(-1), incidence.triangle_locals, tet_mesh.tet_triangles.reshape(-1, 1))


def sum_onto_vertices(tet_mesh: TetMesh, incidence: TetIncidence, values: Float[Array, "nt 4 *k"]) -> Float[Array, "nv *k"]:
    """`(nv, *k)` per-tet corner values summed onto the vertices (one fixed gather)."""
    return gather_sum(values.reshape((-1,) + values.shape[2:]), incidence.vertex_corners, tet_mesh.tets.reshape(-1, 1))


@kernel(static_argnames=("degree",))
def _exterior_derivative(tet_mesh: TetMesh, *, degree: int) -> SparseMatrix:
    dtype = tet_mesh.vertices.dtype
    if degree == 0:
        signs = jnp.broadcast_to(jnp.asarray([-1.0, 1.0], dtype), tet_mesh.edges.shape)
        return incidence_matrix(tet_mesh.edges, signs, tet_mesh.n_vertices)
    if degree == 1:
        signs = jnp.broadcast_to(jnp.asarray(TRIANGLE_EDGE_SIGNS, dtype), tet_mesh.triangle_edges.shape)
        return incidence_matrix(tet_mesh.triangle_edges, signs, tet_mesh.n_edges)
    return incidence_matrix(tet_mesh.tet_triangles, tet_mesh.tet_triangle_signs.astype(dtype), tet_mesh.n_triangles)


def exterior_derivative(tet_mesh: TetMesh, degree: int) -> SparseMatrix:
    """`d0`, `d1` or `d2` by degree (one compiled program each per mesh size)."""
    return _exterior_derivative(require_tet_mesh("tet_mesh", tet_mesh), degree=degree)


def d0(tet_mesh: TetMesh) -> SparseMatrix:
    """Exterior derivative on 0-forms, `(ne, nv)`: `(d0 u)_e = u[head] - u[tail]` for edge `(tail, head)`, low -> high.

    Values `-1, +1` in the vertex dtype. The same matrix as `ddgjax.dec.d0` on a surface's edges.
    Reference: Crane et al., *Digital Geometry Processing with Discrete Exterior Calculus* (2013),
    section 3.6 (the signed incidence matrices). libigl: the edges of `igl.edges(T)` (no `d0`).

    Args:
        tet_mesh: the tet mesh.

    Returns:
        `(ne, nv)` `SparseMatrix`.
    """
    return exterior_derivative(tet_mesh, 0)


def d1(tet_mesh: TetMesh) -> SparseMatrix:
    """Exterior derivative on 1-forms, `(ntri, ne)`: the circulation around each triangle `i < j < k` run `i -> j -> k`.

    `(d1 a)_f = a_ij + a_jk - a_ik` (edges low -> high; `TRIANGLE_EDGE_SIGNS`). `d1 @ d0 == 0` exactly.
    Reference: Crane et al. (2013), section 3.6; Desbrun et al., *Discrete Exterior Calculus* (2005).

    Args:
        tet_mesh: the tet mesh.

    Returns:
        `(ntri, ne)` `SparseMatrix` with entries `-1, +1`.
    """
    return exterior_derivative(tet_mesh, 1)


def d2(tet_mesh: TetMesh) -> SparseMatrix:
    """Exterior derivative on 2-forms, `(nt, ntri)`: the flux out of each tet, `(d2 b)_t = sum_k s_tk b[tet_triangles[t, k]]`.

    `s_tk = tet_triangle_signs[t, k]`, +1 where the outward orientation of the tet's triangle `k` is
    the global one. `d2 @ d1 == 0` exactly. Reference: Desbrun et al., *Discrete Exterior Calculus*
    (2005), section 3 (the coboundary of a simplicial 3-complex).

    Args:
        tet_mesh: the tet mesh.

    Returns:
        `(nt, ntri)` `SparseMatrix` with entries `-1, +1`.
    """
    return exterior_derivative(tet_mesh, 2)


@kernel(static_argnames=("dual",))
def _edge_star(tet_mesh: TetMesh, incidence: TetIncidence, *, dual: str) -> Float[Array, " ne"]:
    if dual != "barycentric":
        return sum_onto_edges(tet_mesh, incidence, tet_cotan_weights(tet_mesh))
    p = tet_corner_positions(tet_mesh)
    total = jnp.sum(p, axis=1, keepdims=True)
    midpoints = 0.5 * (p[:, TET_EDGES[:, 0]] + p[:, TET_EDGES[:, 1]])  # (nt, 6, 3)
    face_centroids = (total - p) / 3.0  # (nt, 4, 3): face k is opposite vertex k
    to_tet = total / 4.0 - midpoints
    opposite = TET_EDGES[(np.arange(6) + 3) % 6]  # the faces containing edge k are those opposite its opposite edge's ends
    areas = sum(0.5 * safe_norm(jnp.cross(face_centroids[:, opposite[:, side]] - midpoints, to_tet)) for side in (0, 1))
    return safe_div(sum_onto_edges(tet_mesh, incidence, areas), edge_lengths(tet_mesh))


@kernel(static_argnames=("dual",))
def _triangle_star(tet_mesh: TetMesh, incidence: TetIncidence, *, dual: str) -> Float[Array, " ntri"]:
    areas = triangle_areas(tet_mesh)
    if dual != "barycentric":
        volumes = tet_volumes(tet_mesh)
        beta = tet_circumcenter_coordinates(tet_edge_lengths_sq(tet_mesh), volumes)
        # The circumcentre's height over face k is beta_k times the height of vertex k, 3 V / A_k.
        lengths = safe_div(3.0 * volumes[:, None] * beta, take_rows(areas, tet_mesh.tet_triangles))
    else:
        p = tet_corner_positions(tet_mesh)
        lengths = safe_norm(jnp.sum(p, axis=1, keepdims=True) - 4.0 * p) / 12.0  # face centroid to tet centroid
    return safe_div(sum_onto_triangles(tet_mesh, incidence, lengths), areas)


def hodge_star_entries(tet_mesh: TetMesh, *, degree: int, dual: str = "voronoi", inverse: bool = False) -> Float[Array, " n"]:
    """Diagonal of the Hodge star `*_degree` of a tet mesh (or of its inverse), as a vector.

    Zero entries invert to zero. Differentiable in the vertex positions. The surface counterpart is
    `ddgjax.dec.hodge_star_entries`. Reference: Desbrun, Hirani, Leok, Marsden, *Discrete Exterior
    Calculus* (2005), section 4; libigl has no tet Hodge stars (its `massmatrix` is `*0`, `-cotmatrix`
    is `d0^T *1 d0`).

    Args:
        tet_mesh: the tet mesh.
        degree: 0..3 (keyword-only): vertex dual volumes, dual face area over edge length, dual edge
            length over triangle area, `1 / volume` (module docstring).
        dual: `"voronoi"` (default), `"circumcentric"` or `"barycentric"` (`TET_DUALS`; keyword-only); `*3` does
            not depend on it, and `"voronoi"` differs from `"circumcentric"` in `*0` only.
        inverse: `True` for the entries of the inverse star (keyword-only; default `False`).

    Returns:
        Float array of shape `(nv,)`, `(ne,)`, `(ntri,)` or `(nt,)` for `degree` 0, 1, 2 or 3.
    """
    tet_mesh = require_tet_mesh("tet_mesh", tet_mesh)
    check_choice("dual", dual, TET_DUALS)
    check_choice("degree", degree, (0, 1, 2, 3))
    if degree == 0:
        entries = vertex_dual_volumes(tet_mesh, dual=dual)
    elif degree == 1:
        entries = _edge_star(tet_mesh, tet_incidence(tet_mesh), dual=dual)
    elif degree == 2:
        entries = _triangle_star(tet_mesh, tet_incidence(tet_mesh), dual=dual)
    else:
        volumes = tet_volumes(tet_mesh)
        return volumes if inverse else safe_reciprocal(volumes)
    return safe_reciprocal(entries) if inverse else entries


def hodge0(tet_mesh: TetMesh, *, dual: str = "voronoi", inverse: bool = False) -> SparseMatrix:
    """Hodge star on 0-forms, diagonal `(nv, nv)`: the vertex dual volumes (`vertex_dual_volumes`).

    `"voronoi"` (default) is libigl's Voronoi mass matrix (`mass_matrix(tet_mesh)`), `"barycentric"`
    its barycentric one; `"circumcentric"` entries can be negative.

    Args:
        tet_mesh: the tet mesh.
        dual: `"voronoi"` (default), `"circumcentric"` or `"barycentric"` (`TET_DUALS`; keyword-only).
        inverse: `True` for `*0^{-1}`, zero entries staying zero (keyword-only; default `False`).

    Returns:
        `(nv, nv)` diagonal `SparseMatrix`.
    """
    return diagonal_matrix(hodge_star_entries(tet_mesh, degree=0, dual=dual, inverse=inverse))


def hodge1(tet_mesh: TetMesh, *, dual: str = "voronoi", inverse: bool = False) -> SparseMatrix:
    """Hodge star on 1-forms, diagonal `(ne, ne)`: dual face area over edge length.

    Voronoi (default) and circumcentric: the summed cotan weight `sum_t l_kl cot(theta_kl) / 6` of
    each edge, so `d0^T *1 d0 == cotan_laplacian` (`== -igl.cotmatrix(V, T)`); barycentric: through
    the face and tet centroids (module docstring).

    Args:
        tet_mesh: the tet mesh.
        dual: `"voronoi"` (default), `"circumcentric"` or `"barycentric"` (`TET_DUALS`; keyword-only).
        inverse: `True` for `*1^{-1}`, zero entries staying zero (keyword-only; default `False`).

    Returns:
        `(ne, ne)` diagonal `SparseMatrix`.
    """
    return diagonal_matrix(hodge_star_entries(tet_mesh, degree=1, dual=dual, inverse=inverse))


def hodge2(tet_mesh: TetMesh, *, dual: str = "voronoi", inverse: bool = False) -> SparseMatrix:
    """Hodge star on 2-forms, diagonal `(ntri, ntri)`: dual edge length over triangle area.

    Voronoi (default) and circumcentric: signed circumcentre-to-circumcentre distances; barycentric:
    centroid distances (module docstring). Reference: Desbrun et al., *Discrete Exterior Calculus* (2005), section 4.

    Args:
        tet_mesh: the tet mesh.
        dual: `"voronoi"` (default), `"circumcentric"` or `"barycentric"` (`TET_DUALS`; keyword-only).
        inverse: `True` for `*2^{-1}`, zero entries staying zero (keyword-only; default `False`).

    Returns:
        `(ntri, ntri)` diagonal `SparseMatrix`.
    """
    return diagonal_matrix(hodge_star_entries(tet_mesh, degree=2, dual=dual, inverse=inverse))


def hodge3(tet_mesh: TetMesh, *, inverse: bool = False) -> SparseMatrix:
    """Hodge star on 3-forms, diagonal `(nt, nt)`: `1 / volume` (a tet's dual is a point); `inverse=True` the volumes.

    Zero-volume tets get 0 (pseudo-inverse). Reference: Desbrun et al., *Discrete Exterior Calculus* (2005).

    Args:
        tet_mesh: the tet mesh.
        inverse: `True` for `*3^{-1}`, the tet volumes (keyword-only; default `False`).

    Returns:
        `(nt, nt)` diagonal `SparseMatrix`.
    """
    return diagonal_matrix(hodge_star_entries(tet_mesh, degree=3, inverse=inverse))
