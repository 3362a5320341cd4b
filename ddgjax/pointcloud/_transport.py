"""Tangent frames and the connection Laplacian of a point cloud, for the vector heat method on it.

Each point `i` gets a frame `(e1_i, e2_i, n_i)`: `n_i` its PCA normal (`point_cloud_normals` on the
triangulation's neighbourhoods), oriented consistently, `e1_i` the world axis least aligned with
`n_i` made tangent and unit, `e2_i = n_i x e1_i`. A tangent vector `v` at `i` is the complex number
`z = v . e1_i + i v . e2_i`.

Orientation: the complex connection needs frames of one orientation on each connected part (a
sign flip of `n_j` turns the transport into a conjugation, which no complex number represents).
The signs propagate along a breadth-first spanning tree of the local triangles' edges, built on the
host from the topology alone: a point takes its parent's side (`n_i . n_parent >= 0`). The products
of the signs along the tree paths are found in JAX by pointer jumping (`ceil(log2 n) + 1` rounds), so
the frames follow the positions under `jit` / `grad` (the signs are piecewise constant). Each
connected part is then turned so that its normals point away from its centroid on the whole
(outward on a closed surface). A non-orientable cloud keeps some neighbours with opposite normals.

Connection (geometry-central's point-cloud connection, the Levi-Civita connection of the sampled
surface to first order): a vector at `j` goes to `i` by the minimal rotation taking `n_j` to `n_i`,
`R v = v + c x v + c x (c x v) / (1 + n_j . n_i)` with `c = n_j x n_i`, so `e1_j` arrives at the
angle `rho_ij` of `r_ij = R e1_j . e1_i + i R e1_j . e2_i` in frame `i`. The connection Laplacian
has the point-cloud Laplacian's weights (`w_ij = -L_ij >= 0` after intrinsic Delaunay flips) on the
cover's edges: `A_ij = L_ij r_ij`, `A_ii = L_ii`, Hermitian (`r_ji = conj r_ij`) and positive
semidefinite (`z^H A z = sum_{ij} w_ij |z_i - r_ij z_j|^2`), 0 on fields parallel along every edge.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse
import scipy.sparse.csgraph
from jaxtyping import Array, Float, Int

from .._indexing import take_rows
from .._numerics import safe_norm
from ..fields import TangentBases
from ..sparse import SparseMatrix
from ._laplacian import _normals
from ._triangulation import PointCloudTriangulation


def orientation_tree(triangulation: PointCloudTriangulation) -> tuple[Int[Array, " n"], Int[Array, " n"]]:
    """`(parents, components)` on the host: a breadth-first spanning forest of the local triangles' edges.

    `parents[i]` is `i`'s parent (a root is its own parent); `components[i]` its tree's label.
    """
    n = triangulation.n_points
    edges = np.asarray(triangulation.edges)
    graph = scipy.sparse.coo_matrix((np.ones(edges.shape[0]), (edges[:, 0], edges[:, 1])), shape=(n, n)).tocsr()
    parents, labels = forest_parents(graph)
    return jnp.asarray(parents), jnp.asarray(labels)


def forest_parents(graph: scipy.sparse.spmatrix) -> tuple[np.ndarray, np.ndarray]:
    """`(parents, components)`, `(n,)` int32 each, on the host: a breadth-first spanning forest of an undirected
    sparse graph (its stored entries are its edges), each tree rooted at its lowest-numbered vertex, which is its
    own parent; `components[i]` is `i`'s tree's label."""
    _, labels = scipy.sparse.csgraph.connected_components(graph, directed=False)
    parents = np.arange(graph.shape[0])
    _, roots = np.unique(labels, return_index=True)
    for root in roots:
        order, predecessors = scipy.sparse.csgraph.breadth_first_order(graph, root, directed=False, return_predecessors=True)
        parents[order[1:]] = predecessors[order[1:]]
    return parents.astype(np.int32), labels.astype(np.int32)


def oriented_frames(points, neighbors, parents, components) -> TangentBases:
    """The points' frames (module docstring), `TangentBases(e1, e2, normal)` of `(n, 3)` each."""
    n = points.shape[0]
    normals = _normals(points, neighbors)
    sign = jnp.where(jnp.sum(normals * take_rows(normals, parents), axis=-1) < 0, -1.0, 1.0).astype(points.dtype)
    jump = parents
    for _ in range(int(np.ceil(np.log2(max(n, 2)))) + 1):  # pointer jumping: products of the signs to the root
        sign = sign * sign[jump]
        jump = jump[jump]
    normals = jax.lax.stop_gradient(sign)[:, None] * normals
    centroids = (
        jax.ops.segment_sum(points, components, n) / jax.ops.segment_sum(jnp.ones(n, points.dtype), components, n)[:, None]
    )
    outward = jax.ops.segment_sum(jnp.sum(normals * (points - centroids[components]), axis=-1), components, n)
    normals = jnp.where(jax.lax.stop_gradient(outward)[components, None] < 0, -normals, normals)
    axes = jnp.eye(3, dtype=points.dtype)[jnp.argmin(jnp.abs(normals), axis=-1)]
    e1 = axes - jnp.sum(axes * normals, axis=-1, keepdims=True) * normals
    e1 = e1 / safe_norm(e1)[:, None]
    return TangentBases(e1, jnp.cross(normals, e1), normals)


def transport_coefficients(frames: TangentBases, rows, cols) -> Array:
    """`r_ij` (module docstring) for each `(i, j) = (rows, cols)`: the unit complex number taking frame `j` to frame `i`."""
    e1, e2, normal = frames
    n_from, n_to, e = take_rows(normal, cols), take_rows(normal, rows), take_rows(e1, cols)
    c = jnp.cross(n_from, n_to)
    # Opposite normals (a non-orientable cloud) have no minimal rotation: kept finite.
    denominator = jnp.maximum(1.0 + jnp.sum(n_from * n_to, axis=-1), 1e-12)[:, None]
    moved = e + jnp.cross(c, e) + jnp.cross(c, jnp.cross(c, e)) / denominator
    return jax.lax.complex(jnp.sum(moved * take_rows(e1, rows), axis=-1), jnp.sum(moved * take_rows(e2, rows), axis=-1))


def point_cloud_connection_laplacian(L: SparseMatrix, frames: TangentBases) -> SparseMatrix:
    """The complex connection Laplacian `A_ij = L_ij r_ij` on `L`'s pattern (module docstring), Hermitian PSD."""
    r = transport_coefficients(frames, L.pattern.rows, L.pattern.cols)
    return SparseMatrix(L.values * r, L.pattern, hermitian=True, positive_semidefinite=True)


def tangent_coordinates(vectors: Float[Array, "m 3"], frames: TangentBases, indices) -> Array:
    """World vectors at points `indices` as complex coordinates in their frames."""
    return jax.lax.complex(jnp.sum(vectors * frames.e1[indices], -1), jnp.sum(vectors * frames.e2[indices], -1))
