"""As-rigid-as-possible surface modelling (Sorkine & Alexa 2007), differentiable by implicit differentiation.

With rest positions `V` (the mesh's vertices) and deformed positions `V'`, the spokes energy
(libigl's `ARAP_ENERGY_TYPE_SPOKES`) is

    E(V', R) = sum_i sum_{j in N(i)} w_ij |(v'_i - v'_j) - R_i (v_i - v_j)|^2,

with one rotation `R_i` per vertex and the cotan weights `w_ij = (cot a_ij + cot b_ij) / 2` of the
rest mesh (minus the off-diagonal entries of the PSD cotan Laplacian `L`, docs/conventions.md;
libigl's `-cotmatrix`). `arap` minimises `E_hat(V') = min_R E(V', R)` over the free vertices, the
handles held at `fixed_values`, by the local-global iteration:

- local step: `R_i = argmax_{R in SO(3)} tr(R S_i)`, `S_i = sum_j w_ij (v_i - v_j)(v'_i - v'_j)^T`;
  with `S_i = U diag(s) W^T`, `R_i = W D U^T`, `D = diag(1, 1, det(W U^T))` (the sign fix flips the
  direction of the smallest singular value, so `R_i` is a rotation, never a reflection);
- global step: `L_ff V'_f = b_f - L_fc V'_c` with `b_i = sum_j w_ij (R_i + R_j) / 2 (v_i - v_j)`,
  the stationarity condition of `E` in `V'` at fixed rotations (`grad_{V'} E = 4 (L V' - b)`),
  solved with ONE factorisation of the free-free block `L_ff`, kept for every iteration.

Each step does not increase `E_hat`, and the iteration stops when the largest displacement of a
step, over the rest mesh's bounding-box diagonal, falls below `rtol` (or after `max_steps` steps:
`RESULTS.max_steps_reached`, an error unless `throw=False`). The convergence is linear and can be
slow: a step's move shrinks tenfold every 80 (a twisted cow), 400 to 560 (a twisted kitten, a bent
9 x 9 grid) or 1,700 steps (a twisted hemisphere), and the distance to the minimum is 30 to 260 times
the last move; `arap`'s defaults are set from those runs (its docstring). With every vertex a handle
there is nothing to solve: the handles are the answer, in 0 steps.

Derivatives (forward and reverse mode, in `fixed_values` and the rest positions): at the answer,
the free positions solve `F(V'_f; V, fixed_values) = L_ff V'_f + L_fc V'_c - b_f(R*(V'), V) = 0`,
the gradient of `E_hat` (by the envelope theorem the rotations' own derivative drops out of the
gradient: `F` is `E`'s gradient at the optimal rotations). `jax.lax.custom_root` differentiates
this condition implicitly, `dV'_f = -(dF/dV'_f)^{-1} dF/dtheta dtheta`, never through the
iterations: `dF/dV'_f` is the Hessian of `E_hat / 4` (symmetric; it does include the derivative of
the optimal rotations, given by the polar decomposition's derivative `_rotations`), solved by
conjugate gradients on its Hessian-vector products, preconditioned by the kept factor of `L_ff`
(the Hessian at frozen rotations). `custom_root` rather than `optimistix.ImplicitAdjoint`: it takes
the local-global loop as the solver without wrapping it as an optimistix solver class, and gives
both modes through a symmetric `lax.custom_linear_solve`.

How it runs: eagerly, one compiled program assembles `L_ff`, `ddgjax.solve.factorize` factors it
outside every program (its definiteness check on the host) and a second program takes the
factorisation and iterates, so both programs can be kept across processes (`ddgjax._program_store`);
under `jit` / `grad` / `vmap` all of it is traced into the caller's program.

Reference: O. Sorkine, M. Alexa, "As-Rigid-As-Possible Surface Modeling", SGP 2007 (eqs. 3-9).
libigl: `data = igl.ARAPData(); data.energy = igl.ARAP_ENERGY_TYPE_SPOKES; data.max_iter = n;
igl.arap_precomputation(V, F, 3, b, data); U = igl.arap_solve(bc, data, U0)`.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int, Real

from .._compile import device_array, kernel
from .._errors import DDGInputError
from .._options import check_solver
from .._results import RESULTS, Solution, first_failure, outcome
from ..discretization.internal import DirichletData
from ..laplacian import TriangulationPlan, cotan_laplacian_from_lengths_sq
from ..laplacian.internal import vertex_plan
from ..mesh import Mesh, corner_cotangents, face_edge_lengths_sq, require_mesh
from ..solve import Factorization, factorize
from ..solve.internal import cholmod_analysis, kept_analysis
from ..sparse import DirichletBlocks, DirichletPlan, SparseMatrix, dirichlet_blocks


def arap(
    mesh: Mesh,
    *,
    fixed_vertices: Int[ArrayLike, " n_fixed"] | Sequence[int],
    fixed_values: Float[ArrayLike, "n_fixed 3"],
    initial: Float[ArrayLike, "nv 3"] | None = None,
    max_steps: int = 5000,
    rtol: float | None = None,
    solver: str = "auto",
    throw: bool = True,
) -> Float[Array, "nv 3"] | Solution:
    """Deform `mesh` as rigidly as possible with the handles `fixed_vertices` moved to `fixed_values`.

    Minimises the spokes energy `E(V') = sum_i sum_{j in N(i)} w_ij |(v'_i - v'_j) - R_i (v_i - v_j)|^2`
    over the free positions and the per-vertex rotations `R_i` (cotan weights `w_ij` of the rest mesh,
    handles exact) by local-global iterations with one kept factorisation (module docstring).
    Differentiable (forward and reverse) in `fixed_values` and the rest positions by implicit
    differentiation of the optimality condition, not through the iterations.

    Args:
        mesh: the rest shape `V`, a triangle mesh; every connected component needs a fixed vertex.
        fixed_vertices: `(n_fixed,)` distinct handle indices (concrete, host data).
        fixed_values: `(n_fixed, 3)` the handles' new positions.
        initial: `(nv, 3)` the first guess `V'_0` (its handle rows are replaced by `fixed_values`).
            Default: the rest positions with the handles moved, as libigl's examples start
            (`U = V; U[b] = bc`). ARAP is not convex: another start can reach another minimum.
        max_steps: the most local-global steps (default 5000, three times the steps the default `rtol`
            takes in the slowest case measured below).
        rtol: stop when a step moves no vertex by more than `rtol` times the rest bounding-box
            diagonal. Default: 1e-6 in float64, 1e-5 in float32 (whose round-off moves vertices by
            about 1e-7 of the diagonal at every step). Why 1e-6: the iteration converges linearly, so a
            tighter default costs hundreds of steps per digit. Measured (float64, distances over the
            diagonal, against a run to 1e-11 or tighter): a kitten (9,447 vertices) with its top tenth
            turned 30 degrees about the vertical and its bottom tenth held meets 1e-6 in 737 steps
            (energy within 1e-6 of the minimum's, every vertex within 2e-4 of it; 1e-8 takes 1,564);
            a 9 x 9 grid with one side held and the opposite side turned 30 degrees out of the plane
            in 1,125 (2e-6, 2.4e-4; 1e-8 takes 2,239); tests/data's spot (2,930) and hemisphere
            (2,051), twisted as the kitten, in 249 (3e-7, 3e-5) and 1,655 (9e-7, 2.6e-4). The implicit
            derivatives inherit the answer's error: 1.5e-4 relative on a twisted cylinder at 1e-6,
            1.5e-6 at 1e-8. libigl stops after a fixed `max_iter` (default 10) steps and reports
            nothing; here a run that ends at `max_steps` still moving by more than `rtol` is
            `RESULTS.max_steps_reached`, never a success.
        solver: the backend of the kept factorisation, one of `ddgjax.LINEAR_SOLVERS`
            (`ddgjax.solve.factorize`).
        throw: raise when the iteration does not converge or a solve fails (default), or return the
            outcome.

    Returns:
        `V'`, `(nv, 3)`; with `throw=False` a `ddgjax.Solution` holding it as `value`, the outcome as
        `result` (`RESULTS.max_steps_reached` when `rtol` was not met) and `stats`
        `{"num_steps": steps taken, "energy": E_hat(V') at the answer, "initial_energy": E_hat of the
        first guess, "relative_change": the last step's largest move over the bounding-box diagonal}`.

    Every vertex a handle: the handles' positions, `RESULTS.successful`, 0 steps and a change of 0 (as
    `biharmonic_deformation`). Unreferenced vertices stay where `initial` puts them.

    Reference: Sorkine & Alexa 2007. libigl: `igl.arap_precomputation(V, F, 3, b, data)` with
    `data.energy = igl.ARAP_ENERGY_TYPE_SPOKES`, then `igl.arap_solve(bc, data, U)` (a fixed `data.max_iter`
    steps, no tolerance).
    """
    mesh = require_mesh("mesh", mesh)
    check_solver(solver)
    if fixed_vertices is None or np.size(fixed_vertices) == 0:
        raise DDGInputError("fixed_vertices: ARAP needs at least one handle vertex per connected component, got none")
    if fixed_values is None:
        raise DDGInputError("fixed_values: expected the (n_fixed, 3) handle positions, got None")
    if isinstance(max_steps, bool) or not isinstance(max_steps, (int, np.integer)) or max_steps < 1:
        raise DDGInputError(f"max_steps: expected an integer >= 1, got {max_steps!r}")
    plan = vertex_plan(mesh)
    dirichlet = DirichletData(mesh, fixed_vertices, fixed_values, (3,), plan.pattern)
    unreferenced = np.setdiff1d(mesh.topology.unreferenced_vertices, dirichlet.vertices)
    if dirichlet.n_pinned > unreferenced.size:
        raise DDGInputError(
            "fixed_vertices: every connected component of the mesh needs at least one fixed vertex (a free "
            f"component's position is undetermined); {dirichlet.n_pinned - unreferenced.size} component(s) have none"
        )
    dtype = jnp.result_type(mesh.vertices.dtype, dirichlet.values.dtype)
    if rtol is None:
        rtol = 1e-6 if jnp.finfo(dtype).bits >= 64 else 1e-5  # the measurements behind both: the docstring
    if isinstance(rtol, bool) or not isinstance(rtol, (int, float, np.floating)) or not rtol > 0:
        raise DDGInputError(f"rtol: expected a positive float, got {rtol!r}")
    if initial is None:
        initial = mesh.vertices
    initial = device_array(initial)  # a host array moved without an eager program
    if initial.shape != (mesh.n_vertices, 3):
        raise DDGInputError(f"initial: expected shape ({mesh.n_vertices}, 3), got {initial.shape}")
    if dirichlet.plan is None:  # every vertex is a handle (or unused): nothing to solve, nothing to factor
        positions, stats = _held(mesh, dirichlet.values, initial, device_array(dirichlet.fixed, dtype=jnp.int32))
        return outcome(positions, RESULTS.successful, throw, stats)
    # Kept for every global step: simplicial up to `SIMPLICIAL_LIMIT` unknowns, the faster solves.
    with cholmod_analysis(kept_analysis(mesh.n_vertices)):
        factorization = factorize(_free_block(mesh, plan, dirichlet.plan, dirichlet.values), solver=solver)
    positions, result, stats = _arap(
        mesh,
        plan,
        dirichlet.plan,
        factorization,
        dirichlet.values,
        initial,
        jax.device_put(np.asarray(max_steps, np.int32)),  # host scalars moved without an eager program
        jax.device_put(np.asarray(rtol, dtype)),
    )
    return outcome(positions, result, throw, stats)


def _rest_blocks(mesh: Mesh, rest: Float[Array, "nv 3"], plan: TriangulationPlan, blocks: DirichletPlan) -> DirichletBlocks:
    """`(L_ff, L_fc)` of the cotan Laplacian of the rest positions `rest`."""
    laplacian = cotan_laplacian_from_lengths_sq(face_edge_lengths_sq(mesh.with_vertices(rest)), plan)
    return dirichlet_blocks(laplacian, blocks)


def _working_dtype(mesh: Mesh, values: Real[Array, "n_fixed 3"]) -> jnp.dtype:
    """The dtype `arap` computes in: the rest positions' and the handles' promoted."""
    return jnp.result_type(mesh.vertices.dtype, values.dtype)


@kernel
def _free_block(mesh: Mesh, plan: TriangulationPlan, blocks: DirichletPlan, values: Real[Array, "n_fixed 3"]) -> SparseMatrix:
    """`L_ff`, the matrix `_arap` takes factored, without derivatives (the iterations run on values only)."""
    rest = mesh.vertices.astype(_working_dtype(mesh, values))
    return jax.lax.stop_gradient(_rest_blocks(mesh, rest, plan, blocks).free_free)


@kernel
def _held(
    mesh: Mesh, values: Real[Array, "n_fixed 3"], initial: Real[Array, "nv 3"], fixed: Int[Array, " nv"]
) -> tuple[Float[Array, "nv 3"], dict[str, Array]]:
    """`(V', stats)` of `arap` when every vertex is held: `fixed` is the handles, then the unreferenced vertices."""
    dtype = _working_dtype(mesh, values)
    held = jnp.concatenate([values.astype(dtype), initial.astype(dtype)[fixed[values.shape[0] :]]])
    positions = jnp.zeros((mesh.n_vertices, 3), dtype).at[fixed].set(held)
    rest = jax.lax.stop_gradient(mesh.vertices.astype(dtype))
    weights = corner_cotangents(mesh.with_vertices(rest)) / 2
    energy, _ = _fitted(_face_edges(rest, mesh.faces), weights, mesh.faces, jax.lax.stop_gradient(positions))
    zero = jnp.zeros((), dtype)
    return positions, {"num_steps": jnp.zeros((), jnp.int32), "energy": energy, "initial_energy": energy, "relative_change": zero}


@kernel
def _arap(
    mesh: Mesh,
    plan: TriangulationPlan,
    blocks: DirichletPlan,
    factorization: Factorization,
    values: Real[Array, "n_fixed 3"],
    initial: Real[Array, "nv 3"],
    max_steps: Int[Array, ""],
    rtol: Float[Array, ""],
) -> tuple[Float[Array, "nv 3"], RESULTS, dict[str, Array]]:
    """`(V', result, stats)` of `arap`, given the factorisation of `_free_block`'s `L_ff`.
    `blocks.fixed` is the handles, then the unreferenced vertices."""
    dtype = _working_dtype(mesh, values)
    values, initial = values.astype(dtype), initial.astype(dtype)
    rest = mesh.vertices.astype(dtype)
    faces = mesh.faces
    n_handles = values.shape[0]
    fixed_positions = jnp.concatenate([values, initial[blocks.fixed[n_handles:]]])
    scale = jnp.linalg.norm(jnp.max(rest, axis=0) - jnp.min(rest, axis=0))

    def pieces(rest):
        """The rest-shape data `F` needs, differentiable in `rest`: `L_ff`, `L_fc`, edge vectors and weights."""
        free_free, free_fixed = _rest_blocks(mesh, rest, plan, blocks)
        return free_free, free_fixed, _face_edges(rest, faces), corner_cotangents(mesh.with_vertices(rest)) / 2

    def residual(free):
        """`F = L_ff V'_f + L_fc V'_c - b_f`, the gradient of `E_hat / 4` in the free positions (module docstring)."""
        free_free, free_fixed, rest_edges, weights = pieces(rest)
        deformed = blocks.join(free, fixed_positions)
        rotations = _rotations(_covariances(rest_edges, _face_edges(deformed, faces), weights, faces, rest.shape[0]))
        rhs = _rotated_rhs(rotations, rest_edges, weights, faces, rest.shape[0])
        return free_free @ free + free_fixed @ fixed_positions - rhs[blocks.free]

    # The local-global loop runs on values only: `custom_root` differentiates `residual` instead.
    _, free_fixed, rest_edges, weights = jax.lax.stop_gradient(pieces(rest))
    fixed_stopped = jax.lax.stop_gradient(fixed_positions)
    constant = free_fixed @ fixed_stopped

    energy = functools.partial(_fitted, rest_edges, weights, faces)

    def local_global(start):
        def step(state):
            free, _, steps, result = state
            _, rotations = energy(blocks.join(free, fixed_stopped))
            rhs = _rotated_rhs(rotations, rest_edges, weights, faces, rest.shape[0])[blocks.free] - constant
            solution = factorization.solve(rhs, throw=False)
            change = jnp.max(jnp.abs(solution.value - free)) / scale
            return solution.value, change, steps + 1, first_failure(result, solution.result)

        def running(state):
            _, change, steps, result = state
            return (change > rtol) & (steps < max_steps) & (result == RESULTS.successful)

        state = (start, jnp.asarray(jnp.inf, rest.dtype), jnp.zeros((), jnp.int32), factorization.result)
        free, change, steps, result = jax.lax.while_loop(running, step, state)
        result = RESULTS.where((result == RESULTS.successful) & (change > rtol), RESULTS.max_steps_reached, result)
        return free, change, steps, result

    def tangent_solve(jacobian, rhs):
        """`J x = rhs` for the symmetric Hessian `J` of `E_hat / 4`: CG preconditioned by the kept `L_ff` factor."""

        def cg(matvec, b):
            precondition = lambda r: factorization.solve(r, throw=False).value
            return jax.scipy.sparse.linalg.cg(matvec, b, M=precondition, tol=1e-12, maxiter=10 * b.size)[0]

        return jax.lax.custom_linear_solve(jacobian, rhs, cg, symmetric=True)

    start = jax.lax.stop_gradient(initial)[blocks.free]
    initial_energy, _ = energy(blocks.join(start, fixed_stopped))
    solved, change, steps, result = local_global(start)
    # The root is found above (its integer outcome cannot pass through `custom_root`'s aux output);
    # `custom_root` only attaches the implicit derivative of `residual(solved) = 0` to it.
    free = jax.lax.custom_root(residual, start, lambda _, __: solved, tangent_solve)
    positions = blocks.join(free, fixed_positions)
    final_energy, _ = energy(jax.lax.stop_gradient(positions))
    stats = {"num_steps": steps, "energy": final_energy, "initial_energy": initial_energy, "relative_change": change}
    return positions, result, stats


def _fitted(rest_edges, weights, faces, deformed: Float[Array, "nv 3"]) -> tuple[Float[Array, ""], Float[Array, "nv 3 3"]]:
    """`(E_hat(V'), R*(V'))`: the local step's rotations for the deformed positions and the energy at them."""
    deformed_edges = _face_edges(deformed, faces)
    rotations = _rotations(_covariances(rest_edges, deformed_edges, weights, faces, deformed.shape[0]))
    return _energy(rotations, rest_edges, deformed_edges, weights, faces), rotations


def _face_edges(positions: Float[Array, "nv 3"], faces: Int[Array, "nf 3"]) -> Float[Array, "nf 3 3"]:
    """`e_k = p_{k+1} - p_{k+2}` per face: the edge opposite corner `k` (its weight is `cot(corner k) / 2`)."""
    corners = positions[faces]
    return jnp.roll(corners, -1, axis=1) - jnp.roll(corners, -2, axis=1)


def _edge_ends(faces: Int[Array, "nf 3"]) -> tuple[Int[Array, "nf 3"], Int[Array, "nf 3"]]:
    """The vertices `(i, j)` of each `e_k = p_i - p_j` of `_face_edges`."""
    return jnp.roll(faces, -1, axis=1), jnp.roll(faces, -2, axis=1)


def _covariances(rest_edges, deformed_edges, weights, faces, n_vertices: int) -> Float[Array, "nv 3 3"]:
    """`S_i = sum_j w_ij e_ij e'_ij^T`: each face edge adds `w e e'^T` to both of its ends (the spokes)."""
    outer = weights[..., None, None] * rest_edges[..., :, None] * deformed_edges[..., None, :]
    i, j = _edge_ends(faces)
    ends = jnp.concatenate([i.ravel(), j.ravel()])
    return jax.ops.segment_sum(jnp.concatenate([outer.reshape(-1, 3, 3)] * 2), ends, n_vertices)


def _rotated_rhs(rotations, rest_edges, weights, faces, n_vertices: int) -> Float[Array, "nv 3"]:
    """`b_i = sum_j w_ij (R_i + R_j) / 2 (v_i - v_j)` (Sorkine & Alexa eq. 8's right-hand side)."""
    i, j = _edge_ends(faces)
    rotated = jnp.einsum("fkab,fkb->fka", rotations[i] + rotations[j], rest_edges) * (weights / 2)[..., None]
    ends = jnp.concatenate([i.ravel(), j.ravel()])
    return jax.ops.segment_sum(jnp.concatenate([rotated.reshape(-1, 3), -rotated.reshape(-1, 3)]), ends, n_vertices)


def _energy(rotations, rest_edges, deformed_edges, weights, faces) -> Float[Array, ""]:
    """The spokes energy: each face edge counts once for each end's rotation."""
    i, j = _edge_ends(faces)
    total = 0.0
    for ends in (i, j):
        misfit = deformed_edges - jnp.einsum("fkab,fkb->fka", rotations[ends], rest_edges)
        total = total + jnp.sum(weights * jnp.sum(misfit**2, axis=-1))
    return total


@jax.custom_jvp
def _rotations(covariances: Float[Array, "n 3 3"]) -> Float[Array, "n 3 3"]:
    """`R = argmax_{R in SO(3)} tr(R S)` per matrix: `S = U diag(s) W^T`, `R = W diag(1, 1, det(W U^T)) U^T`."""
    return _polar(covariances)[0]


def _polar(covariances):
    """`(R, U, signed singular values)` of the sign-fixed polar factor of `S^T` (`S^T = R U diag(s') U^T`)."""
    u, s, wt = jnp.linalg.svd(covariances)
    w = jnp.swapaxes(wt, -1, -2)
    sign = jnp.sign(jnp.linalg.det(w @ jnp.swapaxes(u, -1, -2)))
    sign = jnp.where(sign == 0, 1.0, sign)
    flip = jnp.concatenate([jnp.ones(s.shape[:-1] + (2,), s.dtype), sign[..., None]], axis=-1)
    rotation = (w * flip[..., None, :]) @ jnp.swapaxes(u, -1, -2)
    return rotation, u, s * flip


@_rotations.defjvp
def _rotations_jvp(primals, tangents):
    """`dR = R U Omega U^T`, `Omega_ab = M_ab / (s'_a + s'_b)`, `M = U^T (R^T dA - dA^T R) U`, `A = S^T`.

    From `A = R P` with `P = U diag(s') U^T` symmetric: the skew part of `R^T dA` is `Omega P + P Omega`
    for the skew `Omega = R^T dR`. Defined while `s'_a + s'_b > 0` (the maximiser is isolated); a
    zero denominator (an unused vertex, `S = 0`) gives 0.
    """
    (covariances,), (dcov,) = primals, tangents
    rotation, u, s = _polar(covariances)
    da = jnp.swapaxes(dcov, -1, -2)
    rt_da = jnp.swapaxes(rotation, -1, -2) @ da
    m = jnp.swapaxes(u, -1, -2) @ (rt_da - jnp.swapaxes(rt_da, -1, -2)) @ u
    denominator = s[..., :, None] + s[..., None, :]
    safe = jnp.where(denominator == 0, 1.0, denominator)
    omega = jnp.where(denominator == 0, 0.0, m / safe)
    return rotation, rotation @ u @ omega @ jnp.swapaxes(u, -1, -2)
