"""Exterior derivatives `d0` (vertices -> edges) and `d1` (edges -> faces): signed incidence matrices.

Both are `SparseMatrix`es with constant +-1 values whose patterns are read straight from the mesh's
integer leaves (`mesh.edges`, `mesh.face_edges`), already in CSR order: the rows of `d0` are the
edges, whose columns `tail < head` are sorted by construction; the rows of `d1` are the faces, whose
three edge columns are put in increasing order by a comparison rank (three distinct integers per row),
not by a sort (`incidence_matrix`, shared with `ddgjax.volume`). Nothing is rebuilt on the host per call and nothing large is baked into a jit trace,
so these stay cheap to trace and compile on meshes with millions of faces.
"""

from __future__ import annotations

import jax.numpy as jnp

from ..mesh import Mesh, require_mesh
from ..sparse import SparseMatrix
from ..sparse.internal import incidence_matrix


def d0(mesh: Mesh) -> SparseMatrix:
    """Exterior derivative on 0-forms: the signed edge-vertex incidence matrix, `(ne, nv)`.

    $$(d_0 u)_e = u_h - u_t$$

    for edge $e = (t, h)$, `(tail, head)` of `mesh.edges` (oriented low -> high).
    Works on every mesh (non-manifold or non-orientable too): it needs only the edges. Values are
    `-1, +1` in the vertex dtype. Reference: Crane et al., *Digital Geometry Processing with Discrete
    Exterior Calculus* (SIGGRAPH course 2013), section 3.6. DDG exercises:
    `DEC::buildExteriorDerivative0Form` (opposite global sign). gpytoolbox: `dec_d0`, on its own edge
    order and orientation `E` (`halfedge_edge_map`) and with the opposite sign, `u[E0] - u[E1]`.

    Args:
        mesh: any triangle mesh.

    Returns:
        `(ne, nv)` `SparseMatrix` with entries `-1, +1`.

    Examples:
        >>> import jax.numpy as jnp
        >>> import ddgjax
        >>> sphere = ddgjax.mesh.icosphere(1)
        >>> d0, d1 = ddgjax.dec.d0(sphere), ddgjax.dec.d1(sphere)
        >>> d0.shape, d1.shape
        ((120, 42), (80, 120))
        >>> bool(jnp.all(d1.todense() @ d0.todense() == 0))  # d d = 0
        True
    """
    mesh = require_mesh("mesh", mesh)
    values = jnp.broadcast_to(jnp.asarray([-1.0, 1.0], mesh.vertices.dtype), mesh.edges.shape)
    return incidence_matrix(mesh.edges, values, mesh.n_vertices)


def d1(mesh: Mesh) -> SparseMatrix:
    """Exterior derivative on 1-forms: the signed face-edge incidence matrix, `(nf, ne)`.

    `(d1 a)_f = sum_k face_edge_signs[f, k] a[face_edges[f, k]]`: the circulation of the 1-form around
    face `f` in its own vertex order, each edge counted with +1 where the face runs it low -> high.
    `d1 @ d0 == 0` exactly. Needs consistently oriented faces (raises `MeshDataError` otherwise, via
    `topology.require_oriented`): on a non-orientable or inconsistently oriented mesh the result would
    depend on an arbitrary choice per face. DDG exercises: `DEC::buildExteriorDerivative1Form`;
    gpytoolbox: `dec_d1` (on its own edge order and orientation).

    Args:
        mesh: a consistently oriented triangle mesh (`MeshDataError` otherwise).

    Returns:
        `(nf, ne)` `SparseMatrix` with entries `-1, +1` in the vertex dtype.
    """
    mesh = require_mesh("mesh", mesh)
    mesh.topology.require_oriented("ddgjax.dec.d1")
    return incidence_matrix(mesh.face_edges, mesh.face_edge_signs.astype(mesh.vertices.dtype), mesh.n_edges)
