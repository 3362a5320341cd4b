"""`minimize_shape`: gradient-based shape optimisation of a mesh, each chunk of steps one compiled program.

One step is `value_and_grad` of the user's loss with respect to the parameters, an optax update,
the map back to vertex positions (Large Steps: one solve with the kept factor) and, optionally, the
projection onto the constraint. The steps run in chunks of `chunk_size` through `ddgjax._loop`, the
loop the flows share: one `lax.scan` over the chunks (one compiled program for the whole run), or,
with a progress bar, one compiled chunk per call from a host loop.

Parametrisations: `"large_steps"` optimises `U = (I + lambda L) V` (`ddgjax.optim.large_steps`);
`"vertices"` the free vertex positions themselves. Fixed vertices are not parameters at all in
either, so their gradient is masked exactly and they never move.

Constraint `"volume"`: after every update the vertices are projected back onto the level set
`vol(V) = vol(V_0)` of the enclosed volume along its gradient (the area-weighted vertex normals on
the free vertices), `V <- V + t grad vol(V)` with the scalar `t` found by `optimistix.root_find`
(Newton; the volume is a cubic in `t`, 3-4 iterations). A projection rather than a penalty or an
augmented Lagrangian because it holds the constraint to round-off at every iterate, so the loss
never sees a shrunk shape (the Willmore energy, scale invariant, would otherwise let a penalised
shape drift in size) and there is no penalty weight or multiplier schedule to tune; its cost is a
few volume evaluations per step. With Large Steps the projected vertices are mapped back to
parameters (`U = A V`, a product).

Bounds `(lower, upper)`: after every update the vertices are clipped into the box, which is the
Euclidean projection onto it (projected gradient descent, as `jaxopt.ProjectedGradient` with
`jaxopt.projection.projection_box`; here inside the user's optax optimiser and reparametrisation).

Outcomes (docs/conventions.md): a step whose loss, gradient or update is not finite, or whose Large
Steps solve failed, is not applied (the parameters and the optimiser state are kept), and the run
reports the first such step's outcome (`RESULTS.nonfinite`, or the solve's) in `result`; with
`throw=True` (default) it raises, with `throw=False` the returned vertices are the last good iterate.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax
import optimistix as optx
from jaxtyping import Array, ArrayLike, Bool, Float, Int, PRNGKeyArray, PyTree

from .._compile import kernel
from .._errors import DDGInputError, check_choice, check_count, is_traced
from .._loop import Failure, check_progress, finite_outcome, first_failure_step, no_failure, record, run_chunks, scan_steps
from .._options import check_solver, check_weights
from .._results import RESULTS, Record, first_failure, is_failure, raise_if_failed
from ..mesh import Mesh, enclosed_volume, require_mesh
from ._large_steps import LargeSteps, adam_uniform, fixed_vertex_indices, large_steps

PARAMETRIZATIONS = ("large_steps", "vertices")
CONSTRAINTS = (None, "volume")


class ShapeOptimizationResult(Record):
    """What `minimize_shape` returns.

    Attributes:
        value: `(nv, 3)` final positions (the last good iterate if a step failed); `mesh()` wraps them.
        loss_history: `(steps + 1,)` the loss after `k` steps, `k = 0, ..., steps` (the first is the
            initial shape's, the last the final shape's; a stochastic loss is evaluated with the
            step's key).
        result: the outcome of the first failing step (`ddgjax.RESULTS`): `successful`,
            `nonfinite` (a NaN / inf loss, gradient or update) or a failed Large Steps solve's.
        first_failure_step: int scalar, that step's number (`1, ..., steps`: step `k` updates iterate
            `k - 1`), `steps + 1` when none failed. Failed steps are not applied.
        initial: the input mesh (its connectivity, for `mesh()`).
        parametrization: `"large_steps"` or `"vertices"` (static).
    """

    value: Float[Array, "nv 3"]
    loss_history: Float[Array, " steps_plus_one"]
    result: RESULTS
    first_failure_step: Int[Array, ""]
    initial: Mesh
    parametrization: str = eqx.field(static=True)

    @property
    def stats(self) -> dict[str, Array]:
        """The run's history: `{"loss": loss_history}` (the loss after each step, the initial shape's first)."""
        return {"loss": self.loss_history}

    def mesh(self) -> Mesh:
        """The optimised mesh, `initial.with_vertices(value)` (a method, as the flows' `mesh(index)`)."""
        return self.initial.with_vertices(self.value)


class _Same:
    """A static argument compared by identity: any callable (hashable or not) keys a compiled program,
    and passing the same object again reuses it."""

    def __init__(self, value):
        self.value = value

    def __hash__(self) -> int:
        return id(self.value)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, _Same) and other.value is self.value


class _Problem(eqx.Module):
    """One run's data (arrays: traced) and the user's loss and optimiser (static, by identity).

    The mesh travels inside this module rather than as a kernel argument of its own, so that it keeps
    its topology (`kernel` strips it from top-level `Mesh` arguments): the user's loss needs it.
    """

    mesh: Mesh
    reparam: LargeSteps | None
    free: Int[Array, " n_free"] | None
    free_mask: Bool[Array, " nv"]
    lower: Float[Array, "nv 3"] | None
    upper: Float[Array, "nv 3"] | None
    target_volume: Float[Array, ""] | None
    loss: _Same = eqx.field(static=True)
    optimizer: _Same = eqx.field(static=True)
    keyed: bool = eqx.field(static=True)

    def to_parameters(self, vertices: Float[Array, "nv 3"]) -> PyTree:
        if self.reparam is not None:
            return self.reparam.to_parameters(vertices)
        return vertices if self.free is None else vertices[self.free]

    def to_vertices(self, parameters: PyTree) -> tuple[Float[Array, "nv 3"], RESULTS]:
        """The vertex positions of `parameters` and the outcome of the solve that maps them (Large Steps)."""
        if self.reparam is not None:
            solution = self.reparam.from_parameters(parameters, throw=False)
            return solution.value, solution.result
        vertices = parameters if self.free is None else self.mesh.vertices.at[self.free].set(parameters)
        return vertices, RESULTS.successful

    def objective(self, parameters: PyTree, key: PRNGKeyArray) -> tuple[Float[Array, ""], RESULTS]:
        vertices, result = self.to_vertices(parameters)
        shape = self.mesh.with_vertices(vertices)
        return (self.loss.value(shape, key) if self.keyed else self.loss.value(shape)), result

    def project(self, parameters: PyTree) -> tuple[PyTree, RESULTS]:
        """`parameters` projected onto the constraint or into the bounds (module docstring), with the solve's outcome."""
        if self.target_volume is None and self.lower is None:
            return parameters, RESULTS.successful
        vertices, result = self.to_vertices(parameters)
        if self.target_volume is not None:
            volume = lambda V: enclosed_volume(self.mesh.with_vertices(V))
            direction = jnp.where(self.free_mask[:, None], jax.grad(volume)(vertices), 0.0)
            # Scale the unknown so that t ~ a length: direction has units of area.
            scale = 1.0 / jnp.sqrt(jnp.sum(direction * direction))
            residual = lambda t, _: volume(vertices + t * scale * direction) - self.target_volume
            newton = optx.Newton(rtol=1e-12, atol=1e-12)
            t = optx.root_find(residual, newton, jnp.zeros((), vertices.dtype), throw=False).value
            vertices = vertices + t * scale * direction
        if self.lower is not None:
            vertices = jnp.clip(vertices, self.lower, self.upper)
        return self.to_parameters(vertices), result


class _State(NamedTuple):
    """The carry of the optimisation loop."""

    parameters: PyTree
    optimizer_state: PyTree
    key: PRNGKeyArray
    failure: Failure


def _step(problem: _Problem, state: _State, k) -> tuple[_State, Float[Array, ""]]:
    """Step `k`: the update of iterate `k - 1`, applied only when everything about it is finite; its loss."""
    key, subkey = jax.random.split(state.key)
    (value, solved), gradient = jax.value_and_grad(problem.objective, has_aux=True)(state.parameters, subkey)
    updates, optimizer_state = problem.optimizer.value.update(gradient, state.optimizer_state, state.parameters)
    parameters, projected = problem.project(optax.apply_updates(state.parameters, updates))
    outcome = first_failure(finite_outcome((value, gradient, parameters)), solved, projected)
    keep = lambda new, old: jax.tree.map(lambda a, b: jnp.where(is_failure(outcome), b, a), new, old)
    parameters, optimizer_state = keep((parameters, optimizer_state), (state.parameters, state.optimizer_state))
    return _State(parameters, optimizer_state, key, record(state.failure, k, outcome)), value


def _chunk(problem: _Problem, state: _State, start, idle, last, count: int) -> tuple[_State, tuple]:
    """Steps `start + 1, ..., start + count` (those past `last` skipped); their losses, and the loss of the last iterate."""
    state, values = scan_steps(functools.partial(_step, problem), state, start, count, last=last, idle=idle)
    # The loss of the chunk's last iterate (the final loss after the last chunk), with the next key.
    end_value, _ = problem.objective(state.parameters, jax.random.split(state.key)[1])
    return state, (values, end_value)


_compiled_chunk = kernel(_chunk, static_argnames=("count",))


@kernel(static_argnames=("chunks", "count"))
def _run(problem: _Problem, state: _State, idle, last, *, chunks: int, count: int):
    """Every chunk in one compiled program (the path without a progress bar)."""
    chunk = lambda state, start: _chunk(problem, state, start, idle, last, count)
    return run_chunks(chunk, state, chunks=chunks, every=count)


@kernel
def _start(problem: _Problem, key: PRNGKeyArray) -> tuple[_State, Float[Array, ""]]:
    """The initial state (parameters projected onto the constraint) and a zero of the loss's dtype."""
    parameters = problem.to_parameters(problem.mesh.vertices)
    if problem.target_volume is not None:
        parameters, _ = problem.project(parameters)
    dtype = jax.eval_shape(problem.objective, parameters, key)[0].dtype
    state = _State(parameters, problem.optimizer.value.init(parameters), key, no_failure())
    return state, jnp.zeros((), dtype)


@functools.cache
def _default_optimizer(parametrization: str) -> optax.GradientTransformation:
    """The default optimiser, one object per parametrisation (so that repeated runs reuse their program)."""
    return adam_uniform(1e-2) if parametrization == "large_steps" else optax.adam(1e-3)


def minimize_shape(
    loss: Callable[..., Float[Array, ""]],
    mesh: Mesh,
    *,
    steps: int,
    optimizer: optax.GradientTransformation | None = None,
    parametrization: str = "large_steps",
    lambda_: float = 10.0,
    weights: str = "uniform",
    fixed_vertices: Int[ArrayLike, " n_fixed"] | Sequence[int] | None = None,
    constraint: str | None = None,
    bounds: tuple[Float[ArrayLike, "*b"], Float[ArrayLike, "*b"]] | None = None,
    key: PRNGKeyArray | None = None,
    chunk_size: int | None = None,
    solver: str = "auto",
    progress: bool = False,
    throw: bool = True,
) -> ShapeOptimizationResult:
    r"""Minimise `loss(mesh)` over the vertex positions `V` `(nv, 3)` by a first-order optimiser (module docstring).

    $$U \leftarrow U + \mathrm{update}\bigl(\nabla_U \, \mathrm{loss}(V(U))\bigr), \qquad U = (I + \lambda L)\, V$$

    Each step is `U <- U + optimizer_update(grad_U loss(mesh(V(U))))` with `U` the parameters: the
    Large Steps parameters `U = (I + lambda L) V` (Nicolet et al. 2021) or the free vertices, then
    the projection onto `constraint` or into `bounds`. Example (PyTorch3D's mesh-fitting tutorial,
    with Large Steps):

        def fit(mesh, key):
            points = sample_points(mesh, 2000, key=key)
            return chamfer_distance(points, target) + 0.1 * normal_consistency_loss(mesh)

        result = minimize_shape(fit, icosphere(2), steps=500, key=jax.random.key(0))

    Args:
        loss: `loss(mesh) -> scalar`, or `loss(mesh, key) -> scalar` when `key` is given (a new
            key each step, e.g. for `sample_points`); a JAX-traceable function of `mesh.vertices`.
            It is compiled with the step: passing the same `loss` and `optimizer` objects again
            reuses the compiled program.
        mesh: the initial mesh (concrete vertices: the run is set up on the host).
        steps: number of optimiser steps, >= 1.
        optimizer: an optax `GradientTransformation`. Default: `adam_uniform(1e-2)` (the Large Steps
            paper's) for `"large_steps"`, `optax.adam(1e-3)` for `"vertices"`; learning rates are
            in length units, so these suit meshes of size about 1.
        parametrization: `"large_steps"` (default) or `"vertices"`.
        lambda_, weights, solver: the Large Steps matrix `I + lambda L` (`weights`: one of
            `ddgjax.LAPLACIAN_WEIGHTS`) and the backend of its factorisation (one of
            `ddgjax.LINEAR_SOLVERS`; `ddgjax.optim.large_steps`); ignored for `"vertices"`.
        fixed_vertices: `(n_fixed,)` indices of vertices held in place, or `None`.
        constraint: `None` or `"volume"` (keep the enclosed volume of the initial mesh, by projection;
            the mesh must be closed and consistently oriented for that to be a volume).
        bounds: `(lower, upper)`, each broadcastable to `(nv, 3)` (a scalar, a `(3,)` box corner or
            per-vertex limits): after every update the vertices are clipped into the box, the
            Euclidean projection onto it (with Large Steps, in vertex space, then mapped back to the
            parameters). The initial mesh must lie inside. Not with `constraint="volume"` (the two
            projections do not commute; `DDGInputError`).
        key: a PRNG key, split once per step and passed to `loss`; `None` for a loss without one.
        chunk_size: steps per compiled `lax.scan` chunk, i.e. per progress-bar update (default: about
            a twentieth of `steps`); a last chunk reaching past `steps` skips the extra steps.
        progress: show a tqdm progress bar over the chunks (off by default, as everywhere in ddgjax); `False`
            runs every chunk in one compiled program.
        throw: raise when a step failed (default), or report it in `result`.

    Returns:
        `ShapeOptimizationResult`: `value` the final `(nv, 3)` positions (`.mesh` the mesh),
        `loss_history` `(steps + 1,)`, `result`, `first_failure_step`.

    Raises:
        DDGInputError: a bad option, traced vertices, bounds the initial mesh violates.
        equinox.EquinoxRuntimeError: with `throw=True`, a failed step.

    References: Nicolet, Jacobson, Jakob 2021 (Large Steps); PyTorch3D's "Deform a source mesh to
    form a target mesh" tutorial (the loop it writes by hand); `largesteps.optimize.AdamUniform`.

    Examples:
        >>> import ddgjax
        >>> def loss(mesh):
        ...     return (ddgjax.mesh.total_area(mesh) - 6.0) ** 2
        >>> result = ddgjax.optim.minimize_shape(loss, ddgjax.mesh.icosphere(2), steps=100)
        >>> result.value.shape, result.loss_history.shape
        ((162, 3), (101,))
        >>> bool(result.loss_history[-1] < 0.1 * result.loss_history[0])
        True
    """
    mesh = require_mesh("mesh", mesh)
    steps = check_count("steps", steps)
    check_choice("parametrization", parametrization, PARAMETRIZATIONS)
    check_choice("constraint", constraint, CONSTRAINTS)
    check_weights(weights)
    check_solver(solver)
    if not callable(loss):
        raise DDGInputError(f"loss: expected a function loss(mesh) -> scalar, got {type(loss).__name__}")
    if is_traced(mesh.vertices):
        raise DDGInputError("mesh: minimize_shape sets up its run on the host and needs concrete vertices; call it outside jit")
    progress = check_progress(progress)
    chunk_size = max(1, steps // 20) if chunk_size is None else min(check_count("chunk_size", chunk_size), steps)
    optimizer = _default_optimizer(parametrization) if optimizer is None else optimizer
    if not isinstance(optimizer, optax.GradientTransformation):
        raise DDGInputError(
            f"optimizer: expected an optax GradientTransformation (e.g. optax.adam(1e-3)), got {type(optimizer).__name__}"
        )
    lower, upper = _box(bounds, mesh, constraint)
    fixed = fixed_vertex_indices(fixed_vertices, mesh.n_vertices)
    reparam = free = None
    if parametrization == "large_steps":
        reparam = large_steps(mesh, lambda_=lambda_, weights=weights, fixed_vertices=fixed, solver=solver)
    elif fixed.size:
        free = jnp.asarray(np.setdiff1d(np.arange(mesh.n_vertices), fixed), jnp.int32)
    problem = _Problem(
        mesh=mesh,
        reparam=reparam,
        free=free,
        free_mask=jnp.ones(mesh.n_vertices, bool).at[jnp.asarray(fixed, jnp.int32)].set(False),
        lower=lower,
        upper=upper,
        target_volume=enclosed_volume(mesh) if constraint == "volume" else None,
        loss=_Same(loss),
        optimizer=_Same(optimizer),
        keyed=key is not None,
    )
    state, idle = _start(problem, jax.random.key(0) if key is None else key)
    last = jnp.asarray(steps, jnp.int32)
    chunks = -(-steps // chunk_size)
    if progress:
        chunk = lambda state, start: _compiled_chunk(problem, state, start, idle, last, count=chunk_size)
        state, (values, end_values) = run_chunks(
            chunk,
            state,
            chunks=chunks,
            every=chunk_size,
            steps=steps,
            progress=True,
            description="minimize_shape",
            postfix=lambda saved: {"loss": float(saved[1])},
        )
    else:
        state, (values, end_values) = _run(problem, state, idle, last, chunks=chunks, count=chunk_size)
    vertices, _ = problem.to_vertices(state.parameters)
    optimised = ShapeOptimizationResult(
        value=vertices,
        loss_history=jnp.concatenate([values.reshape(-1)[:steps], end_values[-1:]]),
        result=state.failure.result,
        first_failure_step=first_failure_step(state.failure, steps),
        initial=mesh,
        parametrization=parametrization,
    )
    return raise_if_failed(optimised, optimised.result, throw)


def _box(bounds, mesh: Mesh, constraint):
    """`(lower, upper)` as `(nv, 3)` arrays of the vertices' dtype, or `(None, None)`; `DDGInputError` for bad bounds."""
    if bounds is None:
        return None, None
    if constraint is not None:
        raise DDGInputError(f"bounds: not with constraint={constraint!r} (the two projections do not commute); use one")
    if not isinstance(bounds, (tuple, list)) or len(bounds) != 2:
        raise DDGInputError(f"bounds: expected a pair (lower, upper), got {type(bounds).__name__}")
    shape = mesh.vertices.shape
    try:
        lower, upper = (jnp.broadcast_to(jnp.asarray(b, mesh.vertices.dtype), shape) for b in bounds)
    except ValueError as error:
        raise DDGInputError(f"bounds: lower and upper must broadcast to the vertices' shape {shape}: {error}") from error
    if not bool(jnp.all(lower <= upper)):
        raise DDGInputError("bounds: expected lower <= upper everywhere")
    if not bool(jnp.all((mesh.vertices >= lower) & (mesh.vertices <= upper))):
        raise DDGInputError("bounds: the initial mesh lies outside the box; start inside it (e.g. clip the vertices first)")
    return lower, upper
