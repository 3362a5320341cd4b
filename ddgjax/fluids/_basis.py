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

**Surfaces with handles.** On a closed surface of genus `g` a divergence-free velocity is `u = n x
grad psi + sum_m c_m h_m`, the second part harmonic (curl and divergence free, `2 g` dimensional) and
invisible to the vorticity. The fields `h_m` are piecewise constant per face: the closed 1-forms of a
tree-cotree basis (as `ddgjax.pde.hodge_decomposition` builds) turned into face vectors (`ddgjax.dec.sharp`,
exact for closed forms), minus their `L^2` projection on the gradients of piecewise linear functions
(one Poisson solve; the projection on rotated gradients `n x grad phi` is already 0 for a closed form,
by the discrete Stokes theorem on each vertex star), orthonormalised in `L^2` (Cholesky of the Gram
matrix); faces of (near-)zero area carry none. Being `L^2`-orthogonal to every `n x grad phi`, they
split the kinetic energy exactly: `1/2 int |u|^2 = 1/2 sum lambda b^2 + 1/2 sum c^2` (with the cotan
Laplacian; to the discretisation's accuracy with `robust=True`). They enter the flow through two more tensors,

    H_kmj = -int phi_k h_m . grad phi_j dA      (antisymmetrised in (k, j), as it is for div h = 0),
    G_kmn = int phi_k (n x h_n) . h_m dA          (antisymmetric in (m, n) exactly),

with the same quadrature (`phi_k` by its corner mean, the integrand constant per face otherwise).

References: O. Azencot, S. Weissmann, M. Ovsjanikov, M. Wardetzky, M. Ben-Chen, "Functional fluids on
surfaces" (SGP 2014); K. Polthier, E. Preuss, "Identifying vector field singularities using a discrete
Hodge decomposition" (2003) for the harmonic fields of piecewise constant vector fields.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .._compile import device_array, kernel
from .._errors import DDGInputError, check_count
from .._numerics import safe_div
from .._options import LUMPED_MASS_MATRICES, check_mass
from .._results import RESULTS, Solution, first_failure, outcome
from ..dec import sharp
from ..discretization import discretize
from ..laplacian import IntrinsicTriangulation
from ..mesh import (
    Mesh,
    face_areas,
    face_edge_lengths_sq,
    face_hat_gradients,
    face_normals,
    require_mesh,
    scatter_corners_to_vertices,
)
from ..mesh.internal import default_area_tol
from ..pde import solve_poisson
from ..pde.internal import closed_cocycle_basis
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
        harmonic: `(nf, h, 3)` the `h = 2 g` harmonic velocity fields per face, `L^2`-orthonormal
            (`h = 0` on a sphere).
        areas: `(nf,)` the face areas (the `L^2` pairing of face fields).
        harmonic_advection: `(k, h, k)` the tensor `H_kmj` (module docstring).
        harmonic_exchange: `(k, h, h)` the tensor `G_kmn` (module docstring).
    """

    values: Float[Array, " k"]
    vectors: Float[Array, "nv k"]
    mass: Float[Array, " nv"]
    advection: Float[Array, "k k k"]
    coriolis: Float[Array, " k"]
    harmonic: Float[Array, "nf h 3"]
    areas: Float[Array, " nf"]
    harmonic_advection: Float[Array, "k h k"]
    harmonic_exchange: Float[Array, "k h h"]

    def coefficients(self, function: Float[ArrayLike, "*s nv"]) -> Float[Array, "*s k"]:
        """The basis coefficients `Phi^T M f` of vertex values `f` (the M-orthogonal projection)."""
        return (jnp.asarray(function) * self.mass) @ self.vectors

    def function(self, coefficients: Float[ArrayLike, "*s k"]) -> Float[Array, "*s nv"]:
        """The vertex values `Phi c` of coefficients `c`."""
        return jnp.asarray(coefficients) @ self.vectors.T

    def stream_coefficients(self, vorticity: Float[ArrayLike, "*s k"]) -> Float[Array, "*s k"]:
        """`b = -a / lambda` (0 on the constant modes): the stream function solving `Delta psi = w` in the basis."""
        return -jnp.asarray(vorticity) * inverse_values(self.values)

    def harmonic_coefficients(self, velocity: Float[ArrayLike, "nf 3"]) -> Float[Array, " h"]:
        """`c_m = int u . h_m dA`: the harmonic part of a face velocity field `(nf, 3)` (its `L^2` projection).

        For example the coefficients of the rotation `e_z x p` on a torus of revolution about z
        (`ddgjax.mesh.torus`) describe the flow round the hole.
        """
        velocity = jnp.asarray(velocity)
        if velocity.shape != (self.areas.shape[0], 3):
            raise DDGInputError(
                f"velocity: expected shape ({self.areas.shape[0]}, 3) (one vector per face), got {velocity.shape}"
            )
        return jnp.einsum("f,fmd,fd->m", self.areas, self.harmonic, velocity.astype(self.harmonic.dtype))

    def harmonic_velocity(self, coefficients: Float[ArrayLike, "*s h"]) -> Float[Array, "*s nf 3"]:
        """The face velocities `sum_m c_m h_m` of harmonic coefficients `c`."""
        return jnp.einsum("...m,fmd->...fd", jnp.asarray(coefficients), self.harmonic)


def inverse_values(values: Float[Array, " k"]) -> Float[Array, " k"]:
    """`1 / lambda`, 0 on the constant modes (`lambda` at round-off of 0), with finite gradients."""
    # A connected closed surface has one zero eigenvalue, computed at round-off; more components have more.
    kept = values > 1e-8 * jnp.max(values)
    return jnp.where(kept, 1.0 / jnp.where(kept, values, 1.0), 0.0)


def fluid_basis(
    mesh: Mesh,
    k: int,
    *,
    mass: str = "voronoi",
    robust: bool | IntrinsicTriangulation = False,
    solver: str = "auto",
    throw: bool = True,
) -> FluidBasis | Solution:
    r"""The first `k` Laplacian eigenpairs of a closed mesh and the advection tensor between them (module docstring).

    $$W_{kij} = -\int \phi_k \, J(\phi_i, \phi_j) \, dA, \qquad J(p, q) = n \cdot (\nabla p \times \nabla q)$$

    (exact per-face
    quadrature of the piecewise linear eigenfunctions), replaced by its alternating part so that
    energy and enstrophy are conserved. Cost `O(nf k^3)` (`k = 64` on 20 k faces: a few seconds on
    two CPU cores); memory `O(nf k)`, also in reverse mode (the loop over `k` is checkpointed).

    Args:
        mesh: a closed, consistently oriented triangle mesh (outward normals: vorticity is measured
            about them). Any genus: a surface with handles gets its harmonic fields (module docstring).
        k: number of eigenfunctions, `2 <= k < nv`. On a round sphere choose a square
            (`(l_max + 1)^2`: 16, 25, 36, 49, 64) so that no degree is cut in the middle.
        mass: the lumped mass matrix, `"voronoi"` (default) or `"barycentric"` (`ddgjax.LUMPED_MASS_MATRICES`).
        robust: the intrinsic Delaunay Laplacian (`ddgjax.spectral.eigenpairs`).
        solver: the backend of the eigensolver's and the harmonic fields' linear solves (`ddgjax.LINEAR_SOLVERS`).
        throw: raise when the eigensolve or a Poisson solve fails (default); with `False` return a
            `ddgjax.Solution` holding the basis, the first failure, and `stats` with each step's
            (`"eigenpairs"`, `"poisson"`).

    Returns:
        `FluidBasis` (`values (k,)`, `vectors (nv, k)`, `mass (nv,)`, `advection (k, k, k)`,
        `coriolis (k,)`; `harmonic (nf, 2 g, 3)`, `areas (nf,)`, `harmonic_advection (k, 2 g, k)`,
        `harmonic_exchange (k, 2 g, 2 g)`), differentiable in the vertex positions through `ddgjax.spectral.eigenpairs`
        (any function invariant within clusters of equal eigenvalues); in a `ddgjax.Solution` with `throw=False`.

    Raises:
        DDGInputError: `mesh` not a `Mesh`, a mesh with a boundary, bad `k` or `mass`;
            `MeshDataError` for a mesh that is not consistently oriented.
        equinox.EquinoxRuntimeError: with `throw=True`, the eigensolver or a solve failed (`ddgjax.RESULTS`).

    Examples:
        >>> import ddgjax
        >>> basis = ddgjax.fluids.fluid_basis(ddgjax.mesh.icosphere(2), 16)
        >>> basis.values.shape, basis.vectors.shape, basis.advection.shape
        ((16,), (162, 16), (16, 16, 16))
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
    discretization = discretize(mesh, mass=mass, robust=robust)
    L, M = discretization.laplacian, discretization.mass
    eigen = smallest_eigenpairs(L, M, k, solver=solver, throw=False)
    values, vectors = eigen.value
    # The Poisson solve of the harmonic fields reuses this discretisation's triangulation (no second set of flips).
    triangulation = False if discretization.triangulation is None else discretization.triangulation
    harmonic, poisson = _harmonic_fields(
        mesh, closed_cocycle_basis(mesh.topology), M.diagonal(), mass=mass, robust=triangulation, solver=solver
    )
    basis = _fluid_basis(mesh, values, vectors, M.diagonal(), harmonic)
    return outcome(
        basis, first_failure(eigen.result, poisson.result), throw, {"eigenpairs": eigen.stats, "poisson": poisson.stats}
    )


def _harmonic_fields(mesh: Mesh, cocycles, vertex_mass, *, mass, robust, solver) -> tuple[Float[Array, "nf h 3"], Solution]:
    """`L^2`-orthonormal harmonic face fields spanning the classes of the closed `cocycles (ne, h)` (module docstring).

    The gradient part is removed with the basis's own Laplacian and mass (`vertex_mass`, `mass=`,
    `robust=`): exactly `L^2`-orthogonal to the mesh's gradients with the cotan Laplacian, to the
    discretisation's accuracy with the intrinsic Delaunay one (`robust=True`, which keeps degenerate
    faces finite); with the Poisson solve's `Solution` (an empty one on a sphere)."""
    if cocycles.shape[1] == 0:  # a sphere: no Poisson solve
        return device_array(np.zeros((mesh.n_faces, 0, 3), mesh.vertices.dtype)), Solution(None, RESULTS.successful, {})
    areas = face_areas(mesh)
    # Faces of (near-)zero area carry no field: a closed form's vector there is of size 1 / area.
    regular = (areas > default_area_tol(areas.dtype) * jnp.max(face_edge_lengths_sq(mesh), axis=1))[:, None, None]
    closed = jnp.stack([sharp(mesh, jnp.asarray(eta, mesh.vertices.dtype)) for eta in cocycles.T], axis=1)
    closed = jnp.where(regular, closed, 0.0)
    gradients = face_hat_gradients(mesh)  # (nf, 3 corners, 3)
    # L a = int grad phi_i . v dA: the gradient part of v. `solve_poisson` takes a pointwise right-hand side.
    divergence = scatter_corners_to_vertices(mesh, jnp.einsum("f,fcd,fmd->fcm", areas, gradients, closed))
    poisson = solve_poisson(
        mesh, safe_div(-divergence, vertex_mass[:, None]), mass=mass, robust=robust, solver=solver, throw=False
    )
    potential = poisson.value
    fields = jnp.where(regular, closed - jnp.einsum("fcd,fcm->fmd", gradients, potential[mesh.faces]), 0.0)
    gram = jnp.einsum("f,fmd,fnd->mn", areas, fields, fields)
    factor = jnp.linalg.cholesky(gram)
    return jnp.einsum("mn,fnd->fmd", jnp.linalg.inv(factor), fields), poisson


def check_basis_size(mesh: Mesh, k: int) -> int:
    """`k` if `2 <= k < nv`, else `DDGInputError`."""
    k = check_count("k", k, minimum=2)
    if k >= mesh.n_vertices:
        raise DDGInputError(f"k: expected fewer eigenfunctions than the {mesh.n_vertices} vertices, got {k}")
    return k


@kernel(requires_orientation="fluid_basis")
def _fluid_basis(mesh: Mesh, values, vectors, mass, harmonic) -> FluidBasis:
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

    areas = face_areas(mesh)
    centre_values = jnp.mean(corners, axis=1)  # (nf, k)
    along = jnp.einsum("f,fmd,fcd->fcm", areas, harmonic, face_hat_gradients(mesh))  # A_f h_m . grad hat_c
    harmonic_advection = -jnp.einsum("fk,fcm,fcj->kmj", centre_values, along, corners)
    harmonic_advection = 0.5 * (harmonic_advection - jnp.transpose(harmonic_advection, (2, 1, 0)))
    turned = jnp.cross(face_normals(mesh)[:, None, :], harmonic)  # n x h_n
    harmonic_exchange = jnp.einsum("fk,f,fnd,fmd->kmn", centre_values, areas, turned, harmonic)
    basis = FluidBasis(
        values=values,
        vectors=vectors,
        mass=mass,
        advection=alternating,
        coriolis=jnp.zeros_like(values),
        harmonic=harmonic,
        areas=areas,
        harmonic_advection=harmonic_advection,
        harmonic_exchange=harmonic_exchange,
    )
    return eqx.tree_at(lambda b: b.coriolis, basis, basis.coefficients(2.0 * mesh.vertices[:, 2]))
