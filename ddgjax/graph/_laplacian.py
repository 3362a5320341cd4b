"""The combinatorial Laplacian `L = D - W` of a weighted undirected graph, on a pattern built once.

A graph is given as host data: `edges`, `(ne, 2)` integer vertex pairs of undirected edges, and the
vertex count `n_vertices=` (vertices without an edge are allowed: they are isolated). Its edge_weights
`(ne,)` are JAX values (default ones), the only thing that moves under `jit` / `grad` / `vmap`.

    (L u)_i = sum_{j ~ i} w_ij (u_i - u_j),   L = D - W,   D = diag(sum_j w_ij),

positive semidefinite (the sign of the mesh Laplacian, docs/conventions.md), `L 1 = 0`, and
`u^T L u = sum_edges w_ij (u_i - u_j)^2`. An edge listed more than once (in either orientation) is
one edge whose weight is the sum of its listed edge weights, as networkx sums the edges of a MultiGraph.

How it runs: the host checks the edges and builds, once per edge list (the last few are cached), the
vertex-vertex `SparsityPattern` (`SparsityPattern.from_edges`: the diagonal first, then both
directions of every distinct edge) and the map from listed edges to distinct ones; the values are then
one compiled segment-sum and gather of the edge weights, differentiable in them.

Reference: F. R. K. Chung, *Spectral Graph Theory* (AMS, 1997), ch. 1 (the combinatorial Laplacian);
U. von Luxburg, "A tutorial on spectral clustering" (2007), section 3.1.
"""

from __future__ import annotations

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse as sp
import scipy.sparse.csgraph as csgraph
from jaxtyping import Array, ArrayLike, Float, Int

from .._compile import device_array, kernel
from .._errors import DDGInputError, check_count, first_indices, is_traced
from .._indexing import take_rows_or_zero
from ..sparse import SparseMatrix, SparsityPattern


class GraphPlan(eqx.Module):
    """Device arrays of a graph's Laplacian assembly (built by `graph_structure`).

    Attributes:
        pattern: the `(n, n)` diagonal-first ELL pattern of `L`.
        source: `(pattern.nnz,)` the index of each storage slot in `[diagonal (n) | edges low->high
            (n_pairs) | edges high->low (n_pairs)]`, `n + 2 n_pairs` for padding.
        pair_of_edge: `(ne,)` the distinct edge each listed edge is summed into.
        pairs: `(n_pairs, 2)` the distinct edges, `low < high`, sorted.
    """

    pattern: SparsityPattern
    source: Int[Array, " nnz"]
    pair_of_edge: Int[Array, " ne"]
    pairs: Int[Array, "n_pairs 2"]


class GraphStructure:
    """Host facts about one edge list (cached per edge list by `graph_structure`; never inside jit).

    Attributes:
        n_vertices: the vertex count.
        n_edges: the number of listed edges (`ne`, the length of `edge_weights`).
        pairs: `(n_pairs, 2)` NumPy, the distinct edges `low < high`, sorted.
        plan: the `GraphPlan` (device arrays).
        labels: `(n,)` NumPy, the connected component of each vertex (isolated vertices are components).
        n_components: how many components.
        dirichlet: a small cache of `ddgjax.sparse.DirichletPlan`s per fixed vertex set (`ddgjax.graph._learning`).
    """

    def __init__(self, pairs: np.ndarray, pair_of_edge: np.ndarray, n_vertices: int):
        self.n_vertices = n_vertices
        self.n_edges = pair_of_edge.size
        self.pairs = pairs
        # Host work, also when a caller's trace is open: it depends on the connectivity only.
        with jax.ensure_compile_time_eval():
            pattern, source = SparsityPattern.from_edges(pairs, n_vertices)
            self.plan = GraphPlan(
                pattern=pattern,
                source=device_array(source.astype(np.int32)),
                pair_of_edge=device_array(pair_of_edge.astype(np.int32)),
                pairs=device_array(pairs.astype(np.int32)),
            )
        adjacency = sp.coo_matrix((np.ones(pairs.shape[0]), (pairs[:, 0], pairs[:, 1])), shape=(n_vertices, n_vertices))
        self.n_components, self.labels = csgraph.connected_components(adjacency, directed=False)
        self.dirichlet: dict = {}


# The structures of the last few edge lists: a loop over new edge weights (a gradient descent, a sweep) skips the host work.
_STRUCTURES_KEPT = 8


def graph_structure(edges, n_vertices) -> GraphStructure:
    """The checked `GraphStructure` of `edges` on `n_vertices` vertices (`DDGInputError` naming the argument)."""
    n_vertices = check_count("n_vertices", n_vertices, minimum=1)
    if is_traced(edges):
        raise DDGInputError(
            "edges: the edges decide the sparsity pattern, so they must be concrete host data (a NumPy array), "
            "not traced; make them outside jit and differentiate with respect to the edge weights"
        )
    edges = np.asarray(edges)
    if edges.ndim != 2 or edges.shape[1] != 2 or not (np.issubdtype(edges.dtype, np.integer) or edges.size == 0):
        raise DDGInputError(
            f"edges: expected an (ne, 2) integer array of vertex pairs, got shape {edges.shape} dtype {edges.dtype}"
        )
    edges = np.ascontiguousarray(edges, dtype=np.int64)
    return _structure(edges.tobytes(), edges.shape[0], n_vertices)


@functools.lru_cache(maxsize=_STRUCTURES_KEPT)
def _structure(edge_bytes: bytes, ne: int, n_vertices: int) -> GraphStructure:
    edges = np.frombuffer(edge_bytes, dtype=np.int64).reshape(ne, 2)
    outside = (edges < 0) | (edges >= n_vertices)
    if outside.any():
        raise DDGInputError(
            f"edges: vertex indices must lie in [0, n_vertices) = [0, {n_vertices}); out of range in rows "
            f"{first_indices(outside)} (pass the right n_vertices, or renumber the vertices)"
        )
    loops = edges[:, 0] == edges[:, 1]
    if loops.any():
        raise DDGInputError(
            f"edges: self-loops (i, i) at rows {first_indices(loops)}; remove them (they do not change L = D - W)"
        )
    low, high = edges.min(axis=1), edges.max(axis=1)
    keys, pair_of_edge = np.unique(low * n_vertices + high, return_inverse=True)
    pairs = np.stack([keys // n_vertices, keys % n_vertices], axis=1)
    return GraphStructure(pairs, pair_of_edge.reshape(-1), n_vertices)


def weighted_components(structure: GraphStructure, edge_weights) -> tuple[int, np.ndarray, bytes]:
    """`(n_components, labels, key)` of the graph whose edges have positive weight: an edge of weight 0 joins
    nothing, so a piece it alone connects to a fixed vertex is a component of its own (and gets 0, as a
    piece with no edges does). The edges' components (`key` empty) where every weight is positive, and
    for traced weights (no host values: a cut there leaves the system singular, a failed outcome)."""
    if is_traced(edge_weights):
        return structure.n_components, structure.labels, b""
    pair_weights = np.bincount(np.asarray(structure.plan.pair_of_edge), np.asarray(edge_weights), structure.pairs.shape[0])
    cut = pair_weights <= 0
    if not cut.any():
        return structure.n_components, structure.labels, b""
    kept = structure.pairs[~cut]
    n = structure.n_vertices
    adjacency = sp.coo_matrix((np.ones(kept.shape[0]), (kept[:, 0], kept[:, 1])), shape=(n, n))
    n_components, labels = csgraph.connected_components(adjacency, directed=False)
    return n_components, labels, np.packbits(cut).tobytes()


def check_weights(edge_weights, n_edges: int) -> Float[Array, " ne"]:
    """`edge_weights` as a floating JAX array of shape `(ne,)` (ones when `None`); concrete ones checked `>= 0` and finite."""
    if edge_weights is None:
        return device_array(np.ones(n_edges))  # made on the host: no eager program
    if np.shape(edge_weights) != (n_edges,):
        raise DDGInputError(f"edge_weights: expected shape ({n_edges},) (one per row of edges), got {np.shape(edge_weights)}")
    given, edge_weights = edge_weights, device_array(edge_weights)
    if not (jnp.issubdtype(edge_weights.dtype, jnp.floating) or jnp.issubdtype(edge_weights.dtype, jnp.integer)):
        raise DDGInputError(f"edge_weights: expected real numbers, got dtype {edge_weights.dtype}")
    if not jnp.issubdtype(edge_weights.dtype, jnp.floating):
        edge_weights = device_array(given, float)  # host data converted on the host
    if not is_traced(edge_weights):
        host = np.asarray(edge_weights)
        bad = ~np.isfinite(host) | (host < 0)
        if bad.any():
            raise DDGInputError(
                f"edge_weights: expected finite non-negative edge weights, got negative or NaN/inf ones at {first_indices(bad)}"
            )
    return edge_weights


def graph_laplacian(
    edges: Int[ArrayLike, "ne 2"], *, edge_weights: Float[ArrayLike, " ne"] | None = None, n_vertices: int
) -> SparseMatrix:
    r"""The combinatorial graph Laplacian `L = D - W`, positive semidefinite, as a `SparseMatrix`.

    $$\sum_j L_{ij} u_j = \sum_{j \sim i} w_{ij} (u_i - u_j), \qquad u^\top L u = \sum_{ij \in E} w_{ij} (u_i - u_j)^2:$$

    off-diagonal $L_{ij} = -w_{ij}$, diagonal the weighted
    degree $D_{ii} = \sum_j w_{ij}$, so $L\mathbf{1} = 0$. The sign
    is the mesh Laplacian's (docs/conventions.md): `L` is PSD, flagged symmetric positive
    semidefinite (so `ddgjax.solve` and `ddgjax.spectral` take it as it is). An edge listed more than
    once, in either orientation, counts once with the sum of its edge weights (networkx does the same for a
    MultiGraph). Differentiable in `edge_weights` (`jit`, `grad`, `vmap`); the edges are host data.

    Args:
        edges: `(ne, 2)` integer vertex pairs of undirected edges, in `[0, n_vertices)`, no
            self-loops (concrete host data).
        edge_weights: `(ne,)` non-negative edge weights (default ones); a JAX value, differentiable.
            Checked when concrete; traced edge weights are the caller's promise (negative ones would
            break the PSD flag).
        n_vertices: the number of vertices (isolated ones included: zero rows).

    Returns:
        `(n_vertices, n_vertices)` `SparseMatrix`, in the edge weights' dtype.

    Raises `DDGInputError` for malformed edges (shape, dtype, out of range, self-loops, traced),
    edge_weights of the wrong shape, negative or non-finite, and `n_vertices` not a positive integer.

    networkx: `nx.laplacian_matrix(G, weight="weight")`; SciPy: `scipy.sparse.csgraph.laplacian(W)`.

    Examples:
        >>> import numpy as np
        >>> import ddgjax
        >>> path = np.array([[0, 1], [1, 2]])
        >>> L = ddgjax.graph.graph_laplacian(path, edge_weights=np.array([1.0, 2.0]), n_vertices=3)
        >>> L.todense().tolist()
        [[1.0, -1.0, 0.0], [-1.0, 3.0, -2.0], [0.0, -2.0, 2.0]]
    """
    structure = graph_structure(edges, n_vertices)
    edge_weights = check_weights(edge_weights, structure.n_edges)
    return laplacian_from_plan(edge_weights, structure.plan)


@kernel
def laplacian_from_plan(edge_weights: Float[Array, " ne"], plan: GraphPlan) -> SparseMatrix:
    """`graph_laplacian`'s values on `plan.pattern` (one compiled program per size; used inside the package's kernels)."""
    n = plan.pattern.shape[0]
    n_pairs = plan.pairs.shape[0]
    pair_weights = jax.ops.segment_sum(edge_weights, plan.pair_of_edge, n_pairs)
    degrees = jax.ops.segment_sum(pair_weights, plan.pairs[:, 0], n) + jax.ops.segment_sum(pair_weights, plan.pairs[:, 1], n)
    entries = jnp.concatenate([degrees, -pair_weights, -pair_weights])
    values = take_rows_or_zero(entries, plan.source)
    return SparseMatrix(values, plan.pattern, symmetric=True, positive_semidefinite=True)
