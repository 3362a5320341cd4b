"""Mean curvature flow of a triangle mesh by backward Euler steps, plain and modified, in one `lax.scan`.

Smooth mean curvature flow moves each point along its mean curvature normal, `df/dt = Delta f =
-2 H N` (`H` the mean of the principal curvatures): the `L^2` gradient flow of the area. With the
PSD cotan Laplacian `L` and a mass matrix `M` (pointwise `Delta = -M^{-1} L`, DESIGN.md), one
backward Euler (implicit) step of size `h` is

    (M + h L) f' = M f,

solved for the new positions `f'` (`(nv, 3)`, the three coordinates as one block right-hand side).
Implicit steps are stable for any `h` (Desbrun et al. 1999). Two variants:

- plain (`modified=False`): `M` and `L` of the current surface at every step. Thin necks pinch and
  the cotan weights of collapsing triangles blow up, so it can fail in finite time.
- modified (`modified=True`, Kazhdan, Solomon and Ben-Chen 2012): the stiffness matrix `L` frozen at
  the initial surface, the mass matrix `M` of the current one, `(M_t + h L_0) f' = M_t f`. It is
  the flow of the metric, not of the embedding, and avoids the singularities of the plain flow
  (e.g. genus-0 surfaces tend to round spheres). Because `M_t` changes every step the matrix is
  factorised every step in both variants (CHOLMOD reuses its symbolic analysis of the one pattern);
  only a flow that froze `M` too would be a single factorisation, and that is plain linear
  diffusion of the coordinates, not Kazhdan et al.'s flow.

Units: `h` is smooth time, since `M^{-1} L` is the pointwise operator. A round sphere of radius `r`
has `-Delta x = 2 x / r^2`, so `r' = -2 / r` and `r(t)^2 = r_0^2 - 4 t` (extinction at `t = r_0^2 / 4`).
A step takes `M` and `L` from the surface it starts on (linearly implicit), so on a sphere it gives
`r_{n+1} (1 + 2 h / r_n^2) = r_n`, first-order accurate in `h`. The cotan `L` is scale invariant, so
on a round sphere the plain and modified flows coincide. The enclosed volume decreases
(`dV/dt = -int 2 H dA`) and, for the plain flow, so does the area.

Differentiable with respect to the initial vertex positions and `h` in reverse mode (`jax.grad`;
`linear_solve` differentiates each solve implicitly, and `M`, `L` are differentiable functions of
the positions), under `jit`; failures of a solve raise through `ddgjax.RESULTS`.

The DDG exercises (`test-flow-soln.txt`, `projects/geometric-flow`) use the barycentric mass matrix,
`L + 1e-8 I` in place of `L`, and translate the result so that its unweighted vertex mean is 0:
`mean_curvature_flow(mesh, h=h, steps=steps, mass="barycentric", shift=1e-8)` and then subtract the
mean reproduces it (tests).

References: M. Desbrun, M. Meyer, P. Schroeder, A. Barr, "Implicit fairing of irregular meshes using
diffusion and curvature flow" (SIGGRAPH 1999); M. Kazhdan, J. Solomon, M. Ben-Chen, "Can mean-curvature
flow be modified to be non-singular?" (SGP 2012); K. Crane, *Discrete Differential Geometry: An Applied
Introduction* (2020), "The Laplacian" assignment. Equivalents: libigl's tutorial 205 (Laplacian)
solves `(M - h cotmatrix) f' = M f` with `cotmatrix` of the input and a barycentric `M` recomputed
each step, the modified flow (it also recentres and rescales to unit area after each step);
gpytoolbox and geometry-central have none built in.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Real

from .._compile import kernel
from .._errors import DDGInputError, check_choice, check_count, is_traced
from ..laplacian import cotan_laplacian, mass_matrix
from ..mesh import Mesh, enclosed_volume, require_mesh, total_area
from ..solve import linear_solve
from ..sparse import nonnegative

MASSES = ("voronoi", "barycentric", "galerkin")


class MeanCurvatureFlowResult(eqx.Module):
    """Saved states of `mean_curvature_flow`: the initial surface and one every `save_every` steps.

    `s = steps // save_every + 1` states.

    Attributes:
        vertices: `(s, nv, 3)` positions; `vertices[-1]` (or `final`) is the flowed surface.
        times: `(s,)` flow times `step * h`.
        area: `(s,)` total area.
        volume: `(s,)` enclosed volume (`ddgjax.mesh.enclosed_volume`; a volume only for a closed,
            consistently oriented mesh).
        initial: the input mesh (its connectivity, for `mesh(index)`).
        modified, mass: the flow's settings (static).
    """

    vertices: Float[Array, "s nv 3"]
    times: Float[Array, " s"]
    area: Float[Array, " s"]
    volume: Float[Array, " s"]
    initial: Mesh
    modified: bool = eqx.field(static=True)
    mass: str = eqx.field(static=True)

    @property
    def final(self) -> Float[Array, "nv 3"]:
        """The final vertex positions, `vertices[-1]`."""
        return self.vertices[-1]

    def mesh(self, index: int = -1) -> Mesh:
        """Saved state `index` (default: the final one) as a `Mesh` of the input's connectivity."""
        return self.initial.with_vertices(self.vertices[index])


def mean_curvature_flow(
    mesh: Mesh,
    *,
    h: Real[ArrayLike, ""],
    steps: int,
    modified: bool = False,
    mass: str = "voronoi",
    shift: Real[ArrayLike, ""] = 0.0,
    save_every: int | None = None,
    method: str = "auto",
) -> MeanCurvatureFlowResult:
    """Backward Euler mean curvature flow: `steps` solves of `(M + h L) f' = M f` (module docstring).

    The whole run is one compiled program (a `lax.scan` over saved chunks, each an inner scan of
    `save_every` steps). Differentiable in the initial positions and `h` (reverse mode):

        jax.grad(lambda V: loss(mean_curvature_flow(mesh.with_vertices(V), h=1e-3, steps=10).final))(V)

    Args:
        mesh: any triangle mesh (the volume is meaningful for closed oriented ones). Boundary
            vertices move too (natural boundary condition).
        h: time step, >= 0 (smooth time units; may be traced).
        steps: number of steps, >= 1.
        modified: `False` (plain: `M`, `L` of the current surface) or `True` (Kazhdan et al. 2012:
            `L` frozen at the initial surface, `M` of the current one).
        mass: `"voronoi"` (default), `"barycentric"` (the DDG exercises') or `"galerkin"`.
        shift: adds `shift * I` to `L` (default 0; the DDG exercises use `1e-8`); >= 0.
        save_every: save every this many steps; must divide `steps` (default `steps`: the initial
            and the final surface).
        method: the backend of `linear_solve` (`"auto"`, `"cholesky"`, `"cg"`).

    Returns:
        `MeanCurvatureFlowResult` (`.final` the final positions, `(nv, 3)`).

    libigl: tutorial 205 (`U = spsolve(M - h * igl.cotmatrix(V, F), M @ U)` with `M` recomputed per
    step: `modified=True`, up to its recentring and rescaling). References: module docstring.
    """
    mesh = require_mesh("mesh", mesh)
    steps = check_count("steps", steps)
    save_every = steps if save_every is None else check_count("save_every", save_every)
    if steps % save_every:
        raise DDGInputError(f"save_every: expected a divisor of steps = {steps}, got {save_every}")
    check_choice("modified", modified, (False, True))
    check_choice("mass", mass, MASSES)
    h = _scalar("h", h, mesh.vertices.dtype)
    shift = _scalar("shift", shift, mesh.vertices.dtype)
    settings = {"steps": steps, "save_every": save_every, "modified": modified, "mass": mass, "method": method}
    frames, area, volume = _run(mesh, h, shift, **settings)
    times = h * save_every * jnp.arange(steps // save_every + 1, dtype=h.dtype)
    return MeanCurvatureFlowResult(
        vertices=frames, times=times, area=area, volume=volume, initial=mesh, modified=modified, mass=mass
    )


def _scalar(name: str, value, dtype) -> Real[Array, ""]:
    """A real scalar `>= 0` as an array of the vertices' `dtype` (checked now when concrete, when the
    program runs when traced)."""
    if np.ndim(value) != 0 or np.iscomplexobj(value) or isinstance(value, (bool, np.bool_)):
        raise DDGInputError(f"{name}: expected a real scalar >= 0, got {value!r}")
    if not is_traced(value) and not (np.isfinite(value) and value >= 0):
        raise DDGInputError(f"{name}: expected a finite real number >= 0, got {np.asarray(value).item()!r}")
    return jnp.asarray(value).astype(dtype)


@kernel(static_argnames=("steps", "save_every", "modified", "mass", "method"))
def _run(
    mesh: Mesh, h, shift, *, steps: int, save_every: int, modified: bool, mass: str, method: str
) -> tuple[Float[Array, "s nv 3"], Float[Array, " s"], Float[Array, " s"]]:
    """The saved states `(s, nv, 3)`, their areas and volumes: a scan over `steps // save_every` chunks
    of `save_every` steps."""
    step_size = nonnegative(h)
    frozen = cotan_laplacian(mesh).shifted(nonnegative(shift)) if modified else None

    def step(vertices: Float[Array, "nv 3"], _) -> tuple[Float[Array, "nv 3"], None]:
        current = mesh.with_vertices(vertices)
        laplacian = frozen if modified else cotan_laplacian(current).shifted(nonnegative(shift))
        current_mass = mass_matrix(current, kind=mass)
        system = current_mass + step_size * laplacian
        return linear_solve(system, current_mass @ vertices, method=method).value, None

    def chunk(vertices: Float[Array, "nv 3"], _) -> tuple[Float[Array, "nv 3"], Float[Array, "nv 3"]]:
        vertices, _ = jax.lax.scan(step, vertices, None, length=save_every)
        return vertices, vertices

    _, frames = jax.lax.scan(chunk, mesh.vertices, None, length=steps // save_every)
    frames = jnp.concatenate([mesh.vertices[None], frames])
    area = jax.vmap(lambda vertices: total_area(mesh.with_vertices(vertices)))(frames)
    volume = jax.vmap(lambda vertices: enclosed_volume(mesh.with_vertices(vertices)))(frames)
    return frames, area, volume
