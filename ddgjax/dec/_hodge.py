"""Diagonal Hodge stars `*0`, `*1`, `*2` on the Voronoi (mixed), circumcentric or barycentric dual, and their inverses.

Each star maps primal k-forms (integrated over k-simplices) to dual (2-k)-forms (integrated over the
dual cells) by the ratio `|dual cell| / |primal simplex|`:

- `*0`: vertex dual area (`|v| = 1`);
- `*1`: dual edge length over primal edge length;
- `*2`: one over the face area (the dual of a face is a point).

The dual is the keyword-only `dual=` shared with `ddgjax.mesh` (`ddgjax.dec` module docstring):
`"voronoi"` (default), `"circumcentric"` or `"barycentric"`; `*2` does not depend on it.

Inverses (`inverse=True`) take the reciprocal of each diagonal entry, with one policy everywhere:
**an exactly zero entry inverts to zero** (the Moore-Penrose pseudo-inverse of a diagonal matrix).
Zero entries are not rare: a circumcentric `*1` vanishes on every edge whose opposite angles sum to
pi (the diagonals of a right-triangle grid), and degenerate faces give zero areas. Negative entries
(circumcentric `*1` on non-Delaunay edges, circumcentric `*0` next to obtuse faces) are inverted as
they are. `*2` of a zero-area face is likewise 0 (its pseudo-inverse), consistent with the geometry
policy that degenerate faces contribute nothing; values and gradients stay finite.
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Float

from .._compile import kernel
from .._errors import check_choice
from .._indexing import take_rows
from .._numerics import safe_div, safe_norm, safe_reciprocal
from .._options import DUAL_CELLS
from ..mesh import Mesh, edge_cotan_weights, edge_lengths, face_areas, face_vertex_positions, require_mesh, vertex_dual_areas
from ..sparse import SparseMatrix, diagonal_matrix


@kernel(static_argnames=("dual",))
def edge_dual_length_ratios(mesh: Mesh, *, dual: str = "voronoi") -> Float[Array, " ne"]:
    """`|e*| / |e|` per edge, `(ne,)`: the diagonal of `*1`.

    - `"voronoi"` (default) and `"circumcentric"`: the dual edge joins the circumcentres of the
      adjacent faces, so `|e*| / |e| = (cot a + cot b) / 2` (`edge_cotan_weights`; one term on a
      boundary edge). Negative on non-Delaunay edges, zero where `a + b = pi`. The Voronoi dual
      differs from the circumcentric one in `*0` only, as libigl pairs its cotan Laplacian with
      the Voronoi mass matrix.
    - `"barycentric"`: the dual edge is the polyline from each adjacent face's barycentre to the edge
      midpoint (two segments on an interior edge, one on a boundary edge), so
      `|e*| = sum_f |c_f - m_e|`; always >= 0 (0 on a zero-length edge).

    Non-manifold edges get one term per face (`*1` itself needs no orientation).

    Args:
        mesh: any triangle mesh.
        dual: the dual cells, one of `ddgjax.DUAL_CELLS`: `"voronoi"` (default), `"circumcentric"` or
            `"barycentric"` (keyword-only, static; see above).

    Returns:
        `(ne,)` ratios, in `mesh.edges` order and the vertices' dtype.
    """
    check_choice("dual", dual, DUAL_CELLS)
    if dual != "barycentric":
        return edge_cotan_weights(mesh)
    barycentres = jnp.mean(face_vertex_positions(mesh), axis=1)
    midpoints = 0.5 * (take_rows(mesh.vertices, mesh.edges[:, 0]) + take_rows(mesh.vertices, mesh.edges[:, 1]))
    present = mesh.edge_faces >= 0
    segments = barycentres[jnp.where(present, mesh.edge_faces, 0)] - midpoints[:, None, :]
    dual_lengths = jnp.sum(jnp.where(present, safe_norm(segments), 0.0), axis=-1)
    return safe_div(dual_lengths, edge_lengths(mesh))


def hodge_star_entries(mesh: Mesh, *, degree: int, dual: str = "voronoi", inverse: bool = False) -> Float[Array, " n"]:
    """Diagonal of the Hodge star `*_k` (or of its inverse) on primal `degree`-forms, as a vector.

    Zero entries invert to zero (module docstring). See `hodge0`, `hodge1`, `hodge2` for the matrices and the
    orientation requirement of `*2`.

    Args:
        mesh: any triangle mesh; consistently oriented for `degree=2` (`MeshDataError` otherwise).
        degree: the degree of the primal forms, 0, 1 or 2 (keyword-only, as `codifferential`'s).
        dual: the dual mesh, one of `ddgjax.DUAL_CELLS`: `"voronoi"` (default; mixed areas for `*0`, the
            circumcentric `*1`: the pairing of libigl's cotan Laplacian with its Voronoi mass matrix),
            `"circumcentric"` or `"barycentric"` (keyword-only). `*2` does not depend on it.
        inverse: `True` for the diagonal of `*_k^{-1}` (keyword-only).

    Returns:
        The diagonal: vertex dual areas `(nv,)`, `|e*| / |e|` `(ne,)` or `1 / area` `(nf,)` for degree 0, 1, 2
        (their reciprocals with `inverse=True`).
    """
    mesh = require_mesh("mesh", mesh)
    check_choice("dual", dual, DUAL_CELLS)
    check_choice("degree", degree, (0, 1, 2))
    if degree == 0:
        entries = vertex_dual_areas(mesh, dual=dual)
    elif degree == 1:
        entries = edge_dual_length_ratios(mesh, dual=dual)
    else:
        mesh.topology.require_oriented("ddgjax.dec.hodge2")
        areas = face_areas(mesh)
        return areas if inverse else safe_reciprocal(areas)
    return safe_reciprocal(entries) if inverse else entries


def hodge0(mesh: Mesh, *, dual: str = "voronoi", inverse: bool = False) -> SparseMatrix:
    r"""Hodge star on primal 0-forms, diagonal `(nv, nv)` with entries `|v*|`, the vertex dual areas.

    $$(\star_0)_{ii} = \lvert v_i^\star \rvert$$

    Unreferenced vertices get 0 (and 0 in the inverse). Works on every mesh. Reference: Crane et al., *Digital
    Geometry Processing with Discrete Exterior Calculus* (2013), section 3.8.

    Args:
        mesh: any triangle mesh.
        dual: the dual cell (`ddgjax.mesh.vertex_dual_areas`), one of `ddgjax.DUAL_CELLS`: `"voronoi"` (default;
            mixed area, Meyer et al. 2003; always >= 0; libigl's Voronoi mass matrix, `ddgjax.laplacian.mass_matrix`),
            `"circumcentric"` (the DEC dual of Desbrun et al. 2005; negative shares on obtuse faces, so an entry can
            be <= 0) or `"barycentric"` (a third of each incident face: the DDG exercises' `hodge0`, gpytoolbox
            `dec_h0`) (keyword-only).
        inverse: `True` for `*0^{-1}`, zero entries staying zero (module docstring; keyword-only).

    Returns:
        `(nv, nv)` diagonal `SparseMatrix`.
    """
    mesh = require_mesh("mesh", mesh)
    return diagonal_matrix(hodge_star_entries(mesh, degree=0, dual=dual, inverse=inverse))


def hodge1(mesh: Mesh, *, dual: str = "voronoi", inverse: bool = False) -> SparseMatrix:
    r"""Hodge star on primal 1-forms, diagonal `(ne, ne)` with entries `|e*| / |e|`.

    Voronoi (default) and circumcentric:

    $$(\star_1)_{ee} = \frac{\lvert e^\star \rvert}{\lvert e \rvert} = \tfrac12 (\cot\alpha_e + \cot\beta_e),$$

    the cotan weight, so that the PSD cotan Laplacian is $L = d_0^\top \star_1 d_0$ (DESIGN.md). Barycentric: the
    dual edge runs through the adjacent face barycentres and the edge midpoint (see
    `edge_dual_length_ratios`). `inverse=True` gives $\star_1^{-1}$, zero entries staying zero (module
    docstring). Works on every mesh. Reference: Crane et al. 2013, section 3.8; Desbrun et al.,
    *Discrete Exterior Calculus* (2005). DDG exercises: `DEC::buildHodgeStar1Form`; gpytoolbox:
    `dec_h1` (circumcentric, its own edge order).

    Args:
        mesh: any triangle mesh.
        dual: the dual cells, one of `ddgjax.DUAL_CELLS`: `"voronoi"` (default), `"circumcentric"` or
            `"barycentric"` (keyword-only).
        inverse: `True` for `*1^{-1}` (keyword-only).

    Returns:
        `(ne, ne)` diagonal `SparseMatrix`.

    Examples:
        >>> import jax.numpy as jnp
        >>> import ddgjax
        >>> sphere = ddgjax.mesh.icosphere(1)
        >>> star1 = ddgjax.dec.hodge1(sphere)
        >>> d0 = ddgjax.dec.d0(sphere).todense()
        >>> L = ddgjax.laplacian.cotan_laplacian(sphere).todense()
        >>> star1.shape, bool(jnp.allclose(d0.T @ star1.todense() @ d0, L))  # L = d0^T *1 d0
        ((120, 120), True)
    """
    mesh = require_mesh("mesh", mesh)
    return diagonal_matrix(hodge_star_entries(mesh, degree=1, dual=dual, inverse=inverse))


def hodge2(mesh: Mesh, *, inverse: bool = False) -> SparseMatrix:
    r"""Hodge star on primal 2-forms, diagonal `(nf, nf)` with entries `1 / area_f`.

    $$(\star_2)_{ff} = 1 / \lvert f \rvert$$

    The dual of a face is a point, so `*2` turns a face integral into a point value (the mean density).
    Zero-area faces get 0 (pseudo-inverse, module docstring). Needs consistently oriented faces, since the
    sign of a 2-form on a face is relative to the face's orientation (raises `MeshDataError` otherwise). DDG
    exercises: `DEC::buildHodgeStar2Form`. gpytoolbox's `dec_h2` is the face area, i.e.
    `hodge2(mesh, inverse=True)` (and `dec_h2inv` is ours).

    Args:
        mesh: a consistently oriented triangle mesh (`MeshDataError` otherwise).
        inverse: `True` for `*2^{-1}`, the face areas (keyword-only).

    Returns:
        `(nf, nf)` diagonal `SparseMatrix`.
    """
    mesh = require_mesh("mesh", mesh)
    return diagonal_matrix(hodge_star_entries(mesh, degree=2, inverse=inverse))
