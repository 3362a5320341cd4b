"""networkx interop: a `networkx.Graph` to edges, edge weights and a vertex count, and back (networkx.org).

networkx is not a dependency of ddgjax: it is imported inside these two functions, and a missing
networkx is an `ImportError` saying how to install it.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
from jaxtyping import ArrayLike, Float, Int

from .._errors import DDGInputError
from ._laplacian import check_weights, graph_structure


class NetworkxGraph(NamedTuple):
    """A networkx graph as ddgjax takes graphs (unpacks as `edges, edge_weights, n_vertices, nodes = from_networkx(G)`).

    Attributes:
        edges: `(ne, 2)` NumPy int64 vertex pairs, one row per networkx edge, in `G.edges` order.
        edge_weights: `(ne,)` NumPy float64 edge_weights.
        n_vertices: `G.number_of_nodes()`.
        nodes: the node of each vertex index: vertex `i` is `nodes[i]` (the order of `G.nodes`).
    """

    edges: np.ndarray
    edge_weights: np.ndarray
    n_vertices: int
    nodes: list[Any]


def from_networkx(graph, *, weight: str | None = "weight") -> NetworkxGraph:
    """Edges, edge_weights, vertex count and node order of an undirected networkx graph.

    Vertices are numbered in the order of `graph.nodes`; a MultiGraph gives one row per parallel edge
    (`graph_laplacian` sums them, as `nx.laplacian_matrix` does).

    Args:
        graph: a `networkx.Graph` or `networkx.MultiGraph` (directed graphs and self-loops are refused:
            `graph.to_undirected()`, `graph.remove_edges_from(nx.selfloop_edges(graph))`).
        weight: the edge attribute holding the weight (an edge without it weighs 1, as in networkx), or
            `None` for all ones.

    Returns:
        `NetworkxGraph(edges, edge_weights, n_vertices, nodes)`.

    networkx: `nx.to_scipy_sparse_array(G, weight=weight)` is the adjacency matrix of the same numbering.
    """
    nx = _networkx()
    if not isinstance(graph, nx.Graph):
        raise DDGInputError(f"graph: expected a networkx Graph or MultiGraph, got {type(graph).__name__}")
    if graph.is_directed():
        raise DDGInputError(
            "graph: expected an undirected graph (the Laplacian here is of undirected edges); use graph.to_undirected()"
        )
    nodes = list(graph.nodes)
    index = {node: i for i, node in enumerate(nodes)}
    rows = [(index[u], index[v], 1.0 if weight is None else data.get(weight, 1.0)) for u, v, data in graph.edges(data=True)]
    edges = np.array([row[:2] for row in rows], dtype=np.int64).reshape(-1, 2)
    edge_weights = np.array([row[2] for row in rows], dtype=np.float64)
    loops = edges[:, 0] == edges[:, 1]
    if loops.any():
        raise DDGInputError(
            f"graph: {int(loops.sum())} self-loop(s); remove them with graph.remove_edges_from(nx.selfloop_edges(graph)) "
            "(they do not change the Laplacian)"
        )
    if (~np.isfinite(edge_weights) | (edge_weights < 0)).any():
        raise DDGInputError(f"graph: the {weight!r} attribute must be finite and non-negative on every edge")
    return NetworkxGraph(edges, edge_weights, len(nodes), nodes)


def to_networkx(edges: Int[ArrayLike, "ne 2"], *, edge_weights: Float[ArrayLike, " ne"] | None = None, n_vertices: int):
    """A `networkx.Graph` on the nodes `0 .. n_vertices - 1` with the edges and their `"weight"` attribute.

    An edge listed more than once becomes one networkx edge with the sum of its edge weights (as
    `graph_laplacian` counts it), so `nx.laplacian_matrix(to_networkx(...))` is `graph_laplacian(...)`.

    Args:
        edges: `(ne, 2)` undirected edges (`graph_laplacian`'s checks apply).
        edge_weights: `(ne,)` non-negative edge weights (default ones; JAX or NumPy, concrete).
        n_vertices: the number of vertices (isolated ones become nodes without edges).

    Returns:
        `networkx.Graph`.
    """
    nx = _networkx()
    structure = graph_structure(edges, n_vertices)
    edge_weights = np.asarray(check_weights(edge_weights, structure.n_edges), dtype=np.float64)
    pair_weights = np.zeros(structure.pairs.shape[0])
    np.add.at(pair_weights, np.asarray(structure.plan.pair_of_edge), edge_weights)
    graph = nx.Graph()
    graph.add_nodes_from(range(structure.n_vertices))
    graph.add_weighted_edges_from((int(i), int(j), float(w)) for (i, j), w in zip(structure.pairs, pair_weights, strict=True))
    return graph


def _networkx():
    try:
        import networkx
    except ImportError as error:
        raise ImportError(
            "ddgjax.graph.from_networkx / to_networkx need networkx, which ddgjax does not install: pip install 'networkx>=3'"
        ) from error
    return networkx
