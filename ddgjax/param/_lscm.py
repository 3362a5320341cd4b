"""Free-boundary conformal maps: least squares conformal maps (LSCM) and the spectral conformal map.

The conformal energy of a piecewise-linear map `x = (u, v)` of a surface into the plane is its
Dirichlet energy minus its signed area,

    E_C(u, v) = E_D - A = 1/2 (u^T L u + v^T L v) - 1/2 sum_{boundary edges a->b} (u_a v_b - u_b v_a),

`L` the PSD cotan Laplacian and the boundary edges in loop order (`ddgjax.param._disk`): the signed
area of a disk's image is that of its boundary polygon (the shoelace formula). Per face `E_C` is
`A_f (s_1 - s_2)^2 / 2 >= 0` for the singular values `s_1 >= s_2` of an orientation-preserving
Jacobian (and more on a flipped one), so it vanishes exactly on the similarity maps of each face,
which is the least-squares Cauchy-Riemann energy of Levy et al. 2002. As a quadratic form
`E_C = 1/2 x^T Q x` on `x = [u; v]` (`2 nv` unknowns, `u` first),

    Q = [[L, 0], [0, L]] + C,   C[u_a, v_b] = C[v_b, u_a] = -1/2,   C[u_b, v_a] = C[v_a, u_b] = +1/2

for each boundary edge `a -> b` (`conformal_energy_matrix`). `Q` is symmetric positive semidefinite;
its null space holds the translations (and, for a flat mesh, the rotations and scalings of the
embedding too).

- `lscm`: `E_C` minimised with two (or more) vertices fixed (`fixed_vertices=`, the pins of Levy et al.);
  the free-free block of `Q` is then
  positive definite and one `ddgjax.solve.linear_solve` gives the map, differentiable in the vertex
  positions and the pinned positions (implicit differentiation).
- `spectral_conformal_map`: no pins. Mullen et al. 2008 minimise `E_C` over maps with unit boundary
  norm `x^T B x = 1` (`B` the lumped boundary length, on `u` and `v`) orthogonal to the translations:
  the smallest non-trivial generalised eigenvector of `Q x = lambda B x`. `B` is zero at interior
  vertices, and `ddgjax.spectral.smallest_eigenpairs` needs a positive definite mass, so the mass is
  regularised, `B_eps = B + eps M` with `M` the lumped (Voronoi) vertex area and
  `eps = regularization * perimeter / area` (default `regularization = 1e-6`): for a map `x`,
  `x^T (eps M) x / x^T B x ~ eps area / perimeter = regularization` (the squared map averaged over
  the surface versus over the boundary), so the Rayleigh quotient, and thus the eigenvector, move by
  a relative `O(regularization)`. The translations stay exact null vectors of `Q` (eigenvalue 0);
  the result is the eigenvector of the smallest positive eigenvalue with its translation part
  removed (`B_eps`-orthogonally), then centred, rotated so that the first boundary vertex lies on
  the `+x` axis, and scaled so that its area equals the surface's (the eigenvector's own scale and
  rotation are arbitrary: every eigenvalue of `Q` is double, `x` and its rotation by 90 degrees).

References: B. Levy, S. Petitjean, N. Ray, J. Maillot, "Least squares conformal maps for automatic
texture atlas generation" (2002); P. Mullen, Y. Tong, P. Alliez, M. Desbrun, "Spectral conformal
parameterization" (2008); the cotan form of `E_D - A`: Desbrun, Meyer, Alliez, "Intrinsic
parameterizations of surface meshes" (2002). libigl: `igl.lscm(V, F, b, bc)`, whose second output is
this `Q` (tests); geometry-central / potpourri3d: none exposed.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int

from .._compile import device_array, kernel
from .._errors import DDGInputError, check_choice, check_positive, check_vertex_indices, is_traced
from .._indexing import take_rows, take_rows_or_zero
from .._numerics import cross2, safe_div, safe_norm, safe_sqrt
from .._options import check_solver
from .._results import Solution, outcome
from ..mesh import Mesh, edge_cotan_weights, face_areas, vertex_dual_areas
from ..solve import linear_solve
from ..sparse import SparseMatrix, SparsityPattern, diagonal_matrix, dirichlet_blocks, dirichlet_plan
from ..spectral import EIGENSOLVERS, smallest_eigenpairs
from ._disk import (
    DiskTopology,
    boundary_dual_lengths,
    boundary_edge_lengths,
    cached_plan,
    on_device,
    require_disk,
)
from ._tutte import solves_outcome


class ConformalPlan(eqx.Module):
    """Storage plan of `Q` (module docstring) on the `2 nv`-vertex graph: mesh edges twice, two couplings per boundary edge.

    Attributes:
        pattern: the `(2 nv, 2 nv)` diagonal-first ELL pattern (`SparsityPattern.from_edges`).
        source: `(nnz,)` slot -> index into `[diagonal (2 nv) | edges low->high | edges high->low]`.
        order: `(n_graph_edges,)` the graph edges `[mesh | mesh + nv | (a, nv + b) | (b, nv + a)]` in
            the pattern's sorted edge order (the values are built in the first order and permuted).
    """

    pattern: SparsityPattern
    source: Int[Array, " nnz"]
    order: Int[Array, " n_graph_edges"]


def conformal_plan(mesh: Mesh, disk: DiskTopology) -> ConformalPlan:
    """The `ConformalPlan` of a disk's connectivity (host, cached)."""

    def build():
        n = disk.n_vertices
        edges = np.asarray(mesh.topology.edges, dtype=np.int64)
        a, b = disk.loop.astype(np.int64), np.roll(disk.loop, -1).astype(np.int64)
        graph = np.concatenate([edges, edges + n, np.stack([a, b + n], 1), np.stack([b, a + n], 1)])
        order = np.lexsort((graph[:, 1], graph[:, 0]))
        pattern, source = SparsityPattern.from_edges(graph[order], 2 * n)
        return ConformalPlan(pattern=pattern, source=jnp.asarray(source), order=jnp.asarray(order, dtype=jnp.int32))

    return cached_plan(disk, "conformal", build)


def conformal_energy_matrix(mesh: Mesh) -> SparseMatrix:
    r"""The conformal energy `E_C = E_D - A = 1/2 x^T Q x` as the `(2 nv, 2 nv)` `SparseMatrix` `Q` (module docstring).

    $$E_C(u, v) = E_D(u, v) - \mathcal{A}(u, v) = \tfrac12 x^\top Q x, \qquad E_D = \tfrac12 (u^\top L u + v^\top L v), \qquad x = [u; v]$$

    `x = [u; v]` stacks the two coordinates of the map (`uv[:, 0]` then `uv[:, 1]`). Symmetric
    positive semidefinite (flagged so), differentiable in the vertex positions. For a disk-topology
    mesh only (`DDGInputError` otherwise). libigl: the second output of `igl.lscm(V, F, b, bc)`.

    Args:
        mesh: a mesh of disk topology.

    Returns:
        `(2 nv, 2 nv)` symmetric positive semidefinite `SparseMatrix` `Q`, in the vertex dtype.
    """
    disk = require_disk(mesh, "conformal_energy_matrix")
    return _conformal_matrix(mesh, conformal_plan(mesh, disk), on_device(disk, "loop"))


def _conformal_matrix(mesh: Mesh, plan: ConformalPlan, loop) -> SparseMatrix:
    """`Q` on `plan.pattern`: its values are one program of their own in an eager call, traced inline in a kernel."""
    return SparseMatrix(
        _conformal_values(mesh, plan.source, plan.order, loop), plan.pattern, symmetric=True, positive_semidefinite=True
    )


@kernel
def _conformal_values(mesh: Mesh, source: Int[Array, " nnz"], order: Int[Array, " n_graph_edges"], loop) -> Float[Array, " nnz"]:
    weights = edge_cotan_weights(mesh)
    n, nb = mesh.n_vertices, loop.shape[0]
    degree = jax.ops.segment_sum(jnp.concatenate([weights, weights]), mesh.edges.T.reshape(-1), num_segments=n)
    half = jnp.full((nb,), 0.5, weights.dtype)
    edge_values = jnp.concatenate([-weights, -weights, -half, half])[order]
    entries = jnp.concatenate([degree, degree, edge_values, edge_values])
    return take_rows_or_zero(entries, source)


def lscm(
    mesh: Mesh,
    *,
    fixed_vertices: Int[ArrayLike, " n_fixed"] | None = None,
    fixed_values: Float[ArrayLike, "n_fixed 2"] | None = None,
    solver: str = "auto",
    throw: bool = True,
) -> Float[Array, "nv 2"] | Solution:
    r"""Least squares conformal map of a disk-topology mesh (Levy et al. 2002; module docstring), `(nv, 2)`.

    Minimises

    $$E_C(u, v) = E_D(u, v) - \mathcal{A}(u, v) = \tfrac12 x^\top Q x, \qquad E_D = \tfrac12 (u^\top L u + v^\top L v), \qquad x = [u; v]$$

    ($\mathcal{A}$ the signed area of the image) over all maps with `uv[fixed_vertices] = fixed_values` (the pins); the
    boundary is free.

    Args:
        mesh: a topological disk (else `DDGInputError`).
        fixed_vertices: `(n_fixed,)` distinct referenced vertices, at least two. Default: the boundary
            loop's first vertex and the one half-way along it (by count), `loop[0]` and `loop[nb // 2]`.
        fixed_values: `(n_fixed, 2)` their positions in the plane (at least two distinct). Default
            (only with default or two fixed vertices): `(0, 0)` and `(|p_a - p_b|, 0)`, so the map
            keeps their 3D distance (and the surface's scale).
        solver: the `ddgjax.solve.linear_solve` backend (`ddgjax.LINEAR_SOLVERS`).
        throw: raise when the solve fails (default), or return a `ddgjax.Solution` (`stats`: the
            solve's `"residual"` and `"num_steps"`).

    Returns:
        `(nv, 2)` positions, unreferenced vertices at the origin (in a `ddgjax.Solution` with
        `throw=False`); differentiable in the vertex positions and in `fixed_values`, under `jit`,
        `grad` and `vmap`.

    libigl: `igl.lscm(V, F, b, bc)` (the same map for `b = fixed_vertices`, `bc = fixed_values`).

    Examples:
        >>> import jax.numpy as jnp
        >>> import ddgjax
        >>> disk = ddgjax.mesh.disk(4)  # flat: its conformal maps are similarities
        >>> uv = ddgjax.param.lscm(disk)
        >>> i, j = disk.edges[:, 0], disk.edges[:, 1]
        >>> uv.shape, bool(jnp.allclose(jnp.linalg.norm(uv[i] - uv[j], axis=1), ddgjax.mesh.edge_lengths(disk)))
        ((61, 2), True)
    """
    check_solver(solver)
    disk = require_disk(mesh, "lscm")
    pins, positions = _pins(disk, mesh, fixed_vertices, fixed_values)
    n = disk.n_vertices
    fixed = np.concatenate([pins, pins + n, disk.unreferenced, disk.unreferenced + n])
    plan = conformal_plan(mesh, disk)
    blocks = cached_plan(disk, ("lscm", tuple(pins.tolist())), lambda: dirichlet_plan(plan.pattern, fixed))
    uv, result, stats = _lscm(mesh, plan, blocks, on_device(disk, "loop"), device_array(pins), positions, solver=solver)
    return outcome(uv, result, throw, stats)


def _pins(disk: DiskTopology, mesh: Mesh, vertices, positions) -> tuple[np.ndarray, Float[Array, "n_pins 2"] | None]:
    """Checked `(pins, positions or None)` (`None`: the default positions, computed in the program)."""
    if vertices is None:
        if positions is not None:
            raise DDGInputError("fixed_values: given without fixed_vertices; pass both, or fixed_vertices alone")
        loop = disk.loop
        return np.array([loop[0], loop[loop.size // 2]], dtype=np.int64), None
    pins = check_vertex_indices("fixed_vertices", vertices, disk.n_vertices)
    if pins.size < 2:
        raise DDGInputError(
            f"fixed_vertices: expected at least two vertices, got {pins.size}: with fewer the conformal energy does "
            "not determine the map's rotation and scale (use spectral_conformal_map for a map without pins)"
        )
    unreferenced = np.intersect1d(pins, disk.unreferenced)
    if unreferenced.size:
        raise DDGInputError(f"fixed_vertices: vertices {unreferenced.tolist()} belong to no face; fix vertices of the surface")
    if positions is None:
        if pins.size != 2:
            raise DDGInputError(f"fixed_values: required for {pins.size} fixed vertices (the default places exactly two)")
        return pins, None
    expected = (pins.size, 2)
    if np.shape(positions) != expected:
        raise DDGInputError(f"fixed_values: expected shape {expected} (one row per fixed vertex), got {np.shape(positions)}")
    if not is_traced(positions):
        host = np.asarray(positions)
        if not np.issubdtype(host.dtype, np.number) or np.iscomplexobj(host) or not np.all(np.isfinite(host)):
            raise DDGInputError(f"fixed_values: expected finite real coordinates, got {host.tolist()}")
        if np.all(np.ptp(host, axis=0) == 0):
            raise DDGInputError("fixed_values: all pins at one point collapse the map to that point; give two distinct positions")
    positions = device_array(positions)
    return pins, positions if jnp.issubdtype(positions.dtype, jnp.floating) else positions.astype(float)


@kernel(static_argnames=("solver",))
def _lscm(mesh, plan, blocks, loop, pins, positions, *, solver):
    Q = _conformal_matrix(mesh, plan, loop)
    dtype = Q.values.dtype
    if positions is None:
        ends = take_rows(mesh.vertices, pins)
        distance = safe_norm(ends[1] - ends[0])
        positions = jnp.stack([jnp.zeros(2, dtype), jnp.stack([distance, jnp.zeros((), dtype)])])
    positions = positions.astype(dtype)
    n_unreferenced = blocks.fixed.shape[0] // 2 - pins.shape[0]
    fixed = jnp.concatenate([positions[:, 0], positions[:, 1], jnp.zeros(2 * n_unreferenced, dtype)])
    free_free, free_fixed = dirichlet_blocks(Q, blocks)
    solution = linear_solve(free_free, -(free_fixed @ fixed), solver=solver, throw=False)
    x = blocks.join(solution.value, fixed)
    n = mesh.n_vertices
    return jnp.stack([x[:n], x[n:]], axis=-1), *solves_outcome(solution)


def spectral_conformal_map(
    mesh: Mesh,
    *,
    regularization: float = 1e-6,
    method: str = "auto",
    solver: str = "auto",
    throw: bool = True,
) -> Float[Array, "nv 2"] | Solution:
    r"""Spectral conformal parametrisation without pins (Mullen et al. 2008; module docstring), `(nv, 2)`.

    The smallest non-trivial generalised eigenvector of $Q x = \lambda B_\varepsilon x$ (conformal energy
    against the regularised boundary mass), centred, rotated so that `loop[0]` lies on the `+x` axis
    and scaled to the surface's area.

    Args:
        mesh: a topological disk (else `DDGInputError`).
        regularization: `> 0`, the relative weight of the surface mass added to the boundary mass
            (module docstring; the map moves by a relative `O(regularization)`).
        method, solver: the eigensolver and the backend of its solves
            (`ddgjax.spectral.smallest_eigenpairs`).
        throw: raise when the eigensolver fails (default), or return a `ddgjax.Solution` (its
            `result` and `stats`).

    Returns:
        `(nv, 2)` positions, unreferenced vertices at the origin (in a `ddgjax.Solution` with
        `throw=False`). Differentiable in the vertex
        positions (`ddgjax.spectral.smallest_eigenpairs`' reverse mode; the eigenvector's arbitrary
        rotation within its double eigenvalue is removed before it is returned, so the gradient is
        exact). On CPU the eigensolve is ARPACK's on the host (through a callback): `jit` works,
        `vmap` runs sequentially.

    Examples:
        >>> import jax.numpy as jnp
        >>> import ddgjax
        >>> disk = ddgjax.mesh.disk(4)
        >>> cap = disk.with_vertices(disk.vertices.at[:, 2].set(1.0 - jnp.sum(disk.vertices[:, :2] ** 2, axis=1)))
        >>> uv = ddgjax.param.spectral_conformal_map(cap)
        >>> uv.shape, int(ddgjax.param.map_distortion(cap, uv).flipped.sum())
        ((61, 2), 0)
    """
    regularization = check_positive("regularization", regularization)
    check_choice("method", method, EIGENSOLVERS)
    check_solver(solver)
    disk = require_disk(mesh, "spectral_conformal_map")
    plan = conformal_plan(mesh, disk)
    k = 4 + 2 * disk.unreferenced.size
    uv, result, stats = _spectral(
        mesh, plan, on_device(disk, "loop"), on_device(disk, "unreferenced"), regularization, k=k, method=method, solver=solver
    )
    return outcome(uv, result, throw, stats)


@kernel(static_argnames=("k", "method", "solver"))
def _spectral(mesh, plan, loop, unreferenced, regularization, *, k, method, solver):
    Q = _conformal_matrix(mesh, plan, loop)
    n = mesh.n_vertices
    lengths = boundary_edge_lengths(mesh.vertices, loop)
    perimeter = jnp.sum(lengths)
    area = jnp.sum(face_areas(mesh))
    boundary = jnp.zeros(n, Q.values.dtype).at[loop].set(boundary_dual_lengths(lengths))
    # An unreferenced vertex has an empty row of Q and no area: mass 1 keeps B_eps definite, and its
    # eigenvectors (eigenvalue 0) are discarded below with the translations.
    mass = regularization * safe_div(perimeter, area) * vertex_dual_areas(mesh)
    mass = mass.at[unreferenced].set(1.0)
    weights = boundary + mass
    eigensolve = smallest_eigenpairs(
        Q, diagonal_matrix(jnp.concatenate([weights, weights])), k, method=method, solver=solver, throw=False
    )
    _, vectors = eigensolve.value
    # Every column of the smallest k lies in the null space of Q (translations, unreferenced vertices;
    # on a flat mesh also the similarities), or is the pair of the smallest positive eigenvalue.
    # Removing translations and unreferenced vertices leaves the map, rotated arbitrarily: take the
    # column with most of it left (the choice between equivalent columns does not change the result).
    referenced = jnp.ones(n, Q.values.dtype).at[unreferenced].set(0.0)
    u, v = vectors[:n] * referenced[:, None], vectors[n:] * referenced[:, None]
    total = jnp.sum(weights * referenced)
    u = u - jnp.sum(weights[:, None] * u, axis=0) / total
    v = v - jnp.sum(weights[:, None] * v, axis=0) / total
    u, v = u * referenced[:, None], v * referenced[:, None]
    norms = jnp.sum(weights[:, None] * (u * u + v * v), axis=0)
    best = jnp.argmax(jax.lax.stop_gradient(norms))
    uv = jnp.stack([u[:, best], v[:, best]], axis=-1)
    # Rotate loop[0] onto the +x axis, then scale the signed area of the boundary polygon to the surface's.
    first = uv[loop[0]]
    radius = safe_norm(first)
    cos, sin = safe_div(first[0], radius, 1.0), safe_div(first[1], radius)
    uv = jnp.stack([cos * uv[:, 0] + sin * uv[:, 1], -sin * uv[:, 0] + cos * uv[:, 1]], axis=-1)
    polygon = take_rows(uv, loop)
    image_area = 0.5 * jnp.sum(cross2(polygon, jnp.roll(polygon, -1, axis=0)))
    return uv * safe_sqrt(safe_div(area, jnp.abs(image_area))), eigensolve.result, eigensolve.stats
