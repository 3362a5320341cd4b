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
  direction of the smallest singular value, so `R_i` is a rotation, never a reflection); computed for all
  vertices at once by a closed-form 3 x 3 SVD of elementwise operations (`_rotations.rotation_svd`, ~8x
  faster than LAPACK's batched SVD under XLA:CPU), with `S_i = sum_c K^c V'` three sparse products with
  the Laplacian's pattern (`_spokes`, libigl's covariance scatter matrix);
- global step: `L_ff V'_f = b_f - L_fc V'_c` with `b_i = sum_j w_ij (R_i + R_j) / 2 (v_i - v_j)`,
  the stationarity condition of `E` in `V'` at fixed rotations (`grad_{V'} E = 4 (L V' - b)`),
  solved with ONE factorisation of the free-free block `L_ff`, kept for every iteration; `b` is three
  more sparse products with the same `K^c`.

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
the optimal rotations, given by the polar decomposition's derivative, `_rotations.fit_rotations`), solved by
conjugate gradients on its Hessian-vector products, preconditioned by the kept factor of `L_ff`
(the Hessian at frozen rotations). `custom_root` rather than `optimistix.ImplicitAdjoint`: it takes
the local-global loop as the solver without wrapping it as an optimistix solver class, and gives
both modes through a symmetric `lax.custom_linear_solve`.

How it runs: eagerly, one compiled program assembles `L_ff`, `ddgjax.solve.factorize` factors it
outside every program (its definiteness check on the host) and a second program takes the
factorisation and iterates, so both programs can be kept across processes (`ddgjax._program_store`);
under `jit` / `grad` / `vmap` all of it is traced into the caller's program. The whole iteration is one
`lax.while_loop` with the kept factor's solve inside; its first pass also gives the start's energy and
one last pass (no step) the answer's, so the rotation fit has a single call site in the program (each
call site of it adds ~3-4 s of XLA:CPU compilation on 2 cores).

Reference: O. Sorkine, M. Alexa, "As-Rigid-As-Possible Surface Modeling", SGP 2007 (eqs. 3-9).
libigl: `data = igl.ARAPData(); data.energy = igl.ARAP_ENERGY_TYPE_SPOKES; data.max_iter = n;
igl.arap_precomputation(V, F, 3, b, data); U = igl.arap_solve(bc, data, U0)`.
"""

from __future__ import annotations

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
from ..mesh import Mesh, face_edge_lengths_sq, require_mesh
from ..solve import Factorization, factorize
from ..solve.internal import cholmod_analysis, kept_analysis
from ..sparse import DirichletPlan, SparseMatrix, dirichlet_blocks
from ._rotations import fit_rotations


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
    r"""Deform `mesh` as rigidly as possible with the handles `fixed_vertices` moved to `fixed_values`.

    Minimises the spokes energy

    $$E(V') = \sum_i \sum_{j \in N(i)} w_{ij} \lVert (v'_i - v'_j) - R_i (v_i - v_j) \rVert^2$$

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

    Examples:
        >>> import numpy as np
        >>> import jax.numpy as jnp
        >>> import ddgjax
        >>> strip = ddgjax.mesh.grid(8, 2)
        >>> x = np.asarray(strip.vertices[:, 0])
        >>> ends = np.flatnonzero((x == x.min()) | (x == x.max()))
        >>> turn = jnp.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # a quarter turn about z
        >>> deformed = ddgjax.deform.arap(strip, fixed_vertices=ends, fixed_values=strip.vertices[ends] @ turn.T)
        >>> deformed.shape, bool(jnp.allclose(deformed, strip.vertices @ turn.T, atol=1e-4))  # rigid handles: a rigid motion
        ((27, 3), True)
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
        positions, stats = _held(mesh, plan, dirichlet.values, initial, device_array(dirichlet.fixed, dtype=jnp.int32))
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


def _rest_pieces(mesh: Mesh, rest: Float[Array, "nv 3"], plan: TriangulationPlan, blocks: DirichletPlan) -> tuple:
    """`(L_ff, L_fc, L, spokes)` of the rest positions `rest`: the cotan Laplacian, its Dirichlet blocks and `_spokes`."""
    laplacian = cotan_laplacian_from_lengths_sq(face_edge_lengths_sq(mesh.with_vertices(rest)), plan)
    free_free, free_fixed = dirichlet_blocks(laplacian, blocks)
    return free_free, free_fixed, laplacian, _spokes(laplacian, rest)


def _working_dtype(mesh: Mesh, values: Real[Array, "n_fixed 3"]) -> jnp.dtype:
    """The dtype `arap` computes in: the rest positions' and the handles' promoted."""
    return jnp.result_type(mesh.vertices.dtype, values.dtype)


@kernel
def _free_block(mesh: Mesh, plan: TriangulationPlan, blocks: DirichletPlan, values: Real[Array, "n_fixed 3"]) -> SparseMatrix:
    """`L_ff`, the matrix `_arap` takes factored, without derivatives (the iterations run on values only)."""
    rest = mesh.vertices.astype(_working_dtype(mesh, values))
    laplacian = cotan_laplacian_from_lengths_sq(face_edge_lengths_sq(mesh.with_vertices(rest)), plan)
    return jax.lax.stop_gradient(dirichlet_blocks(laplacian, blocks).free_free)


@kernel
def _held(
    mesh: Mesh, plan: TriangulationPlan, values: Real[Array, "n_fixed 3"], initial: Real[Array, "nv 3"], fixed: Int[Array, " nv"]
) -> tuple[Float[Array, "nv 3"], dict[str, Array]]:
    """`(V', stats)` of `arap` when every vertex is held: `fixed` is the handles, then the unreferenced vertices."""
    dtype = _working_dtype(mesh, values)
    held = jnp.concatenate([values.astype(dtype), initial.astype(dtype)[fixed[values.shape[0] :]]])
    positions = jnp.zeros((mesh.n_vertices, 3), dtype).at[fixed].set(held)
    rest = jax.lax.stop_gradient(mesh.vertices.astype(dtype))
    laplacian = cotan_laplacian_from_lengths_sq(face_edge_lengths_sq(mesh.with_vertices(rest)), plan)
    energy, _ = _fitted(laplacian, _spokes(laplacian, rest), rest, jax.lax.stop_gradient(positions))
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
    n_handles = values.shape[0]
    fixed_positions = jnp.concatenate([values, initial[blocks.fixed[n_handles:]]])
    scale = jnp.linalg.norm(jnp.max(rest, axis=0) - jnp.min(rest, axis=0))

    def residual(free):
        """`F = L_ff V'_f + L_fc V'_c - b_f`, the gradient of `E_hat / 4` in the free positions (module docstring)."""
        free_free, free_fixed, _, spokes = _rest_pieces(mesh, rest, plan, blocks)
        rotations = fit_rotations(_covariances(spokes, blocks.join(free, fixed_positions)))
        return free_free @ free + free_fixed @ fixed_positions - _rotated_rhs(spokes, rotations)[blocks.free]

    # The local-global loop runs on values only: `custom_root` differentiates `residual` instead.
    _, free_fixed, laplacian, spokes = jax.lax.stop_gradient(_rest_pieces(mesh, rest, plan, blocks))
    fixed_stopped = jax.lax.stop_gradient(fixed_positions)
    constant = free_fixed @ fixed_stopped
    rest_stopped = jax.lax.stop_gradient(rest)

    def local_global(start):
        """The steps, and the energies of the start and of the answer from the rotations the loop fits anyway:
        every call site of the rotation fit is compiled apart (~3 s each on 2 cores), so there is one."""

        def step(state):
            free, change, steps, result, energies, _ = state
            deformed = blocks.join(free, fixed_stopped)
            rotations = fit_rotations(_covariances(spokes, deformed))
            going = (change > rtol) & (steps < max_steps) & (result == RESULTS.successful)
            # The first pass fits the start's rotations, the last (which takes no step) the answer's.
            energy = jax.lax.cond(
                (steps == 0) | ~going,
                lambda: _spokes_energy(laplacian, rest_stopped, deformed, rotations),
                lambda: jnp.zeros((), rest.dtype),
            )
            energies = jnp.where(jnp.stack([steps == 0, ~going]), energy, energies)
            rhs = _rotated_rhs(spokes, rotations)[blocks.free] - constant
            solution = factorization.solve(rhs, throw=False)
            moved = jnp.max(jnp.abs(solution.value - free)) / scale
            return (
                jnp.where(going, solution.value, free),
                jnp.where(going, moved, change),
                steps + going.astype(steps.dtype),
                RESULTS.where(going, first_failure(result, solution.result), result),
                energies,
                ~going,
            )

        state = (
            start,
            jnp.asarray(jnp.inf, rest.dtype),
            jnp.zeros((), jnp.int32),
            factorization.result,
            jnp.zeros((2,), rest.dtype),
            jnp.asarray(False),
        )
        free, change, steps, result, energies, _ = jax.lax.while_loop(lambda state: ~state[-1], step, state)
        result = RESULTS.where((result == RESULTS.successful) & (change > rtol), RESULTS.max_steps_reached, result)
        return free, change, steps, result, energies

    def tangent_solve(jacobian, rhs):
        """`J x = rhs` for the symmetric Hessian `J` of `E_hat / 4`: CG preconditioned by the kept `L_ff` factor."""

        def cg(matvec, b):
            precondition = lambda r: factorization.solve(r, throw=False).value
            return jax.scipy.sparse.linalg.cg(matvec, b, M=precondition, tol=1e-12, maxiter=10 * b.size)[0]

        return jax.lax.custom_linear_solve(jacobian, rhs, cg, symmetric=True)

    start = jax.lax.stop_gradient(initial)[blocks.free]
    solved, change, steps, result, (initial_energy, final_energy) = local_global(start)
    # The root is found above (its integer outcome cannot pass through `custom_root`'s aux output);
    # `custom_root` only attaches the implicit derivative of `residual(solved) = 0` to it.
    free = jax.lax.custom_root(residual, start, lambda _, __: solved, tangent_solve)
    positions = blocks.join(free, fixed_positions)
    stats = {"num_steps": steps, "energy": final_energy, "initial_energy": initial_energy, "relative_change": change}
    return positions, result, stats


def _spokes(laplacian: SparseMatrix, rest: Float[Array, "nv 3"]) -> tuple[SparseMatrix, SparseMatrix, SparseMatrix]:
    """`K^a`, `a = 0, 1, 2`: the matrices with `S_i[a, :] = (K^a V')_i` (libigl's covariance scatter matrix).

    `S_i = sum_j w_ij e_ij (v'_i - v'_j)^T = (L V)_i v'_i^T + sum_{j != i} L_ij e_ij v'_j^T` with
    `e_ij = v_i - v_j` and `w_ij = -L_ij`, as `sum_j w_ij e_ij = (L V)_i`. So `K^a` has `L`'s pattern, the
    values `L_ij (e_ij)_a` off the diagonal and `(L V)_{ia}` on it. Built once from the rest shape; each
    local step is then three sparse products, with no per-face scatter.
    """
    pattern = laplacian.pattern
    spokes = laplacian.values[:, None] * (rest[pattern.rows] - rest[pattern.cols])  # 0 on the diagonal and padding
    # The vertex pattern is diagonal-first (`TriangulationPlan`): its first `nv` slots hold the diagonal.
    spokes = spokes.at[: rest.shape[0]].add(laplacian @ rest)
    return tuple(SparseMatrix(spokes[:, a], pattern) for a in range(3))


def _covariances(spokes, deformed: Float[Array, "nv 3"]) -> Float[Array, "nv 3 3"]:
    """`S_i = sum_j w_ij e_ij e'_ij^T`, the spokes' covariances (`_spokes`)."""
    return jnp.stack([scatter @ deformed for scatter in spokes], axis=1)


def _rotated_rhs(spokes, rotations: Float[Array, "nv 3 3"]) -> Float[Array, "nv 3"]:
    """`b_i = sum_j w_ij (R_i + R_j) / 2 (v_i - v_j)` (Sorkine & Alexa eq. 8's right-hand side).

    `= sum_c [K^c_ii R_i[:, c] - (K^c R[:, :, c])_i / 2]` with `_spokes`' `K^c` (its diagonal `sum_j w_ij e_ij`
    carries `R_i`'s half, the off-diagonal `-w_ij e_ij` the neighbours' `R_j` half, and `K^c`'s diagonal counted
    by the product is taken back)."""
    n = rotations.shape[0]
    return sum(
        scatter.values[:n, None] * rotations[:, :, c] - (scatter @ rotations[:, :, c]) / 2 for c, scatter in enumerate(spokes)
    )


def _fitted(
    laplacian: SparseMatrix, spokes, rest, deformed: Float[Array, "nv 3"]
) -> tuple[Float[Array, ""], Float[Array, "nv 3 3"]]:
    """`(E_hat(V'), R*(V'))`: the local step's rotations for the deformed positions and the spokes energy at them."""
    rotations = fit_rotations(_covariances(spokes, deformed))
    return _spokes_energy(laplacian, rest, deformed, rotations), rotations


def _spokes_energy(laplacian: SparseMatrix, rest, deformed, rotations) -> Float[Array, ""]:
    """`sum_i sum_{j != i} w_ij |e'_ij - R_i e_ij|^2` over the Laplacian's off-diagonal slots (`w_ij = -L_ij`; its
    diagonal and padding slots add 0)."""
    rows, cols = laplacian.pattern.rows, laplacian.pattern.cols
    misfit = deformed[rows] - deformed[cols] - jnp.einsum("sab,sb->sa", rotations[rows], rest[rows] - rest[cols])
    return -jnp.sum(laplacian.values * jnp.sum(misfit**2, axis=-1))
