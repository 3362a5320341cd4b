"""Graphs of point sets: k-nearest-neighbour and epsilon graphs with Gaussian edge weights.

The edges come from a neighbour search on the host (SciPy's `cKDTree`), so they are fixed host data;
the edge weights are a JAX function of the points (`gaussian_weights`), differentiable in them:

    w_ij = exp(-|p_i - p_j|^2 / (2 sigma^2)),

with `sigma` by default the mean length of the graph's edges (the mean neighbour distance, a scale
that follows the points: scaling the cloud leaves the edge weights unchanged). Both graphs are undirected:
the k-nearest-neighbour graph joins `i` and `j` when either is among the other's `n_neighbors`
nearest points (the symmetrised, "or" graph), the epsilon graph when `|p_i - p_j| <= radius`.

Reference: U. von Luxburg, "A tutorial on spectral clustering" (2007), section 2.2 (the graphs and
the Gaussian similarity). scikit-learn: `kneighbors_graph(X, n_neighbors, mode="distance")` made
symmetric (`maximum(A, A.T)`), `radius_neighbors_graph(X, radius)`.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
import numpy as np
import scipy.spatial
from jaxtyping import Array, ArrayLike, Float, Int

from .._compile import device_array, kernel
from .._errors import DDGInputError, check_count, check_float_array, check_positive, is_traced
from .._numerics import safe_sqrt


class WeightedEdges(NamedTuple):
    """A graph's edges and edge weights (unpacks as `edges, edge_weights = knn_graph(points)`).

    Attributes:
        edges: `(ne, 2)` NumPy int64 vertex pairs `i < j`, sorted, each edge once (host data).
        edge_weights: `(ne,)` JAX edge_weights, differentiable in the points.
    """

    edges: np.ndarray
    edge_weights: Float[Array, " ne"]


def knn_graph(
    points: Float[ArrayLike, "n d"], *, n_neighbors: int = 10, sigma: float | Float[ArrayLike, ""] | None = None
) -> WeightedEdges:
    r"""The symmetrised k-nearest-neighbour graph of a point set, with Gaussian edge weights (module docstring).

    $$w_{ij} = \exp\Bigl(-\frac{\lVert x_i - x_j \rVert^2}{2\sigma^2}\Bigr)$$

    `i` and `j` are joined when `j` is among the `n_neighbors` nearest other points of `i`, or `i`
    among those of `j`; each edge is listed once (`i < j`). A point is never its own neighbour, also
    when another point coincides with it. Ties at the `n_neighbors`-th distance are broken by the
    tree search.

    Args:
        points: `(n, d)` concrete coordinates (the search runs on the host; NaN / inf refused).
        n_neighbors: neighbours per point, `1 <= n_neighbors <= n - 1` (default 10, scikit-learn's
            `SpectralClustering` default).
        sigma: the Gaussian's width (a positive number, or a JAX scalar to differentiate); default
            the mean edge length (every weight 1 when all the points coincide).

    Returns:
        `WeightedEdges(edges, edge_weights)`; `edge_weights` is `gaussian_weights(points, edges, sigma=sigma)`.

    To differentiate in the points, find the edges once (here) and differentiate
    `gaussian_weights(points, edges)`: the search itself is not differentiable (it decides the edge count).
    scikit-learn: `kneighbors_graph(X, n_neighbors)` symmetrised with `maximum(A, A.T)`.

    Examples:
        >>> import numpy as np
        >>> import ddgjax
        >>> angles = np.linspace(0.0, 2 * np.pi, 12, endpoint=False)
        >>> points = np.stack([np.cos(angles), np.sin(angles)], axis=1)
        >>> graph = ddgjax.graph.knn_graph(points, n_neighbors=2)  # each point's two neighbours: a 12-cycle
        >>> graph.edges.shape, graph.edge_weights.shape
        ((12, 2), (12,))
        >>> L = ddgjax.graph.graph_laplacian(graph.edges, edge_weights=graph.edge_weights, n_vertices=12)
    """
    host = _host_points(points)
    n = host.shape[0]
    n_neighbors = check_count("n_neighbors", n_neighbors, minimum=1)
    if n_neighbors > n - 1:
        raise DDGInputError(f"n_neighbors: expected at most n - 1 = {n - 1} (the other points), got {n_neighbors}")
    _, found = scipy.spatial.cKDTree(host).query(host, k=n_neighbors + 1)
    others = found != np.arange(n)[:, None]
    # Each row holds its own index at most once: drop it, or the farthest when a tie with a coincident point hid it.
    others[others.all(axis=1), -1] = False
    neighbors = found[others].reshape(n, n_neighbors)
    tails = np.repeat(np.arange(n), n_neighbors)
    heads = neighbors.reshape(-1)
    edges = _distinct_pairs(tails, heads, n)
    return WeightedEdges(edges, gaussian_weights(points, edges, sigma=sigma))


def epsilon_graph(
    points: Float[ArrayLike, "n d"], *, radius: float, sigma: float | Float[ArrayLike, ""] | None = None
) -> WeightedEdges:
    """The epsilon graph of a point set: `i ~ j` when `|p_i - p_j| <= radius`, with Gaussian edge weights.

    Args:
        points: `(n, d)` concrete coordinates (host search; NaN / inf refused).
        radius: the connection radius, a positive number.
        sigma: the Gaussian's width; default the mean edge length (module docstring).

    Returns:
        `WeightedEdges(edges, edge_weights)`, edges `i < j` sorted; empty `(0, 2)` / `(0,)` when no two
        points are within `radius`.

    scikit-learn: `radius_neighbors_graph(X, radius)`; SciPy: `cKDTree(X).query_pairs(radius)`.
    """
    host = _host_points(points)
    radius = check_positive("radius", radius)
    pairs = scipy.spatial.cKDTree(host).query_pairs(radius, output_type="ndarray")
    edges = _distinct_pairs(pairs[:, 0], pairs[:, 1], host.shape[0])
    return WeightedEdges(edges, gaussian_weights(points, edges, sigma=sigma))


def gaussian_weights(
    points: Float[ArrayLike, "n d"],
    edges: Int[ArrayLike, "ne 2"],
    *,
    sigma: float | Float[ArrayLike, ""] | None = None,
) -> Float[Array, " ne"]:
    """The Gaussian (heat-kernel) edge_weights `w_ij = exp(-|p_i - p_j|^2 / (2 sigma^2))` of given edges.

    Differentiable in `points` (and in a JAX `sigma`), under `jit`, `grad` and `vmap`: the edge weights of
    `knn_graph` / `epsilon_graph` with their edges held fixed. Coincident points give weight 1 and
    finite gradients.

    Args:
        points: `(n, d)` coordinates (may be traced).
        edges: `(ne, 2)` integer vertex pairs (host data or a JAX array).
        sigma: the width, `> 0`; default the mean edge length `mean |p_i - p_j|` (the mean neighbour distance;
            when every edge has length 0, points that all coincide, every weight is 1).

    Returns:
        `(ne,)` edge_weights in `(0, 1]`, in the points' dtype.
    """
    if is_traced(points):
        if np.ndim(points) != 2:
            raise DDGInputError(f"points: expected shape (n, d), got {np.shape(points)}")
    else:
        _host_points(points)
    edges = device_array(edges)
    if edges.ndim != 2 or edges.shape[1] != 2 or not (jnp.issubdtype(edges.dtype, jnp.integer) or edges.size == 0):
        raise DDGInputError(f"edges: expected an (ne, 2) integer array, got shape {edges.shape} dtype {edges.dtype}")
    if sigma is not None and not is_traced(sigma):
        check_positive("sigma", sigma)
    points = device_array(points)
    if not jnp.issubdtype(points.dtype, jnp.floating):
        points = points.astype(float)
    return _gaussian(points, edges.astype(jnp.int32), sigma)


@kernel
def _gaussian(points, edges, sigma):
    lengths_sq = jnp.sum((points[edges[:, 0]] - points[edges[:, 1]]) ** 2, axis=-1)
    if edges.shape[0] == 0:
        return lengths_sq
    if sigma is None:
        mean = jnp.mean(safe_sqrt(lengths_sq))
        # Every edge of zero length (coincident points): each weight is exp(0) = 1 at any width, so any
        # positive one serves; the mean would give 0 / 0.
        sigma = jnp.where(mean > 0, mean, 1.0)
    return jnp.exp(-lengths_sq / (2 * jnp.asarray(sigma, points.dtype) ** 2))


def _host_points(points) -> np.ndarray:
    if is_traced(points):
        raise DDGInputError(
            "points: the neighbour search decides the edges, so the points must be concrete here; find the edges "
            "once outside jit and differentiate gaussian_weights(points, edges, sigma=...)"
        )
    if np.ndim(points) != 2:
        raise DDGInputError(f"points: expected shape (n, d), got {np.shape(points)}")
    return check_float_array("points", np.asarray(points), np.shape(points)[1:], min_rows=2).astype(np.float64)


def _distinct_pairs(tails: np.ndarray, heads: np.ndarray, n: int) -> np.ndarray:
    """`(ne, 2)` the distinct undirected pairs `low < high` of `(tails, heads)`, sorted."""
    low = np.minimum(tails, heads).astype(np.int64)
    high = np.maximum(tails, heads).astype(np.int64)
    # A sort and a comparison of neighbours: NumPy 2's `np.unique` of a million keys takes ~10x as long.
    keys = np.sort(low * n + high)
    keys = keys[np.concatenate([[True], keys[1:] != keys[:-1]])] if keys.size else keys
    return np.stack([keys // n, keys % n], axis=1)
