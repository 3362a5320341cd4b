"""The storage plan of a tetrahedral mesh's vertex-vertex operators: where per-tet edge values land in the pattern.

Host work, built once per connectivity and cached (as `ddgjax.laplacian`'s plans are), shared by the
Laplacian (`ddgjax.volume._laplacian`) and the dual cells and Hodge stars (`ddgjax.volume._dual`).
"""

from __future__ import annotations

import weakref

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from .._errors import DDGInputError
from ..laplacian.internal import edge_slot_maps
from ..sparse import SparseMatrix, SparsityPattern, gather_sum
from ._tet_mesh import TetMesh, require_tet_mesh
from ._topology import TetTopology


class TetPlan(eqx.Module):
    """Where per-tet edge values land in the `(nv, nv)` vertex pattern of a tet mesh (host-built, cached).

    Local edge `6 t + k` is edge `k` of tet `t` (`TET_EDGES` order).

    Attributes:
        pattern: the symmetric vertex pattern (diagonal plus both directions of every edge).
        source: `(nnz,)` each storage slot's index in `[diagonal | edges low->high | edges high->low]`.
        slot_edges: `(nnz - nv, w)` the local tet edges of each off-diagonal slot's edge (`6 nt` pads).
        edge_slots: `(6 nt, 2)` its transpose: the two off-diagonal slots (minus `nv`) of each local edge.
    """

    pattern: SparsityPattern
    source: Int[Array, " nnz"]
    slot_edges: Int[Array, "n_off w"]
    edge_slots: Int[Array, "n_local 2"]

    @property
    def n_vertices(self) -> int:
        """Number of vertices `nv`."""
        return self.pattern.shape[0]


_PLANS: "weakref.WeakKeyDictionary[TetTopology, TetPlan]" = weakref.WeakKeyDictionary()


def tet_plan(tet_mesh: TetMesh) -> TetPlan:
    """The `TetPlan` of `tet_mesh`'s connectivity (built on the host on first use, then cached).

    The vertex pattern of `ddgjax.sparse.SparsityPattern.from_edges` and the slot maps of
    `ddgjax.laplacian`'s plans (`edge_slot_maps`), with the local tet edges `6 t + k` as the
    "corners"; cached per `TetTopology` (weakly: it goes with the last mesh of that connectivity).
    libigl and gpytoolbox build their matrices from triplets on every call and have no plan.

    Args:
        tet_mesh: the tet mesh; it needs its topology (not under a compiled kernel).

    Returns:
        The cached `TetPlan`: the `(nv, nv)` sparsity pattern and the slot maps.
    """
    topology = require_tet_mesh("tet_mesh", tet_mesh).topology
    if topology is None:
        raise DDGInputError("tet_mesh: a storage plan needs the topology, which a compiled kernel does not see; build it before")
    plan = _PLANS.get(topology)
    if plan is None:
        with jax.ensure_compile_time_eval():  # host work, even inside a caller's trace
            n_local = 6 * topology.n_tets
            edge_locals = np.where(topology.edge_tets >= 0, 6 * topology.edge_tets + topology.edge_tet_edges, n_local)
            pattern, source, slot_edges, edge_slots = edge_slot_maps(
                topology.n_vertices, topology.edges, edge_locals.astype(np.int32), topology.tet_edges.reshape(-1)
            )
            arrays = jax.device_put({"source": source, "slot_edges": slot_edges, "edge_slots": edge_slots})
            plan = _PLANS[topology] = TetPlan(pattern=pattern, **arrays)
    return plan


def slot_values(per_edge: Float[Array, "nt 6"], plan: TetPlan) -> Float[Array, " n_off"]:
    """Per-tet edge values summed onto the off-diagonal storage slots of `plan.pattern` (one fixed gather)."""
    return gather_sum(per_edge.reshape(-1), plan.slot_edges, plan.edge_slots)


def with_diagonal(diagonal: Float[Array, " nv"], off_diagonal: Float[Array, " n_off"]) -> Float[Array, " nnz"]:
    return jnp.concatenate([diagonal, off_diagonal])


def row_sums(off_diagonal: Float[Array, " n_off"], plan: TetPlan) -> Float[Array, " nv"]:
    """Row sums of the symmetric matrix on `plan.pattern` with these off-diagonal values and a zero diagonal."""
    zeros = jnp.zeros(plan.n_vertices, off_diagonal.dtype)
    return SparseMatrix(with_diagonal(zeros, off_diagonal), plan.pattern, symmetric=True).row_sums()


def laplacian_values_from_weights(weights: Float[Array, "nt 6"], plan: TetPlan) -> Float[Array, " nnz"]:
    """Values of the Laplacian on `plan.pattern` from per-tet edge weights `w` (`L_ij = -sum w`, `L 1 = 0` exactly)."""
    off_diagonal = slot_values(-weights, plan)
    return with_diagonal(-row_sums(off_diagonal, plan), off_diagonal)
