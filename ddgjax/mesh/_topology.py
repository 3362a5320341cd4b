"""Mesh topology, built once in NumPy when a `Mesh` is made (DESIGN.md, phase 1).

Everything here depends only on the face list, never on vertex positions, and is computed outside
jit: edges, face-edge incidence and signs, edge-face incidence, boundary, components, Euler
characteristic, genus, and the manifold / orientation checks. Conventions (DESIGN.md):

- entry `k` of a per-face triple belongs to the edge opposite corner `k`, i.e. the edge from
  `faces[f, (k+1) % 3]` to `faces[f, (k+2) % 3]` (libigl / gpytoolbox order);
- global edges run from the lower to the higher vertex index and are sorted lexicographically;
- `face_edge_signs[f, k] = +1` where face `f` traverses its edge `k` from low to high, else `-1`.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from .._errors import DDGInputError, MeshDataError, first_indices


def validate_faces(faces, n_vertices: int) -> np.ndarray:
    """Host `(nf, 3)` int array of faces, refusing bad shape, dtype, range or repeated corners."""
    host = np.asarray(faces)
    if host.ndim != 2 or host.shape[1] != 3:
        raise DDGInputError(f"faces: expected shape (nf, 3) (triangles), got {host.shape}")
    if host.shape[0] == 0:
        raise DDGInputError("faces: expected at least one face, got an empty array")
    if not np.issubdtype(host.dtype, np.integer):
        if np.issubdtype(host.dtype, np.floating) and np.all(np.isfinite(host)) and np.all(host == np.round(host)):
            host = host.astype(np.int64)
        else:
            raise DDGInputError(f"faces: expected an integer array of vertex indices, got dtype {host.dtype}")
    out_of_range = (host < 0) | (host >= n_vertices)
    if out_of_range.any():
        raise DDGInputError(
            f"faces: vertex indices must lie in [0, {n_vertices}), got out-of-range entries in faces "
            f"{first_indices(out_of_range)}"
        )
    repeated = (host[:, 0] == host[:, 1]) | (host[:, 1] == host[:, 2]) | (host[:, 2] == host[:, 0])
    if repeated.any():
        raise DDGInputError(f"faces: a triangle must have three distinct vertices; faces {first_indices(repeated)} repeat one")
    return host.astype(np.int32)


@dataclasses.dataclass(frozen=True, eq=False)
class MeshTopology:
    """Connectivity of a triangle mesh (NumPy arrays; static under jit, hashed by identity).

    Attributes:
        n_vertices, n_faces, n_edges: element counts (`n_vertices` includes unreferenced vertices).
        faces: `(nf, 3)` vertex indices.
        edges: `(ne, 2)` vertex indices, `edges[:, 0] < edges[:, 1]`, sorted lexicographically.
        face_edges: `(nf, 3)` edge opposite each corner.
        face_edge_signs: `(nf, 3)` +1 / -1, the face's traversal of that edge relative to low -> high.
        edge_faces: `(ne, m)` faces of each edge, padded with -1 (`m >= 2`; `m > 2` only on
            non-manifold meshes); `edge_face_corners` gives the corner of that face opposite the edge.
        edge_face_counts: `(ne,)` number of faces of each edge.
        boundary_edges: indices of edges with exactly one face.
        boundary_loops: tuple of vertex-index arrays, each boundary loop in the order its faces traverse it
            (see `_boundary_loops` for non-orientable and non-manifold meshes).
        boundary_vertices: sorted vertex indices on the boundary.
        face_components: `(nf,)` connected-component label of each face; `n_components` their count.
        unreferenced_vertices: vertices used by no face.
        nonmanifold_edges: edges with three or more faces.
        nonmanifold_vertices: vertices whose faces form more than one fan (edge-connected corner group).
        inconsistent_edges: two-face edges that both faces traverse in the same direction.
    """

    n_vertices: int
    faces: np.ndarray
    edges: np.ndarray
    face_edges: np.ndarray
    face_edge_signs: np.ndarray
    edge_faces: np.ndarray
    edge_face_corners: np.ndarray
    edge_face_counts: np.ndarray
    boundary_edges: np.ndarray
    boundary_loops: tuple
    boundary_vertices: np.ndarray
    face_components: np.ndarray
    n_components: int
    unreferenced_vertices: np.ndarray
    nonmanifold_edges: np.ndarray
    nonmanifold_vertices: np.ndarray
    inconsistent_edges: np.ndarray

    @property
    def n_faces(self) -> int:
        return int(self.faces.shape[0])

    @property
    def n_edges(self) -> int:
        return int(self.edges.shape[0])

    @property
    def n_referenced_vertices(self) -> int:
        return self.n_vertices - int(self.unreferenced_vertices.size)

    @property
    def euler_characteristic(self) -> int:
        """`chi = V - E + F` over referenced vertices (unreferenced vertices are not part of the surface)."""
        return self.n_referenced_vertices - self.n_edges + self.n_faces

    @property
    def is_edge_manifold(self) -> bool:
        return self.nonmanifold_edges.size == 0

    @property
    def is_manifold(self) -> bool:
        return self.is_edge_manifold and self.nonmanifold_vertices.size == 0

    @property
    def is_oriented(self) -> bool:
        """True when every two-face edge is traversed in opposite directions by its faces."""
        return self.is_edge_manifold and self.inconsistent_edges.size == 0

    @property
    def is_closed(self) -> bool:
        return self.boundary_edges.size == 0

    @property
    def genus(self) -> int | None:
        """`g = (2 - chi - b) / 2` for a connected, oriented manifold with `b` boundary loops; else None."""
        if self.n_components != 1 or not self.is_manifold or not self.is_oriented:
            return None
        return (2 - self.euler_characteristic - len(self.boundary_loops)) // 2

    def require_manifold(self, operation: str) -> None:
        """Raise `MeshDataError` naming `operation` unless the mesh is an edge- and vertex-manifold."""
        if not self.is_edge_manifold:
            raise MeshDataError(
                f"{operation} needs an edge-manifold mesh; edges {first_indices_of(self.nonmanifold_edges)} "
                "have three or more faces"
            )
        if self.nonmanifold_vertices.size:
            raise MeshDataError(
                f"{operation} needs a vertex-manifold mesh; vertices {first_indices_of(self.nonmanifold_vertices)} "
                "join separate fans of faces"
            )

    def require_oriented(self, operation: str) -> None:
        """Raise `MeshDataError` naming `operation` unless faces are consistently oriented."""
        if not self.is_edge_manifold:
            self.require_manifold(operation)
        if self.inconsistent_edges.size:
            raise MeshDataError(
                f"{operation} needs consistently oriented faces (an orientable, oriented mesh); edges "
                f"{first_indices_of(self.inconsistent_edges)} are traversed the same way by both their faces"
            )

    # Identity semantics: a topology is a static pytree field, so jit caches on the object itself and a
    # mesh with moved vertices (same topology object) never recompiles.
    __hash__ = object.__hash__

    def __eq__(self, other: object) -> bool:
        return self is other


def first_indices_of(indices: np.ndarray, limit: int = 10) -> str:
    shown = ", ".join(str(int(i)) for i in indices[:limit])
    return f"[{shown}{', ...' if indices.size > limit else ''}] ({indices.size} in all)"


def build_topology(faces: np.ndarray, n_vertices: int) -> MeshTopology:
    """All connectivity of a validated `(nf, 3)` face array (see module docstring for conventions)."""
    nf = faces.shape[0]
    # Half-edge opposite corner k runs faces[:, k+1] -> faces[:, k+2].
    tails = faces[:, [1, 2, 0]]
    heads = faces[:, [2, 0, 1]]
    low = np.minimum(tails, heads).astype(np.int64)
    high = np.maximum(tails, heads).astype(np.int64)
    keys = (low * n_vertices + high).ravel()
    unique_keys, face_edges = np.unique(keys, return_inverse=True)
    face_edges = face_edges.reshape(nf, 3).astype(np.int32)
    edges = np.stack([unique_keys // n_vertices, unique_keys % n_vertices], axis=1).astype(np.int32)
    ne = edges.shape[0]
    face_edge_signs = np.where(tails < heads, 1, -1).astype(np.int8)

    # Edge -> faces, grouped with one stable sort of the flat face-edge list.
    flat_edges = face_edges.ravel()
    counts = np.bincount(flat_edges, minlength=ne)
    order = np.argsort(flat_edges, kind="stable")
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    slot = np.arange(order.size) - starts[flat_edges[order]]
    width = max(2, int(counts.max()))
    edge_faces = np.full((ne, width), -1, dtype=np.int32)
    edge_face_corners = np.full((ne, width), -1, dtype=np.int8)
    edge_faces[flat_edges[order], slot] = order // 3
    edge_face_corners[flat_edges[order], slot] = order % 3

    boundary_edges = np.flatnonzero(counts == 1).astype(np.int32)
    nonmanifold_edges = np.flatnonzero(counts > 2).astype(np.int32)
    two_face = np.flatnonzero(counts == 2)
    sign_of = face_edge_signs.ravel()
    f0, f1 = edge_faces[two_face, 0], edge_faces[two_face, 1]
    c0, c1 = edge_face_corners[two_face, 0], edge_face_corners[two_face, 1]
    same_direction = sign_of[f0 * 3 + c0] == sign_of[f1 * 3 + c1]
    inconsistent_edges = two_face[same_direction].astype(np.int32)

    referenced = np.zeros(n_vertices, dtype=bool)
    referenced[faces.ravel()] = True
    unreferenced = np.flatnonzero(~referenced).astype(np.int32)

    # Faces sharing an edge are in one component.
    n_components, face_components = _face_components(nf, edge_faces, counts)
    nonmanifold_vertices = _nonmanifold_vertices(faces, edge_faces, edge_face_corners, counts, n_vertices)
    boundary_loops = _boundary_loops(faces, edge_faces, edge_face_corners, boundary_edges)
    boundary_vertices = np.unique(edges[boundary_edges].ravel()).astype(np.int32)

    return MeshTopology(
        n_vertices=int(n_vertices),
        faces=faces,
        edges=edges,
        face_edges=face_edges,
        face_edge_signs=face_edge_signs,
        edge_faces=edge_faces,
        edge_face_corners=edge_face_corners,
        edge_face_counts=counts.astype(np.int32),
        boundary_edges=boundary_edges,
        boundary_loops=boundary_loops,
        boundary_vertices=boundary_vertices,
        face_components=face_components,
        n_components=n_components,
        unreferenced_vertices=unreferenced,
        nonmanifold_edges=nonmanifold_edges,
        nonmanifold_vertices=nonmanifold_vertices,
        inconsistent_edges=inconsistent_edges,
    )


def _face_components(nf: int, edge_faces: np.ndarray, counts: np.ndarray) -> tuple[int, np.ndarray]:
    shared = np.flatnonzero(counts >= 2)
    a = np.repeat(edge_faces[shared, 0], edge_faces.shape[1] - 1)
    b = edge_faces[shared, 1:].ravel()
    keep = b >= 0
    graph = sp.coo_matrix((np.ones(int(keep.sum())), (a[keep], b[keep])), shape=(nf, nf))
    n, labels = connected_components(graph, directed=False)
    return int(n), labels.astype(np.int32)


def _nonmanifold_vertices(faces, edge_faces, edge_face_corners, counts, n_vertices) -> np.ndarray:
    """Vertices whose incident corners split into more than one fan.

    Corners (face, k) are graph nodes; two corners at the same vertex are joined when their faces share
    an edge at that vertex. A manifold vertex has exactly one connected group of corners.
    """
    nf = faces.shape[0]
    shared = np.flatnonzero(counts >= 2)
    f0 = np.repeat(edge_faces[shared, 0], edge_faces.shape[1] - 1).astype(np.int64)
    c0 = np.repeat(edge_face_corners[shared, 0], edge_faces.shape[1] - 1).astype(np.int64)
    f1 = edge_faces[shared, 1:].ravel().astype(np.int64)
    c1 = edge_face_corners[shared, 1:].ravel().astype(np.int64)
    keep = f1 >= 0
    f0, c0, f1, c1 = f0[keep], c0[keep], f1[keep], c1[keep]
    # Endpoint corners of the edge in each face: (c+1)%3 and (c+2)%3; match them by vertex.
    a0, b0 = f0 * 3 + (c0 + 1) % 3, f0 * 3 + (c0 + 2) % 3
    a1, b1 = f1 * 3 + (c1 + 1) % 3, f1 * 3 + (c1 + 2) % 3
    flat = faces.ravel()
    direct = flat[a0] == flat[a1]
    src = np.concatenate([a0, b0])
    dst = np.concatenate([np.where(direct, a1, b1), np.where(direct, b1, a1)])
    graph = sp.coo_matrix((np.ones(src.size), (src, dst)), shape=(3 * nf, 3 * nf))
    _, labels = connected_components(graph, directed=False)
    # Distinct (vertex, fan label) pairs, as one int64 key: a 1-D unique is ~10x faster than axis=0.
    # Links join only corners at the same vertex, so each fan (component) has exactly one vertex:
    # count the fans of each vertex without a sort (the vertex of each label, then a bincount).
    vertex_of_fan = np.empty(int(labels.max()) + 1, dtype=np.int64)
    vertex_of_fan[labels] = flat
    fans_per_vertex = np.bincount(vertex_of_fan, minlength=n_vertices)
    return np.flatnonzero(fans_per_vertex > 1).astype(np.int32)


def _boundary_loops(faces, edge_faces, edge_face_corners, boundary_edges) -> tuple:
    """Boundary loops as vertex sequences, each following the traversal direction of its faces.

    The walk goes from vertex to vertex along unused boundary edges, preferring an edge that its face
    traverses away from the current vertex. On an oriented manifold that is the only choice, so loops
    follow the faces' direction; on a non-orientable surface (a Moebius strip) the faces' directions
    disagree along one loop, and the undirected fallback still closes it as one loop. At a non-manifold
    boundary vertex several boundary edges meet; every boundary edge still lands in exactly one loop,
    and where they cannot close up (odd boundary degree) a "loop" is an open chain listing both ends.
    """
    if boundary_edges.size == 0:
        return ()
    f = edge_faces[boundary_edges, 0].astype(np.int64)
    c = edge_face_corners[boundary_edges, 0].astype(np.int64)
    tails = faces[f, (c + 1) % 3]
    heads = faces[f, (c + 2) % 3]
    n = boundary_edges.size
    # Incidence vertex -> boundary edges (both endpoints), outgoing ones first within each vertex.
    ends = np.concatenate([tails, heads])
    edge_of = np.concatenate([np.arange(n), np.arange(n)])
    order = np.lexsort((np.repeat([0, 1], n), ends))
    sorted_ends, sorted_edges = ends[order], edge_of[order]
    # Where boundary edges do not close up (odd boundary degree, only at non-manifold vertices) they
    # form open chains; starting there first keeps each chain in one piece.
    odd_degree = np.bincount(ends)[tails] % 2 == 1
    used = np.zeros(n, dtype=bool)
    loops = []
    for start in np.argsort(~odd_degree, kind="stable"):
        if used[start]:
            continue
        loop = [int(tails[start])]
        used[start] = True
        current = int(heads[start])
        while True:
            lo, hi = np.searchsorted(sorted_ends, [current, current + 1])
            candidates = sorted_edges[lo:hi]
            free = candidates[~used[candidates]]
            if free.size == 0:
                break
            edge = int(free[0])
            used[edge] = True
            loop.append(current)
            current = int(heads[edge]) if tails[edge] == current else int(tails[edge])
        if current != loop[0]:
            loop.append(current)
        loops.append(np.asarray(loop, dtype=np.int32))
    return tuple(loops)
