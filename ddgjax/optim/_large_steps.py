"""Large Steps reparametrisation (Nicolet, Jacobson, Jakob 2021) and its optimiser, uniform Adam.

Gradient descent on vertex positions moves each vertex by its own gradient: a loss that sees only
part of the surface (a silhouette, a sparse set of points) crumples the mesh, and smoothing
regularisers with large weights slow the descent. Nicolet et al. optimise instead the parameters

    U = (I + lambda L) V,        V = (I + lambda L)^{-1} U,

with `L` a Laplacian of the initial mesh. A gradient step in `U` moves the vertices by
`(I + lambda L)^{-2}`-smoothed gradients (the chain rule applies `(I + lambda L)^{-1}` once more),
a Sobolev-type preconditioning: high-frequency components of the update are damped, large smooth
steps are allowed. The matrix is fixed for the whole run, so it is factorised once
(`ddgjax.solve.factorize`, CHOLMOD where installed) and every `from_parameters` is one solve with
the kept factor; its reverse-mode derivative is another solve with the same factor (`A` is
symmetric: `U_bar = A^{-1} V_bar`).

Fixed vertices: the rows and columns of fixed vertices are removed, `U_free = A_ff V_free + A_fb
V_fixed` and `V_free = A_ff^{-1} (U_free - A_fb V_fixed)`, so fixed vertices never move and the
free ones are smoothed with the fixed ones as Dirichlet data (the restriction of the same
preconditioner to the free block; `A_ff` stays positive definite).

The paper's optimiser (`AdamUniform` in its code) is Adam whose per-entry second-moment
normalisation is replaced by one scale per parameter array, the maximum of the second-moment
estimate: a per-entry scale would undo the smoothing by equalising the step of every entry.

Reference: B. Nicolet, A. Jacobson, W. Jakob, "Large Steps in Inverse Rendering of Geometry",
ACM Trans. Graph. 40(6) (SIGGRAPH Asia 2021), sections 4-5. Their `largesteps` package:
`compute_matrix(v, f, lambda_)`, `to_differential(M, v)`, `from_differential(M, u)`, `AdamUniform`.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax
import scipy.sparse as sp
from jaxtyping import Array, ArrayLike, Float, Int

from .._errors import DDGInputError, check_positive, is_traced
from .._options import check_solver, check_weights
from .._results import Solution, outcome
from ..laplacian import cotan_laplacian
from ..mesh import Mesh, require_mesh
from ..solve import Factorization, factorize
from ..sparse import SparseMatrix, from_scipy


class LargeSteps(eqx.Module):
    """The map between vertex positions and Large Steps parameters, `U = (I + lambda L) V` (module docstring).

    Made by `large_steps(mesh, lambda_=...)`. A pytree: pass it into `jit` (its factor is referenced
    by an array token, the matrix values are leaves). Shapes: `V` is `(nv, 3)`, `U` is `(n_free, 3)`.

    Attributes:
        matrix: `A_ff`, `(n_free, n_free)`, the free block of `I + lambda L`.
        factorization: the kept factorisation of `matrix`.
        offset: `A_fb V_fixed`, `(n_free, 3)` (zeros without fixed vertices).
        free: `(n_free,)` indices of the free vertices, or `None` when every vertex is free.
        template: `(nv, 3)` positions whose fixed rows are the fixed vertices' positions.
        lambda_, weights: the settings (static).
    """

    matrix: SparseMatrix
    factorization: Factorization
    offset: Float[Array, "n_free 3"]
    free: Int[Array, " n_free"] | None
    template: Float[Array, "nv 3"]
    lambda_: float = eqx.field(static=True)
    weights: str = eqx.field(static=True)

    def to_parameters(self, vertices: Float[Array, "nv 3"]) -> Float[Array, "n_free 3"]:
        """`U = ((I + lambda L) V)_free`, `(n_free, 3)`: the parameters of positions `(nv, 3)`."""
        free = vertices if self.free is None else vertices[self.free]
        return self.matrix @ free + self.offset

    def from_parameters(self, parameters: Float[Array, "n_free 3"], *, throw: bool = True) -> Float[Array, "nv 3"] | Solution:
        """`V = (I + lambda L)^{-1} U` on the free vertices (fixed ones from `template`), `(nv, 3)`; one solve.

        The solve reuses the kept factor (an iterative `solver` can fail to converge): with
        `throw=True` (default) a failed solve raises; with `throw=False` the result is a
        `ddgjax.Solution` whose `value` is `V` and `result` the solve's outcome.
        """
        solution = self.factorization.solve(parameters - self.offset, throw=False)
        solved = solution.value
        vertices = solved if self.free is None else self.template.at[self.free].set(solved)
        stats = solution.stats
        return outcome(vertices, solution.result, throw, stats)


def large_steps(
    mesh: Mesh,
    *,
    lambda_: float = 10.0,
    weights: str = "uniform",
    fixed_vertices: Int[ArrayLike, " k"] | Sequence[int] | None = None,
    solver: str = "auto",
) -> LargeSteps:
    r"""Build the Large Steps map `U = (I + lambda L) V` of `mesh` and factorise it once (module docstring).

    $$U = (I + \lambda L)\, V, \qquad V = (I + \lambda L)^{-1} U$$

    `L` is a PSD Laplacian of the initial mesh (`L 1 = 0`; the cotan one is `-igl.cotmatrix`), so
    `I + lambda L` is symmetric positive definite; with fixed vertices, its free block `A_ff` is
    (module docstring). A gradient step on `U` moves `V` by `(I + lambda L)^{-2}`-smoothed gradients.

    Args:
        mesh: the initial mesh; `L` is its Laplacian, fixed for the whole optimisation.
        lambda_: smoothing weight `lambda > 0`. With the uniform Laplacian it is dimensionless (the
            paper's examples use 10-100 or so: larger is smoother and slower to reach fine detail);
            with the cotan Laplacian it has units of area.
        weights: one of `ddgjax.LAPLACIAN_WEIGHTS`: `"uniform"` (the graph Laplacian
            `deg_i delta_ij - [ij edge]`, the paper's default) or `"cotan"` (the PSD cotan Laplacian
            of the initial mesh, docs/conventions.md).
        fixed_vertices: `(n_fixed,)` indices of vertices that stay where they are (e.g. a boundary),
            or `None`.
        solver: the backend of the factorisation and its solves, one of `ddgjax.LINEAR_SOLVERS`
            (`ddgjax.solve.factorize`).

    Returns:
        `LargeSteps` with `to_parameters` (`(nv, 3) -> (n_free, 3)`) and `from_parameters` (back).

    Built on the host from concrete vertex positions (a setup step, like a factorisation): not under
    `jit`. Reference: Nicolet et al. 2021. Equivalent: `largesteps.geometry.compute_matrix(v, f,
    lambda_)` with `to_differential` / `from_differential` (uniform weights, no fixed vertices).

    Examples:
        >>> import jax.numpy as jnp
        >>> import ddgjax
        >>> sphere = ddgjax.mesh.icosphere(2)
        >>> steps = ddgjax.optim.large_steps(sphere, lambda_=10.0)
        >>> U = steps.to_parameters(sphere.vertices)  # (I + lambda L) V
        >>> U.shape, bool(jnp.allclose(steps.from_parameters(U), sphere.vertices))
        ((162, 3), True)
    """
    mesh = require_mesh("mesh", mesh)
    lambda_ = check_positive("lambda_", lambda_)
    check_weights(weights)
    check_solver(solver)
    if is_traced(mesh.vertices):
        raise DDGInputError("mesh: large_steps builds its matrix on the host from concrete vertices; call it outside jit")
    nv = mesh.n_vertices
    if weights == "uniform":
        edges = np.asarray(mesh.edges)
        adjacency = sp.coo_matrix((np.ones(2 * len(edges)), (edges.T.reshape(-1), edges[:, ::-1].T.reshape(-1))), shape=(nv, nv))
        stiffness = sp.diags(np.asarray(adjacency.sum(axis=1)).ravel()) - adjacency
    else:
        stiffness = cotan_laplacian(mesh).to_scipy()
    system = (sp.identity(nv) + lambda_ * stiffness).tocsr()
    vertices = mesh.vertices
    fixed = fixed_vertex_indices(fixed_vertices, nv)
    if fixed.size == 0:
        free, block, offset = None, system, jnp.zeros_like(vertices)
    else:
        free = np.setdiff1d(np.arange(nv), fixed)
        block = system[free][:, free]
        offset = jnp.asarray(system[free][:, fixed] @ np.asarray(vertices)[fixed], vertices.dtype)
    matrix = from_scipy(block.astype(np.dtype(vertices.dtype)), positive_semidefinite=True)
    return LargeSteps(
        matrix=matrix,
        factorization=factorize(matrix, solver=solver),
        offset=offset,
        free=None if free is None else jnp.asarray(free, jnp.int32),
        template=vertices,
        lambda_=lambda_,
        weights=weights,
    )


def fixed_vertex_indices(fixed_vertices, n_vertices: int) -> np.ndarray:
    """Sorted unique fixed-vertex indices as an int array, or `DDGInputError` (shared with the driver)."""
    if fixed_vertices is None:
        return np.zeros(0, np.int64)
    fixed = np.asarray(fixed_vertices)
    if fixed.ndim != 1 or not (fixed.size == 0 or np.issubdtype(fixed.dtype, np.integer)):
        raise DDGInputError(
            f"fixed_vertices: expected a 1-D array of vertex indices, got shape {fixed.shape} dtype {fixed.dtype}"
        )
    if fixed.size and (fixed.min() < 0 or fixed.max() >= n_vertices):
        raise DDGInputError(f"fixed_vertices: expected indices in [0, {n_vertices}), got min {fixed.min()} max {fixed.max()}")
    fixed = np.unique(fixed)
    if fixed.size == n_vertices:
        raise DDGInputError("fixed_vertices: every vertex is fixed; nothing is left to optimise")
    return fixed


class ScaleByAdamUniformState(NamedTuple):
    """State of `scale_by_adam_uniform`: step count and Adam's first and second moment estimates."""

    count: Int[Array, ""]
    mu: optax.Updates
    nu: optax.Updates


def scale_by_adam_uniform(b1: float = 0.9, b2: float = 0.999, eps: float = 1e-8) -> optax.GradientTransformation:
    """Adam's moments with one uniform scale per parameter array: `m_hat / (sqrt(max(v_hat)) + eps)`.

    `m = b1 m + (1 - b1) g`, `v = b2 v + (1 - b2) g^2`, bias-corrected `m_hat = m / (1 - b1^t)`,
    `v_hat = v / (1 - b2^t)`; the update of each array is `m_hat / (sqrt(max_entries v_hat) + eps)`.
    Plain Adam divides entrywise by `sqrt(v_hat)`, which rescales each vertex's step separately and
    so undoes a smooth parametrisation; the maximum keeps the direction of `m_hat` (Nicolet et al.
    2021, section 5: `AdamUniform`). Chain with a learning rate (`adam_uniform`).

    Args:
        b1: the decay rate of the first moment (default 0.9, Adam's).
        b2: the decay rate of the second moment (default 0.999).
        eps: added to the denominator `sqrt(max v_hat)` (default `1e-8`).

    Returns:
        An `optax.GradientTransformation` whose state is a `ScaleByAdamUniformState`.
    """

    def init(params):
        zeros = jax.tree_util.tree_map(jnp.zeros_like, params)
        return ScaleByAdamUniformState(count=jnp.zeros((), jnp.int32), mu=zeros, nu=zeros)

    def update(updates, state, params=None):
        del params
        count = state.count + 1
        mu = jax.tree_util.tree_map(lambda m, g: b1 * m + (1 - b1) * g, state.mu, updates)
        nu = jax.tree_util.tree_map(lambda v, g: b2 * v + (1 - b2) * g * g, state.nu, updates)
        t = count.astype(jnp.result_type(float))
        first, second = 1 - b1**t, 1 - b2**t

        def scaled(m, v):
            return (m / first.astype(m.dtype)) / (jnp.sqrt(jnp.max(v) / second.astype(v.dtype)) + eps)

        return jax.tree_util.tree_map(scaled, mu, nu), ScaleByAdamUniformState(count=count, mu=mu, nu=nu)

    return optax.GradientTransformation(init, update)


def adam_uniform(
    learning_rate: float | optax.Schedule, *, b1: float = 0.9, b2: float = 0.999, eps: float = 1e-8
) -> optax.GradientTransformation:
    """The Large Steps paper's optimiser (`AdamUniform`) as an optax transformation: `scale_by_adam_uniform`
    then `-learning_rate`. Use with `large_steps` parameters or any others.

    Args:
        learning_rate: the step size, a float or an optax schedule.
        b1, b2, eps: as for `scale_by_adam_uniform` (keyword-only; defaults 0.9, 0.999, `1e-8`).

    Returns:
        An `optax.GradientTransformation`.
    """
    return optax.chain(scale_by_adam_uniform(b1=b1, b2=b2, eps=eps), optax.scale_by_learning_rate(learning_rate))
