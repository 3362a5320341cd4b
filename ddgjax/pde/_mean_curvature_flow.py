"""Mean curvature flow of a triangle mesh by backward Euler steps, plain and modified, in one `lax.scan`.

Smooth mean curvature flow moves each point along its mean curvature normal, `df/dt = Delta f =
-2 H N` (`H` the mean of the principal curvatures): the `L^2` gradient flow of the area. With the
PSD cotan Laplacian `L` and a mass matrix `M` (pointwise `Delta = -M^{-1} L`, docs/conventions.md),
one backward Euler (implicit) step of size `tau` is

    (M + tau L) f' = M f,

solved for the new positions `f'` (`(nv, 3)`, the three coordinates as one block right-hand side).
Implicit steps are stable for any `tau` (Desbrun et al. 1999). Two variants:

- plain (`modified=False`): `M` and `L` of the current surface at every step. Thin necks pinch and
  the cotan weights of collapsing triangles blow up, so it can fail in finite time.
- modified (`modified=True`, Kazhdan, Solomon and Ben-Chen 2012): the stiffness matrix `L` frozen at
  the initial surface, the mass matrix `M` of the current one, `(M_t + tau L_0) f' = M_t f`. It is
  the flow of the metric, not of the embedding, and avoids the singularities of the plain flow
  (e.g. genus-0 surfaces tend to round spheres). Because `M_t` changes every step the matrix is
  factorised every step in both variants (CHOLMOD reuses its symbolic analysis of the one pattern);
  only a flow that froze `M` too would be a single factorisation, and that is plain linear
  diffusion of the coordinates, not Kazhdan et al.'s flow.

Both operators come from the squared edge lengths of the current surface (the intrinsic core of
`ddgjax.laplacian`, `cotan_laplacian_from_lengths_sq` and `mass_matrix_from_lengths_sq`), on the
storage plan of the mesh's connectivity, built once on the host before the compiled loop.

Units: `tau` is smooth time, since `M^{-1} L` is the pointwise operator. A round sphere of radius
`r` has `-Delta x = 2 x / r^2`, so `r' = -2 / r` and `r(t)^2 = r_0^2 - 4 t` (extinction at
`t = r_0^2 / 4`). A step takes `M` and `L` from the surface it starts on (linearly implicit), so on
a sphere it gives `r_{n+1} (1 + 2 tau / r_n^2) = r_n`, first-order accurate in `tau`. The cotan `L`
is scale invariant, so on a round sphere the plain and modified flows coincide. The enclosed volume
decreases (`dV/dt = -int 2 H dA`) and, for the plain flow, so does the area.

Differentiable with respect to the initial vertex positions and `tau` in reverse mode (`jax.grad`;
`linear_solve` differentiates each solve implicitly, and `M`, `L` are differentiable functions of
the positions), under `jit` and `vmap`. Outcomes (docs/conventions.md): a step whose solve failed
(`ddgjax.RESULTS` of `linear_solve`) or whose positions are not finite ends the flow (the steps
after it are skipped) and is reported as the record's `result` and `first_failure_step`.

The DDG exercises (`test-flow-soln.txt`, `projects/geometric-flow`) use the barycentric mass matrix,
`L + 1e-8 I` in place of `L`, and translate the result so that its unweighted vertex mean is 0:
`mean_curvature_flow(mesh, tau=tau, steps=steps, mass="barycentric", shift=1e-8)` and then
subtracting the mean reproduces it (tests).

References: M. Desbrun, M. Meyer, P. Schroeder, A. Barr, "Implicit fairing of irregular meshes using
diffusion and curvature flow" (SIGGRAPH 1999); M. Kazhdan, J. Solomon, M. Ben-Chen, "Can mean-curvature
flow be modified to be non-singular?" (SGP 2012); K. Crane, *Discrete Differential Geometry: An Applied
Introduction* (2020), "The Laplacian" assignment. Equivalents: libigl's tutorial 205 (Laplacian)
solves `(M - tau cotmatrix) f' = M f` with `cotmatrix` of the input and a barycentric `M` recomputed
each step, the modified flow (it also recentres and rescales to unit area after each step);
gpytoolbox and geometry-central have none built in.
"""

from __future__ import annotations

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int, Real

from .._compile import kernel
from .._errors import DDGInputError, check_choice, is_traced
from .._loop import (
    Failure,
    check_progress,
    check_steps,
    check_time_step,
    failed_before,
    finite_outcome,
    first_failure_step,
    no_failure,
    record,
    run_chunks,
    scan_steps,
)
from .._options import check_mass, check_solver
from .._results import RESULTS, Record, first_failure, raise_if_failed
from ..laplacian import TriangulationPlan, cotan_laplacian_from_lengths_sq, mass_matrix_from_lengths_sq
from ..laplacian.internal import vertex_plan
from ..mesh import Mesh, enclosed_volume, face_edge_lengths_sq, require_mesh, total_area
from ..solve import linear_solve
from ..sparse import nonnegative


class MeanCurvatureFlowResult(Record):
    """Saved states of `mean_curvature_flow`: the initial surface and one every `save_every` steps.

    `s = steps // save_every + 1` states.

    Attributes:
        vertices: `(s, nv, 3)` positions; `value` is the last, `mesh(i)` state `i` as a `Mesh`.
        times: `(s,)` flow times `step * tau`.
        area: `(s,)` total area.
        volume: `(s,)` enclosed volume (`ddgjax.mesh.enclosed_volume`; a volume only for a closed,
            consistently oriented mesh).
        result: the outcome of the first failing step (`ddgjax.RESULTS`): `successful`, a failed
            solve's (`max_steps_reached`, `singular`, ...) or `nonfinite` (NaN / inf positions).
            `mean_curvature_flow(..., throw=True)` (the default) raises instead of returning it.
        first_failure_step: int scalar, that step's number (`1, ..., steps`; 0 for non-finite traced
            input), `steps + 1` when none failed. The steps after it are skipped: later saved states
            repeat its state.
        tau: the time step.
        initial: the input mesh (its connectivity, for `mesh(index)`).
        modified, mass, solver: the flow's settings (static).
    """

    vertices: Float[Array, "s nv 3"]
    times: Float[Array, " s"]
    area: Float[Array, " s"]
    volume: Float[Array, " s"]
    result: RESULTS
    first_failure_step: Int[Array, ""]
    tau: Float[Array, ""]
    initial: Mesh
    modified: bool = eqx.field(static=True)
    mass: str = eqx.field(static=True)
    solver: str = eqx.field(static=True)

    @property
    def value(self) -> Float[Array, "nv 3"]:
        """The final vertex positions, `vertices[-1]` (`(nv, 3)`; `mesh()` wraps them in a `Mesh`)."""
        return self.vertices[-1]

    @property
    def stats(self) -> dict[str, Array]:
        """The run's history per saved state: `times`, `area`, `volume`, as the fields hold them."""
        return {"times": self.times, "area": self.area, "volume": self.volume}

    def mesh(self, index: int = -1) -> Mesh:
        """Saved state `index` (default: the final one) as a `Mesh` of the input's connectivity."""
        return self.initial.with_vertices(self.vertices[index])


def mean_curvature_flow(
    mesh: Mesh,
    *,
    tau: Real[ArrayLike, ""],
    steps: int,
    save_every: int | None = None,
    modified: bool = False,
    mass: str = "voronoi",
    shift: Real[ArrayLike, ""] = 0.0,
    solver: str = "auto",
    progress: bool = False,
    throw: bool = True,
) -> MeanCurvatureFlowResult:
    r"""Backward Euler mean curvature flow: `steps` solves of `(M + tau L) f' = M f` (module docstring).

    $$(M + \tau L) f' = M f$$

    `L` is the PSD cotan Laplacian (`L == -igl.cotmatrix`), `M` the mass matrix `mass`, `f` the
    `(nv, 3)` positions; `tau` is smooth time (a round sphere of radius `r` follows
    $r(t)^2 = r_0^2 - 4 t$). The whole run is one compiled `lax.scan` (over saved chunks of
    `save_every` steps), differentiable in the initial positions and `tau` (reverse mode):

        jax.grad(lambda V: loss(mean_curvature_flow(mesh.with_vertices(V), tau=1e-3, steps=10).value))(V)

    Args:
        mesh: any triangle mesh (the volume is meaningful for closed oriented ones). Boundary
            vertices move too (natural boundary condition).
        tau: time step, > 0 (smooth time units; may be traced).
        steps: number of steps, >= 1.
        save_every: save every this many steps; must divide `steps` (default `steps`: the initial
            and the final surface).
        modified: `False` (plain: `M`, `L` of the current surface) or `True` (Kazhdan et al. 2012:
            `L` frozen at the initial surface, `M` of the current one).
        mass: one of `ddgjax.MASS_MATRICES`: `"voronoi"` (default), `"barycentric"` (the DDG
            exercises') or `"galerkin"`.
        shift: adds `shift * I` to `L` (default 0; the DDG exercises use `1e-8`); >= 0.
        solver: the backend of the linear solves, one of `ddgjax.LINEAR_SOLVERS` (`"auto"`:
            CHOLMOD on CPU where installed; `"cg"` runs inside the program on any device).
        progress: show a tqdm progress bar over the saved chunks (one compiled chunk per save,
            called from a host loop; needs concrete vertices and `tau`: not under jit / vmap / grad).
        throw: raise when a step failed (default), or return the record to inspect `result`.

    Returns:
        `MeanCurvatureFlowResult`: `vertices` `(s, nv, 3)`, `value` the final `(nv, 3)` positions,
        `times`, `area`, `volume`, `result`, `first_failure_step`.

    Raises:
        DDGInputError: `mesh` not a `Mesh`; bad `steps`, `save_every`, `modified`, `mass`, `solver`;
            a concrete `tau` that is not finite and positive, a concrete `shift` below 0;
            `progress=True` on traced input.
        equinox.EquinoxRuntimeError: with `throw=True`, a failed step (a `jax.errors.JaxRuntimeError`
            under a plain `jax.jit`).

    libigl: tutorial 205 (`U = spsolve(M - tau * igl.cotmatrix(V, F), M @ U)` with `M` recomputed per
    step: `modified=True`, up to its recentring and rescaling). References: module docstring.

    Examples:
        >>> import jax.numpy as jnp
        >>> import ddgjax
        >>> run = ddgjax.pde.mean_curvature_flow(ddgjax.mesh.icosphere(3), tau=0.01, steps=10)
        >>> run.vertices.shape, run.value.shape
        ((2, 642, 3), (642, 3))
        >>> round(float(jnp.linalg.norm(run.value, axis=1).mean()), 2)  # r(t)^2 = 1 - 4 t: 0.77 at t = 0.1
        0.78
    """
    mesh = require_mesh("mesh", mesh)
    steps, save_every = check_steps(steps, save_every)
    check_choice("modified", modified, (False, True))
    check_mass(mass)
    check_solver(solver)
    tau = check_time_step(tau, mesh.vertices.dtype)
    shift = _shift(shift, mesh.vertices.dtype)
    progress = check_progress(progress, mesh.vertices, tau, shift)
    settings = {"steps": steps, "save_every": save_every, "modified": modified, "mass": mass, "solver": solver}
    run = functools.partial(_states, progress=True) if progress else _run
    frames, failure = run(mesh, vertex_plan(mesh), tau, shift, **settings)
    area, volume, result, first = _saved_invariants(mesh, frames, failure, steps=steps)
    flow = MeanCurvatureFlowResult(
        vertices=frames,
        times=tau * save_every * jnp.arange(steps // save_every + 1, dtype=tau.dtype),
        area=area,
        volume=volume,
        result=result,
        first_failure_step=first,
        tau=tau,
        initial=mesh,
        modified=modified,
        mass=mass,
        solver=solver,
    )
    return raise_if_failed(flow, flow.result, throw)


def _shift(value, dtype) -> Real[Array, ""]:
    """`shift`, a real scalar `>= 0`, as an array of `dtype` (checked now when concrete)."""
    if np.ndim(value) != 0 or np.iscomplexobj(value) or isinstance(value, (bool, np.bool_)):
        raise DDGInputError(f"shift: expected a real scalar >= 0, got {value!r}")
    if not is_traced(value) and not (np.isfinite(value) and value >= 0):
        raise DDGInputError(f"shift: expected a finite real number >= 0, got {np.asarray(value).item()!r}")
    return jnp.asarray(value).astype(dtype)


@kernel(static_argnames=("count", "modified", "mass", "solver"))
def _advance(
    mesh: Mesh, plan: TriangulationPlan, vertices, failure: Failure, start, tau, shift, *, count, modified, mass, solver
):
    """Steps `start + 1, ..., start + count` from `vertices`: `((vertices, failure), vertices)`.

    `mesh` is the initial surface (without its topology: `plan` carries what the operators need).
    """
    step_size = nonnegative(tau)

    def laplacian(lengths_sq):
        return cotan_laplacian_from_lengths_sq(lengths_sq, plan).shifted(nonnegative(shift))

    frozen = laplacian(face_edge_lengths_sq(mesh)) if modified else None

    def step(carry, k):
        vertices, failure = carry
        lengths_sq = face_edge_lengths_sq(mesh.with_vertices(vertices))
        current_mass = mass_matrix_from_lengths_sq(lengths_sq, plan, mass=mass)
        system = current_mass + step_size * (frozen if modified else laplacian(lengths_sq))
        solution = linear_solve(system, current_mass @ vertices, solver=solver, throw=False)
        # A non-finite state says more than whatever the solver made of it.
        return (solution.value, record(failure, k, first_failure(finite_outcome(solution.value), solution.result))), None

    def step_or_stop(carry, k):
        # After a failure the flow stops: steps from a failed state (NaN, or an indefinite matrix)
        # would only repeat the failure, and the recorded first failing step must stay the first.
        return jax.lax.cond(failed_before(carry[1], k), lambda carry, _: (carry, None), step, carry, k)

    carry, _ = scan_steps(step_or_stop, (vertices, failure), start, count)
    return carry, carry[0]


def _states(mesh, plan, tau, shift, *, steps, save_every, modified, mass, solver, progress):
    """The saved states `(s, nv, 3)` and the first `Failure`: `run_chunks` over chunks of `save_every` steps."""
    settings = {"count": save_every, "modified": modified, "mass": mass, "solver": solver}

    def chunk(carry, start):
        return _advance(mesh, plan, *carry, start, tau, shift, **settings)

    # The input is state 0: non-finite traced input (concrete input is checked by `Mesh`) fails there.
    start = (mesh.vertices, record(no_failure(), 0, finite_outcome(mesh.vertices)))
    (_, failure), frames = run_chunks(
        chunk,
        start,
        chunks=steps // save_every,
        every=save_every,
        progress=progress,
        description="mean curvature flow",
    )
    return jnp.concatenate([mesh.vertices[None], frames]), failure


@kernel(static_argnames=("steps", "save_every", "modified", "mass", "solver"))
def _run(mesh: Mesh, plan: TriangulationPlan, tau, shift, *, steps, save_every, modified, mass, solver):
    """`_states` as one compiled program (the path without a progress bar)."""
    return _states(
        mesh, plan, tau, shift, steps=steps, save_every=save_every, modified=modified, mass=mass, solver=solver, progress=False
    )


@kernel(static_argnames=("steps",))
def _saved_invariants(mesh: Mesh, frames, failure: Failure, *, steps):
    """`(area, volume, result, first_failure_step)` of the saved states."""
    area = jax.vmap(lambda vertices: total_area(mesh.with_vertices(vertices)))(frames)
    volume = jax.vmap(lambda vertices: enclosed_volume(mesh.with_vertices(vertices)))(frames)
    return area, volume, failure.result, first_failure_step(failure, steps)
