"""Storage plan of vertex-vertex operators, built once per connectivity on first use and cached.

The cotan Laplacian and the Galerkin mass matrix share one sparsity pattern (the diagonal plus both
directions of every edge, `SparsityPattern.from_edges`). Their values change with the geometry and
are re-assembled into that pattern with fixed gathers whose indices are computed here, on the host,
from the topology alone (DESIGN.md, two phases). A mesh used only for areas or curvature never
builds a plan.
"""

from __future__ import annotations

import weakref

import equinox as eqx
import jax
import numpy as np
from jaxtyping import Array, Int

from .._errors import DDGInputError
from ..mesh import Mesh, MeshTopology, require_mesh
from ..sparse import CongruencePlan, SparsityPattern, congruence_plan


class VertexPlan(eqx.Module):
    """Where per-vertex, per-edge and per-corner values land in the vertex-vertex pattern.

    Attributes:
        pattern: the `(nv, nv)` symmetric pattern (diagonal-first ELL storage, `SparsityPattern`).
        source: `(nnz,)` for each storage slot, its index in the list
            `[diagonal (nv) | edges low->high (ne) | edges high->low (ne)]`, or `nv + 2 ne` for an ELL
            padding slot, so values assemble with one gather (`take_rows_or_zero(entries, source)`).
        slot_corners: `(nnz - nv, m)` for each off-diagonal storage slot `nv + s`, the flat corners
            `3 f + k` opposite its edge (`3 nf` pads), so per-corner values (cotangents) land in
            storage order with one gather.
        corner_slots: `(3 nf, 2)` its transpose: the two off-diagonal slots (minus `nv`) of each
            corner's edge, for a scatter-free reverse pass (`ddgjax.sparse.gather_sum`).
    """

    pattern: SparsityPattern
    source: Int[Array, " nnz"]
    slot_corners: Int[Array, "n_off m"]
    corner_slots: Int[Array, "n_corners 2"]


# Keyed by topology, which compares by content: meshes of one connectivity share one plan.
_VERTEX_PLANS: "weakref.WeakKeyDictionary[MeshTopology, VertexPlan]" = weakref.WeakKeyDictionary()
_DEC_PLANS: "weakref.WeakKeyDictionary[MeshTopology, CongruencePlan]" = weakref.WeakKeyDictionary()


def vertex_plan(mesh: Mesh) -> VertexPlan:
    """The `VertexPlan` of `mesh`'s connectivity (built on the host on first use, then cached)."""
    topology = _topology(mesh)
    plan = _VERTEX_PLANS.get(topology)
    if plan is None:
        # Host work even when called inside a caller's trace: the plan depends on the topology only.
        with jax.ensure_compile_time_eval():
            plan = _VERTEX_PLANS[topology] = _build_vertex_plan(topology)
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


def _build_vertex_plan(topology: MeshTopology) -> VertexPlan:
    nv, ne, nf = topology.n_vertices, topology.n_edges, topology.n_faces
    pattern, source = SparsityPattern.from_edges(topology.edges, nv)
    # int32 throughout: every index here is below nv + 2 ne + 3 nf.
    off_source = source[nv:].astype(np.int32)
    edge = off_source - np.int32(nv)
    # high -> low entries map to their edge too; padding (2 ne) lands on ne, the padding row.
    np.subtract(edge, np.int32(ne), out=edge, where=edge >= ne)
    edge_corners = np.full((ne + 1, topology.edge_faces.shape[1]), 3 * nf, dtype=np.int32)
    np.copyto(edge_corners[:ne], 3 * topology.edge_faces + topology.edge_face_corners, where=topology.edge_faces >= 0)
    slot_corners = np.take(edge_corners, edge, axis=0)
    slot_of_source = np.empty(nv + 2 * ne + 1, dtype=np.int32)
    slot_of_source[off_source] = np.arange(off_source.size, dtype=np.int32)
    corner_edges = topology.face_edges.reshape(-1)
    corner_slots = np.empty((corner_edges.size, 2), dtype=np.int32)
    corner_slots[:, 0] = np.take(slot_of_source[nv : nv + ne], corner_edges)
    corner_slots[:, 1] = np.take(slot_of_source[nv + ne : nv + 2 * ne], corner_edges)
    arrays = jax.device_put({"source": source, "slot_corners": slot_corners, "corner_slots": corner_slots})
    return VertexPlan(pattern=pattern, **arrays)
