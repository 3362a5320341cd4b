"""The storage plan of vertex-vertex operators on a triangulation: built once per connectivity, on the host.

The cotan Laplacian and the Galerkin mass matrix share one sparsity pattern: the diagonal plus both
directions of every pair of distinct vertices joined by an edge (`SparsityPattern.from_edges`).
Their values change with the metric and are re-assembled into that pattern from per-corner values
(the corner opposite each edge) with fixed gathers whose indices are computed here from the faces
alone (DESIGN.md, two phases). One builder, `_build`, makes every plan:

- `triangulation_plan(faces, n_vertices)` for any face list, including the general triangulations
  (Delta-complexes) that intrinsic triangulations become after edge flips: a face may repeat a
  vertex (its edge between the two copies is a *loop*) and two vertices may be joined by several
  edges (*parallel* edges, whose weights add into the one matrix entry). The vertex pairs are found
  by one sort of the corners' edge keys.
- `vertex_plan(mesh)` for a `Mesh`: the pairs are the mesh's edges, which its topology already
  found (the same sort, done once when the mesh was made), and the plan is cached per connectivity,
  so meshes of one connectivity share it. A mesh used only for areas or curvature builds none.

`dec_plan(mesh)` is another concept: the product -> slot map of the congruence `d0^T W d0` onto the
same pattern (`ddgjax.sparse.congruence`), for operators given by edge weights (the Hodge
decomposition's); the cotan Laplacian does not use it.
"""

from __future__ import annotations

import weakref

import equinox as eqx
import jax
import numpy as np
from jaxtyping import Array, ArrayLike, Int

from .._compile import device_array
from .._errors import DDGInputError, check_count, first_indices, is_traced
from ..mesh import Mesh, MeshTopology, require_mesh
from ..sparse import CongruencePlan, SparsityPattern, congruence_plan
from ..sparse.internal import stable_order


class TriangulationPlan(eqx.Module):
    """Faces of a triangulation and where per-corner values land in its `(nv, nv)` vertex pattern.

    Corner `3 f + k` is corner `k` of face `f`; it is opposite the edge `faces[f, k+1] - faces[f, k+2]`
    (libigl order).

    Attributes:
        faces: `(nf, 3)` int32 vertex indices; a face may repeat a vertex (module docstring).
        pattern: the `(nv, nv)` symmetric pattern (diagonal-first ELL storage, `SparsityPattern`):
            the diagonal and both directions of every pair of distinct vertices joined by an edge.
        source: `(nnz,)` for each storage slot, its index in the list
            `[diagonal (nv) | pairs low->high (n_pairs) | pairs high->low (n_pairs)]`, or
            `nv + 2 n_pairs` for an ELL padding slot, so per-pair values assemble with one gather
            (`take_rows_or_zero(entries, source)`).
        slot_corners: `(nnz - nv, m)` for each off-diagonal storage slot `nv + s`, the corners
            opposite the edges of its vertex pair (`3 nf` pads), so per-corner values (cotangents)
            land in storage order with one gather (`ddgjax.sparse.gather_sum`).
        corner_slots: `(3 nf, 2)` its transpose: the two off-diagonal slots (minus `nv`) of each
            corner's pair, for a scatter-free reverse pass; loop corners have none (`nnz - nv` pads).
        loop_corners: `(n_loops,)` the corners opposite a loop edge (empty on a mesh).
        loop_vertices: `(n_loops,)` the vertex at both ends of that loop.
    """

    faces: Int[Array, "nf 3"]
    pattern: SparsityPattern
    source: Int[Array, " nnz"]
    slot_corners: Int[Array, "n_off m"]
    corner_slots: Int[Array, "n_corners 2"]
    loop_corners: Int[Array, " n_loops"]
    loop_vertices: Int[Array, " n_loops"]

    @property
    def n_vertices(self) -> int:
        """Number of vertices `nv` (the pattern's size; vertices used by no face included)."""
        return self.pattern.shape[0]


def triangulation_plan(faces: Int[ArrayLike, "nf 3"], n_vertices: int) -> TriangulationPlan:
    """The `TriangulationPlan` of a face list (NumPy, once per connectivity, outside jit).

    Accepts what an intrinsic triangulation can hold: faces that repeat a vertex and vertex pairs
    joined by several edges (module docstring); faces need no orientation. Build it once and reuse
    it for any edge lengths on these faces (`cotan_laplacian_from_lengths_sq`,
    `mass_matrix_from_lengths_sq`). For a `Mesh`, the operators build and cache its plan themselves.

    Args:
        faces: `(nf, 3)` non-negative integer vertex indices below `n_vertices`.
        n_vertices: number of vertices `nv` (vertices used by no face get empty rows).

    Returns:
        `TriangulationPlan`.

    Raises `DDGInputError` for traced faces, a bad shape or dtype, or indices out of range.
    libigl and gpytoolbox build their matrices from triplets on every call and have no plan.
    """
    if is_traced(faces):
        raise DDGInputError("faces: triangulation_plan works on the host and needs a concrete array; build it outside jit")
    n_vertices = check_count("n_vertices", n_vertices)
    host = np.asarray(faces)
    if host.ndim != 2 or host.shape[1] != 3 or not np.issubdtype(host.dtype, np.integer):
        raise DDGInputError(f"faces: expected an (nf, 3) integer array, got shape {host.shape} dtype {host.dtype}")
    out_of_range = (host < 0) | (host >= n_vertices)
    if out_of_range.any():
        raise DDGInputError(
            f"faces: vertex indices must lie in [0, {n_vertices}), got out-of-range entries in faces {first_indices(out_of_range)}"
        )
    host = host.astype(np.int32)
    return _build(host, n_vertices, *_vertex_pairs(host, n_vertices))


# Keyed by topology, which compares by content: meshes of one connectivity share one plan.
_VERTEX_PLANS: "weakref.WeakKeyDictionary[MeshTopology, TriangulationPlan]" = weakref.WeakKeyDictionary()
_DEC_PLANS: "weakref.WeakKeyDictionary[MeshTopology, CongruencePlan]" = weakref.WeakKeyDictionary()


def vertex_plan(mesh: Mesh) -> TriangulationPlan:
    """The `TriangulationPlan` of `mesh`'s connectivity (built on the host on first use, then cached)."""
    topology = _topology(mesh)
    plan = _VERTEX_PLANS.get(topology)
    if plan is None:
        # Host work even when called inside a caller's trace: the plan depends on the topology only.
        with jax.ensure_compile_time_eval():
            plan = _VERTEX_PLANS[topology] = _mesh_plan(topology)
    return plan


def dec_plan(mesh: Mesh) -> CongruencePlan:
    """The `d0^T W d0` congruence plan onto the vertex pattern (rows of `d0` are `[tail, head]`), cached per connectivity."""
    topology = _topology(mesh)
    plan = _DEC_PLANS.get(topology)
    if plan is None:
        pattern = vertex_plan(mesh).pattern
        with jax.ensure_compile_time_eval():
            plan = _DEC_PLANS[topology] = congruence_plan(topology.edges, pattern)
    return plan


def _topology(mesh: Mesh) -> MeshTopology:
    topology = require_mesh("mesh", mesh).topology
    if topology is None:
        raise DDGInputError(
            "mesh: a storage plan needs the mesh's topology, which a compiled kernel does not see; "
            "build the plan before the kernel and pass it in"
        )
    return topology


def _mesh_plan(topology: MeshTopology) -> TriangulationPlan:
    """The plan of a mesh, its vertex pairs read from the topology (its edges, already sorted and numbered)."""
    pair_corners = np.where(topology.edge_faces >= 0, 3 * topology.edge_faces + topology.edge_face_corners, 3 * topology.n_faces)
    corner_pairs = topology.face_edges.reshape(-1)
    return _build(topology.faces, topology.n_vertices, topology.edges, pair_corners.astype(np.int32), corner_pairs)


def _vertex_pairs(faces: np.ndarray, nv: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`(pairs, pair_corners, corner_pairs)` of a Delta-complex (arguments of `_build`), by one sort of edge keys."""
    n_corners = faces.size
    tails = faces[:, [1, 2, 0]].reshape(-1).astype(np.int64)
    heads = faces[:, [2, 0, 1]].reshape(-1).astype(np.int64)
    corners = np.flatnonzero(tails != heads)  # loop corners have no pair
    keys = np.minimum(tails, heads)[corners] * nv + np.maximum(tails, heads)[corners]
    order, sorted_keys = stable_order(keys)
    is_first = np.ones(sorted_keys.size, dtype=bool)
    is_first[1:] = sorted_keys[1:] != sorted_keys[:-1]
    pair_of_sorted = np.cumsum(is_first) - 1
    starts = np.flatnonzero(is_first)
    pairs = np.stack([sorted_keys[starts] // nv, sorted_keys[starts] % nv], axis=1)
    width = max(1, int(np.diff(np.append(starts, sorted_keys.size)).max(initial=0)))
    position = np.arange(sorted_keys.size) - starts[pair_of_sorted]
    pair_corners = np.full((starts.size, width), n_corners, dtype=np.int32)
    pair_corners[pair_of_sorted, position] = corners[order]
    corner_pairs = np.full(n_corners, -1, dtype=np.int64)
    corner_pairs[corners[order]] = pair_of_sorted
    return pairs, pair_corners, corner_pairs


def _build(
    faces: np.ndarray, nv: int, pairs: np.ndarray, pair_corners: np.ndarray, corner_pairs: np.ndarray
) -> TriangulationPlan:
    """The one builder of `TriangulationPlan`s.

    Args:
        faces: `(nf, 3)` int32.
        nv: number of vertices.
        pairs: `(n_pairs, 2)` distinct vertex pairs `low < high`, sorted lexicographically.
        pair_corners: `(n_pairs, m)` the corners opposite the edges of each pair, padded with `3 nf`.
        corner_pairs: `(3 nf,)` the pair of each corner's opposite edge, `-1` for a loop.
    """
    pattern, source, slot_corners, corner_slots = edge_slot_maps(nv, pairs, pair_corners, corner_pairs)
    loop_corners = np.flatnonzero(corner_pairs < 0).astype(np.int32)
    face, k = np.divmod(loop_corners, 3)
    loop_vertices = faces[face, (k + 1) % 3].astype(np.int32)
    arrays = jax.device_put(
        {
            "source": source,
            "slot_corners": slot_corners,
            "corner_slots": corner_slots,
            "loop_corners": loop_corners,
            "loop_vertices": loop_vertices,
        }
    )
    return TriangulationPlan(faces=device_array(faces, np.int32), pattern=pattern, **arrays)


def edge_slot_maps(
    nv: int, pairs: np.ndarray, pair_corners: np.ndarray, corner_pairs: np.ndarray
) -> tuple[SparsityPattern, np.ndarray, np.ndarray, np.ndarray]:
    """`(pattern, source, slot_corners, corner_slots)`: where per-element edge values land in the vertex pattern.

    A "corner" is any per-element edge slot: the corner opposite an edge of a triangle here, a local
    edge `6 t + k` of a tet in `ddgjax.volume` (shared through `ddgjax.laplacian.internal`). Arguments as
    `_build`'s (`pair_corners` padded with the number of corners, `corner_pairs` `-1` for none);
    the results are `TriangulationPlan`'s fields of the same names, on the host.
    """
    n_corners = corner_pairs.size
    n_pairs = pairs.shape[0]
    pattern, source = SparsityPattern.from_edges(pairs, nv)
    # int32 throughout: every index here is below nv + 2 n_pairs + n_corners.
    off_source = source[nv:].astype(np.int32) - np.int32(nv)  # [low->high | high->low | 2 n_pairs: padding]
    n_off = off_source.size
    pair_of_slot = np.where(off_source >= n_pairs, off_source - n_pairs, off_source)  # padding -> n_pairs, a row of pads
    padded = np.concatenate([pair_corners.astype(np.int32), np.full((1, pair_corners.shape[1]), n_corners, np.int32)])
    slot_corners = np.take(padded, pair_of_slot, axis=0)
    # The slot of each pair low->high and high->low, then n_off: what a corner without a pair (-1) reads.
    slot_of_source = np.empty(2 * n_pairs + 1, dtype=np.int32)
    slot_of_source[off_source] = np.arange(n_off, dtype=np.int32)
    corner_slots = np.empty((n_corners, 2), dtype=np.int32)
    for column, first in enumerate((0, n_pairs)):
        slots = np.append(slot_of_source[first : first + n_pairs], np.int32(n_off))
        np.take(slots, corner_pairs, out=corner_slots[:, column])
    return pattern, source, slot_corners, corner_slots
