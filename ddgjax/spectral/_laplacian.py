"""Laplacian eigenfunctions of a mesh and the spectral tools built on them.

`eigenpairs(mesh, k)` solves `L phi = lambda M phi` (`L` the PSD cotan Laplacian, `M` a mass matrix):
the discrete counterpart of `-Delta phi = lambda phi`, so the unit sphere gives `l (l + 1)` with
multiplicity `2 l + 1`. Eigenvectors are M-orthonormal, `Phi^T M Phi = I`: the discrete
`int phi_i phi_j dA = delta_ij`. With `boundary="dirichlet"` the boundary vertices are held at 0
(the problem is solved on the interior vertices and the eigenvectors are 0 on the boundary); with
`"neumann"` (default) nothing is held, the natural boundary condition of the weak form. A solid
(`ddgjax.volume.TetMesh`) works the same with its own `L` and `M` (`ddgjax.volume.cotan_laplacian`,
`mass_matrix`): the unit ball's Dirichlet spectrum is the squared zeros of the spherical Bessel
functions, `pi^2` then `4.4934^2` (three times), its first nonzero Neumann eigenvalue `2.0816^2` (tests).

On top of an eigenbasis: `spectral_coefficients` (`c = Phi^T M f`), `spectral_reconstruction`
(`Phi c`), `spectral_filter` (`Phi g(Lambda) Phi^T M f`), `heat_kernel` (`k_t(x, y) = sum_i
exp(-lambda_i t) phi_i(x) phi_i(y)`), `heat_kernel_signature` (`k_t(x, x)`, Sun, Ovsjanikov &
Guibas 2009) and `wave_kernel_signature` (band-passed `phi_i(x)^2` in log-eigenvalue, Aubry,
Schlickewei & Cremers 2011), all plain JAX functions of the eigenpairs, so differentiable through them. They take
the eigenvalues and eigenvectors as their first two arguments, so an `Eigenpairs` passes unpacked:
`heat_kernel(*eigenpairs(mesh, 30), sources, t=0.1)`.

References: B. Vallet & B. Lévy, "Spectral geometry processing with manifold harmonics" (2008);
J. Sun, M. Ovsjanikov & L. Guibas, "A concise and provably informative multi-scale signature based
on heat diffusion" (2009). libigl (C++ only: its Python bindings have no `eigs`): `igl::eigs(L, M, k, igl::EIGS_TYPE_SM, ...)`; SciPy:
`scipy.sparse.linalg.eigsh(L, k, M, sigma=0)`.
"""

from __future__ import annotations

from collections.abc import Callable

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int

from .._errors import DDGInputError, check_choice
from .._options import BOUNDARY_CONDITIONS
from .._results import Solution, outcome
from ..discretization import discretize
from ..discretization.internal import require_domain
from ..laplacian import IntrinsicTriangulation
from ..mesh import Mesh
from ..solve import AMGHierarchy
from ..sparse import SparseMatrix, diagonal_matrix, dirichlet_blocks, dirichlet_plan
from ..volume import TetMesh
from ._generalized import Eigenpairs, smallest_eigenpairs


def eigenpairs(
    mesh: Mesh | TetMesh,
    k: int,
    *,
    mass: str = "voronoi",
    boundary: str = "neumann",
    robust: bool | IntrinsicTriangulation = False,
    method: str = "auto",
    solver: str = "auto",
    preconditioner: str | AMGHierarchy | None = None,
    throw: bool = True,
) -> Eigenpairs | Solution:
    r"""The `k` smallest eigenpairs of the mesh's Laplacian, `L phi = lambda M phi` (module docstring).

    $$L\phi = \lambda M\phi, \qquad \phi_i^\top M \phi_j = \delta_{ij}$$

    Args:
        mesh: a triangle mesh, or a `ddgjax.volume.TetMesh` (a solid: `ddgjax.volume.cotan_laplacian`
            and `mass_matrix`; Dirichlet holds its boundary surface's vertices at 0).
        k: number of eigenpairs (fewer than the unknowns).
        mass: the mass matrix `M`: `"voronoi"` (default), `"barycentric"` or `"galerkin"`.
        boundary: `"neumann"` (default) or `"dirichlet"` (zero on the boundary; needs a boundary).
        robust: the intrinsic Delaunay Laplacian and mass instead of the mesh's (`True`, or an
            `IntrinsicTriangulation` inside `jit`; `ddgjax.laplacian.laplacian_and_mass`): mollified,
            they work on meshes with faces of zero or near-zero area, which `robust=False` refuses
            (`MeshDataError`) on concrete positions. Triangle meshes only (a `TetMesh` takes `False`).
        method, solver, preconditioner: the eigensolver (`"arpack"` on the host, `"subspace"` in JAX,
            `"auto"`), the backend of its solves and their CG preconditioner
            (`ddgjax.spectral.smallest_eigenpairs`; with Dirichlet conditions a hierarchy is of the
            free-free block).
        throw: raise when the eigensolver fails (default), or return a `ddgjax.Solution` with the
            pairs, `result` and `stats` (`smallest_eigenpairs`). A failure includes pairs that do not
            solve the problem to round-off and negative eigenvalues beyond it (what a degenerate mesh
            gives under `jit`, where its faces cannot be checked first): `smallest_eigenpairs`.

    Returns:
        `Eigenpairs(values (k,), vectors (nv, k))` (unpacks as `values, vectors = ...`), ascending,
        M-orthonormal, each eigenvector's entry of largest magnitude positive, 0 at vertices no face
        (tet) uses (their rows of `L` and `M` are zero: no eigenvalue is theirs); in a `ddgjax.Solution`
        with `throw=False`. Differentiable in the vertex positions
        (`ddgjax.spectral.smallest_eigenpairs`: eigenvalues always; eigenvectors away from clusters
        of equal eigenvalues; any function invariant within a cluster), under `jit` and `vmap`.

    libigl (C++ only): `igl::eigs(-cotmatrix, massmatrix, k, igl::EIGS_TYPE_SM, U, D)` (on `V, F` or `V, T`).

    Examples:
        >>> import ddgjax
        >>> values, vectors = ddgjax.spectral.eigenpairs(ddgjax.mesh.icosphere(3), 4)
        >>> vectors.shape
        (642, 4)
        >>> [round(float(value), 3) for value in values[1:]]  # l (l + 1) = 2 on the unit sphere
        [2.0, 2.0, 2.0]
    """
    mesh = require_domain("mesh", mesh)
    check_choice("boundary", boundary, BOUNDARY_CONDITIONS)
    discretization = discretize(mesh, mass=mass, robust=robust)
    L, M = discretization.laplacian, discretization.mass
    # Vertices of no face (tet) have zero rows in L and M, so no eigenvalue: they are held at 0 (as the
    # Poisson problems hold them), and the eigenproblem is solved on the others.
    unreferenced = mesh.topology.unreferenced_vertices
    if boundary == "neumann" and unreferenced.size == 0:
        return smallest_eigenpairs(L, M, k, method=method, solver=solver, preconditioner=preconditioner, throw=throw)
    fixed = unreferenced
    if boundary == "dirichlet":
        if mesh.topology.boundary_vertices.size == 0:
            raise DDGInputError("boundary: 'dirichlet' needs a mesh with a boundary; this mesh is closed (use 'neumann')")
        fixed = np.union1d(mesh.topology.boundary_vertices, unreferenced)
    if fixed.size == mesh.n_vertices:
        raise DDGInputError(
            f"boundary: 'dirichlet' holds the boundary at 0, and all {fixed.size} vertices of this mesh lie on its "
            "boundary (a strip, a single triangle or tet), so no eigenfunction is left (use 'neumann')"
        )
    plan = dirichlet_plan(discretization.pattern, fixed)
    L_ff, _ = dirichlet_blocks(L, plan)
    if M.pattern.is_diagonal:  # a lumped mass: its block is the free part of the diagonal
        M_ff = diagonal_matrix(M.diagonal()[plan.free], positive_semidefinite=True)
    else:  # the Galerkin mass lives on the Laplacian's pattern
        M_ff, _ = dirichlet_blocks(M, plan)
    solution = smallest_eigenpairs(L_ff, M_ff, k, method=method, solver=solver, preconditioner=preconditioner, throw=False)
    values, vectors = solution.value
    pairs = Eigenpairs(values, plan.join(vectors, jnp.zeros((fixed.size, k), vectors.dtype)))
    return outcome(pairs, solution.result, throw, solution.stats)


def spectral_coefficients(
    vectors: Float[ArrayLike, "nv k"], M: SparseMatrix, f: Float[ArrayLike, "nv *m"], /
) -> Float[Array, "k *m"]:
    """`c = Phi^T M f`: the coordinates of `f` in an M-orthonormal eigenbasis (the discrete `int f phi_i dA`).

    Args:
        vectors: `(nv, k)` the M-orthonormal basis `Phi` (`eigenpairs(mesh, k).vectors`).
        M: `(nv, nv)` the mass matrix the basis is orthonormal in.
        f: `(nv,)` or `(nv, m)` functions at the vertices.

    Returns:
        `(k,)` or `(k, m)` float array of coefficients `c`.
    """
    vectors, f = _basis("vectors", vectors, M), _functions("f", f, M)
    return vectors.T @ (M @ f)


def spectral_reconstruction(vectors: Float[ArrayLike, "nv k"], coefficients: Float[ArrayLike, "k *m"]) -> Float[Array, "nv *m"]:
    """`Phi c`: the function with coordinates `c` (its projection onto the basis, for `c = Phi^T M f`).

    Args:
        vectors: `(nv, k)` the basis `Phi`.
        coefficients: `(k,)` or `(k, m)` coordinates `c` (`spectral_coefficients`).

    Returns:
        `(nv,)` or `(nv, m)` float array `Phi c`.
    """
    vectors, coefficients = jnp.asarray(vectors), jnp.asarray(coefficients)
    if vectors.ndim != 2 or coefficients.ndim not in (1, 2) or coefficients.shape[0] != vectors.shape[1]:
        raise DDGInputError(
            f"coefficients: expected shape ({vectors.shape[-1]},) or ({vectors.shape[-1]}, m) for vectors of shape "
            f"{vectors.shape}, got {coefficients.shape}"
        )
    return vectors @ coefficients


def spectral_filter(
    values: Float[ArrayLike, " k"],
    vectors: Float[ArrayLike, "nv k"],
    M: SparseMatrix,
    f: Float[ArrayLike, "nv *m"],
    /,
    *,
    response: Callable[[Float[Array, " k"]], ArrayLike],
) -> Float[Array, "nv *m"]:
    """`Phi g(Lambda) Phi^T M f`: `f` filtered by the frequency response `g` (a JAX function of the eigenvalues).

    E.g. `response=lambda lam: lam < 50` keeps the low frequencies (smoothing), `jnp.exp(-t lam)` is
    heat diffusion for time `t` restricted to the basis: `spectral_filter(*eigenpairs(mesh, k), M, f,
    response=...)`. Differentiable in every argument.

    Reference: B. Vallet, B. Levy, "Spectral geometry processing with manifold harmonics" (2008), section 4.

    Args:
        values: `(k,)` eigenvalues, as `eigenpairs` returns them.
        vectors: `(nv, k)` their eigenvectors, M-orthonormal.
        M: `(nv, nv)` the mass matrix they are orthonormal in.
        f: `(nv,)` or `(nv, m)` functions at the vertices.
        response: the frequency response `g`, a JAX function of the `(k,)` eigenvalues returning `(k,)` gains
            (booleans too; keyword-only).

    Returns:
        Float array of `f`'s shape, `Phi g(Lambda) Phi^T M f`.
    """
    values = jnp.asarray(values)
    coefficients = spectral_coefficients(vectors, M, f)
    gains = jnp.asarray(response(values), coefficients.dtype)
    return spectral_reconstruction(vectors, gains.reshape(gains.shape + (1,) * (coefficients.ndim - 1)) * coefficients)


def heat_kernel(
    values: Float[ArrayLike, " k"], vectors: Float[ArrayLike, "nv k"], sources: Int[ArrayLike, " n_sources"], *, t: float
) -> Float[Array, "nv n_sources"]:
    r"""The heat kernel `k_t(x, y)` of the surface, truncated to an eigenbasis, from each source vertex `y` to every vertex `x`.

    The solution of the heat equation $\partial u / \partial t = \Delta u$ ($\Delta = -M^{-1} L$, the pointwise
    Laplace-Beltrami operator) started from a unit of heat concentrated at `y` is

    $$k_t(x, y) = \sum_i e^{-\lambda_i t} \phi_i(x) \phi_i(y),$$

    summed over the eigenpairs of `L phi = lambda M phi` (`eigenpairs`), whose eigenvectors are
    M-orthonormal, so `k_t` is a density per unit area: `1^T M k_t(., y) = 1` on a closed
    surface with the constant eigenvector in the basis (Neumann), and `k_t(x, y) = k_t(y, x)`.
    Truncating to the `k` smallest pairs drops the terms `exp(-lambda_i t)` of the higher frequencies,
    so the kernel is accurate for `t` large against `1 / lambda_k`; small times need many pairs (or a
    backward-Euler heat step, `ddgjax.geodesics`). Differentiable in `values`, `vectors` (so in the
    vertex positions through `eigenpairs`) and `t`.

    Args:
        values: `(k,)` eigenvalues, as `eigenpairs` returns them.
        vectors: `(nv, k)` their M-orthonormal eigenvectors.
        sources: `(n_sources,)` vertex indices `y` (concrete integers; one integer gives one column).
        t: the diffusion time, `> 0` (keyword-only).

    Returns:
        `(nv, n_sources)`: column `j` is `k_t(., sources[j])`.

    `heat_kernel(*eigenpairs(mesh, 100), sources, t=0.01)`. References: J. Sun, M. Ovsjanikov, L.
    Guibas, "A concise and provably informative multi-scale signature based on heat diffusion" (2009),
    eq. (2); B. Vallet, B. Levy (2008). libigl / gpytoolbox / potpourri3d: none (compute the
    eigenpairs with SciPy `eigsh` and sum the series by hand).
    """
    values, vectors = jnp.asarray(values), jnp.asarray(vectors)
    sources = np.atleast_1d(np.asarray(sources))
    if sources.ndim != 1 or not np.issubdtype(sources.dtype, np.integer) or sources.size == 0:
        raise DDGInputError(f"sources: expected a non-empty 1-d array of vertex indices, got {sources!r}")
    if sources.min() < 0 or sources.max() >= vectors.shape[0]:
        raise DDGInputError(f"sources: vertex indices must lie in [0, {vectors.shape[0]})")
    return (vectors * jnp.exp(-values * t)) @ vectors[sources].T


def heat_kernel_signature(
    values: Float[ArrayLike, " k"], vectors: Float[ArrayLike, "nv k"], *, t: Float[ArrayLike, " *n_times"] | float
) -> Float[Array, "nv n_times"]:
    r"""The heat kernel signature `HKS(x, t) = k_t(x, x) = sum_i exp(-lambda_i t) phi_i(x)^2` (Sun et al. 2009), `(nv, n_times)`.

    $$\mathrm{HKS}(x, t) = k_t(x, x) = \sum_i e^{-\lambda_i t} \phi_i(x)^2$$

    `t` is one time or a `(n_times,)` array of times (keyword-only); one column per time.
    Invariant within clusters of equal eigenvalues (a sum of `phi_i^2` over an eigenspace does not
    depend on its basis), so differentiable on symmetric shapes too. `values, vectors` as
    `heat_kernel` takes them: `heat_kernel_signature(*eigenpairs(mesh, 100), t=times)`.

    Args:
        values: `(k,)` eigenvalues (`eigenpairs(mesh, k).values`).
        vectors: `(nv, k)` their M-orthonormal eigenvectors.
        t: one time or `(n_times,)` times, `> 0` (keyword-only).

    Returns:
        `(nv, n_times)` signatures, one column per time (`(nv, 1)` for one time).

    Examples:
        >>> import jax.numpy as jnp
        >>> import ddgjax
        >>> values, vectors = ddgjax.spectral.eigenpairs(ddgjax.mesh.icosphere(2), 16)
        >>> hks = ddgjax.spectral.heat_kernel_signature(values, vectors, t=jnp.array([0.1, 1.0]))
        >>> hks.shape, bool(jnp.all(hks[:, 0] > hks[:, 1]))  # heat spreads out with time
        ((162, 2), True)
    """
    values, vectors, times = jnp.asarray(values), jnp.asarray(vectors), jnp.atleast_1d(jnp.asarray(t))
    return (vectors**2) @ jnp.exp(-values[:, None] * times[None, :])


def wave_kernel_signature(
    values: Float[ArrayLike, " k"],
    vectors: Float[ArrayLike, "nv k"],
    *,
    energies: Float[ArrayLike, " n_energies"] | None = None,
    n_energies: int = 100,
    sigma: float | Float[ArrayLike, ""] | None = None,
) -> Float[Array, "nv n_energies"]:
    """The wave kernel signature `WKS(x, e) = sum_i w_i(e) phi_i(x)^2 / sum_i w_i(e)` (Aubry et al. 2011), `(nv, n_energies)`.

    `w_i(e) = exp(-(e - log lambda_i)^2 / (2 sigma^2))`: a Gaussian band in log-eigenvalue around the
    log-energy `e`, over the eigenpairs with `lambda_i > 1e-8 max lambda` (the constant eigenvector of
    a closed or Neumann shape, `lambda_0 = 0`, carries no log-energy and is left out). Each column is
    divided by its band's total weight `sum_i w_i(e)` (pyFM's `scaled=True`). One column per energy.

    Default grid (pyFM's `auto_WKS`): with `l_0 <= l_1 <= ... <= l_{k-1}` the sorted `|lambda|`, `e_min = log l_1` (the
    second smallest), `e_max = log l_{k-1}`, `sigma = 7 (e_max - e_min) / n_energies` and
    `n_energies` log-energies evenly spaced on `[e_min + 2 sigma, e_max - 2 sigma]`. Eigenvalues are
    expected ascending (as `eigenpairs` returns them).

    A plain JAX function of the eigenpairs: under `jit`, differentiable (away from repeated
    eigenvalues it is smooth; like the HKS it is invariant within eigenspaces).
    pyFM: `pyFM.signatures.auto_WKS(values, vectors, n_energies)` (and `WKS(..., scaled=True)`).
    Reference: M. Aubry, U. Schlickewei & D. Cremers, "The wave kernel signature: a quantum mechanical
    approach to shape analysis" (2011).

    Args:
        values: `(k,)` eigenvalues, ascending (`eigenpairs(mesh, k).values`).
        vectors: `(nv, k)` their M-orthonormal eigenvectors.
        energies: `(n_energies,)` log-energies `e` (keyword-only); `None` (default): the default grid.
        n_energies: the size of the default grid (keyword-only; default 100; ignored when `energies` is given).
        sigma: the band's width in log-eigenvalue (keyword-only); `None` (default): the default one for
            `len(energies)` energies.

    Returns:
        `(nv, n_energies)` float array, one column per energy.
    """
    values, vectors = jnp.asarray(values), jnp.asarray(vectors)
    if energies is None:
        energies, default_sigma = wave_kernel_energies(values, n_energies)
    else:
        energies = jnp.atleast_1d(jnp.asarray(energies))
        default_sigma = wave_kernel_energies(values, energies.shape[0])[1]
    weights = wave_kernel_weights(values, energies, default_sigma if sigma is None else sigma)
    return (vectors**2) @ weights.T / jnp.sum(weights, axis=1)


def wave_kernel_energies(values: Float[Array, " k"], n_energies: int) -> tuple[Float[Array, " n"], Float[Array, ""]]:
    """pyFM's `auto_WKS` grid: `(log-energies (n_energies,), sigma)` from the sorted `|lambda|`."""
    sorted_values = jnp.sort(jnp.abs(values))
    e_min, e_max = jnp.log(sorted_values[1]), jnp.log(sorted_values[-1])
    sigma = 7 * (e_max - e_min) / n_energies
    return jnp.linspace(e_min + 2 * sigma, e_max - 2 * sigma, n_energies), sigma


def wave_kernel_weights(values: Float[Array, " k"], energies: Float[Array, " n"], sigma) -> Float[Array, "n k"]:
    """`w_i(e) = exp(-(e - log|lambda_i|)^2 / (2 sigma^2))`, 0 for `|lambda_i| <= 1e-8 max` (pyFM's dropped pairs)."""
    magnitudes = jnp.abs(values)
    kept = magnitudes > 1e-8 * jnp.max(magnitudes)
    # The dropped pairs' log is taken of 1 so that neither the value nor its gradient is NaN.
    log_values = jnp.log(jnp.where(kept, magnitudes, 1.0))
    weights = jnp.exp(-jnp.square(energies[:, None] - log_values[None, :]) / (2 * jnp.square(sigma)))
    return jnp.where(kept[None, :], weights, 0.0)


def _basis(name: str, vectors, M: SparseMatrix) -> Float[Array, "nv k"]:
    vectors = jnp.asarray(vectors)
    if vectors.ndim != 2 or vectors.shape[0] != M.shape[0]:
        raise DDGInputError(f"{name}: expected shape ({M.shape[0]}, k), got {vectors.shape}")
    return vectors


def _functions(name: str, f, M: SparseMatrix) -> Float[Array, "nv *m"]:
    f = jnp.asarray(f)
    if f.ndim not in (1, 2) or f.shape[0] != M.shape[0]:
        raise DDGInputError(f"{name}: expected shape ({M.shape[0]},) or ({M.shape[0]}, m), got {f.shape}")
    return f
