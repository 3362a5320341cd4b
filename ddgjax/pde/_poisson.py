"""The Poisson problem and harmonic interpolation on a triangle or tetrahedral mesh, solved exactly and differentiably.

Sign convention (the reading report, `ddgjax.pde._energies`): the Poisson problem is
`Delta phi = rho` with the pointwise Laplace-Beltrami operator `Delta = -M^{-1} L`, so the discrete
system is

    L phi = -M rho,

the minimiser of `poisson_energy(mesh, phi, rho) = 1/2 phi^T L phi + phi^T M rho`. (The solution of
`-Delta u = f`, e.g. `(1 - r^2) / 4` for `f = 1` on the unit disk, is `solve_poisson(mesh, -f)`.)

Boundary conditions: Dirichlet values on any vertex set (`fixed_vertices=`, `fixed_values=`),
natural Neumann (zero normal derivative) everywhere else. A connected component without a fixed
vertex (a closed surface, or a free piece) determines `phi` only up to a constant and needs
`int rho = 0`: there `rho` is made compatible by removing its area-weighted mean
(`rho - int rho / area`), and the solution is the one with `int phi = 0` on that component. This is
exact, not a regularisation: one vertex per such component is pinned to 0, the remaining positive
definite system is solved, and the constant is fixed afterwards. Unreferenced vertices (empty rows)
are set to 0.

A `ddgjax.volume.TetMesh` is solved the same way with its own operators (`ddgjax.volume.cotan_laplacian`,
`ddgjax.volume.mass_matrix`; "area" above reads volume, faces read tets): `-Delta u = 1` in the unit
ball with `u = 0` on the sphere is `(1 - r^2) / 6` to second order in the mean edge length (tests).
`robust=` has no tetrahedral meaning and is refused there.

`robust=True` (or an `IntrinsicTriangulation`) solves with the intrinsic Delaunay Laplacian and
mass matrix (`ddgjax.laplacian.laplacian_and_mass`): non-negative interior weights, so a harmonic
interpolant obeys the maximum principle on meshes with obtuse triangles too.

How it runs: the bookkeeping that depends on the connectivity (components, pins, the block plan of
`ddgjax.sparse.dirichlet_plan`) is host work before one compiled program, which assembles `L` and `M`
from the squared edge lengths (the intrinsic core of `ddgjax.laplacian`, on the mesh's own lengths or
the intrinsic Delaunay ones) and solves the free-free block with `ddgjax.solve.linear_solve` (the
backend is `solver=`); a tet mesh's `L` and `M` come from `ddgjax.volume` and enter the same solve. `phi` is differentiable with respect to `rho`, the fixed values and the
vertex positions (forward and reverse mode), under `jit` and `vmap`. A failed solve is an outcome
(`ddgjax.RESULTS`, `throw=`): with `throw=False` the answer is a `ddgjax.Solution` whose `stats` are
the linear solve's relative `residual` and `num_steps`.

References: the reading report, "The Poisson problem" (Crane's DDG notes, ch. 6); libigl
`min_quad_with_fixed` and `harmonic`; gpytoolbox `min_quad_with_fixed`.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from .._compile import kernel
from .._errors import DDGInputError
from .._options import check_solver
from .._results import RESULTS, Solution, outcome
from ..discretization import discretize
from ..discretization.internal import DirichletData, require_domain
from ..laplacian import (
    IntrinsicTriangulation,
)
from ..mesh import Mesh
from ..solve import linear_solve
from ..sparse import DirichletPlan, SparseMatrix, dirichlet_blocks
from ..volume import TetMesh


def solve_poisson(
    mesh: Mesh | TetMesh,
    rho: Float[ArrayLike, "nv *k"],
    *,
    fixed_vertices: Int[ArrayLike, " n_fixed"] | None = None,
    fixed_values: Float[ArrayLike, " n_fixed *k"] | None = None,
    mass: str = "voronoi",
    robust: bool | IntrinsicTriangulation = False,
    solver: str = "auto",
    throw: bool = True,
) -> Float[Array, "nv *k"] | Solution:
    r"""Solve the Poisson problem `Delta phi = rho`, i.e. `L phi = -M rho`, with Dirichlet values where given.

    $$\Delta\phi = \rho, \quad \Delta = -M^{-1} L, \qquad\text{i.e.}\qquad L\phi = -M\rho$$

    `L` is the PSD cotan Laplacian and `M` the mass matrix (`Delta = -M^{-1} L`, docs/conventions.md),
    so $\phi$ minimises `poisson_energy(mesh, phi, rho)` $= \tfrac12 \phi^\top L \phi + \phi^\top M \rho$ with
    `phi = fixed_values` on `fixed_vertices` and natural Neumann conditions elsewhere. Components
    without a fixed vertex get a compatible `rho` and a zero-mean `phi` (module docstring).
    Differentiable in `rho`, `fixed_values` and the vertex positions; one compiled program per
    connectivity and size.

    Args:
        mesh: any triangle mesh (closed, with boundary, several components), or a
            `ddgjax.volume.TetMesh` (a solid: its own cotan Laplacian and mass matrix).
        rho: `(nv,)` or `(nv, k)` pointwise right-hand side at the vertices (`k` problems at once).
        fixed_vertices: `(n_fixed,)` distinct vertex indices whose values are prescribed (concrete,
            host data). Default: none (Neumann everywhere).
        fixed_values: `(n_fixed,)` or `(n_fixed, k)` values there (default 0).
        mass: the mass matrix `M`, one of `ddgjax.MASS_MATRICES`: `"voronoi"` (default),
            `"barycentric"` or `"galerkin"`.
        robust: the intrinsic Delaunay Laplacian and mass instead of the mesh's (`True`, or an
            `IntrinsicTriangulation` from `intrinsic_delaunay(mesh)` inside `jit` / `grad`); triangle
            meshes only (a `TetMesh` takes `False`).
        solver: the backend of the linear solve, one of `ddgjax.LINEAR_SOLVERS` (`"auto"`,
            `"cholesky"`, `"superlu"`, `"cg"`, `"pyamg"`; `ddgjax.solve.linear_solve`'s `method`).
        throw: raise on a failed solve (default), or return the outcome.

    Returns:
        `phi`, the shape of `rho`; with `throw=False` a `ddgjax.Solution` holding it as `value`, the
        solve's outcome as `result` (an item of `ddgjax.RESULTS`) and `stats`
        `{"residual": |A x - b| / |b|, "num_steps": CG iterations}` of the free-free system.

    Reference: the reading report, "The Poisson problem"; Crane's DDG notes, ch. 6.
    libigl: `igl.min_quad_with_fixed(L, M @ rho, known, values, ...)` with `L = -igl.cotmatrix(V, F)`
    (`V, T` for tets); gpytoolbox: `min_quad_with_fixed(L, c=M @ rho, k=known, y=values)`.

    Examples:
        >>> import jax.numpy as jnp
        >>> import ddgjax
        >>> sphere = ddgjax.mesh.icosphere(3)
        >>> z = sphere.vertices[:, 2]  # Delta z = -2 z on the unit sphere
        >>> phi = ddgjax.pde.solve_poisson(sphere, -2 * z, fixed_vertices=jnp.array([0]), fixed_values=z[:1])
        >>> phi.shape, bool(jnp.allclose(phi, z, atol=1e-3))
        ((642,), True)
    """
    mesh = require_domain("mesh", mesh)
    check_solver(solver)
    rho = _vertex_values("rho", mesh, rho)
    discretization = discretize(mesh, mass=mass, robust=robust, caller="solve_poisson")
    dirichlet = DirichletData(mesh, fixed_vertices, fixed_values, rho.shape[1:], discretization.pattern)
    if dirichlet.plan is None:  # every vertex prescribed: nothing to solve
        phi = jnp.zeros_like(rho).at[dirichlet.vertices].set(dirichlet.values.astype(rho.dtype))
        stats = {"residual": jnp.zeros((), rho.dtype), "num_steps": jnp.zeros((), jnp.int32)}
        return outcome(phi, RESULTS.successful, throw, stats)
    problem = (rho, dirichlet.values, dirichlet.plan, dirichlet.labels, dirichlet.floating)
    options = {"n_pinned": dirichlet.n_pinned, "n_components": dirichlet.n_components, "solver": solver}
    phi, result, stats = _solve_system(discretization.laplacian, discretization.mass, *problem, **options)
    return outcome(phi, result, throw, stats)


def _solve_system(
    laplacian: SparseMatrix,
    mass_matrix_: SparseMatrix,
    rho: Float[Array, "nv *k"],
    values: Float[Array, " n_fixed *k"],
    blocks: DirichletPlan,
    labels: Int[Array, " nv"],
    floating: Bool[Array, " nv"],
    *,
    n_pinned: int,
    n_components: int,
    solver: str,
) -> tuple[Float[Array, "nv *k"], RESULTS, dict[str, Array]]:
    """`(phi, result, stats)` of `L phi = -M rho` with the Dirichlet data and pins (module docstring), given `L` and `M`.

    Called eagerly: the free-free system comes from one compiled program, `linear_solve` runs its own
    (its definiteness check and outcome on the host, outside them) and one more re-centres `phi`, so
    every program can be kept across processes (`ddgjax._program_store`). Under `jit` / `grad` it is
    all traced into the caller's program.
    """
    free_free, rhs, fixed_values = _reduced_system(
        laplacian, mass_matrix_, rho, values, blocks, labels, floating, n_pinned=n_pinned, n_components=n_components
    )
    solution = linear_solve(free_free, rhs, solver=solver, throw=False)
    phi = _recentred(mass_matrix_, solution.value, fixed_values, blocks, labels, floating, n_components=n_components)
    return phi, solution.result, solution.stats


def _component_mean(mass_matrix_: SparseMatrix, values, labels, n_components: int):
    """`int values / area` of each vertex's component, `(nv, ...)` (areas: `M 1`; Galerkin rows sum to them too)."""
    component_area = jax.ops.segment_sum(mass_matrix_.row_sums(), labels, n_components)
    integral = jax.ops.segment_sum(mass_matrix_ @ values, labels, n_components)
    return (integral / _broadcast(component_area, integral))[labels]


@kernel(static_argnames=("n_pinned", "n_components"))
def _reduced_system(laplacian, mass_matrix_, rho, values, blocks: DirichletPlan, labels, floating, *, n_pinned, n_components):
    """`(L_ff, -(M rho_c)_f - L_fx x_fixed, x_fixed)`: the free-free system, `rho_c` the compatible part of
    `rho` (zero mean on components without a fixed vertex), `x_fixed` the values then the pins' zeros."""
    fixed_values = jnp.concatenate([values.astype(rho.dtype), jnp.zeros((n_pinned,) + rho.shape[1:], rho.dtype)])
    compatible = rho - jnp.where(_broadcast(floating, rho), _component_mean(mass_matrix_, rho, labels, n_components), 0.0)
    rhs = -(mass_matrix_ @ compatible)
    free_free, free_fixed = dirichlet_blocks(laplacian, blocks)
    return free_free, rhs[blocks.free] - free_fixed @ fixed_values, fixed_values


@kernel(static_argnames=("n_components",))
def _recentred(mass_matrix_, free_values, fixed_values, blocks: DirichletPlan, labels, floating, *, n_components):
    """`phi` joined from its free and fixed values, each component without a fixed vertex shifted to zero mean."""
    phi = blocks.join(free_values, fixed_values)
    return phi - jnp.where(_broadcast(floating, phi), _component_mean(mass_matrix_, phi, labels, n_components), 0.0)


def harmonic_interpolation(
    mesh: Mesh | TetMesh,
    *,
    fixed_vertices: Int[ArrayLike, " n_fixed"],
    fixed_values: Float[ArrayLike, " n_fixed *k"],
    robust: bool | IntrinsicTriangulation = False,
    solver: str = "auto",
    throw: bool = True,
) -> Float[Array, "nv *k"] | Solution:
    r"""The report's smoothest interpolant: `L phi = 0` away from `fixed_vertices`, `phi = fixed_values` on them.

    The minimiser of the Dirichlet energy

    $$\tfrac12 \int \lVert \nabla\phi \rVert^2 \, dA = \tfrac12 \phi^\top L \phi$$

    with the given
    values (natural Neumann boundary elsewhere): `solve_poisson` with `rho = 0`. A component without
    a fixed vertex gets 0 (its harmonic functions are the constants; the zero-mean one).
    Differentiable in `fixed_values` and the vertex positions.

    Args:
        mesh: any triangle mesh, or a `ddgjax.volume.TetMesh`.
        fixed_vertices: `(n_fixed,)` distinct vertex indices, at least one (concrete, host data).
        fixed_values: `(n_fixed,)` or `(n_fixed, k)` values at them (e.g. `(n_fixed, 3)` positions).
        robust: the intrinsic Delaunay Laplacian (`solve_poisson`): with it the interpolant lies
            between the smallest and largest values (the maximum principle) on any triangle mesh
            (a `TetMesh` takes `False`).
        solver: the backend of the linear solve, one of `ddgjax.LINEAR_SOLVERS`.
        throw: raise on a failed solve (default), or return the outcome.

    Returns:
        `phi`, `(nv,)` or `(nv, k)`; with `throw=False` a `ddgjax.Solution` (as `solve_poisson`).

    Reference: the reading report, "Dirichlet energy"; Crane's DDG notes, ch. 6. libigl:
    `igl.harmonic(V, F, fixed_vertices, fixed_values, 1)`; gpytoolbox: `min_quad_with_fixed` with
    `L` and no linear term.

    Examples:
        >>> import numpy as np
        >>> import jax.numpy as jnp
        >>> import ddgjax
        >>> square = ddgjax.mesh.grid(8, 8)
        >>> x = np.asarray(square.vertices[:, 0])
        >>> sides = np.flatnonzero((x == x.min()) | (x == x.max()))
        >>> phi = ddgjax.pde.harmonic_interpolation(square, fixed_vertices=sides, fixed_values=x[sides])
        >>> bool(jnp.allclose(phi, x))  # linear functions are harmonic
        True
    """
    mesh = require_domain("mesh", mesh)
    if fixed_vertices is None or np.size(fixed_vertices) == 0:
        raise DDGInputError("fixed_vertices: expected at least one vertex to interpolate from, got none")
    fixed_values = jnp.asarray(fixed_values)
    if fixed_values.ndim not in (1, 2):
        raise DDGInputError(f"fixed_values: expected shape (n_fixed,) or (n_fixed, k), got {fixed_values.shape}")
    dtype = fixed_values.dtype if jnp.issubdtype(fixed_values.dtype, jnp.floating) else float
    rho = jnp.zeros((mesh.n_vertices,) + fixed_values.shape[1:], dtype)
    return solve_poisson(
        mesh, rho, fixed_vertices=fixed_vertices, fixed_values=fixed_values, robust=robust, solver=solver, throw=throw
    )


def _vertex_values(name: str, mesh: Mesh | TetMesh, values) -> Float[Array, "nv *k"]:
    n = mesh.n_vertices
    if np.ndim(values) not in (1, 2) or np.shape(values)[0] != n:
        raise DDGInputError(f"{name}: expected shape ({n},) or ({n}, k), got {np.shape(values)}")
    values = jnp.asarray(values)
    return values if jnp.issubdtype(values.dtype, jnp.floating) else values.astype(float)


def _broadcast(x, like):
    return x.reshape(x.shape + (1,) * (like.ndim - x.ndim))
