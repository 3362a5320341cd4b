"""Dual cells of a tetrahedral mesh: the volume of each vertex's dual cell (`*0`), for the mass matrices and DEC.

Every dual `dual=` (`TET_DUALS`, the names of the surface duals of `ddgjax.dec`) picks a centre in
each tet and in each of its triangles (edges keep their midpoints), and the cell of vertex `i` in a
tet is the polyhedron with corners `p_i`, the three edge midpoints `m_ij`, the centres of the three
triangles at `i` and the tet's centre. In barycentric coordinates of the tet, with `beta` those of
the tet centre and `gamma_k` those of the centre of the triangle opposite `k` (`gamma_k[k] = 0`), the
piece `(p_i, m_ij, c_k, c)` of that cell has volume `V / 2 beta_k gamma_k[l]` (a 4 x 4 determinant of
barycentric coordinates; `kl` the edge opposite `ij`), and the same piece mirrored at `j` has the
same volume, so

    x_ij = V / 2 (beta_k gamma_k[l] + beta_l gamma_l[k]),    |cell_i| = sum_{tets} sum_{j ~ i} x_ij,

the row sums of per-tet edge values on the vertex pattern: one fixed gather (`tet_plan`), as the
Laplacian is assembled. The four cells of a tet sum to `V`, so the volumes sum to the solid's. The centres:

- `"barycentric"`: centroids (`beta = 1/4`, `gamma = 1/3`): `x_ij = V / 12`, a quarter of each tet
  per vertex (libigl `MASSMATRIX_TYPE_BARYCENTRIC`).
- `"circumcentric"`: circumcentres, the dual of Desbrun et al. 2005: signed, negative next to tets
  and triangles that do not contain their circumcentre, and unbounded as a tet flattens (its
  circumcentre runs off; an exactly flat tet contributes 0). In 3-D this is *not* `sum_j l_ij^2 w_ij / 6`
  (`w` the cotan weights): that sum is `V (1 - beta_i) / 3`, a third of each circumcentric sub-tet
  `(c, triangle)` per triangle vertex, which the circumcentric cell only equals for a regular tet
  (a Kuhn tet gives its first vertex `V / 8`, not `V / 6`).
- `"voronoi"` (default): libigl's hybrid Voronoi volume (`voronoi_mass`, i.e.
  `massmatrix(V, T, MASSMATRIX_TYPE_VORONOI)`): circumcentres, where a triangle circumcentre
  outside its triangle snaps to the midpoint of the edge opposite its most negative barycentric
  coordinate, and a tet circumcentre outside the tet snaps to the (snapped) centre of the triangle
  opposite its most negative barycentric coordinate. Never negative; equal to the circumcentric
  dual where nothing snaps.

The circumcentres' barycentric coordinates come from the squared edge lengths alone (intrinsic
core): `c = 1/2 sum_i |p_i|^2 grad phi_i` (the gradient of the linear interpolant of `|x|^2`), so
`beta_j = 1 - sum_i l_ij^2 w_ij / (2 V)`; a triangle `(p, q, r)` with opposite squared lengths
`(a, b, c)` has its circumcentre at coordinates proportional to `(a (b + c - a), b (c + a - b),
c (a + b - c))`. The snapping makes the Voronoi volume piecewise smooth in the vertex positions;
zero-volume tets contribute 0 with finite values and gradients (`safe_div`).

Reference: Desbrun, Hirani, Leok, Marsden, *Discrete Exterior Calculus* (2005) for the circumcentric
dual; Meyer, Desbrun, Schroeder, Barr (2003) for the hybrid Voronoi idea; libigl `voronoi_mass`.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._compile import kernel
from .._errors import check_choice
from .._numerics import safe_div
from .._options import DUAL_CELLS
from ._geometry import tet_cotan_weights_from_lengths_sq, tet_edge_lengths_sq, tet_volumes, tet_volumes_from_lengths_sq
from ._plan import TetPlan, row_sums, slot_values, tet_plan
from ._tet_mesh import TetMesh
from ._topology import TET_EDGES, TET_TRIANGLES

#: The duals of a tet mesh (`dual=`): the names and meanings of the surface duals (`ddgjax.dec`).
TET_DUALS = DUAL_CELLS

# Local edge of each pair of local vertices, the edge opposite each local edge, and per local
# triangle the local edges opposite its three corners.
_EDGE_OF = np.full((4, 4), -1, dtype=np.int32)
_EDGE_OF[TET_EDGES[:, 0], TET_EDGES[:, 1]] = _EDGE_OF[TET_EDGES[:, 1], TET_EDGES[:, 0]] = np.arange(6)
_OPPOSITE_EDGE = (np.arange(6) + 3) % 6
_TRIANGLE_OPPOSITE_EDGES = _EDGE_OF[np.roll(TET_TRIANGLES, -1, axis=1), np.roll(TET_TRIANGLES, -2, axis=1)]
# (4, 3, 4) one-hot: corner r of local triangle k is local vertex TET_TRIANGLES[k, r].
_TRIANGLE_CORNERS = np.eye(4)[TET_TRIANGLES]
# (6, 4) one-hot pair: the two local vertices of each local edge.
_EDGE_ENDS = np.eye(4)[TET_EDGES].sum(axis=1)


def _vertex_shares(edge_shares: Float[Array, "nt 6"]) -> Float[Array, "nt 4"]:
    """`(nt, 4)` per tet vertex, the sum of the per-edge values of its three edges."""
    return edge_shares @ jnp.asarray(_EDGE_ENDS, edge_shares.dtype)


def tet_circumcenter_coordinates(lengths_sq: Float[Array, "nt 6"], volumes: Float[Array, " nt"]) -> Float[Array, "nt 4"]:
    """`(nt, 4)` barycentric coordinates of each tet's circumcentre: `beta_j = 1 - sum_i l_ij^2 w_ij / (2 V)`.

    Module docstring; zero on a zero-volume tet (whose circumcentre is at infinity or undefined).
    """
    weights = tet_cotan_weights_from_lengths_sq(lengths_sq, volumes=volumes)
    return jnp.where(volumes[:, None] != 0, 1.0 - safe_div(_vertex_shares(lengths_sq * weights), 2.0 * volumes[:, None]), 0.0)


def _face_circumcenters(lengths_sq: Float[Array, "nt 6"], *, snap: bool) -> Float[Array, "nt 4 4"]:
    """`(nt, 4, 4)` row `k`: tet barycentric coordinates of the circumcentre of the triangle opposite `k` (snapped: libigl's)."""
    opposite = lengths_sq[:, _TRIANGLE_OPPOSITE_EDGES]  # (nt, 4, 3) the squared length opposite each corner
    weights = opposite * (jnp.sum(opposite, axis=-1, keepdims=True) - 2.0 * opposite)
    coordinates = safe_div(weights, jnp.sum(weights, axis=-1, keepdims=True))  # 0 on a zero-area triangle
    if snap:  # outside the triangle: the midpoint of the edge opposite the most negative coordinate
        midpoints = 0.5 * (1.0 - jax.nn.one_hot(jnp.argmin(coordinates, axis=-1), 3, dtype=coordinates.dtype))
        coordinates = jnp.where(jnp.min(coordinates, axis=-1, keepdims=True) < 0, midpoints, coordinates)
    return jnp.einsum("tkr,krj->tkj", coordinates, jnp.asarray(_TRIANGLE_CORNERS, coordinates.dtype))


def _centres(lengths_sq: Float[Array, "nt 6"], volumes: Float[Array, " nt"], dual: str):
    """`(beta, gamma)`: barycentric coordinates `(nt, 4)` of each tet's centre and `(nt, 4, 4)` of its triangles' (module docstring)."""
    if dual == "barycentric":
        faces = jnp.broadcast_to(jnp.asarray((1.0 - np.eye(4)) / 3.0, lengths_sq.dtype), (lengths_sq.shape[0], 4, 4))
        return jnp.full((lengths_sq.shape[0], 4), 0.25, lengths_sq.dtype), faces
    faces = _face_circumcenters(lengths_sq, snap=dual == "voronoi")
    beta = tet_circumcenter_coordinates(lengths_sq, volumes)
    if dual == "voronoi":  # outside the tet: the snapped centre of the triangle opposite the most negative coordinate
        nearest_face = jnp.take_along_axis(faces, jnp.argmin(beta, axis=-1)[:, None, None], axis=1)[:, 0]
        beta = jnp.where(jnp.min(beta, axis=-1, keepdims=True) < 0, nearest_face, beta)
    return beta, faces


def tet_edge_dual_volumes_from_lengths_sq(
    lengths_sq: Float[Array, "nt 6"], *, dual: str = "voronoi", volumes: Float[Array, " nt"] | None = None
) -> Float[Array, "nt 6"]:
    """`(nt, 6)` per tet edge `ij`, the volume `x_ij` that the dual cell of each of its two ends takes next to it.

    `x_ij = V / 2 (beta_k gamma_k[l] + beta_l gamma_l[k])` (module docstring, `dual` picks the
    centres); the dual volume of local vertex `i` in the tet is `sum_{j != i} x_ij`
    (`tet_vertex_dual_volumes_from_lengths_sq`), the four summing to `V`. Edges in the local order
    `TET_EDGES`. Reference: Desbrun et al., *Discrete Exterior Calculus* (2005) (circumcentric dual);
    libigl `voronoi_mass` (the snapped centres of `"voronoi"`).

    Args:
        lengths_sq: `(nt, 6)` squared edge lengths of each tet in the local order `TET_EDGES`.
        dual: `"voronoi"` (default), `"circumcentric"` or `"barycentric"` (`TET_DUALS`; keyword-only): the centres.
        volumes: `(nt,)` tet volumes (keyword-only); default `None`: `tet_volumes_from_lengths_sq(lengths_sq)`.

    Returns:
        `(nt, 6)` float array, column `k` the share `x_ij` of the local edge `TET_EDGES[k]`.
    """
    check_choice("dual", dual, TET_DUALS)
    if volumes is None:
        volumes = tet_volumes_from_lengths_sq(lengths_sq)
    beta, faces = _centres(lengths_sq, volumes, dual)
    pieces = beta[:, :, None] * faces  # [k, l]: 2 / V times the piece next to triangle k at the edge opposite kl
    k, other = TET_EDGES[_OPPOSITE_EDGE, 0], TET_EDGES[_OPPOSITE_EDGE, 1]
    return 0.5 * volumes[:, None] * (pieces[:, k, other] + pieces[:, other, k])


def tet_vertex_dual_volumes_from_lengths_sq(
    lengths_sq: Float[Array, "nt 6"], *, dual: str = "voronoi", volumes: Float[Array, " nt"] | None = None
) -> Float[Array, "nt 4"]:
    """`(nt, 4)` the volume of each tet's part of the dual cell of each of its vertices, from the six squared lengths.

    The intrinsic core of `vertex_dual_volumes` (module docstring for `dual`); each row sums to the
    tet's volume. libigl: the per-tet terms of `voronoi_mass` (`"voronoi"`).

    Args:
        lengths_sq: `(nt, 6)` squared edge lengths of each tet in the local order `TET_EDGES`.
        dual: `"voronoi"` (default), `"circumcentric"` or `"barycentric"` (`TET_DUALS`; keyword-only).
        volumes: `(nt,)` tet volumes (keyword-only); default `None`: `tet_volumes_from_lengths_sq(lengths_sq)`.

    Returns:
        `(nt, 4)` float array, column `k` the share of local vertex `k`.
    """
    return _vertex_shares(tet_edge_dual_volumes_from_lengths_sq(lengths_sq, dual=dual, volumes=volumes))


@kernel(static_argnames=("dual",))
def _vertex_dual_volumes(tet_mesh: TetMesh, plan: TetPlan, *, dual: str) -> Float[Array, " nv"]:
    shares = tet_edge_dual_volumes_from_lengths_sq(tet_edge_lengths_sq(tet_mesh), dual=dual, volumes=tet_volumes(tet_mesh))
    return row_sums(slot_values(shares, plan), plan)


def vertex_dual_volumes(tet_mesh: TetMesh, *, dual: str = "voronoi") -> Float[Array, " nv"]:
    """`(nv,)` the volume of each vertex's dual cell (the Hodge star `*0`); they sum to the solid's volume.

    Unreferenced vertices get 0. Differentiable in the vertex positions (piecewise for `"voronoi"`: its
    snapping switches where a circumcentre crosses a face or edge); zero-volume tets contribute 0 with
    finite gradients.

    libigl: `igl.massmatrix(V, T, igl.MASSMATRIX_TYPE_VORONOI).diagonal()` (`"voronoi"`),
    `MASSMATRIX_TYPE_BARYCENTRIC` (`"barycentric"`); `ddgjax.volume.mass_matrix(mass=)` wraps the two.

    Args:
        tet_mesh: the tet mesh.
        dual: the dual cell (keyword-only, `TET_DUALS`; module docstring): `"voronoi"` (default; libigl's hybrid
            Voronoi volume, never negative), `"circumcentric"` (the circumcentric dual cell, signed: negative next
            to tets and triangles that do not contain their circumcentre) or `"barycentric"` (a quarter of each
            incident tet).

    Returns:
        `(nv,)` float array of dual volumes, summing to the solid's volume.
    """
    check_choice("dual", dual, TET_DUALS)
    return _vertex_dual_volumes(tet_mesh, tet_plan(tet_mesh), dual=dual)
