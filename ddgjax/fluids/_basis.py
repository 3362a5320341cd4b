"""The reduced basis of a spectral fluid: Laplacian eigenfunctions and the advection tensor between them.

Vorticity `w = Phi a` and stream function `psi = Phi b` live in the first `k` eigenfunctions of
`L phi = lambda M phi` (`-Delta phi = lambda phi`, M-orthonormal; `ddgjax.spectral`). `Delta psi = w`
gives `b_i = -a_i / lambda_i` (the constant mode, `lambda_0 = 0`, carries no stream function). The
velocity `u = n x grad psi` advects a scalar `q` by `u . grad q = J(psi, q)`, `J(p, q) = n . (grad p x
grad q)`, and projecting `dq/dt = -J(psi, q)` on the basis gives

    dq_k/dt = sum_ij W_kij b_i q_j,     W_kij = -int phi_k J(phi_i, phi_j) dA.

Quadrature: on a face the hat gradients satisfy `grad h_a x grad h_b = n / (2 A)` for the cyclic
corner pairs `(a, b) = (0, 1), (1, 2), (2, 0)`, so the integral of `J(phi_i, phi_j)` over face `f`
(piecewise linear `phi`) is exactly

    J_f(i, j) = 1/2 sum_(a, b) cyclic (phi_i[a] phi_j[b] - phi_i[b] phi_j[a]),

free of the metric (the metric enters through the eigenfunctions), and `phi_k` is integrated exactly
by its corner mean: `W_kij = -sum_f mean_c(phi_k[c]) J_f(i, j)`. On a closed surface the smooth
tensor is alternating (`int f J(g, h) = int g J(h, f)`); this discrete one is antisymmetric in
`(i, j)` only, so it is replaced by its alternating part `(W_kij + W_ijk + W_jki) / 3` (the same
order of accuracy). Antisymmetry in `(k, j)` conserves the enstrophy `1/2 sum a^2`, in `(k, i)` the
kinetic energy `1/2 sum lambda b^2`, both exactly under an implicit midpoint step (`euler_flow`).

Reference: O. Azencot, S. Weissmann, M. Ovsjanikov, M. Wardetzky, M. Ben-Chen, "Functional fluids on
surfaces" (SGP 2014).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from .._compile import kernel
from .._errors import DDGInputError, check_count
from .._options import LUMPED_MASS_MATRICES, check_mass
from ..laplacian import IntrinsicTriangulation, laplacian_and_mass
from ..mesh import Mesh, require_mesh
from ..spectral import smallest_eigenpairs


class FluidBasis(eqx.Module):
    """What `euler_flow` needs of a mesh, built once by `fluid_basis` and kept for repeated runs.

    Attributes:
        values: `(k,)` eigenvalues `lambda_i` of `L phi = lambda M phi`, ascending (`lambda_0 = 0`).
        vectors: `(nv, k)` M-orthonormal eigenfunctions `phi_i` at the vertices.
        mass: `(nv,)` the lumped mass (vertex areas): a function `f` has coefficients `Phi^T (mass f)`.
        advection: `(k, k, k)` the alternating tensor `W_kij` (module docstring).
        coriolis: `(k,)` the coefficients of `2 z` (the vertices' z coordinate): the Coriolis
            parameter `f = 2 Omega z` of a frame turning at `Omega` about +z is `Omega * coriolis`.
    """

    values: Float[Array, " k"]
    vectors: Float[Array, "nv k"]
    mass: Float[Array, " nv"]
    advection: Float[Array, "k k k"]
    coriolis: Float[Array, " k"]

    def coefficients(self, function: Float[ArrayLike, "*s nv"]) -> Float[Array, "*s k"]:
        """The basis coefficients `Phi^T M f` of vertex values `f` (the M-orthogonal projection)."""
        return (jnp.asarray(function) * self.mass) @ self.vectors

    def function(self, coefficients: Float[ArrayLike, "*s k"]) -> Float[Array, "*s nv"]:
        """The vertex values `Phi c` of coefficients `c`."""
        return jnp.asarray(coefficients) @ self.vectors.T

    def stream_coefficients(self, vorticity: Float[ArrayLike, "*s k"]) -> Float[Array, "*s k"]:
        """`b = -a / lambda` (0 on the constant modes): the stream function solving `Delta psi = w` in the basis."""
        return -jnp.asarray(vorticity) * inverse_values(self.values)


def inverse_values(values: Float[Array, " k"]) -> Float[Array, " k"]:
    """`1 / lambda`, 0 on the constant modes (`lambda` at round-off of 0), with finite gradients."""
    # A connected closed surface has one zero eigenvalue, computed at round-off; more components have more.
    kept = values > 1e-8 * jnp.max(values)
    return jnp.where(kept, 1.0 / jnp.where(kept, values, 1.0), 0.0)


def fluid_basis(mesh: Mesh, k: int, *, mass: str = "voronoi", robust: bool | IntrinsicTriangulation = False) -> FluidBasis:
    """The first `k` Laplacian eigenpairs of a closed mesh and the advection tensor between them (module docstring).

    `W_kij = -int phi_k J(phi_i, phi_j)` with `J(p, q) = n . (grad p x grad q)` (exact per-face
    quadrature of the piecewise linear eigenfunctions), replaced by its alternating part so that
    energy and enstrophy are conserved. Cost `O(nf k^3)` (`k = 64` on 20 k faces: a few seconds on
    two CPU cores); memory `O(nf k)`, also in reverse mode (the loop over `k` is checkpointed).

    Args:
        mesh: a closed, consistently oriented triangle mesh (outward normals: vorticity is measured
            about them). Any genus (the harmonic velocity of handles is not part of the basis).
        k: number of eigenfunctions, `2 <= k < nv`. On a round sphere choose a square
            (`(l_max + 1)^2`: 16, 25, 36, 49, 64) so that no degree is cut in the middle.
        mass: the lumped mass matrix, `"voronoi"` (default) or `"barycentric"` (`ddgjax.LUMPED_MASS_MATRICES`).
        robust: the intrinsic Delaunay Laplacian (`ddgjax.spectral.eigenpairs`).

    Returns:
        `FluidBasis` (`values (k,)`, `vectors (nv, k)`, `mass (nv,)`, `advection (k, k, k)`,
        `coriolis (k,)`), differentiable in the vertex positions through `ddgjax.spectral.eigenpairs`
        (any function invariant within clusters of equal eigenvalues).

    Raises:
        DDGInputError: `mesh` not a `Mesh`, a mesh with a boundary, bad `k` or `mass`;
            `MeshDataError` for a mesh that is not consistently oriented.
        equinox.EquinoxRuntimeError: the eigensolver failed (`ddgjax.RESULTS.eigensolver_failed`).
    """
    mesh = require_mesh("mesh", mesh)
    check_basis_size(mesh, k)
    check_mass(mass, LUMPED_MASS_MATRICES)
    if mesh.topology is not None and mesh.topology.boundary_vertices.size:
        raise DDGInputError(
            f"mesh: expected a closed surface; this one has {mesh.topology.boundary_vertices.size} boundary "
            "vertices (the stream function's boundary condition is not modelled)"
        )
    # What `ddgjax.spectral.eigenpairs` does with Neumann conditions, keeping the mass matrix it used.
    L, M = laplacian_and_mass(mesh, mass=mass, robust=robust)
    values, vectors = smallest_eigenpairs(L, M, k)
    return _fluid_basis(mesh, values, vectors, M.diagonal())


def check_basis_size(mesh: Mesh, k: int) -> int:
    """`k` if `2 <= k < nv`, else `DDGInputError`."""
    k = check_count("k", k, minimum=2)
    if k >= mesh.n_vertices:
        raise DDGInputError(f"k: expected fewer eigenfunctions than the {mesh.n_vertices} vertices, got {k}")
    return k


@kernel(requires_orientation="fluid_basis")
def _fluid_basis(mesh: Mesh, values, vectors, mass) -> FluidBasis:
    corners = vectors[mesh.faces]  # (nf, 3, k)
    k = vectors.shape[1]
    weights = jnp.broadcast_to(jnp.mean(corners, axis=1, keepdims=True), corners.shape).reshape(-1, k)
    # The three cyclic corner pairs (0, 1), (1, 2), (2, 0) of every face, one row each.
    first = corners.reshape(-1, k)
    second = jnp.roll(corners, -1, axis=1).reshape(-1, k)

    # T_kij = sum_rows weight_k first_i second_j, one k at a time: O(nf k) memory; the checkpoint keeps
    # reverse mode from storing a (3 nf, k) product per k.
    @jax.checkpoint
    def slice_k(weight):
        return (first * weight[:, None]).T @ second

    products = jax.lax.map(slice_k, weights.T)
    advection = 0.5 * (jnp.swapaxes(products, 1, 2) - products)
    cyclic = (advection + jnp.einsum("ijk->kij", advection) + jnp.einsum("jki->kij", advection)) / 3.0
    # The cyclic mean is alternating up to round-off; this makes `(i, j)` antisymmetry exact.
    alternating = 0.5 * (cyclic - jnp.swapaxes(cyclic, 1, 2))
    basis = FluidBasis(values=values, vectors=vectors, mass=mass, advection=alternating, coriolis=jnp.zeros_like(values))
    return eqx.tree_at(lambda b: b.coriolis, basis, basis.coefficients(2.0 * mesh.vertices[:, 2]))
