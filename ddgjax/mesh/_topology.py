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
import functools
import hashlib

import numpy as np
import scipy.sparse as sp

from .._errors import DDGInputError, MeshDataError, first_indices
from ..sparse.internal import stable_order

_SIMPLICES = {3: ("nf", "triangles", "face", "triangle", "three"), 4: ("nt", "tetrahedra", "tetrahedron", "tetrahedron", "four")}


def validate_simplices(name: str, simplices, n_vertices: int, *, width: int) -> np.ndarray:
    """Host `(n, width)` int32 copy of a simplex list (`width` 3: faces, 4: tets), or `DDGInputError`
    naming `name`: a bad shape, an empty list, a non-integer dtype, indices out of range, a simplex
    repeating a vertex. Faces of a `Mesh`, tets of a `TetMesh` (`ddgjax.volume`, through `ddgjax.mesh.internal`)."""
    rows, plural, element, simplex, count = _SIMPLICES[width]
    host = np.asarray(simplices)
    if host.ndim != 2 or host.shape[1] != width:
        raise DDGInputError(f"{name}: expected shape ({rows}, {width}) ({plural}), got {host.shape}")
    if host.shape[0] == 0:
        raise DDGInputError(f"{name}: expected at least one {element}, got an empty array")
    if not np.issubdtype(host.dtype, np.integer):
        # Floats are refused even when they hold whole numbers: a float index array is almost always a
        # mix-up (vertices passed as faces, or indices that went through float arithmetic).
        raise DDGInputError(f"{name}: expected an integer array of vertex indices (e.g. int32 or int64), got dtype {host.dtype}")
    out_of_range = (host < 0) | (host >= n_vertices)
    if out_of_range.any():
        raise DDGInputError(
            f"{name}: vertex indices must lie in [0, {n_vertices}), got out-of-range entries in {name} "
            f"{first_indices(out_of_range)}"
        )
    ordered = np.sort(host, axis=1)
    repeated = (ordered[:, 1:] == ordered[:, :-1]).any(axis=1)
    if repeated.any():
        raise DDGInputError(
            f"{name}: a {simplex} must have {count} distinct vertices; {name} {first_indices(repeated)} repeat one"
        )
    return np.array(host, dtype=np.int32, order="C")  # a copy: the topology makes its arrays read-only


@dataclasses.dataclass(frozen=True, eq=False)
class MeshTopology:
    """Connectivity of a triangle mesh (NumPy arrays; static under jit, equal when the faces are equal).

    Two topologies are equal when they have the same vertex count and the same face array (compared
    through a 128-bit BLAKE2b digest of the faces, computed on first use), so a function jitted with
    a `Mesh` argument compiles once per connectivity: the same mesh loaded twice, or built twice from
    the same arrays, reuses the compiled program.

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
    nonmanifold_edges: np.ndarray

    def __post_init__(self):
        # Read-only: a Mesh's device arrays may share these buffers (`jax.device_put` does
        # not copy on CPU), so an in-place edit would change the mesh behind jit's back.
        for field in dataclasses.fields(self):
            value = getattr(self, field.name)
            if isinstance(value, np.ndarray):
                value.setflags(write=False)

    # The vertex- and component-level checks cost more than the rest of the topology together and
    # no operator on an edge-manifold mesh needs them, so they are computed on first use and cached
    # (functools.cached_property writes the instance __dict__, frozen or not). So is the orientation
    # check, needed only by the DEC operators that require an orientation and by the checks.

    @functools.cached_property
    def inconsistent_edges(self) -> np.ndarray:
        """Two-face edges that both faces traverse in the same direction."""
        two_face = np.flatnonzero(self.edge_face_counts == 2)
        faces, corners = self.edge_faces[two_face, :2], self.edge_face_corners[two_face, :2]
        signs = self.face_edge_signs[faces, corners]
        return two_face[signs[:, 0] == signs[:, 1]].astype(np.int32)

    @functools.cached_property
    def unreferenced_vertices(self) -> np.ndarray:
        referenced = np.zeros(self.n_vertices, dtype=bool)
        referenced[self.faces.ravel()] = True
        return np.flatnonzero(~referenced).astype(np.int32)

    @functools.cached_property
    def boundary_vertices(self) -> np.ndarray:
        return np.unique(self.edges[self.boundary_edges].ravel()).astype(np.int32)

    @functools.cached_property
    def boundary_loops(self) -> tuple:
        return _boundary_loops(self.faces, self.edge_faces, self.edge_face_corners, self.boundary_edges)

    @functools.cached_property
    def nonmanifold_vertices(self) -> np.ndarray:
        return _nonmanifold_vertices(self.faces, self._corner_pairs, self.n_vertices, self.nonmanifold_edges.size == 0)

    @functools.cached_property
    def _components(self) -> tuple[int, np.ndarray]:
        # Faces sharing an edge are in one component.
        return _face_components(self.faces, self.edges, self._corner_pairs, self.nonmanifold_vertices.size == 0)

    @property
    def face_components(self) -> np.ndarray:
        return self._components[1]

    @property
    def cells(self) -> np.ndarray:
        """The top-dimensional simplices, `faces` (as `ddgjax.volume.TetTopology.cells` is `tets`)."""
        return self.faces

    @property
    def cell_components(self) -> np.ndarray:
        """The connected component of each cell, `face_components`."""
        return self.face_components

    @property
    def n_components(self) -> int:
        return self._components[0]

    @property
    def _corner_pairs(self) -> tuple[np.ndarray, np.ndarray]:
        """Pairs of flat corners `3 f + k` opposite one shared edge: each edge's first corner with each later one."""
        corners = 3 * self.edge_faces.astype(np.int64) + self.edge_face_corners
        later = self.edge_faces[:, 1:] >= 0
        first = np.broadcast_to(corners[:, :1], later.shape)
        return first[later].astype(np.int32), corners[:, 1:][later].astype(np.int32)

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
                f"{operation} needs an edge-manifold mesh; edges "
                f"{first_indices(index_mask(self.nonmanifold_edges, self.n_edges))} "
                "have three or more faces"
            )
        if self.nonmanifold_vertices.size:
            raise MeshDataError(
                f"{operation} needs a vertex-manifold mesh; vertices "
                f"{first_indices(index_mask(self.nonmanifold_vertices, self.n_vertices))} "
                "join separate fans of faces"
            )

    def require_oriented(self, operation: str) -> None:
        """Raise `MeshDataError` naming `operation` unless faces are consistently oriented."""
        if not self.is_edge_manifold:
            self.require_manifold(operation)
        if self.inconsistent_edges.size:
            raise MeshDataError(
                f"{operation} needs consistently oriented faces (an orientable, oriented mesh); edges "
                f"{first_indices(index_mask(self.inconsistent_edges, self.n_edges))} "
                "are traversed the same way by both their faces"
            )

    @functools.cached_property
    def _key(self) -> tuple[int, int, bytes]:
        return self.n_vertices, self.n_faces, hashlib.blake2b(np.ascontiguousarray(self.faces), digest_size=16).digest()

    # By content: jit compares static pytree fields with `==` and `hash` on every call.
    def __hash__(self) -> int:
        return hash(self._key)

    def __eq__(self, other: object) -> bool:
        return self is other or (isinstance(other, MeshTopology) and self._key == other._key)


def index_mask(indices: np.ndarray, size: int) -> np.ndarray:
    """Boolean mask of length `size`, true at `indices` (for `ddgjax._errors.first_indices`)."""
    mask = np.zeros(size, dtype=bool)
    mask[indices] = True
    return mask


def build_topology(faces: np.ndarray, n_vertices: int) -> MeshTopology:
    """All connectivity of a validated `(nf, 3)` face array (see module docstring for conventions).

    Args:
        faces: `(nf, 3)` host int32 vertex indices, already validated (`validate_simplices`: in range, no
            repeated vertex in a face).
        n_vertices: the number of vertices, unreferenced ones included.

    Returns:
        `MeshTopology` of the faces (NumPy arrays, host data).
    """
    nf = faces.shape[0]
    n_corners = 3 * nf
    # Half-edge opposite corner k runs faces[:, k+1] -> faces[:, k+2].
    tails = faces[:, [1, 2, 0]]
    heads = faces[:, [2, 0, 1]]
    low = np.minimum(tails, heads).ravel()
    high = np.maximum(tails, heads).ravel()
    # One stable sort of the int64 edge keys numbers the edges (lexicographic order) and groups the
    # corners of each edge by ascending flat corner index, which is the edge -> faces order.
    keys = low.astype(np.int64) * n_vertices + high
    order, sorted_keys = stable_order(keys)
    is_first = np.empty(n_corners, dtype=bool)
    is_first[0] = True
    np.not_equal(sorted_keys[1:], sorted_keys[:-1], out=is_first[1:])
    edge_of_sorted = np.cumsum(is_first, dtype=np.int32) - 1
    starts = np.flatnonzero(is_first)
    ne = starts.size
    face_edges = np.empty(n_corners, dtype=np.int32)
    face_edges[order] = edge_of_sorted
    face_edges = face_edges.reshape(nf, 3)
    # The edges from the sorted keys themselves: a sequential pass, not a scattered gather of corners.
    edge_keys = sorted_keys[starts]
    edges = np.empty((ne, 2), dtype=np.int32)
    edges[:, 0] = edge_keys // n_vertices
    edges[:, 1] = edge_keys - edges[:, 0].astype(np.int64) * n_vertices
    face_edge_signs = (tails < heads).view(np.int8) * np.int8(2) - np.int8(1)

    counts = np.diff(starts, append=n_corners)
    slot = np.arange(n_corners, dtype=np.int32) - np.repeat(starts.astype(np.int32), counts)
    width = max(2, int(counts.max()))
    # One write of the flat corners 3 f + k in edge order, then whole-array divisions: a single
    # scattered write instead of two.
    edge_corners = np.full((ne, width), -1, dtype=np.int32)
    edge_corners.ravel()[edge_of_sorted * width + slot] = order
    padding = edge_corners < 0
    edge_faces = np.floor_divide(edge_corners, 3)  # padding: -1 // 3 = -1
    edge_face_corners = (edge_corners - 3 * edge_faces).astype(np.int8)
    edge_face_corners[padding] = -1

    boundary_edges = np.flatnonzero(counts == 1).astype(np.int32)
    nonmanifold_edges = np.flatnonzero(counts > 2).astype(np.int32)

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
        nonmanifold_edges=nonmanifold_edges,
    )


def _connected_components(graph: sp.coo_matrix) -> tuple[int, np.ndarray]:
    # Imported on first use: scipy.sparse.csgraph is a tenth of ddgjax's import time, and only the
    # lazily computed checks need it.
    from scipy.sparse.csgraph import connected_components

    return connected_components(graph, directed=False)


def _face_components(faces, edges, corner_pairs, vertex_manifold: bool) -> tuple[int, np.ndarray]:
    """Components of the faces, two faces joined when they share an edge, numbered by their first face.

    Where every vertex is manifold, faces sharing only a vertex are edge-connected through its fan, so
    the components follow from the smaller vertex-edge graph; otherwise from the face-face graph.
    """
    nf = faces.shape[0]
    if not vertex_manifold:
        a, b = corner_pairs
        graph = sp.coo_matrix((np.ones(a.size, dtype=np.int8), (a // 3, b // 3)), shape=(nf, nf))
        n, labels = _connected_components(graph)
        return int(n), labels.astype(np.int32)
    nv = int(faces.max()) + 1
    graph = sp.coo_matrix((np.ones(edges.shape[0], dtype=np.int8), (edges[:, 0], edges[:, 1])), shape=(nv, nv))
    n_vertex_labels, vertex_labels = _connected_components(graph)
    raw = vertex_labels[faces[:, 0]]
    # Renumber as a face-graph search would: components in order of their first face.
    first_face = np.full(n_vertex_labels, nf, dtype=np.int64)
    np.minimum.at(first_face, raw, np.arange(nf))
    present = np.flatnonzero(first_face < nf)
    rank = np.empty(n_vertex_labels, dtype=np.int32)
    rank[present[np.argsort(first_face[present])]] = np.arange(present.size, dtype=np.int32)
    return int(present.size), rank[raw]


def _nonmanifold_vertices(faces, corner_pairs, n_vertices, edge_manifold: bool) -> np.ndarray:
    """Vertices whose incident corners split into more than one fan.

    Corners (face, k) are graph nodes; two corners at the same vertex are joined when their faces share
    an edge at that vertex. A manifold vertex has exactly one connected group of corners.
    `corner_pairs` are the flat corners `3 f + k` opposite each shared edge, one pair per linked face.
    """
    nf = faces.shape[0]
    q0, q1 = corner_pairs
    # Endpoint corners of the edge in each face: (c+1)%3 and (c+2)%3; match them by vertex.
    to_next = np.array([1, 1, -2], dtype=q0.dtype)
    to_prev = np.array([2, -1, -1], dtype=q0.dtype)
    c0, c1 = q0 % 3, q1 % 3
    a0, b0 = q0 + to_next[c0], q0 + to_prev[c0]
    a1, b1 = q1 + to_next[c1], q1 + to_prev[c1]
    flat = faces.ravel()
    direct = flat[a0] == flat[a1]
    if edge_manifold:
        fan_walk = _nonmanifold_vertices_by_walk(flat, (a0, b0, a1, b1), direct, n_vertices)
        if fan_walk is not None:
            return fan_walk
    src = np.concatenate([a0, b0])
    dst = np.concatenate([np.where(direct, a1, b1), np.where(direct, b1, a1)])
    graph = sp.coo_matrix((np.ones(src.size, dtype=np.int8), (src, dst)), shape=(3 * nf, 3 * nf))
    _, labels = _connected_components(graph)
    # Links join only corners at the same vertex, so each fan (component) has exactly one vertex:
    # count the fans of each vertex without a sort (the vertex of each label, then a bincount).
    vertex_of_fan = np.empty(int(labels.max()) + 1, dtype=np.int32)
    vertex_of_fan[labels] = flat
    fans_per_vertex = np.bincount(vertex_of_fan, minlength=n_vertices)
    return np.flatnonzero(fans_per_vertex > 1).astype(np.int32)


# Longest fan walk (corners on one side of the start corner) before falling back to a graph search.
_MAX_FAN_WALK = 128


def _nonmanifold_vertices_by_walk(flat, ends, direct, n_vertices) -> np.ndarray | None:
    """`_nonmanifold_vertices` on an edge-manifold mesh, by walking one fan per vertex.

    With at most two faces per edge each corner has at most two links (one per edge at its vertex), so
    the fans are paths and cycles: walking from one corner of each vertex in both directions (stopping
    at a boundary or back at the start) visits its whole fan, and the vertex is manifold exactly when
    that fan holds all its corners. All vertices walk together, one step per loop pass; None where a
    fan is longer than `_MAX_FAN_WALK` (very high valence), left to the graph search.
    """
    a0, b0, a1, b1 = ends
    n_corners = flat.size
    # Walk states 2 x + s: at corner x, leaving across side s (0: the edge opposite next(x), 1: opposite
    # prev(x)). link[state] is the state of arrival in the linked corner, -1 across a boundary edge.
    # a = next(q), so the edge opposite q is side 1 of a; b = prev(q), side 0 of b.
    link = np.full(2 * n_corners, -1, dtype=np.int32)
    sa0, sb0, sa1, sb1 = 2 * a0 + 1, 2 * b0, 2 * a1 + 1, 2 * b1
    link[sa0] = np.where(direct, sa1, sb1)
    link[sb0] = np.where(direct, sb1, sa1)
    link[sa1] = np.where(direct, sa0, sb0)
    link[sb1] = np.where(direct, sb0, sa0)
    corners_per_vertex = np.bincount(flat, minlength=n_vertices)
    referenced = np.flatnonzero(corners_per_vertex)
    start_of = np.empty(n_vertices, dtype=np.int32)
    start_of[flat] = np.arange(n_corners, dtype=np.int32)  # any one corner of each vertex
    start = start_of[referenced]
    fan_size = np.ones(referenced.size, dtype=np.int64)
    closed = np.zeros(referenced.size, dtype=bool)
    for side in (0, 1):
        active = np.flatnonzero(~closed)
        state = 2 * start[active] + side
        for _ in range(_MAX_FAN_WALK):
            arrival = link[state]
            going = arrival >= 0
            active, arrival = active[going], arrival[going]
            back = (arrival >> 1) == start[active]
            closed[active[back]] = True
            active, arrival = active[~back], arrival[~back]
            if active.size == 0:
                break
            fan_size[active] += 1
            state = arrival ^ 1
        else:
            return None
    return referenced[fan_size != corners_per_vertex[referenced]].astype(np.int32)


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
