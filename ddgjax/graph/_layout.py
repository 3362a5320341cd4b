"""Graph drawing: the spectral layout (Koren 2005) and Tutte's barycentric layout of planar graphs.

Spectral layout: the coordinates are the generalized eigenvectors `2 .. dim + 1` of

    L x = lambda D x,      x^T D x = 1,

(`L = D - W`, `D` the weighted degrees), Koren's degree-normalized eigenvectors: they minimise
`sum_edges w_ij |x_i - x_j|^2` subject to `x^T D x = 1` and `x^T D 1 = 0` (D-orthogonal to the
constant, the trivial eigenvector `x_1`), which keeps low-degree vertices from crowding the
centre. networkx's `spectral_layout` uses the plain (unnormalized) Laplacian, `L x = lambda x`, and
rescales to `[-scale, scale]`; the two agree up to a scale on a regular graph (constant `D`).

Tutte's layout: the boundary cycle fixed on a convex polygon (default the unit circle at equal angles)
and every other vertex at the weighted mean of its neighbours, one sparse solve
(`harmonic_interpolation`). For a 3-connected planar graph whose boundary is a face cycle, and positive
edge_weights, the drawing is planar with convex faces (Tutte 1963; Floater 1997 for edge_weights).

References: Y. Koren, "Drawing graphs by eigenvectors: theory and practice" (Computers & Mathematics
with Applications, 2005); W. T. Tutte, "How to draw a graph" (1963); M. S. Floater, "Parametrization
and smooth approximation of surface triangulations" (1997).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int

from .._errors import DDGInputError, check_count, check_vertex_indices, first_indices
from .._results import Solution, outcome
from ..sparse import diagonal_matrix
from ..spectral import smallest_eigenpairs
from ._laplacian import check_weights, graph_structure, laplacian_from_plan, weighted_components
from ._learning import harmonic_interpolation


def spectral_layout(
    edges: Int[ArrayLike, "ne 2"],
    *,
    edge_weights: Float[ArrayLike, " ne"] | None = None,
    n_vertices: int,
    dim: int = 2,
    throw: bool = True,
) -> Float[Array, "n dim"] | Solution:
    """Koren's spectral drawing: the generalized eigenvectors `2 .. dim + 1` of `L x = lambda D x` (module docstring).

    Column `c` is the eigenvector of the `(c + 2)`-th smallest eigenvalue, D-normalized
    (`x^T D x = 1`, `x^T D 1 = 0`), with the sign of `ddgjax.spectral.smallest_eigenpairs` (its entry of
    largest magnitude positive). Differentiable in `edge_weights` (the eigenvector adjoint of
    `smallest_eigenpairs`): any function invariant to the sign of each column (and to rotations within a
    repeated eigenvalue, e.g. the two axes of a cycle) gets its exact gradient.

    Args:
        edges: `(ne, 2)` undirected edges of a connected graph (host data).
        edge_weights: `(ne,)` positive edge weights (default ones).
        n_vertices: the number of vertices, at least `dim + 2`.
        dim: the dimension of the drawing (default 2).
        throw: raise when the eigensolver fails (default), or return a `ddgjax.Solution` (`stats`:
            the eigen-residual, `smallest_eigenpairs`).

    Returns:
        `(n_vertices, dim)` coordinates.

    Raises `DDGInputError` for a disconnected graph (draw each component apart: its eigenvalue 0 is
    repeated, so the drawing would be undefined) and for `n_vertices < dim + 2`.

    networkx: `nx.spectral_layout(G, dim=dim)` uses `L x = lambda x` instead, rescaled (module docstring).
    """
    structure = graph_structure(edges, n_vertices)
    edge_weights = check_weights(edge_weights, structure.n_edges)
    dim = check_count("dim", dim, minimum=1)
    if structure.n_vertices < dim + 2:
        raise DDGInputError(
            f"n_vertices: a {dim}-d spectral layout needs at least dim + 2 = {dim + 2} vertices, got {n_vertices}"
        )
    n_components, _, cut = weighted_components(structure, edge_weights)
    if n_components > 1:
        joined = " (counting only edges of positive weight: an edge of weight 0 joins nothing)" if cut else ""
        raise DDGInputError(
            f"edges: the graph has {n_components} connected components{joined}; a spectral layout needs a connected "
            "graph (lay out each component apart)"
        )
    laplacian = laplacian_from_plan(edge_weights, structure.plan)
    degrees = diagonal_matrix(laplacian.diagonal(), positive_semidefinite=True)
    solution = smallest_eigenpairs(laplacian, degrees, dim + 1, throw=False)
    return outcome(solution.value.vectors[:, 1:], solution.result, throw, solution.stats)


def tutte_layout(
    edges: Int[ArrayLike, "ne 2"],
    *,
    fixed_vertices: Int[ArrayLike, " nb"],
    fixed_values: Float[ArrayLike, "nb 2"] | None = None,
    edge_weights: Float[ArrayLike, " ne"] | None = None,
    n_vertices: int,
    solver: str = "auto",
    throw: bool = True,
) -> Float[Array, "n 2"] | Solution:
    r"""Tutte's barycentric embedding: the boundary cycle on a convex polygon, every other vertex the mean of its neighbours.

    $$x_i = b_i \quad \text{at a fixed vertex } i, \qquad \sum_j w_{ij} (x_i - x_j) = 0 \quad \text{elsewhere},$$

    with `b` the `fixed_values` (`harmonic_interpolation` with
    two columns): for a 3-connected planar graph with `fixed_vertices` a face cycle, positive edge weights and
    `fixed_values` a convex polygon in the cycle's order, no two edges cross (Tutte 1963,
    Floater 1997). A component without a boundary vertex is placed at the origin. Differentiable in
    `edge_weights` and `fixed_values`.

    Args:
        edges: `(ne, 2)` undirected edges (host data).
        fixed_vertices: `(nb,)` distinct vertices in cycle order, `nb >= 3`, each joined by an edge to the
            next (and the last to the first).
        fixed_values: `(nb, 2)` their positions (a convex polygon, in the same order); default
            the unit circle at equal angles, `(cos 2 pi k / nb, sin 2 pi k / nb)`, counterclockwise.
        edge_weights: `(ne,)` positive edge weights (default ones: Tutte's barycentric weights).
        n_vertices: the number of vertices.
        solver: the backend of the linear solve, one of `ddgjax.LINEAR_SOLVERS`.
        throw: raise on a failed solve (default), or return a `ddgjax.Solution`.

    Returns:
        `(n_vertices, 2)` positions.

    On a mesh, `ddgjax.param.tutte_embedding(mesh, shape=positions)` with the mesh's boundary loop gives
    the same drawing (its default circle spaces the boundary by arc length instead). networkx has no
    Tutte layout (`nx.planar_layout` draws by a combinatorial embedding).

    Examples:
        >>> import numpy as np
        >>> import jax.numpy as jnp
        >>> import ddgjax
        >>> rim = np.arange(1, 7)  # a wheel: hub 0, rim 1 to 6
        >>> edges = np.concatenate([np.stack([np.zeros(6, int), rim], 1), np.stack([rim, np.roll(rim, -1)], 1)])
        >>> xy = ddgjax.graph.tutte_layout(edges, fixed_vertices=rim, n_vertices=7)
        >>> xy.shape, bool(jnp.allclose(xy[0], 0.0))  # the hub at the centre of the rim's hexagon
        ((7, 2), True)
    """
    structure = graph_structure(edges, n_vertices)
    n = structure.n_vertices
    boundary = check_vertex_indices("fixed_vertices", fixed_vertices, n, minimum=3)  # a simple cycle
    pair_keys = structure.pairs[:, 0] * n + structure.pairs[:, 1]
    following = np.roll(boundary, -1)
    keys = np.minimum(boundary, following).astype(np.int64) * n + np.maximum(boundary, following)
    found = np.searchsorted(pair_keys, keys)
    missing = (found >= pair_keys.size) | (pair_keys[np.minimum(found, max(pair_keys.size - 1, 0))] != keys)
    if missing.any():
        raise DDGInputError(
            f"fixed_vertices: consecutive boundary vertices must be joined by an edge (a cycle of the graph, in order); "
            f"no edge from boundary positions {first_indices(missing)} to the next"
        )
    if fixed_values is None:
        angles = 2 * np.pi * np.arange(boundary.size) / boundary.size
        dtype = check_weights(edge_weights, structure.n_edges).dtype
        fixed_values = jnp.asarray(np.stack([np.cos(angles), np.sin(angles)], axis=1), dtype)
    elif np.shape(fixed_values) != (boundary.size, 2):
        raise DDGInputError(f"fixed_values: expected shape ({boundary.size}, 2), got {np.shape(fixed_values)}")
    return harmonic_interpolation(
        edges,
        fixed_vertices=boundary,
        fixed_values=fixed_values,
        edge_weights=edge_weights,
        n_vertices=n_vertices,
        solver=solver,
        throw=throw,
    )
