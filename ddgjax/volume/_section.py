"""The section of a tet mesh by a plane, as a triangle mesh carrying a piecewise-linear function (for drawing slices)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from jaxtyping import ArrayLike, Float

from .._errors import DDGInputError
from ..mesh import Mesh
from ._tet_mesh import TetMesh, require_tet_mesh
from ._topology import TET_EDGES

#: The local edge (`TET_EDGES` index) between local vertices `i` and `j` of a tet (diagonal unused).
_LOCAL_EDGE = np.zeros((4, 4), dtype=np.int64)
_LOCAL_EDGE[TET_EDGES[:, 0], TET_EDGES[:, 1]] = _LOCAL_EDGE[TET_EDGES[:, 1], TET_EDGES[:, 0]] = np.arange(6)
#: The three other local vertices of each local vertex.
_OTHERS = np.array([[j for j in range(4) if j != i] for i in range(4)])


class PlaneSection(NamedTuple):
    """What `plane_section` returns (unpacks as `section, values = plane_section(...)`).

    Attributes:
        mesh: the cut as a `ddgjax.Mesh`, one vertex per crossed edge of the tet mesh.
        values: `(n_points,)` or `(n_points, k)` the function interpolated linearly along those edges.
    """

    mesh: Mesh
    values: np.ndarray


def plane_section(
    tet_mesh: TetMesh,
    values: Float[ArrayLike, "nv *k"],
    *,
    point: tuple[float, float, float] | Float[ArrayLike, "3"] = (0.0, 0.0, 0.0),
    normal: tuple[float, float, float] | Float[ArrayLike, "3"] = (0.0, 0.0, 1.0),
) -> PlaneSection:
    """The plane through `point` with normal `normal` cut through `tet_mesh`, with `values` restricted to it.

    A tet crossed by the plane contributes a triangle (one vertex on one side) or two (a quad: two on
    each side), its normal along `normal`; the section's vertices are the crossing points of the tet mesh's edges, one per
    edge, so neighbouring tets share them and the result is a proper triangle mesh. A piecewise-
    linear function restricted to the plane is linear along each edge: its value at a crossing point
    `p = (1 - s) a + s b`, `s = d_a / (d_a - d_b)` (`d` the signed distances to the plane) is
    `(1 - s) u_a + s u_b`, exactly the restriction. Vertices on the plane count as on its positive
    side. Host work in NumPy (for figures: not differentiable); draw it with
    `ddgjax.plot.plot_mesh_function(ax, section.mesh, section.values)`.

    Args:
        tet_mesh: the tet mesh.
        values: `(nv,)` or `(nv, k)` values at its vertices.
        point: `(3,)` a point of the plane (default the origin).
        normal: `(3,)` its normal, any length but not zero (default +z).

    Returns:
        `PlaneSection(mesh, values)`. Raises `DDGInputError` when the plane misses the mesh.

    libigl: `igl.slice_tets(V, T, S)` (the same cut, from per-vertex signed distances `S`).
    """
    tet_mesh = require_tet_mesh("tet_mesh", tet_mesh)
    vertices = np.asarray(tet_mesh.vertices, dtype=float)
    values = np.asarray(values)
    if values.ndim not in (1, 2) or values.shape[0] != vertices.shape[0]:
        raise DDGInputError(f"values: expected shape ({vertices.shape[0]},) or ({vertices.shape[0]}, k), got {values.shape}")
    normal = np.asarray(normal, dtype=float)
    if normal.shape != (3,) or not np.linalg.norm(normal) > 0:
        raise DDGInputError(f"normal: expected a non-zero (3,) vector, got {normal!r}")
    point = np.asarray(point, dtype=float)
    if point.shape != (3,):
        raise DDGInputError(f"point: expected a (3,) point, got shape {point.shape}")
    distances = (vertices - point) @ (normal / np.linalg.norm(normal))
    below = distances < 0
    edges = np.asarray(tet_mesh.edges)
    crossed = below[edges[:, 0]] != below[edges[:, 1]]
    index = np.full(edges.shape[0], -1)
    index[crossed] = np.arange(crossed.sum())
    tail, head = edges[crossed, 0], edges[crossed, 1]
    s = distances[tail] / (distances[tail] - distances[head])
    weights = s.reshape((-1,) + (1,) * (values.ndim - 1))
    points = (1 - s[:, None]) * vertices[tail] + s[:, None] * vertices[head]
    point_values = (1 - weights) * values[tail] + weights * values[head]

    tet_points = index[np.asarray(tet_mesh.tet_edges)]  # (nt, 6) the section vertex on each local edge, or -1
    tet_below = below[np.asarray(tet_mesh.tets)]
    count = tet_below.sum(axis=1)
    triangles = []
    # One vertex alone on its side: the triangle on its three edges.
    alone_tets = np.flatnonzero((count == 1) | (count == 3))
    alone = np.argmax(tet_below[alone_tets] == (count[alone_tets] == 1)[:, None], axis=1)
    others = _OTHERS[alone]  # (n, 3) the other local vertices
    triangles.append(tet_points[alone_tets[:, None], _LOCAL_EDGE[alone[:, None], others]])
    # Two on each side (local a, b below, c, d above): the quad on edges a-c, a-d, b-d, b-c, in cyclic order.
    quad_tets = np.flatnonzero(count == 2)
    order = np.argsort(~tet_below[quad_tets], axis=1, kind="stable")  # the two below first
    a, b, c, d = order.T
    quad = tet_points[
        quad_tets[:, None], np.stack([_LOCAL_EDGE[a, c], _LOCAL_EDGE[a, d], _LOCAL_EDGE[b, d], _LOCAL_EDGE[b, c]], axis=1)
    ]
    triangles += [quad[:, [0, 1, 2]], quad[:, [0, 2, 3]]]
    triangles = np.concatenate(triangles)
    corners = points[triangles]
    flipped = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]) @ normal < 0
    triangles[flipped] = triangles[flipped][:, [0, 2, 1]]  # every triangle's normal along `normal`
    if triangles.shape[0] == 0:
        raise DDGInputError("point, normal: the plane does not cross the tet mesh")
    return PlaneSection(Mesh.from_arrays(points, triangles), point_values)
