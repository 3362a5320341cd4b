"""The cotan Laplacian of a vertex-partitioned mesh, applied across devices, and a conjugate gradient on it.

Each device computes its own rows of `L u` (`ddgjax.sharding._partition`): it receives its halo
with one `jax.lax.all_to_all`, computes the cotangents of its local faces from squared edge lengths
(the intrinsic core `ddgjax.mesh.corner_cotangents_from_lengths_sq`), gathers them onto the directed
edges of its rows (`ddgjax.sparse.gather_sum`, whose transpose is a gather) and sums

    (L u)_i = sum_{j ~ i} w_ij (u_i - u_j),    w_ij = (cot a_ij + cot b_ij) / 2,

the convention of DESIGN.md (`L` positive semidefinite, `L == -igl.cotmatrix(V, F)`), equal to
`ddgjax.laplacian.laplacian_apply` to round-off. Written with `jax.shard_map`, so it is an ordinary
JAX function: `jit`, `grad` (in `u` and in the vertex positions), `vmap`.

`sharded_cg` solves `(L + shift M) x = b` (`M` the lumped mass, `shift >= 0`) with
`ddgjax.solve`'s pure-JAX preconditioned conjugate gradient, Jacobi or algebraic multigrid (a
sharded finest level over a replicated coarse V-cycle, `ddgjax.sharding._amg`): the products are the
`shard_map` above, the vectors stay sharded `P("vertices")` through the `lax.while_loop`, and each
inner product is one all-reduce of a scalar that XLA inserts. The padding vertices of the layout
carry the identity (so the system stays definite) and a zero right-hand side, so their solution is 0.
Differentiable in `b` and the vertex positions by implicit differentiation
(`jax.lax.custom_linear_solve`, as `ddgjax.solve.linear_solve`).

Reference: JAX documentation, "Manual parallelism with shard_map"; Y. Saad, "Iterative Methods for
Sparse Linear Systems" (2003), Algorithm 9.1; U. Pinkall, K. Polthier (1993) for the cotan weights.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse as sp
from jax.sharding import PartitionSpec as P
from jaxtyping import Array, ArrayLike, Float, Real

from .._compile import kernel
from .._errors import DDGInputError, is_traced
from .._indexing import take_rows
from .._options import LUMPED_MASS_MATRICES, check_mass
from .._results import raise_if_failed
from ..mesh import corner_cotangents_from_lengths_sq, corner_dual_areas_from_lengths_sq
from ..solve import AMGHierarchy, LinearSolution, amg_hierarchy
from ..solve.internal import PRECONDITIONERS, linear_solution, preconditioned_cg
from ..sparse import from_scipy, gather_sum
from ._amg import ShardedAMG, check_layout, layout, local_v_cycle
from ._partition import VERTICES, LocalPlan, VertexPartition


def sharded_laplacian_apply(
    partition: VertexPartition, u: Float[ArrayLike, "n_padded *k"], /, *, vertices: Float[ArrayLike, "n_padded 3"] | None = None
) -> Float[Array, "n_padded *k"]:
    """`L u` on a vertex-partitioned mesh, each device computing its own rows (module docstring).

    Args:
        partition: from `partition_vertices(mesh)`.
        u: `(n_padded,)` or `(n_padded, k)` in partitioned layout (`partition.shard(u)`).
        vertices: `(n_padded, 3)` positions in partitioned layout (default `partition.vertices`);
            pass them to differentiate with respect to the positions.

    Returns:
        `L u` in partitioned layout, sharded `P("vertices")` (`partition.unshard` brings it back to
        the mesh's order). Equals `laplacian_apply(mesh, u)` to round-off; 0 on padding.
    """
    u, vertices = _check(partition, u, vertices)
    return _apply(partition.plan, vertices, u, **_sizes(partition))


def sharded_cg(
    partition: VertexPartition,
    b: Float[ArrayLike, " n_padded"],
    /,
    *,
    shift: Real[ArrayLike, ""] = 0.0,
    mass: str = "voronoi",
    vertices: Float[ArrayLike, "n_padded 3"] | None = None,
    rtol: float = 1e-10,
    max_steps: int | None = None,
    residual_tolerance: float = 1e-6,
    throw: bool = True,
    preconditioner: str | AMGHierarchy | ShardedAMG = "jacobi",
) -> LinearSolution:
    """Solve `(L + shift M) x = b` on a vertex-partitioned mesh by preconditioned CG (module docstring).

    `L` the cotan Laplacian, `M` a lumped mass matrix (`mass="voronoi"` or `"barycentric"`, as
    `ddgjax.laplacian.mass_matrix`; the full `"galerkin"` one is refused: each device keeps only the
    diagonal of its own rows). With `shift > 0` the system is positive definite; the heat step
    `(M + t L) x = M u` is `(L + M / t) x = M u / t`. With `shift = 0` on a closed mesh `L` is
    singular: CG converges only for a right-hand side orthogonal to the constants.

    Args:
        partition: from `partition_vertices(mesh)`.
        b: `(n_padded,)` right-hand side in partitioned layout (`partition.shard(b)`; 0 on padding).
        shift: `>= 0` (may be traced).
        mass: `"voronoi"` (default) or `"barycentric"`, the lumped `ddgjax.MASS_MATRICES`.
        vertices: positions in partitioned layout (default `partition.vertices`).
        rtol, max_steps, residual_tolerance, throw: as `ddgjax.solve.linear_solve` (CG stops at
            `|b - A x| <= rtol |b|`; `max_steps` defaults to `10 n_padded`).
        preconditioner: `"jacobi"` (default, `D^{-1}`); `"amg"`, a smoothed-aggregation hierarchy of
            `A = L + shift M` built here on the host from the partition (`sharded_amg_hierarchy`;
            `shift` and `vertices` must be concrete, and the build costs a pyamg set-up per call);
            an `AMGHierarchy` of the mesh's matrix in the mesh's vertex order
            (`amg_hierarchy(cotan_laplacian(mesh) + shift * mass_matrix(mesh))`, laid out here by
            `partition_amg`); or a `ShardedAMG` from `partition_amg` / `sharded_amg_hierarchy`,
            built once for many solves. The AMG preconditioner is `B = ` a two-grid cycle at the
            top (`ddgjax.sharding._amg`): `x = S(0, r)`, `r_c = psum_d P_0[d]^T (r - A x)`,
            `z = S(x + P_0 amg_v_cycle(levels 1.., r_c), r)`, `S` the finest level's Chebyshev /
            Jacobi polynomial smoother in `D^{-1} A` with the sharded product; SPD, so CG applies.
            The hierarchy is a constant (`stop_gradient`): it changes the iterations, not the answer.

    Returns:
        `ddgjax.solve.LinearSolution` whose `value` is sharded `P("vertices")`; failures through
        `ddgjax.RESULTS` (`throw=`). SciPy: `scipy.sparse.linalg.spsolve(L + shift * M, b)`.
    """
    _check_mass(mass)
    b, vertices = _check(partition, b, vertices)
    if b.ndim != 1:
        raise DDGInputError(f"b: expected one right-hand side of shape ({partition.n_padded},), got {b.shape}")
    if max_steps is None:
        max_steps = 10 * partition.n_padded
    amg = _preconditioner(partition, preconditioner, shift=shift, mass=mass, vertices=vertices)
    settings = {"mass": mass, "rtol": rtol, "max_steps": max_steps, "residual_tolerance": residual_tolerance}
    solution = _cg(partition.plan, vertices, b, jnp.asarray(shift, b.dtype), amg, **settings, **_sizes(partition))
    return raise_if_failed(solution, solution.result, throw)


def sharded_amg_hierarchy(
    partition: VertexPartition,
    *,
    shift: float = 0.0,
    mass: str = "voronoi",
    vertices: Float[ArrayLike, "n_padded 3"] | None = None,
    **options,
) -> ShardedAMG:
    """The AMG preconditioner of `A = L + shift M` for `sharded_cg`, built from the partition alone (host, once).

    Computes the weights of `L` and the lumped masses with the same sharded kernel as `sharded_cg`,
    gathers them to the host as the `(nv, nv)` matrix `A` in the partition's locality order (the
    exact matrix the sharded product applies), builds `ddgjax.solve.amg_hierarchy(A, **options)` and
    lays it out (`partition_amg`). Outside `jit`: `shift` and `vertices` must be concrete.

    Args:
        partition: from `partition_vertices(mesh)`.
        shift: `>= 0`, concrete.
        mass: `"voronoi"` (default) or `"barycentric"`.
        vertices: positions in partitioned layout (default `partition.vertices`), concrete.
        **options: passed to `amg_hierarchy` (`smoother`, `steps`, `strength`, `max_coarse`, `max_levels`).

    Returns:
        `ShardedAMG` for `sharded_cg(..., preconditioner=...)`.
    """
    _check_mass(mass)
    _, vertices = _check(partition, jnp.zeros(partition.n_padded), vertices)
    for name, value in (("shift", shift), ("vertices", vertices)):
        if is_traced(value):
            raise DDGInputError(
                f"{name}: the AMG hierarchy is built on the host from concrete values; pass a concrete {name} with "
                'preconditioner="amg", or build the preconditioner outside jit (sharded_amg_hierarchy, partition_amg) and pass it'
            )
    if not float(shift) >= 0:
        raise DDGInputError(f"shift: expected a number >= 0 (L + shift M must be positive semidefinite), got {shift!r}")
    geometry = jax.jit(
        _shard_map(functools.partial(_local_geometry, n_local=partition.n_local, mass=mass), partition.sharding.mesh, 2, 2)
    )
    weights, masses = (np.asarray(array) for array in geometry(partition.plan, vertices))
    matrix = _gathered_matrix(partition, weights, float(shift) * masses)
    return layout(partition, amg_hierarchy(from_scipy(matrix), **options), np.arange(partition.n_vertices))


def _gathered_matrix(partition: VertexPartition, weights: np.ndarray, shift_masses: np.ndarray) -> sp.csr_matrix:
    """`L + shift M` in locality order from each device's ELL weights, its local columns mapped back to global ones.

    Device `d`'s local column `c < n_local` is its vertex `d n_local + c`; `n_local + e n_halo + t` is
    the `t`-th vertex device `e` sends it, `e n_local + send_index[e, d, t]` (`ddgjax.sharding._partition`).
    """
    n, n_local, n_halo, n_dev = partition.n_vertices, partition.n_local, partition.n_halo, partition.n_devices
    neighbours = np.asarray(partition.plan.neighbours).astype(np.int64)
    sends = np.asarray(partition.plan.send_index).astype(np.int64).reshape(n_dev, n_dev, n_halo)
    device = np.repeat(np.arange(n_dev), n_local)[:, None]
    halo = np.maximum(neighbours - n_local, 0)
    source = halo // n_halo
    columns = np.where(
        neighbours < n_local, device * n_local + neighbours, source * n_local + sends[source, device, halo % n_halo]
    )
    rows = np.broadcast_to(np.arange(partition.n_padded)[:, None], columns.shape)
    keep = (rows < n) & (columns != rows) & (weights != 0)
    off = sp.coo_matrix((weights[keep], (rows[keep], columns[keep])), shape=(n, n)).tocsr()
    diagonal = -weights[:n].sum(axis=1) + shift_masses[:n]
    matrix = off + sp.diags(diagonal)
    # The two devices holding a boundary face compute its cotangents alike; the mean removes any round-off asymmetry.
    return sp.csr_matrix((matrix + matrix.T) / 2)


def _check_mass(mass: str) -> None:
    if check_mass(mass) not in LUMPED_MASS_MATRICES:
        raise DDGInputError(
            f"mass: sharded_cg supports the lumped mass matrices {', '.join(map(repr, LUMPED_MASS_MATRICES))}, got {mass!r} "
            "(each device keeps only the diagonal of its rows; the full Galerkin mass matrix is not partitioned)"
        )


def _preconditioner(partition: VertexPartition, preconditioner, *, shift, mass, vertices) -> ShardedAMG | None:
    """`None` for Jacobi, else the `ShardedAMG` that `preconditioner` names or holds."""
    if isinstance(preconditioner, ShardedAMG):
        check_layout(preconditioner, partition)
        return preconditioner
    if isinstance(preconditioner, AMGHierarchy):
        return layout(partition, preconditioner, np.asarray(partition.order))
    if isinstance(preconditioner, str) and preconditioner in PRECONDITIONERS:
        if preconditioner == "jacobi":
            return None
        return sharded_amg_hierarchy(partition, shift=shift, mass=mass, vertices=vertices)
    raise DDGInputError(
        f"preconditioner: expected 'jacobi', 'amg', an AMGHierarchy (ddgjax.solve.amg_hierarchy) or a ShardedAMG "
        f"(partition_amg, sharded_amg_hierarchy), got {preconditioner!r}"
    )


def _check(partition: VertexPartition, u, vertices):
    if not isinstance(partition, VertexPartition):
        raise DDGInputError(
            f"partition: expected a VertexPartition, got {type(partition).__name__}; make one with "
            "ddgjax.sharding.partition_vertices(mesh)"
        )
    n = partition.n_padded
    vertices = partition.vertices if vertices is None else jnp.asarray(vertices)
    if vertices.shape != (n, 3):
        raise DDGInputError(f"vertices: expected shape ({n}, 3) (partitioned layout), got {vertices.shape}")
    u = jnp.asarray(u)
    if u.ndim not in (1, 2) or u.shape[0] != n:
        raise DDGInputError(f"u: expected shape ({n},) or ({n}, k) in partitioned layout (partition.shard(u)), got {u.shape}")
    return u, vertices


def _sizes(partition: VertexPartition) -> dict:
    return {"device_mesh": partition.sharding.mesh, "n_local": partition.n_local}


def _exchange(owned, send_index):
    """`[owned | halo]`: this device's values followed by those it receives from every device (one all-to-all)."""
    received = jax.lax.all_to_all(take_rows(owned, send_index), VERTICES, 0, 0, tiled=True)
    return jnp.concatenate([owned, received])


def _local_geometry(plan: LocalPlan, vertices, *, n_local: int, mass: str):
    """Per device: `(w, m)`, `w (n_local, width)` the weights `L_ij` of its directed edges and `m (n_local,)` its lumped masses."""
    points = take_rows(_exchange(vertices, plan.send_index), plan.faces)  # (f, 3 corners, 3)
    edges = jnp.roll(points, -2, axis=1) - jnp.roll(points, -1, axis=1)  # edge k: p_{k+2} - p_{k+1}, opposite corner k
    lengths_sq = jnp.sum(edges * edges, axis=-1)
    entries = -0.5 * corner_cotangents_from_lengths_sq(lengths_sq)  # L_ij of the edge opposite each corner
    weights = gather_sum(entries.reshape(-1), plan.slot_corners, plan.corner_slots).reshape(n_local, -1)
    areas = corner_dual_areas_from_lengths_sq(lengths_sq, dual=mass).reshape(-1)
    return weights, gather_sum(areas, plan.vertex_corners, plan.corner_vertices)


def _local_apply(plan: LocalPlan, weights, u):
    """Per device: its rows of `L u`, `sum_j L_ij (u_j - u_i)` (`L_ii = -sum_j L_ij`), one halo exchange of `u`."""
    columns = u.reshape(u.shape[0], -1)
    everything = _exchange(columns, plan.send_index)
    result = jnp.zeros_like(columns)
    for k in range(weights.shape[1]):
        result = result + weights[:, k, None] * (take_rows(everything, plan.neighbours[:, k]) - columns)
    return result.reshape(u.shape)


def _shard_map(function, device_mesh, n_in: int, n_out: int):
    """`jax.shard_map` with every input and output split `P("vertices")`."""
    spec = P(VERTICES)
    outs = spec if n_out == 1 else (spec,) * n_out
    return jax.shard_map(function, mesh=device_mesh, in_specs=(spec,) * n_in, out_specs=outs)


# kernel: XLA:CPU without the YNNPACK fusions that slow the short reductions of geometry (ddgjax._compile).
@kernel(static_argnames=("device_mesh", "n_local"))
def _apply(plan: LocalPlan, vertices, u, *, device_mesh, n_local: int):
    geometry = _shard_map(functools.partial(_local_geometry, n_local=n_local, mass="voronoi"), device_mesh, 2, 2)
    apply = _shard_map(_local_apply, device_mesh, 3, 1)
    weights, _ = geometry(plan, vertices)
    return apply(plan, weights, u)


@kernel(static_argnames=("device_mesh", "n_local", "mass", "rtol", "max_steps", "residual_tolerance"))
def _cg(plan: LocalPlan, vertices, b, shift, amg, *, device_mesh, n_local, mass, rtol, max_steps, residual_tolerance):
    geometry = _shard_map(functools.partial(_local_geometry, n_local=n_local, mass=mass), device_mesh, 2, 2)
    apply = _shard_map(_local_apply, device_mesh, 3, 1)
    weights, masses = geometry(plan, vertices)
    # Padding rows are empty in L and M: the identity there keeps A definite (and b is 0 there).
    diagonal_shift = shift * masses + plan.padding

    def matvec(x):
        return apply(plan, weights, x) + diagonal_shift * x

    diagonal = -jnp.sum(weights, axis=1) + diagonal_shift
    fixed = jax.lax.stop_gradient(diagonal)
    inverse = jnp.where(fixed > 0, 1.0 / jnp.where(fixed > 0, fixed, 1.0), 1.0)
    if amg is None:
        precondition = lambda r: inverse * r
    else:
        precondition = _amg_cycle(
            plan, jax.lax.stop_gradient(weights), jax.lax.stop_gradient(diagonal_shift), inverse, amg, device_mesh
        )

    def solve(operator, rhs):
        return preconditioned_cg(operator, rhs, precondition, rtol, max_steps)

    x, (num_steps, converged) = jax.lax.custom_linear_solve(matvec, b, solve, symmetric=True, has_aux=True)
    return linear_solution(matvec, b, x, (num_steps, converged, True), "cg", residual_tolerance)


def _amg_cycle(plan: LocalPlan, weights, diagonal_shift, inverse, amg: ShardedAMG, device_mesh):
    """`r -> B r`, the AMG cycle of `ddgjax.sharding._amg`, in one `shard_map`: the finest level split, the coarse replicated."""
    amg = jax.lax.stop_gradient(amg)

    def local(plan, weights, diagonal_shift, inverse, columns, values, smoothing, coarse, r):
        def matvec(x):
            return _local_apply(plan, weights, x) + diagonal_shift * x

        return local_v_cycle(matvec, inverse, columns, values, smoothing, coarse, r)

    split = P(VERTICES)
    cycle = jax.shard_map(local, mesh=device_mesh, in_specs=(split,) * 6 + (P(), P(), split), out_specs=split)
    return lambda r: cycle(plan, weights, diagonal_shift, inverse, amg.columns, amg.values, amg.weights, amg.coarse, r)
