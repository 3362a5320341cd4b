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
`ddgjax.solve`'s pure-JAX Jacobi-preconditioned conjugate gradient: the products are the
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
from jax.sharding import PartitionSpec as P
from jaxtyping import Array, ArrayLike, Float, Real

from .._compile import kernel
from .._errors import DDGInputError
from .._indexing import take_rows
from .._options import LUMPED_MASS_MATRICES, check_mass
from .._results import raise_if_failed
from ..internal import linear_solution, preconditioned_cg
from ..mesh import corner_cotangents_from_lengths_sq, corner_dual_areas_from_lengths_sq
from ..solve import LinearSolution
from ..sparse import gather_sum
from ._partition import VERTICES, LocalPlan, VertexPartition

"""The `mass=` values `sharded_cg` supports: the lumped (diagonal) ones of `ddgjax.MASS_MATRICES`."""


def sharded_laplacian_apply(
    partition: VertexPartition, u: Float[ArrayLike, "n_padded *k"], *, vertices: Float[ArrayLike, "n_padded 3"] | None = None
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
    *,
    shift: Real[ArrayLike, ""] = 0.0,
    mass: str = "voronoi",
    vertices: Float[ArrayLike, "n_padded 3"] | None = None,
    rtol: float = 1e-10,
    max_steps: int | None = None,
    residual_tolerance: float = 1e-6,
    throw: bool = True,
) -> LinearSolution:
    """Solve `(L + shift M) x = b` on a vertex-partitioned mesh by Jacobi-preconditioned CG (module docstring).

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

    Returns:
        `ddgjax.solve.LinearSolution` whose `value` is sharded `P("vertices")`; failures through
        `ddgjax.RESULTS` (`throw=`). SciPy: `scipy.sparse.linalg.spsolve(L + shift * M, b)`.
    """
    if check_mass(mass) not in LUMPED_MASS_MATRICES:
        raise DDGInputError(
            f"mass: sharded_cg supports the lumped mass matrices {', '.join(map(repr, LUMPED_MASS_MATRICES))}, got {mass!r} "
            "(each device keeps only the diagonal of its rows; the full Galerkin mass matrix is not partitioned)"
        )
    b, vertices = _check(partition, b, vertices)
    if b.ndim != 1:
        raise DDGInputError(f"b: expected one right-hand side of shape ({partition.n_padded},), got {b.shape}")
    if max_steps is None:
        max_steps = 10 * partition.n_padded
    settings = {"mass": mass, "rtol": rtol, "max_steps": max_steps, "residual_tolerance": residual_tolerance}
    solution = _cg(partition.plan, vertices, b, jnp.asarray(shift, b.dtype), **settings, **_sizes(partition))
    return raise_if_failed(solution, solution.result, throw)


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
def _cg(plan: LocalPlan, vertices, b, shift, *, device_mesh, n_local, mass, rtol, max_steps, residual_tolerance):
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

    def solve(operator, rhs):
        return preconditioned_cg(operator, rhs, lambda r: inverse * r, rtol, max_steps)

    x, (num_steps, converged) = jax.lax.custom_linear_solve(matvec, b, solve, symmetric=True, has_aux=True)
    return linear_solution(matvec, b, x, (num_steps, converged, True), "cg", residual_tolerance)
