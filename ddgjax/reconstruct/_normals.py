"""Consistently oriented PCA normals of a point cloud, for reconstructing a surface from points alone.

Each point's normal is the direction of least spread of its `k` nearest neighbours (PCA,
`ddgjax.pointcloud.point_cloud_normals`). Their signs are made consistent as Hoppe et al. 1992
propose: along a minimum spanning tree of the k-nearest-neighbour graph weighted by
`1 - |n_i . n_j|` (so the propagation crosses nearly parallel normals first and avoids the
ambiguous crossings of thin parts), each point takes its parent's side; each connected piece is
then turned so its normals point away from its centroid on the whole (outward on a closed surface).
The sign propagation is `ddgjax.pointcloud`'s (the frames of its vector heat method), on this tree.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse
import scipy.sparse.csgraph
from jaxtyping import Array, ArrayLike, Float

from .._errors import DDGInputError, is_traced
from ..pointcloud import point_cloud_normals
from ..pointcloud.internal import check_neighbors, check_points, forest_parents, nearest_neighbor_graph, oriented_frames


def estimate_normals(points: ArrayLike, /, *, n_neighbors: int = 30) -> Float[Array, "n 3"]:
    """`(n, 3)` unit normals of a point cloud, by PCA, oriented consistently (outward on a closed surface).

    The PCA normal of each point (the eigenvector of the smallest eigenvalue of its neighbours'
    covariance), with signs propagated along a minimum spanning tree of the k-nearest-neighbour graph
    weighted by `1 - |n_i . n_j|` (Hoppe et al. 1992), each connected piece turned to point away from
    its centroid on the whole (module docstring). Differentiable in `points` for the fixed
    neighbourhoods and signs (the signs are piecewise constant).

    Args:
        points: `(n, 3)` concrete finite positions.
        n_neighbors: the neighbourhood size `k` (keyword-only; default 30, Open3D's `KDTreeSearchParamKNN` and
            `ddgjax.pointcloud`'s).

    Returns:
        `(n, 3)` unit normals.

    Reference: H. Hoppe, T. DeRose, T. Duchamp, J. McDonald, W. Stuetzle, "Surface reconstruction from unorganized
    points", SIGGRAPH 1992. Open3D: `estimate_normals` then `orient_normals_consistent_tangent_plane(k)`.

    Examples:
        >>> import jax, numpy as np
        >>> jax.config.update("jax_enable_x64", True)
        >>> from ddgjax.mesh import icosphere
        >>> from ddgjax.reconstruct import estimate_normals
        >>> points = icosphere(3).vertices
        >>> normals = estimate_normals(points, n_neighbors=10)
        >>> bool(np.all(np.sum(np.asarray(normals) * np.asarray(points), axis=1) > 0.99))  # outward, radial
        True
    """
    points = check_points(points)
    if is_traced(points):
        raise DDGInputError("points: the neighbourhoods and the spanning tree are found on the host; pass concrete points")
    n = points.shape[0]
    n_neighbors = check_neighbors(n, n_neighbors)
    host = np.asarray(points, dtype=np.float64)
    neighbors = nearest_neighbor_graph(host, n_neighbors)
    normals = np.asarray(point_cloud_normals(points, neighbors=neighbors))
    parents, components = _spanning_tree(normals, neighbors)
    return oriented_frames(points, neighbors, parents, components).normal


def _spanning_tree(normals: np.ndarray, neighbors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`(parents, components)`: a minimum spanning forest of the kNN graph under `1 - |n_i . n_j|`, each tree rooted
    at its first point (a root is its own parent)."""
    n, k = neighbors.shape
    rows = np.repeat(np.arange(n), k)
    cols = neighbors.reshape(-1)
    # A small floor keeps every edge in the graph (a weight of exactly 0 reads as no edge).
    weights = 1.0 - np.abs(np.sum(normals[rows] * normals[cols], axis=1)) + 1e-9
    graph = scipy.sparse.coo_matrix((weights, (rows, cols)), shape=(n, n)).tocsr()
    return forest_parents(scipy.sparse.csgraph.minimum_spanning_tree(graph.maximum(graph.T)))
