"""The tufted cover of any triangle mesh, and its intrinsic Delaunay flips, on the host.

Sharp & Crane 2020: a triangle mesh that is not edge-manifold (three or more faces at an edge) or
not consistently oriented (a Moebius strip, flipped faces) cannot be flipped as it is (an edge has no
single pair of faces with opposite orientations along it), but its *tufted cover* can: two copies of
every face, one per orientation, glued around each edge in the angular order of the faces about it
(each copy to the neighbouring face's copy of opposite orientation along the edge), a closed,
consistently oriented surface with the same vertices and metric. Its cotan Laplacian and mass
matrix, halved (the cover holds every face twice), are the robust Laplacian of the mesh; on an
oriented manifold mesh they are those of the mesh with every boundary edge doubled into a fold (a
boundary edge can then be flipped, unlike in `ddgjax.laplacian.intrinsic_delaunay`'s manifold path,
which keeps boundaries; the same operator on closed meshes).

`tufted_delaunay(points, faces, mollify_factor)` is the whole host phase: the cover
(`tufted_cover`), the mollified lengths of the distinct edges, Lawson flips of the cover (an edge
flipped where its cotan weight is below `-1e-6`, geometry-central `flipToDelaunay`'s test) and the
replay layout (`ddgjax.laplacian._intrinsic`), with the replay's slots on the distinct edges, so the
JAX replay (`replayed_lengths_sq`) reads the lengths `|p_i - p_j|^2` of the input's edges only. It
serves `intrinsic_delaunay(mesh)` on non-manifold and non-oriented meshes (each face once) and
`ddgjax.pointcloud`'s triangulation (the union of the local triangles, each up to three times).

References: N. Sharp, K. Crane, "A Laplacian for nonmanifold triangle meshes", Computer Graphics
Forum 39(5) (SGP 2020). geometry-central `buildIntrinsicTuftedCover`, `buildTuftedLaplacian`;
robust_laplacian `mesh_laplacian(V, F, mollify_factor=1e-5)` (`L` and `M` of the cover, halved).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .._stdsort import std_sort_order
from ..mesh import MeshTopology
from ._flips import flip_to_delaunay, mollified, replay_layout

# geometry-central's `flipToDelaunay` leaves an edge whose cotan weight is above this (absolute) unflipped:
# the same tolerance gives the same cover where near co-circular quads could go either way (duplicated points).
_GEOMETRY_CENTRAL_DELAUNAY_EPS = 1e-6


class _CoverTopology(MeshTopology):
    """The corner tables of the tufted cover that `flip_to_delaunay` reads (those fields of a `MeshTopology`).

    A subclass only so that the mesh flips' annotated helper accepts it: the cover is no `Mesh` (two
    vertices may be joined by several edges), and nothing else of `MeshTopology` is used.
    """

    def __init__(self, faces, face_edges, edge_faces, edge_face_corners, edge_face_counts):
        for name, value in (
            ("faces", faces),
            ("face_edges", face_edges),
            ("edge_faces", edge_faces),
            ("edge_face_corners", edge_face_corners),
            ("edge_face_counts", edge_face_counts),
        ):
            object.__setattr__(self, name, value)


class TuftedDelaunay(NamedTuple):
    """The host phase of a tufted intrinsic Delaunay triangulation (`tufted_delaunay`): NumPy arrays.

    Attributes:
        edges: `(ne, 2)` the distinct vertex pairs `(low, high)` joined by an edge of the input, sorted.
        face_edges: `(nf, 3)` the distinct edge opposite each corner of the input faces (what the
            mollification reads).
        faces: `(2 nf, 3)` the faces of the flipped cover (a Delta-complex on the input's vertices).
        flip_slots: `(n_steps, 5, width)` the replay's flips (`ddgjax.laplacian.IntrinsicTriangulation`),
            slots `0 .. ne-1` being the distinct edges.
        face_length_slots: `(2 nf, 3)` the slot of the edge opposite each corner of `faces`.
        n_flips: the number of flips.
        n_rounds: the number of rounds of independent flips.
    """

    edges: np.ndarray
    face_edges: np.ndarray
    faces: np.ndarray
    flip_slots: np.ndarray
    face_length_slots: np.ndarray
    n_flips: int
    n_rounds: int


def tufted_delaunay(points: np.ndarray, faces: np.ndarray, mollify_factor: float) -> TuftedDelaunay:
    """Build the tufted cover of `faces`, mollify its lengths, flip it to intrinsic Delaunay (host, NumPy).

    `points` `(n, 3)` float64 and `faces` `(nf, 3)` any triangles on them (non-manifold, inconsistently
    oriented, repeated: all fine); `mollify_factor` as `intrinsic_delaunay`'s. The replay of the result
    starts from the mollified squared lengths of `edges` (`replayed_lengths_sq(points, edges,
    face_edges, flip_slots, face_length_slots)`); every cover edge starts at its distinct edge's length.
    """
    edges, face_edges, cover, cover_edge_of = tufted_cover(points, faces)
    edge_lengths_sq = np.sum((points[edges[:, 1]] - points[edges[:, 0]]) ** 2, axis=1)
    edge_lengths_sq = mollified(edge_lengths_sq, face_edges, float(mollify_factor), np, np.sqrt, np.take)
    cover_faces, cover_face_edges, rounds = flip_to_delaunay(
        cover, edge_lengths_sq[cover_edge_of], weight_tolerance=_GEOMETRY_CENTRAL_DELAUNAY_EPS
    )
    n_cover_edges = cover_edge_of.size
    flip_slots, face_length_slots = replay_layout(rounds, cover_face_edges, n_cover_edges)
    # Unflipped cover edges read their distinct edge's slot; the new diagonals' slots shift down to follow the distinct edges.
    shift = np.int32(n_cover_edges - edges.shape[0])

    def remap(slots):
        return np.where(slots < n_cover_edges, cover_edge_of[np.minimum(slots, n_cover_edges - 1)], slots - shift).astype(
            np.int32
        )

    return TuftedDelaunay(
        edges=edges,
        face_edges=face_edges,
        faces=cover_faces.astype(np.int32),
        flip_slots=remap(flip_slots),
        face_length_slots=remap(face_length_slots),
        n_flips=sum(quads.shape[0] for quads in rounds),
        n_rounds=len(rounds),
    )


def tufted_cover(points: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, _CoverTopology, np.ndarray]:
    """`(edges, face_edges, cover, cover_edge_of)`: the triangles' distinct edges, and their tufted cover (module docstring).

    `edges` `(ne, 2)` are the distinct vertex pairs `(low, high)`, sorted (`MeshTopology.edges`' order),
    `face_edges` `(nf, 3)` the distinct edge opposite each corner of `faces`. Cover face `f` is
    triangle `f`, face `nf + f` its reversed copy `(a, c, b)`; around each edge (its triangles
    sorted by the angle of their third corner about it, ties as geometry-central's sort leaves them:
    `_fan_angles_and_ties`) the copy running the edge against its first half-edge in one triangle is
    glued to the copy running it along in the next, cyclically. `cover_edge_of[e]` is the distinct
    edge of cover edge `e`.
    """
    nf = faces.shape[0]
    n = points.shape[0]
    tails, heads = faces[:, [1, 2, 0]].reshape(-1).astype(np.int64), faces[:, [2, 0, 1]].reshape(-1).astype(np.int64)
    low, high = np.minimum(tails, heads), np.maximum(tails, heads)
    keys = low * n + high
    opposite = faces.reshape(-1)  # the corner opposite each half-edge
    angles, rank, first_tail = _fan_angles_and_ties(points, faces, tails, heads, opposite, keys)
    # Clockwise about the edge's first half-edge (geometry-central's descending sort), ties in its order.
    order = np.lexsort((rank, -angles, keys))
    sorted_keys = keys[order]
    starts = np.flatnonzero(np.r_[True, sorted_keys[1:] != sorted_keys[:-1]])
    sizes = np.diff(np.r_[starts, sorted_keys.size])
    # Past 16 triangles its sort is a quicksort, and a NaN angle (a zero-length edge) stops its insertion
    # sort: there the order is replayed from the sibling cycle.
    unsorted = np.isnan(angles[order])
    replayed = (sizes > 16) | (np.add.reduceat(unsorted, starts) > 0 if starts.size else np.zeros(0, dtype=bool))
    for start, size in zip(starts[replayed], sizes[replayed]):
        members = order[start : start + size]
        members = members[np.argsort(rank[members], kind="stable")]
        order[start : start + size] = members[std_sort_order((-angles[members]).tolist())]
    edge_of_sorted = np.repeat(np.arange(starts.size), sizes)
    edges = np.stack([sorted_keys[starts] // n, sorted_keys[starts] % n], axis=1).astype(np.int32)
    face_edges = np.empty(3 * nf, dtype=np.int32)
    face_edges[order] = edge_of_sorted
    # Corner c = 3 f + k of the triangle; its reversed copy holds that vertex at position (0, 2, 1)[k].
    front = order
    back = 3 * nf + 3 * (order // 3) + np.array([0, 2, 1])[order % 3]
    forwards = tails[order] == first_tail[order]
    plus = np.where(forwards, front, back)  # the copy running the edge as its first half-edge does
    minus = np.where(forwards, back, front)
    position = np.arange(order.size)
    next_in_fan = np.where(position + 1 < np.repeat(starts + sizes, sizes), position + 1, np.repeat(starts, sizes))
    corners_a, corners_b = minus, plus[next_in_fan]  # cover edge i glues these two corners
    cover_faces = np.concatenate([faces, faces[:, [0, 2, 1]]]).astype(np.int32)
    n_cover_edges = order.size
    cover_face_edges = np.empty(2 * 3 * nf, dtype=np.int32)
    cover_face_edges[corners_a] = position
    cover_face_edges[corners_b] = position
    cover = _CoverTopology(
        faces=cover_faces,
        face_edges=cover_face_edges.reshape(-1, 3),
        edge_faces=np.stack([corners_a // 3, corners_b // 3], axis=1),
        edge_face_corners=np.stack([corners_a % 3, corners_b % 3], axis=1),
        edge_face_counts=np.full(n_cover_edges, 2, dtype=np.int32),
    )
    return edges, face_edges.reshape(-1, 3), cover, edge_of_sorted.astype(np.int32)


def _fan_angles_and_ties(points, faces, tails, heads, opposite, keys) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`(angles, rank, tail)` per half-edge: the angle of its triangle about its edge, its place among equal
    angles, and the tail of its edge's first half-edge.

    As geometry-central's `buildIntrinsicTuftedCover` computes them, to the bit, since triangles repeated in a
    point cloud's union (and coplanar ones) tie exactly or to round-off: about the edge's first half-edge
    (in face order, a face's half-edges `(v0, v1), (v1, v2), (v2, v0)`), in the basis of
    `Vector3::buildTangentBasis`; equal angles keep the order of its edge's sibling cycle (the first
    half-edge, then the others from the last back), which its sort (an insertion sort up to 16 faces)
    keeps.
    """
    nf = faces.shape[0]
    # Half-edge 3 f + k is opposite corner k; geometry-central's half-edge j of a face runs v_j -> v_{j+1}.
    sequence = 3 * (np.arange(3 * nf) // 3) + (np.arange(3 * nf) % 3 + 1) % 3
    by_edge = np.lexsort((sequence, keys))
    sorted_keys = keys[by_edge]
    starts = np.flatnonzero(np.r_[True, sorted_keys[1:] != sorted_keys[:-1]])
    sizes = np.diff(np.r_[starts, sorted_keys.size])
    occurrence = np.arange(keys.size) - np.repeat(starts, sizes)
    rank = np.empty(keys.size, dtype=np.int64)
    rank[by_edge] = np.where(occurrence == 0, 0, np.repeat(sizes, sizes) - occurrence)
    first = np.repeat(by_edge[starts], sizes)
    tail, tip = np.empty(keys.size, dtype=np.int64), np.empty(keys.size, dtype=np.int64)
    tail[by_edge], tip[by_edge] = tails[first], heads[first]

    def dot(a, b):
        return a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1] + a[:, 2] * b[:, 2]

    def normalize(a):
        # A zero-length edge or a corner on its tail gives NaN angles, as there; the sort replays them.
        with np.errstate(divide="ignore", invalid="ignore"):
            return a * (1.0 / np.sqrt(dot(a, a)))[:, None]

    direction = normalize(points[tip] - points[tail])
    test = np.where(np.abs(direction[:, :1]) > 0.9, [[0.0, 1.0, 0.0]], [[1.0, 0.0, 0.0]])
    basis_x = normalize(np.cross(test, direction))
    basis_y = normalize(np.cross(direction, basis_x))
    out = normalize(points[opposite] - points[tail])
    return np.arctan2(dot(basis_y, out), dot(basis_x, out)), rank, tail
