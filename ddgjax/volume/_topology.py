"""Tetrahedral mesh topology, built once in NumPy when a `TetMesh` is made (DESIGN.md, phase 1).

Everything here depends only on the tet list: edges, triangles, their incidences and relative
orientations, the boundary surface, components, the Euler characteristic and the manifold check.
Conventions (docs/conventions.md, the tetrahedra rows):

- a tet `(a, b, c, d)` is positively oriented when `det(b - a, c - a, d - a) > 0`
  (`TetMesh.from_arrays` orients every non-degenerate tet so);
- the six edges of a tet, in libigl's `edge_lengths` order, are `(3, 0), (3, 1), (3, 2), (1, 2),
  (2, 0), (0, 1)` (`TET_EDGES`); local edge `k` and `k + 3 (mod 6)` are opposite (share no vertex);
- local triangle `k` is the one opposite vertex `k`, listed so that its normal
  `(p1 - p0) x (p2 - p0)` points out of a positive tet (`TET_TRIANGLES`);
- global edges run from the lower to the higher vertex index; global triangles are sorted vertex
  triples `i < j < k`, oriented by that order; both lists are sorted lexicographically;
- `tet_edge_signs[t, k] = +1` where local edge `k` runs low -> high, `tet_triangle_signs[t, k] = +1`
  where the outward orientation of local triangle `k` agrees with the global one; entry `k` of a
  per-triangle triple is the edge opposite corner `k`, with signs `(+1, -1, +1)` (the sorted triple
  `i < j < k` runs `j -> k`, `k -> i`, `i -> j`).
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib

import numpy as np
import scipy.sparse as sp

from ..sparse.internal import stable_order

#: Local vertex pairs of the six edges of a tet (libigl `edge_lengths` order); edge `k` is opposite `k + 3 (mod 6)`.
TET_EDGES = np.array([[3, 0], [3, 1], [3, 2], [1, 2], [2, 0], [0, 1]], dtype=np.int32)
#: Local triangle `k`: the vertices opposite vertex `k`, ordered so that its normal points out of a positive tet.
TET_TRIANGLES = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]], dtype=np.int32)


@dataclasses.dataclass(frozen=True, eq=False)
class TetTopology:
    """Connectivity of a tetrahedral mesh (NumPy arrays; static under jit, equal when the tets are equal).

    Two topologies are equal when they have the same vertex count and tet array (a 128-bit BLAKE2b
    digest, computed on first use), so a function jitted with a `TetMesh` argument compiles once per
    connectivity, as for `ddgjax.mesh.MeshTopology`.

    Attributes:
        n_vertices: vertex count, unreferenced vertices included.
        tets: `(nt, 4)` vertex indices (positively oriented where the geometry allowed; module docstring).
        edges: `(ne, 2)` low -> high, sorted; `tet_edges`, `tet_edge_signs`: `(nt, 6)` per local edge.
        triangles: `(ntri, 3)` sorted triples, sorted; `tet_triangles`, `tet_triangle_signs`: `(nt, 4)`.
        triangle_edges: `(ntri, 3)` the edge opposite each corner (signs `TRIANGLE_EDGE_SIGNS`).
        triangle_tets: `(ntri, m)` the tets of each triangle, padded with -1; `triangle_tet_counts` `(ntri,)`.
        edge_tets, edge_tet_edges: `(ne, w)` the tets of each edge and which of their local edges it
            is, padded with -1 (the incidence the Laplacian's gathers use).
    """

    n_vertices: int
    tets: np.ndarray
    edges: np.ndarray
    tet_edges: np.ndarray
    tet_edge_signs: np.ndarray
    triangles: np.ndarray
    tet_triangles: np.ndarray
    tet_triangle_signs: np.ndarray
    triangle_edges: np.ndarray
    triangle_tets: np.ndarray
    triangle_tet_counts: np.ndarray
    edge_tets: np.ndarray
    edge_tet_edges: np.ndarray

    def __post_init__(self):
        for field in dataclasses.fields(self):  # read-only: a TetMesh's device arrays may share these buffers
            value = getattr(self, field.name)
            if isinstance(value, np.ndarray):
                value.setflags(write=False)

    @property
    def n_tets(self) -> int:
        return int(self.tets.shape[0])

    @property
    def n_edges(self) -> int:
        return int(self.edges.shape[0])

    @property
    def n_triangles(self) -> int:
        return int(self.triangles.shape[0])

    @functools.cached_property
    def boundary_triangles(self) -> np.ndarray:
        """Triangles of exactly one tet (the boundary surface), as indices into `triangles`."""
        return np.flatnonzero(self.triangle_tet_counts == 1).astype(np.int32)

    @functools.cached_property
    def nonmanifold_triangles(self) -> np.ndarray:
        """Triangles of three or more tets (a volume mesh cannot be a 3-manifold there)."""
        return np.flatnonzero(self.triangle_tet_counts > 2).astype(np.int32)

    @functools.cached_property
    def boundary_faces(self) -> np.ndarray:
        """`(nb, 3)` the boundary triangles as their tet lists them, so their normals point out of the solid."""
        triangles = self.boundary_triangles
        tets = self.triangle_tets[triangles, 0]
        local = np.argmax(self.tet_triangles[tets] == triangles[:, None], axis=1)
        return self.tets[tets[:, None], TET_TRIANGLES[local]].astype(np.int32)

    @functools.cached_property
    def boundary_vertices(self) -> np.ndarray:
        return np.unique(self.triangles[self.boundary_triangles].ravel()).astype(np.int32)

    @functools.cached_property
    def unreferenced_vertices(self) -> np.ndarray:
        referenced = np.zeros(self.n_vertices, dtype=bool)
        referenced[self.tets.ravel()] = True
        return np.flatnonzero(~referenced).astype(np.int32)

    @functools.cached_property
    def _components(self) -> tuple[int, np.ndarray]:
        # Tets sharing a triangle are in one component (as faces sharing an edge on surfaces).
        from scipy.sparse.csgraph import connected_components  # first use only: a slow import

        shared = self.triangle_tets[self.triangle_tet_counts >= 2]
        first = np.repeat(shared[:, 0], shared.shape[1] - 1)
        others = shared[:, 1:].ravel()
        keep = others >= 0
        graph = sp.coo_matrix((np.ones(keep.sum()), (first[keep], others[keep])), shape=(self.n_tets, self.n_tets))
        count, labels = connected_components(graph, directed=False)
        return int(count), labels.astype(np.int32)

    @property
    def tet_components(self) -> np.ndarray:
        """`(nt,)` the connected component of each tet (tets sharing a triangle are connected)."""
        return self._components[1]

    @property
    def cells(self) -> np.ndarray:
        """The top-dimensional simplices, `tets` (as `ddgjax.mesh.MeshTopology.cells` is `faces`)."""
        return self.tets

    @property
    def cell_components(self) -> np.ndarray:
        """The connected component of each cell, `tet_components`."""
        return self.tet_components

    @property
    def n_components(self) -> int:
        return self._components[0]

    @property
    def n_referenced_vertices(self) -> int:
        return self.n_vertices - int(self.unreferenced_vertices.size)

    @property
    def euler_characteristic(self) -> int:
        """`chi = V - E + T - C` (vertices, edges, triangles, tets) over referenced vertices; 1 for a ball, 0 for a solid torus."""
        return self.n_referenced_vertices - self.n_edges + self.n_triangles - self.n_tets

    @property
    def is_manifold(self) -> bool:
        """True when no triangle has three or more tets."""
        return self.nonmanifold_triangles.size == 0

    @property
    def is_closed(self) -> bool:
        """True for a mesh without boundary triangles (only possible for a non-embedded, e.g. periodic, complex)."""
        return self.boundary_triangles.size == 0

    @functools.cached_property
    def _key(self) -> tuple[int, int, bytes]:
        return self.n_vertices, self.n_tets, hashlib.blake2b(np.ascontiguousarray(self.tets), digest_size=16).digest()

    def __hash__(self) -> int:
        return hash(self._key)

    def __eq__(self, other: object) -> bool:
        return self is other or (isinstance(other, TetTopology) and self._key == other._key)


#: Orientation of the edge opposite each corner of a sorted triangle `i < j < k` (`j -> k`, `k -> i`, `i -> j`).
TRIANGLE_EDGE_SIGNS = np.array([1, -1, 1], dtype=np.int8)


def build_tet_topology(tets: np.ndarray, n_vertices: int) -> TetTopology:
    """All connectivity of a validated `(nt, 4)` tet array (module docstring for the conventions)."""
    # Edges: one stable sort of the 6 nt local edge keys numbers them and groups each edge's tets.
    ends = tets[:, TET_EDGES]  # (nt, 6, 2)
    low, high = ends.min(axis=2), ends.max(axis=2)
    edges, tet_edges, edge_slots = _number(low.astype(np.int64) * n_vertices + high)
    edges = np.stack([edges // n_vertices, edges % n_vertices], axis=1).astype(np.int32)
    tet_edge_signs = np.where(ends[..., 0] < ends[..., 1], 1, -1).astype(np.int8)
    edge_tets = np.where(edge_slots >= 0, edge_slots // 6, -1).astype(np.int32)
    edge_tet_edges = np.where(edge_slots >= 0, edge_slots % 6, -1).astype(np.int8)

    # Triangles: sorted triples; the outward local order agrees with the sorted one when it is an even permutation.
    local = tets[:, TET_TRIANGLES]  # (nt, 4, 3)
    ordered = np.sort(local, axis=2)
    keys = (ordered[..., 0].astype(np.int64) * n_vertices + ordered[..., 1]) * n_vertices + ordered[..., 2]
    triangle_keys, tet_triangles, triangle_slots = _number(keys)
    triangles = np.stack(
        [triangle_keys // (n_vertices * n_vertices), (triangle_keys // n_vertices) % n_vertices, triangle_keys % n_vertices],
        axis=1,
    ).astype(np.int32)
    # A cyclic rotation keeps the orientation: rotate the smallest vertex first, then compare the rest.
    first = np.argmin(local, axis=2)
    rotated_second = np.take_along_axis(local, ((first + 1) % 3)[..., None], axis=2)[..., 0]
    tet_triangle_signs = np.where(rotated_second == ordered[..., 1], 1, -1).astype(np.int8)
    counts = (triangle_slots >= 0).sum(axis=1).astype(np.int32)
    triangle_tets = np.where(triangle_slots >= 0, triangle_slots // 4, -1).astype(np.int32)

    # Edge opposite each corner of a sorted triangle: (j, k), (i, k), (i, j).
    pair_keys = triangles[:, [1, 0, 0]].astype(np.int64) * n_vertices + triangles[:, [2, 2, 1]]
    edge_keys = edges[:, 0].astype(np.int64) * n_vertices + edges[:, 1]
    triangle_edges = np.searchsorted(edge_keys, pair_keys).astype(np.int32)

    return TetTopology(
        n_vertices=int(n_vertices),
        tets=tets,
        edges=edges,
        tet_edges=tet_edges,
        tet_edge_signs=tet_edge_signs,
        triangles=triangles,
        tet_triangles=tet_triangles,
        tet_triangle_signs=tet_triangle_signs,
        triangle_edges=triangle_edges,
        triangle_tets=triangle_tets,
        triangle_tet_counts=counts,
        edge_tets=edge_tets,
        edge_tet_edges=edge_tet_edges,
    )


def _number(keys: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Distinct `keys` (sorted), the index of each key among them (`keys`' shape), and each distinct key's
    flat positions in `keys` (`(n_distinct, width)`, ascending, padded with -1)."""
    flat = keys.reshape(-1)
    order, sorted_keys = stable_order(flat)
    is_first = np.empty(flat.size, dtype=bool)
    is_first[0] = True
    np.not_equal(sorted_keys[1:], sorted_keys[:-1], out=is_first[1:])
    number_of_sorted = np.cumsum(is_first, dtype=np.int32) - 1
    starts = np.flatnonzero(is_first)
    index = np.empty(flat.size, dtype=np.int32)
    index[order] = number_of_sorted
    counts = np.diff(starts, append=flat.size)
    slot = np.arange(flat.size) - np.repeat(starts, counts)
    positions = np.full((starts.size, max(2, int(counts.max()))), -1, dtype=np.int64)
    positions[number_of_sorted, slot] = order
    return sorted_keys[starts], index.reshape(keys.shape), positions
