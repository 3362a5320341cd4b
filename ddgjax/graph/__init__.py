r"""Weighted undirected graphs: Laplacians, graphs of point sets, learning and drawing, differentiable in the edge weights.

A graph is `edges`, an `(ne, 2)` integer array of undirected vertex pairs (host data: it fixes the
sparsity pattern), `n_vertices=` (the vertex count, as `Mesh.n_vertices`), and `edge_weights=`, `(ne,)`
non-negative floats (default ones), the JAX values that `jit`, `grad` and `vmap` move.

$$L = D - W, \qquad D_{ii} = \sum_j w_{ij}, \qquad u^\top L u = \sum_{ij \in E} w_{ij} (u_i - u_j)^2$$

- `graph_laplacian(edges, *, edge_weights=None, n_vertices)`: the PSD combinatorial Laplacian $L = D - W$
  as a `ddgjax.sparse.SparseMatrix` (duplicate edges summed); networkx's `laplacian_matrix`.
- `knn_graph(points, *, n_neighbors=10, sigma=None)`, `epsilon_graph(points, *, radius, sigma=None)`:
  `WeightedEdges(edges, edge_weights)` of a point set, Gaussian edge weights $w = \exp(-d^2 / (2\sigma^2))$
  (`gaussian_weights`, differentiable in the points; `sigma` default the mean edge length).
- `harmonic_interpolation(edges, *, fixed_vertices, fixed_values, ...)`: label propagation (Zhu,
  Ghahramani & Lafferty 2003); `tikhonov_smoothing(edges, signal, *, alpha, ...)`: $(I + \alpha L) f = y$.
- `spectral_layout(edges, *, n_vertices, dim=2)` (Koren 2005: $L x = \lambda D x$) and
  `tutte_layout(edges, *, fixed_vertices, ...)` (Tutte's barycentric embedding).
- `from_networkx(G, *, weight="weight")`, `to_networkx(edges, *, edge_weights, n_vertices)` (networkx
  imported only there; it is not a dependency).

Solves go through `ddgjax.solve.linear_solve` (`solver=`), outcomes through `throw=` / `ddgjax.Solution`.
"""

from ._construction import WeightedEdges as WeightedEdges
from ._construction import epsilon_graph as epsilon_graph
from ._construction import gaussian_weights as gaussian_weights
from ._construction import knn_graph as knn_graph
from ._laplacian import graph_laplacian as graph_laplacian
from ._layout import spectral_layout as spectral_layout
from ._layout import tutte_layout as tutte_layout
from ._learning import harmonic_interpolation as harmonic_interpolation
from ._learning import tikhonov_smoothing as tikhonov_smoothing
from ._networkx import NetworkxGraph as NetworkxGraph
from ._networkx import from_networkx as from_networkx
from ._networkx import to_networkx as to_networkx
