"""An algebraic-multigrid preconditioner for the vertex-partitioned conjugate gradient: a sharded two-grid at the top.

`ddgjax.solve.amg_v_cycle` applies a smoothed-aggregation V-cycle to a whole vector on one device.
On a partitioned mesh (`ddgjax.sharding._partition`) only the finest level is as large as the mesh;
the coarse levels have ~n / 20 unknowns and fewer. So the finest level is sharded like the vectors
of the conjugate gradient and the rest of the hierarchy is replicated: with `A = L + shift M` (the
sharded product), `D = diag(A)`, `w_1..w_s` the finest level's smoother weights and `P_0` its
prolongator (rows in the partition's layout, padding rows empty), one application `z = B r` is

    x   = S(0, r)                 pre-smoothing, S(x, r): s steps x <- x + w_k D^{-1} (r - A x)
    r_c = P_0^T (r - A x)         each device multiplies its own rows of P_0; psum over devices
    e_c = B_c r_c                 amg_v_cycle on levels 1, 2, ... (replicated on every device)
    z   = S(x + P_0 e_c, r)       prolongation (each device its own rows), post-smoothing

The same structure as `amg_v_cycle`'s first level: the smoother's steps are polynomials in
`D^{-1} A` with the same weights before and after, so `I - B A = E_S (I - P_0 B_c P_0^T A) E_S`
with `E_S = prod_k (I - w_k D^{-1} A)` self-adjoint in the `A` inner product, and `B` is symmetric
positive definite when `B_c` is (an SPD V-cycle, or the coarsest pseudo-inverse) and the smoother
contracts (`ddgjax.solve._amg`, module docstring). The padding vertices carry the identity in `A`
and nothing in `P_0`, so `B` is `1 - prod_k (1 - w_k)^2` times the identity there: positive. Per application: one
all-reduce of the `n_1`-vector `r_c`, the halo exchanges of the `2 s - 1` sharded products, and the
whole coarse V-cycle on every device.

The hierarchy is built on the host (pyamg): `partition_amg(partition, hierarchy)` converts one made
by `ddgjax.solve.amg_hierarchy(L + shift * M)` from the mesh's matrix in the mesh's vertex order;
`sharded_amg_hierarchy` (`ddgjax.sharding._operator`) builds it from the partition alone.

References: P. Vaněk, J. Mandel & M. Brezina, "Algebraic multigrid by smoothed aggregation for second
and fourth order elliptic problems", Computing 56 (1996); K. Stüben, "A review of algebraic multigrid",
J. Comput. Appl. Math. 128 (2001); M. Adams, M. Brezina, J. Hu & R. Tuminaro, "Parallel multigrid
smoothing: polynomial versus Gauss-Seidel", J. Comput. Phys. 188 (2003).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse as sp
from jax.sharding import NamedSharding
from jax.sharding import PartitionSpec as P
from jaxtyping import Array, Float, Int

from .._errors import DDGInputError, is_traced
from ..solve import AMGHierarchy, amg_v_cycle
from ..solve.internal import AMGLevel, jacobi_steps
from ._partition import VERTICES, VertexPartition


class ShardedAMG(eqx.Module):
    """An `AMGHierarchy` laid out for a `VertexPartition` (module docstring); a pytree, for `sharded_cg(preconditioner=...)`.

    Attributes:
        columns: `(n_padded, k)` int32, the coarse columns of each row of `P_0` in the partition's
            layout (ELL, padding slots point at column 0 with value 0), sharded `P("vertices")`.
        values: `(n_padded, k)` the entries of `P_0` there (0 on padding rows), sharded `P("vertices")`.
        weights: `(s,)` the finest level's smoother weights `w_k`, replicated (`(0,)` when the
            hierarchy has a single level: then `P_0` is the identity and `B = A^{-1}` exactly).
        coarse: the `AMGHierarchy` of levels 1, 2, ... (its finest operator `A_1`), replicated.
        n_padded: the partition's `n_padded` (static).
    """

    columns: Int[Array, "n_padded k"]
    values: Float[Array, "n_padded k"]
    weights: Float[Array, " s"]
    coarse: AMGHierarchy
    n_padded: int = eqx.field(static=True)


def partition_amg(partition: VertexPartition, hierarchy: AMGHierarchy) -> ShardedAMG:
    """Lay out an `AMGHierarchy` of the mesh's matrix for `partition` (module docstring): done once, on the host.

    Args:
        partition: from `partition_vertices(mesh)`.
        hierarchy: `amg_hierarchy(cotan_laplacian(mesh) + shift * mass_matrix(mesh, mass=mass))`, of
            shape `(nv, nv)` in the mesh's vertex order (the same matrix `sharded_cg` applies; another
            SPD matrix of that size gives a valid but weaker preconditioner).

    Returns:
        `ShardedAMG`: `P_0`'s rows permuted to the partition's layout and sharded, the rest replicated.
    """
    return layout(partition, hierarchy, np.asarray(partition.order))


def layout(partition: VertexPartition, hierarchy: AMGHierarchy, order: np.ndarray) -> ShardedAMG:
    """`hierarchy` (rows in some order) on `partition`: layout position `p < nv` is the hierarchy's row `order[p]`."""
    if not isinstance(partition, VertexPartition):
        raise DDGInputError(
            f"partition: expected a VertexPartition, got {type(partition).__name__}; make one with "
            "ddgjax.sharding.partition_vertices(mesh)"
        )
    if not isinstance(hierarchy, AMGHierarchy):
        raise DDGInputError(
            f"hierarchy: expected an AMGHierarchy from ddgjax.solve.amg_hierarchy, got {type(hierarchy).__name__}"
        )
    n = partition.n_vertices
    if hierarchy.shape != (n, n):
        raise DDGInputError(
            f"hierarchy: expected an AMGHierarchy of shape ({n}, {n}) (the partitioned mesh's vertices), got {hierarchy.shape}"
        )
    if any(is_traced(leaf) for leaf in jax.tree.leaves(hierarchy)):
        raise DDGInputError(
            "hierarchy: laying out an AMGHierarchy reads its prolongator on the host; call partition_amg(partition, hierarchy) "
            "outside jit and pass the ShardedAMG into the jitted function"
        )
    hierarchy = jax.lax.stop_gradient(hierarchy)
    dtype = hierarchy.coarse_inverse.dtype
    if hierarchy.levels:
        first = hierarchy.levels[0]
        prolongator = sp.csr_matrix(first.P.to_scipy())
        weights = np.asarray(first.weights)
        # The galerkin maps serve amg_refresh only; the replicated copy does without them.
        levels = tuple(
            AMGLevel(A=lv.A, P=lv.P, R=lv.R, inverse_diagonal=lv.inverse_diagonal, weights=lv.weights)
            for lv in hierarchy.levels[1:]
        )
        coarse = AMGHierarchy(
            levels=levels, coarse=hierarchy.coarse, coarse_inverse=hierarchy.coarse_inverse, smoother=hierarchy.smoother
        )
    else:
        # One level: P_0 = I and no smoothing, so the "coarse" solve is the dense inverse itself.
        prolongator = sp.identity(n, dtype=dtype, format="csr")
        weights = np.zeros(0, dtype)
        coarse = hierarchy
    rows = prolongator[order]
    counts = np.diff(rows.indptr)
    width = max(1, int(counts.max(initial=0)))
    columns = np.zeros((partition.n_padded, width), np.int32)
    values = np.zeros((partition.n_padded, width), dtype)
    row = np.repeat(np.arange(n), counts)
    slot = np.arange(rows.nnz) - np.repeat(rows.indptr[:-1], counts)
    columns[row, slot] = rows.indices
    values[row, slot] = rows.data
    replicated = NamedSharding(partition.sharding.mesh, P())
    columns, values = jax.device_put((columns, values), partition.sharding)
    weights, coarse = jax.device_put((weights, coarse), replicated)
    return ShardedAMG(columns=columns, values=values, weights=weights, coarse=coarse, n_padded=partition.n_padded)


def local_v_cycle(matvec, inverse_diagonal, columns, values, weights, coarse: AMGHierarchy, r):
    """Per device, inside `jax.shard_map`: its rows of `B r` (module docstring); `matvec` its rows of `A x` (halo exchange)."""

    def smooth(x):
        return jacobi_steps(matvec, inverse_diagonal, weights, x, r)

    x = smooth(None)
    residual = r if x is None else r - matvec(x)
    n_coarse = coarse.shape[0]
    # Each device restricts with its own rows of P_0 (a scatter-add); the sum over devices is P_0^T r.
    local = jnp.zeros(n_coarse, r.dtype).at[columns.reshape(-1)].add((values * residual[:, None]).reshape(-1))
    correction = amg_v_cycle(coarse, jax.lax.psum(local, VERTICES)).astype(r.dtype)
    prolonged = jnp.sum(values * jnp.take(correction, columns, axis=0), axis=1)
    return smooth(prolonged if x is None else x + prolonged)


def check_layout(amg: ShardedAMG, partition: VertexPartition) -> None:
    """Refuse a `ShardedAMG` laid out for another partition."""
    if amg.n_padded != partition.n_padded or amg.columns.shape[0] != partition.n_padded:
        raise DDGInputError(
            f"preconditioner: a ShardedAMG for {amg.n_padded} padded vertices on a partition of {partition.n_padded}; "
            "make it with partition_amg(partition, hierarchy) for this partition"
        )
