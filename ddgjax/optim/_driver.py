"""`minimize_shape`: gradient-based shape optimisation of a mesh, the whole step under one `jax.jit`.

One step is `value_and_grad` of the user's loss with respect to the parameters, an optax update,
the map back to vertex positions (Large Steps: one solve with the kept factor) and, optionally, the
projection onto the constraint; `lax.scan` runs a chunk of steps per compiled call and a host loop
over chunks drives a tqdm progress bar (as `ddgjax.curves.curve_shortening_flow` does).

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

Failures: a step whose loss or gradient is not finite is not applied (the parameters and the
optimiser state are kept), and the run reports `RESULTS.nonfinite` with the first such step; with
`throw=True` (default) it raises, with `throw=False` the returned vertices are the last finite iterate.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax
import optimistix as optx
from jaxtyping import Array, ArrayLike, Float, Int, PRNGKeyArray

from .._compile import cpu_compiler_options
from .._errors import DDGInputError, check_choice, check_count, is_traced
from .._results import RESULTS, raise_if_failed
from ..mesh import Mesh, enclosed_volume, require_mesh
from ._large_steps import adam_uniform, fixed_vertex_indices, large_steps

PARAMETRIZATIONS = ("large_steps", "vertices")
CONSTRAINTS = (None, "volume")


class ShapeOptimizationResult(eqx.Module):
    """What `minimize_shape` returns.

    Attributes:
        vertices: `(nv, 3)` final positions (the last finite iterate if the run failed).
        loss_history: `(steps + 1,)` the loss after `k` steps, `k = 0, ..., steps` (the first is the
            initial shape's, the last the final shape's; a stochastic loss is evaluated with the
            step's key).
        result: `RESULTS.successful`, or `RESULTS.nonfinite` when some step's loss or gradient was
            NaN / inf (that step and the ones after it with the same value were not applied).
        first_nonfinite_step: that step's index, `steps` when there was none.
        initial: the input mesh (its connectivity, for `mesh`).
        compile_time, run_time: seconds spent compiling the step chunks and running them.
        parametrization: `"large_steps"` or `"vertices"` (static).
    """

    vertices: Float[Array, "nv 3"]
    loss_history: Float[Array, " steps_plus_one"]
    result: RESULTS
    first_nonfinite_step: Int[Array, ""]
    initial: Mesh
    compile_time: float
    run_time: float
    parametrization: str = eqx.field(static=True)

    @property
    def mesh(self) -> Mesh:
        """The optimised mesh, `initial.with_vertices(vertices)`."""
        return self.initial.with_vertices(self.vertices)


def minimize_shape(
    loss: Callable[..., Float[Array, ""]],
    mesh: Mesh,
    *,
    steps: int,
    optimizer: optax.GradientTransformation | None = None,
    parametrization: str = "large_steps",
    lambda_: float = 10.0,
    laplacian: str = "uniform",
    fixed_vertices: Int[ArrayLike, " k"] | Sequence[int] | None = None,
    constraint: str | None = None,
    bounds: tuple[Float[ArrayLike, "*b"], Float[ArrayLike, "*b"]] | None = None,
    key: PRNGKeyArray | None = None,
    chunk_size: int | None = None,
    method: str = "auto",
    progress: bool = True,
    throw: bool = True,
) -> ShapeOptimizationResult:
    """Minimise `loss(mesh)` over the vertex positions by a first-order optimiser (module docstring).

    Example (PyTorch3D's mesh-fitting tutorial, with Large Steps):

        def fit(mesh, key):
            points = sample_points(mesh, 2000, key)
            return chamfer_distance(points, target) + 0.1 * normal_consistency_loss(mesh)

        result = minimize_shape(fit, icosphere(2), steps=500, key=jax.random.key(0))

    Args:
        loss: `loss(mesh) -> scalar`, or `loss(mesh, key) -> scalar` when `key` is given (a new
            key each step, e.g. for `sample_points`); a JAX-traceable function of `mesh.vertices`.
        mesh: the initial mesh (concrete vertices: the run is driven from the host).
        steps: number of optimiser steps, >= 1.
        optimizer: an optax `GradientTransformation`. Default: `adam_uniform(1e-2)` (the Large Steps
            paper's) for `"large_steps"`, `optax.adam(1e-3)` for `"vertices"`; learning rates are
            in length units, so these suit meshes of size about 1.
        parametrization: `"large_steps"` (default) or `"vertices"`.
        lambda_, laplacian, method: the Large Steps matrix `I + lambda L` and its factorisation
            (`ddgjax.optim.large_steps`); ignored for `"vertices"`.
        fixed_vertices: indices of vertices held in place, or `None`.
        constraint: `None` or `"volume"` (keep the enclosed volume of the initial mesh, by projection;
            the mesh must be closed and consistently oriented for that to be a volume).
        bounds: `(lower, upper)`, each broadcastable to `(nv, 3)` (a scalar, a `(3,)` box corner or
            per-vertex limits): after every update the vertices are clipped into the box, the
            Euclidean projection onto it (with Large Steps, in vertex space, then mapped back to the
            parameters). The initial mesh must lie inside. Not with `constraint="volume"` (the two
            projections do not commute; `DDGInputError`).
        key: a PRNG key, split once per step and passed to `loss`; `None` for a loss without one.
        chunk_size: steps per compiled `lax.scan` chunk, i.e. per progress-bar update (default: about
            a twentieth of `steps`).
        progress: show a tqdm progress bar over the chunks.
        throw: raise when a step was not finite (default), or report it in `result`.

    Returns:
        `ShapeOptimizationResult` (`.mesh`, `.vertices`, `.loss_history`, timings).

    The step (`value_and_grad`, optimiser update, reparametrisation, projection) is one jitted
    function, compiled once per call of `minimize_shape` into one program that runs a chunk (a
    last chunk reaching past `steps` skips the extra steps). References: Nicolet, Jacobson, Jakob 2021 (Large Steps); PyTorch3D's
    "Deform a source mesh to form a target mesh" tutorial (the loop it writes by hand).
    """
    mesh = require_mesh("mesh", mesh)
    steps = check_count("steps", steps)
    check_choice("parametrization", parametrization, PARAMETRIZATIONS)
    check_choice("constraint", constraint, CONSTRAINTS)
    if not callable(loss):
        raise DDGInputError(f"loss: expected a function loss(mesh) -> scalar, got {type(loss).__name__}")
    if is_traced(mesh.vertices):
        raise DDGInputError(
            "mesh: minimize_shape drives its steps from the host and needs concrete vertices; call it outside jit"
        )
    chunk_size = max(1, steps // 20) if chunk_size is None else min(check_count("chunk_size", chunk_size), steps)
    lower, upper = _box(bounds, mesh, constraint)
    fixed = fixed_vertex_indices(fixed_vertices, mesh.n_vertices)
    initial = mesh.vertices

    if parametrization == "large_steps":
        reparam = large_steps(mesh, lambda_=lambda_, laplacian=laplacian, fixed_vertices=fixed, method=method)
        to_parameters, to_vertices = reparam.to_parameters, reparam.from_parameters
        optimizer = adam_uniform(1e-2) if optimizer is None else optimizer
    else:
        free = jnp.asarray(np.setdiff1d(np.arange(mesh.n_vertices), fixed), jnp.int32) if fixed.size else None
        to_parameters = lambda V: V if free is None else V[free]
        to_vertices = lambda U: U if free is None else initial.at[free].set(U)
        optimizer = optax.adam(1e-3) if optimizer is None else optimizer
    if not isinstance(optimizer, optax.GradientTransformation):
        raise DDGInputError(
            f"optimizer: expected an optax GradientTransformation (e.g. optax.adam(1e-3)), got {type(optimizer).__name__}"
        )

    free_mask = jnp.ones(mesh.n_vertices, bool).at[jnp.asarray(fixed, jnp.int32)].set(False)
    target_volume = enclosed_volume(mesh) if constraint == "volume" else None

    def objective(parameters, step_key):
        shape = mesh.with_vertices(to_vertices(parameters))
        return loss(shape) if key is None else loss(shape, step_key)

    def project(parameters):
        vertices = to_vertices(parameters)
        direction = jnp.where(free_mask[:, None], jax.grad(lambda V: enclosed_volume(mesh.with_vertices(V)))(vertices), 0.0)
        # Scale the unknown so that t ~ a length: direction has units of area.
        scale = 1.0 / jnp.sqrt(jnp.sum(direction * direction))
        residual = lambda t, _: enclosed_volume(mesh.with_vertices(vertices + t * scale * direction)) - target_volume
        t = optx.root_find(residual, optx.Newton(rtol=1e-12, atol=1e-12), jnp.zeros((), vertices.dtype), throw=False).value
        return to_parameters(vertices + t * scale * direction)

    def step(carry, index):
        parameters, state, step_key, first_bad = carry
        step_key, subkey = jax.random.split(step_key)
        value, gradient = jax.value_and_grad(objective)(parameters, subkey)
        updates, new_state = optimizer.update(gradient, state, parameters)
        new_parameters = optax.apply_updates(parameters, updates)
        if constraint == "volume":
            new_parameters = project(new_parameters)
        if lower is not None:
            new_parameters = to_parameters(jnp.clip(to_vertices(new_parameters), lower, upper))
        finite = jnp.isfinite(value) & jnp.all(jnp.isfinite(gradient)) & jnp.all(jnp.isfinite(new_parameters))
        keep = lambda new, old: jax.tree_util.tree_map(lambda a, b: jnp.where(finite, a, b), new, old)
        parameters, state = keep((new_parameters, new_state), (parameters, state))
        first_bad = jnp.where(finite, first_bad, jnp.minimum(first_bad, index))
        return (parameters, state, step_key, first_bad), value

    def step_or_skip(carry, index):
        # The last chunk may reach past `steps`: those steps are skipped, so one program serves all chunks.
        return jax.lax.cond(index < steps, step, lambda c, _: (c, jnp.zeros((), dtype)), carry, index)

    def chunk(carry, start):
        carry, values = jax.lax.scan(step_or_skip, carry, start + jnp.arange(chunk_size, dtype=jnp.int32))
        # The loss of the chunk's last iterate (the final loss after the last chunk), with the next key.
        end_value = objective(carry[0], jax.random.split(carry[2])[1])
        return carry, values, end_value

    parameters = to_parameters(initial)
    if constraint == "volume":
        parameters = project(parameters)
    dtype = jax.eval_shape(objective, parameters, jax.random.key(0)).dtype
    carry = (parameters, optimizer.init(parameters), jax.random.key(0) if key is None else key, jnp.asarray(steps, jnp.int32))
    options = cpu_compiler_options() if jax.default_backend() == "cpu" else {}
    compile_start = time.perf_counter()
    compiled = jax.jit(chunk, compiler_options=options or None).lower(carry, jnp.zeros((), jnp.int32)).compile()
    compile_time = time.perf_counter() - compile_start

    from tqdm.auto import tqdm

    history = []
    run_start = time.perf_counter()
    with tqdm(total=steps, desc="minimize_shape", unit="step", disable=not progress) as bar:
        for start in range(0, steps, chunk_size):
            carry, values, final_loss = compiled(carry, jnp.asarray(start, jnp.int32))
            values.block_until_ready()
            history.append(values[: min(chunk_size, steps - start)])
            bar.update(min(chunk_size, steps - start))
            bar.set_postfix(loss=float(final_loss))
    parameters, _, _, first_bad = carry
    vertices = to_vertices(parameters)
    run_time = time.perf_counter() - run_start

    loss_history = jnp.concatenate([*history, final_loss[None]])
    result = RESULTS.where(first_bad < steps, RESULTS.nonfinite, RESULTS.successful)
    outcome = ShapeOptimizationResult(
        vertices=vertices,
        loss_history=loss_history,
        result=result,
        first_nonfinite_step=first_bad,
        initial=mesh,
        compile_time=compile_time,
        run_time=run_time,
        parametrization=parametrization,
    )
    return raise_if_failed(outcome, outcome.result, throw)


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
