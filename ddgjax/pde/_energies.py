"""Quadratic energies of functions on a triangle mesh: Dirichlet, screened Dirichlet, Poisson and the
reading report's gradient-fitting energy `E_X`.

Each energy is a plain scalar JAX function of the unknowns `phi` (a piecewise-linear function given
by its vertex values) and of the mesh: jit-, grad-, vmap- and jvp-able, differentiable in `phi` and
in the vertex positions (`jax.grad(lambda V: energy(mesh.with_vertices(V), phi))(V)`). Their
gradients in `phi` are the linear systems of the Poisson problems, so a Newton step (one linear solve)
minimises them, and optimistix / lineax see them as ordinary objectives. `phi` is `(nv,)` or `(nv, k)`;
an `(nv, k)` array is `k` independent functions whose energies are summed.

Conventions (DESIGN.md): `L` is the positive semidefinite weak cotan Laplacian
(`L == -igl.cotmatrix(V, F)`), `M` a mass matrix (`mass=`, one of `ddgjax.MASS_MATRICES`: `"voronoi"`,
`"barycentric"` or `"galerkin"`),
and the pointwise Laplace-Beltrami operator is `Delta = -M^{-1} L` (the analyst's `div grad`,
negative semidefinite). Integrated divergence: `ddgjax.dec.divergence(mesh, X)_i =
-sum_f A_f <grad phi_i, X_f>`, so `divergence(gradient(u)) == -L u`.

**Sign of the Poisson problem.** The reading report states the Poisson problem as

    Delta phi = rho,    with    E_X(phi + eps psi) = E_X(phi) - 2 eps int psi (Delta phi - div X) + O(eps^2),

so the minimiser of `E_X(phi) = int |grad phi - X|^2` solves `Delta phi = rho` with `rho = div X`
(report, "Dirichlet energy" and "Poisson problem"; Crane's DDG notes and exercises use the same
`Delta`). With `Delta = -M^{-1} L` that is `L phi = -M rho`, and since
`1/2 E_X(phi) = 1/2 int |grad phi|^2 + int phi div X + const`, the energy whose minimiser solves it is

    poisson_energy(phi, rho) = 1/2 phi^T L phi + phi^T M rho,    gradient  L phi + M rho = -M (Delta phi - rho).

This is the sign of the DDG exercises' reference solution `test-spp-soln.txt`
(`(L + 1e-8 I) phi = -M (rho - mean rho)`, tests) and of `solve_poisson` (`Delta phi = rho`: `-Delta u = 1` on the
unit disk, `solve_poisson(disk, -1)`, gives `(1 - r^2) / 4`). The report's finite-element paragraph drops the
minus sign of Green's identity and arrives at `L phi = M rho` (`-Delta phi = rho`); for that
equation pass `-rho` (gradient `L phi - M rho`). A source (`rho > 0`) is a minimum of `phi`.

References: the DDG reading report ("Dirichlet energy",
"Poisson problem"); K. Crane, *Discrete Differential Geometry: An Applied Introduction* (2020),
ch. 6; K. Crane, C. Weischedel, M. Wardetzky, *The heat method for distance computation* (2017).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Real

from .._compile import device_array, kernel
from .._errors import DDGInputError, check_float_shape
from .._options import check_mass
from ..dec import gradient
from ..laplacian import dirichlet_energy as dirichlet_energy
from ..laplacian import mass_matrix
from ..mesh import Mesh, face_areas, require_mesh
from ..sparse import SparseMatrix


def screened_dirichlet_energy(
    mesh: Mesh, phi: Float[ArrayLike, "nv *k"], screening: Real[ArrayLike, ""], *, mass: str = "voronoi"
) -> Float[Array, ""]:
    r"""Screened Dirichlet energy `1/2 phi^T (L + s M) phi = 1/2 int |grad phi|^2 + s/2 int phi^2`.

    $$E(\phi) = \tfrac12 \phi^\top (L + s M) \phi = \tfrac12 \int \lVert \nabla\phi \rVert^2 \, dA + \frac{s}{2} \int \phi^2 \, dA$$

    Its gradient in `phi` is `(L + s M) phi`, the operator of the screened Poisson equation
    `(L + s M) phi = M f` and of a backward-Euler heat step `(M + t L) u = M u_0` (`s = 1 / t`).
    Convex for `s >= 0` and strictly convex for `s > 0` (convention of the module docstring: `L` PSD).

    Args:
        mesh: any triangle mesh.
        phi: `(nv,)` or `(nv, k)` vertex values (columns summed).
        screening: the scalar `s` (may be traced; differentiable).
        mass: one of `ddgjax.MASS_MATRICES`: `"voronoi"` (default), `"barycentric"` or `"galerkin"`
            (`ddgjax.laplacian.mass_matrix`).

    Returns:
        The scalar energy.

    libigl: `0.5 * phi @ ((-igl.cotmatrix(V, F) + s * igl.massmatrix(V, F, type)) @ phi)`; gpytoolbox:
    the same with `cotangent_laplacian(V, F)` and `massmatrix(V, F, type=...)`. Reference: the module
    docstring.
    """
    mesh = require_mesh("mesh", mesh)
    phi = _vertex_values("phi", mesh, phi)
    check_mass(mass)
    if np.ndim(screening) != 0 or not np.isrealobj(screening):
        raise DDGInputError(f"screening: expected a real scalar, got {_describe(screening)}")
    return _plus_mass_term(mesh, dirichlet_energy(mesh, phi), _galerkin(mesh, mass), phi, phi, 0.5 * screening, mass=mass)


def poisson_energy(
    mesh: Mesh, phi: Float[ArrayLike, "nv *k"], rho: Float[ArrayLike, "nv *k"], *, mass: str = "voronoi"
) -> Float[Array, ""]:
    r"""Poisson energy `1/2 phi^T L phi + phi^T M rho`, minimised by the solution of `Delta phi = rho`.

    $$E(\phi) = \tfrac12 \phi^\top L \phi + \phi^\top M \rho, \qquad \nabla_\phi E = L\phi + M\rho = -M(\Delta\phi - \rho)$$

    Its gradient in `phi` is `L phi + M rho = -M (Delta phi - rho)` with `Delta = -M^{-1} L`: it
    vanishes exactly where `L phi = -M rho`, the report's Poisson problem `Delta phi = rho` (the sign is
    discussed in the module docstring; for `-Delta phi = rho`, i.e. gradient `L phi - M rho`, pass
    `-rho`). Continuous form: `int 1/2 |grad phi|^2 + phi rho dA`. On a closed surface it is bounded
    below only when `sum(M rho) = 0` (each connected component), the compatibility condition of the
    Poisson problem.

    Args:
        mesh: any triangle mesh.
        phi: `(nv,)` or `(nv, k)` vertex values (columns summed).
        rho: pointwise right-hand side at the vertices, the shape of `phi`.
        mass: one of `ddgjax.MASS_MATRICES`: `"voronoi"` (default), `"barycentric"` or `"galerkin"`
            (`ddgjax.laplacian.mass_matrix`).

    Returns:
        The scalar energy.

    libigl / gpytoolbox: the objective `1/2 Z^T A Z + Z^T B` of `igl.min_quad_with_fixed` and
    `gpytoolbox.min_quad_with_fixed` with `A = -igl.cotmatrix(V, F)` (`cotangent_laplacian(V, F)`) and
    `B = M @ rho`. Reference: the module docstring.
    """
    mesh = require_mesh("mesh", mesh)
    phi = _vertex_values("phi", mesh, phi)
    rho = _vertex_values("rho", mesh, rho, like=phi)
    check_mass(mass)
    return _plus_mass_term(mesh, dirichlet_energy(mesh, phi), _galerkin(mesh, mass), phi, rho, 1.0, mass=mass)


def _galerkin(mesh: Mesh, mass: str) -> SparseMatrix | None:
    """The Galerkin mass matrix (it needs the mesh's storage plan, which a kernel does not see), else `None`."""
    return mass_matrix(mesh, mass=mass) if mass == "galerkin" else None


# One program for the mass term of an eager call (the Dirichlet term keeps its own kernel and its
# written-out vertex derivative); under a caller's jit both are traced into the caller's program.
@kernel(static_argnames=("mass",))
def _plus_mass_term(
    mesh: Mesh,
    energy: Float[Array, ""],
    galerkin: SparseMatrix | None,
    phi: Float[Array, "nv *k"],
    rho: Float[Array, "nv *k"],
    scale: Real[ArrayLike, ""],
    *,
    mass: str,
) -> Float[Array, ""]:
    """`energy + scale * phi^T M rho`, `M` the lumped `mass` matrix of `mesh` or the given Galerkin one."""
    matrix = mass_matrix(mesh, mass=mass) if galerkin is None else galerkin
    return energy + scale * jnp.sum(phi * (matrix @ rho))


def gradient_fitting_energy(mesh: Mesh, phi: Float[ArrayLike, "nv *k"], field: Float[ArrayLike, "nf 3 *k"]) -> Float[Array, ""]:
    """The reading report's `E_X(phi) = int |grad phi - X|^2 dA`: how far `grad phi` is from a face field `X`.

    Discretely `E_X = sum_f A_f |grad_f phi - X_f|^2`, with `grad_f phi` the gradient of the
    piecewise-linear interpolant on face `f` (`ddgjax.dec.gradient`) and `A_f` its area; zero exactly
    when `X = grad phi`. Its gradient in `phi` is

        2 (L phi - sum_f A_f <grad phi_i, X_f>) = 2 (L phi + divergence(X)),

    with the integrated `ddgjax.dec.divergence`, so its minimiser solves `L phi = -divergence(X)`,
    the report's `Delta phi = div X` (module docstring; the heat method's last step), and
    `1/2 E_X(phi) = poisson_energy(phi, rho) + 1/2 int |X|^2` when `M rho = divergence(X)`. Components of
    `X` normal to a face add the constant `A_f |X_f . N_f|^2` and do not change the gradient.

    Args:
        mesh: any triangle mesh.
        phi: `(nv,)` or `(nv, k)` vertex values.
        field: `(nf, 3)` one vector per face, or `(nf, 3, k)` for `(nv, k)` `phi` (column by column,
            summed).

    Returns:
        The scalar energy.

    libigl: `G = igl.grad(V, F)` (rows: all x components, then y, then z), `A = igl.doublearea(V, F) / 2`,
    `np.sum(A[:, None] * ((G @ phi).reshape(3, -1).T - X) ** 2)`; gpytoolbox: the same with
    `gpytoolbox.grad(V, F)` and `gpytoolbox.doublearea(V, F)`. Reference: the module docstring;
    Crane et al. 2017 (heat method), section 3.2.
    """
    mesh = require_mesh("mesh", mesh)
    phi = _vertex_values("phi", mesh, phi)
    expected = (mesh.n_faces, 3) + phi.shape[1:]
    if np.shape(field) != expected:
        raise DDGInputError(f"field: expected shape {expected} (one 3-vector per face, per column of phi), got {np.shape(field)}")
    check_float_shape("field", field, expected[1:])
    return _gradient_fitting_energy(mesh, phi, device_array(field))


@kernel
def _gradient_fitting_energy(mesh: Mesh, phi: Float[Array, "nv *k"], field: Float[Array, "nf 3 *k"]) -> Float[Array, ""]:
    if phi.ndim == 1:
        gradients = gradient(mesh, phi)
    else:
        gradients = jax.vmap(lambda column: gradient(mesh, column), in_axes=1, out_axes=2)(phi)
    areas = face_areas(mesh).reshape((-1,) + (1,) * (field.ndim - 1))
    return jnp.sum(areas * (gradients - field) ** 2)


def _vertex_values(name: str, mesh: Mesh, values, like: Array | None = None) -> Array:
    """`values` as a JAX array of shape `(nv,)` / `(nv, k)` (or `like`'s shape), else `DDGInputError`.

    Shapes and dtypes are known under jit, so traced arrays are checked the same way.
    """
    shape = np.shape(values)
    n = mesh.n_vertices
    if like is not None and shape != like.shape:
        raise DDGInputError(f"{name}: expected the shape of phi, {like.shape}, got {shape}")
    if len(shape) not in (1, 2) or shape[0] != n:
        raise DDGInputError(f"{name}: expected shape ({n},) or ({n}, k), got {shape}")
    check_float_shape(name, values, shape[1:])
    return values if isinstance(values, jax.Array) else device_array(values)


def _describe(value) -> str:
    return f"shape {np.shape(value)}" if np.ndim(value) else repr(value)
