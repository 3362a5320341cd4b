"""Globally smoothest n-direction fields (Knoeppel et al. 2013), with or without alignment to a guidance field.

- Without alignment: the minimiser of `u^H A u` over `u^H M u = 1`, the eigenvector of the smallest
  eigenvalue of `A u = lambda M u` (`A` the connection Laplacian, `M` the lumped mass). It is found
  through the real form `[[Re A, -Im A], [Im A, Re A]] x = lambda diag(M, M) x`, where every
  eigenvalue of `A` appears twice (`x = [Re u; Im u]` and `[-Im u; Re u]`, i.e. `u` and `i u`), by
  `ddgjax.spectral.smallest_eigenpairs(..., k=2)`, which closes that pair.
- With alignment to a guidance field `q` (the same representation: `n`-th powers in the vertices'
  polar coordinates, magnitudes as weights): the screened problem
  `min_u u^H A u + s (u - q)^H M (u - q)`, i.e. `(A + s M) u = s M q`, one Hermitian positive definite
  solve (`ddgjax.solve.linear_solve`). It is Knoeppel's family `(A - lambda_t M) u = M q` with
  `lambda_t = -s` (the part below 0 of their `lambda_t < lambda_1`; the solution is scaled by `s`,
  which the unit field does not see): large `s` follows `q`; as `s -> 0` the solution tends to
  `s A^{-1} M q`, one step of inverse iteration from `q` (smoother than `q`, not the eigenvector:
  that is Knoeppel's limit `lambda_t -> lambda_1`, which is not offered here).

`smoothest_field` returns both the unit field and what it came from (`SmoothestField`: the field,
the minimiser `u` and its energy), since a loss uses any of them. Outcomes (`throw=`): the
eigensolver's (`RESULTS.eigensolver_failed`) or the solve's (`ddgjax.RESULTS`), as
`smallest_eigenpairs` and `linear_solve` report them.

Derivatives in the vertex positions: the solve is differentiated implicitly (always defined). On the
eigenvector path the eigenvalue `lambda = u^H A u` (the energy) has an exact gradient where the
complex eigenvalue is simple. The eigenvector itself is defined up to a phase `exp(i c)` (the pair
above is an exact cluster); it is fixed by rotating the entry of largest magnitude to the positive
real axis, a phase-invariant function of the eigenvector, so the returned field is differentiable
too wherever that entry is unique and the eigenvalue simple.

References: F. Knoeppel, K. Crane, U. Pinkall, P. Schroeder, "Globally optimal direction fields"
(SIGGRAPH 2013), sections 4-6. geometry-central: `computeSmoothestVertexDirectionField`,
`computeCurvatureAlignedVertexDirectionField`.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Complex, Float, Inexact

from .._compile import kernel
from .._errors import DDGInputError, check_choice, check_positive
from .._numerics import safe_reciprocal, safe_sqrt
from .._options import check_solver
from .._results import Solution, outcome
from ..mesh import Mesh, edge_dihedral_angles, edge_lengths, require_mesh
from ..solve import linear_solve
from ..sparse import SparseMatrix
from ..spectral import EIGENSOLVERS, smallest_eigenpairs
from ._connection import check_boundary_scaling, connection, plan_of
from ._laplacian import check_degree, connection_laplacian, connection_mass_matrix, real_form, real_form_diagonal
from ._plan import require_referenced


class SmoothestField(NamedTuple):
    """A direction field from `smoothest_field` (complex `n`-th powers in the vertices' polar coordinates).

    Unpacks as `field, solution, energy = smoothest_field(...)`.

    Attributes:
        field: `(nv,)` unit complex numbers `u_i / |u_i|` (0 where `u_i = 0`): the field's directions.
        solution: `(nv,)` the minimiser `u` itself: on the eigenvector path normalised
            `u^H M u = 1` (its magnitude is small near singularities), with alignment the solution of
            `(A + s M) u = s M q` (magnitude near `|q|` where the alignment wins).
        energy: `()` the smoothness `u^H A u / u^H M u` of `solution` (the smallest eigenvalue on the
            eigenvector path).
    """

    field: Complex[Array, " nv"]
    solution: Complex[Array, " nv"]
    energy: Float[Array, ""]


def smoothest_field(
    mesh: Mesh,
    *,
    n: int = 1,
    alignment: Inexact[ArrayLike, " nv"] | None = None,
    alignment_weight: float = 1.0,
    boundary_scaling: str = "geodesic",
    mass: str = "voronoi",
    method: str = "auto",
    solver: str = "auto",
    throw: bool = True,
) -> SmoothestField | Solution:
    r"""The globally smoothest `n`-direction field on the vertices, optionally aligned to a guidance field.

    Without `alignment`: the eigenvector of the smallest eigenvalue of $Au = \lambda M u$ (module
    docstring), with a deterministic phase (its entry of largest magnitude, the first on ties, is real
    and positive). With `alignment = q`: the solution of $(A + sM)\, u = s M q$, $s$ = `alignment_weight`
    (Knoeppel's `lambda_t = -s`). `A` is `connection_laplacian(mesh, n=n, boundary_scaling=...)`, `M`
    `connection_mass_matrix(mesh, mass=mass)`. The field's value at a vertex is the `n`-th power of
    its directions in the vertex's tangent basis (`tangent_bases`, the polar coordinates of
    `edge_polar_angles`); `field_to_vectors` turns it into 3D vectors.

    On a flat disk with `boundary_scaling="unscaled"` the answer is a constant field (energy 0); with
    the default `"geodesic"` the boundary bends the connection (geometry-central's convention), so it
    is not. Differentiable in the vertex positions (module docstring for what is defined); works
    under `jit` (the eigensolve and the solve are host calls on CPU). Needs a manifold, consistently
    oriented mesh without unreferenced vertices (`MeshDataError` otherwise).

    Args:
        mesh: the mesh.
        n: number of directions: 1 vector field, 2 line field, 4 cross field (keyword-only).
        alignment: `(nv,)` complex guidance `q` in the same representation (e.g.
            `principal_curvature_alignment(mesh, n=4)`), or `None`.
        alignment_weight: `s > 0`, the weight of `|u - q|_M^2` against the smoothness (default 1).
        boundary_scaling: `"geodesic"` (default) or `"unscaled"` (`ddgjax.fields._connection`).
        mass: `"voronoi"` (default) or `"barycentric"` lumped mass (`connection_mass_matrix`; a
            `"galerkin"` mass is refused).
        method: the eigensolver without alignment (`"auto"`, `"arpack"`, `"subspace"`;
            `ddgjax.spectral.smallest_eigenpairs`).
        solver: the backend of the linear solves (`ddgjax.LINEAR_SOLVERS`): the aligned solve, and the
            subspace iteration's.
        throw: raise when the eigensolve or the solve fails (default), or return a `ddgjax.Solution`
            holding the `SmoothestField`, `result` and the eigensolver's or the solve's `stats`.

    Returns:
        `SmoothestField(field, solution, energy)` (in a `ddgjax.Solution` with `throw=False`).

    Reference: Knoeppel, Crane, Pinkall, Schroeder (2013), sections 5-6. geometry-central:
    `computeSmoothestVertexDirectionField(geometry, n)` (the unit field; its phase is arbitrary) and
    `computeCurvatureAlignedVertexDirectionField`.

    Examples:
        >>> import ddgjax
        >>> sphere = ddgjax.mesh.icosphere(2)
        >>> cross = ddgjax.fields.smoothest_field(sphere, n=4)
        >>> indices = ddgjax.fields.field_singularities(sphere, cross.field, n=4)
        >>> cross.field.shape, int((indices != 0).sum()), float(indices.sum())  # eight of index 1/4: chi = 2
        ((162,), 8, 2.0)
    """
    mesh = require_mesh("mesh", mesh)
    n = check_degree(n)
    check_boundary_scaling(boundary_scaling)
    check_choice("method", method, EIGENSOLVERS)
    check_solver(solver)
    plan = plan_of(mesh)
    require_referenced(mesh, "smoothest_field")  # the name users call
    A = connection_laplacian(mesh, n=n, boundary_scaling=boundary_scaling)
    M = connection_mass_matrix(mesh, mass=mass)
    if alignment is None:
        eigensolve = smallest_eigenpairs(
            real_form(A, plan),
            real_form_diagonal(M.values),
            2,
            method=method,
            solver=solver,
            hermitian_real_form=True,
            throw=False,
        )
        field = _eigenvector_field(*eigensolve.value)
        result, stats = eigensolve.result, eigensolve.stats
    else:
        q = _complex_field("alignment", alignment, mesh.n_vertices)
        s = check_positive("alignment_weight", alignment_weight)
        solve = linear_solve(A + s * M, s * (M @ q), solver=solver, throw=False)
        field = _solved_field(A, M, solve.value)
        result, stats = solve.result, solve.stats
    return outcome(field, result, throw, stats)


@kernel
def _eigenvector_field(values: Float[Array, " 2"], vectors: Float[Array, "n2 2"]) -> SmoothestField:
    """The `SmoothestField` of the real form's first eigenvector `[Re u; Im u]`, its phase fixed so that
    the largest entry is real and positive (geometry-central leaves it arbitrary)."""
    nv = vectors.shape[0] // 2
    u = jax.lax.complex(vectors[:nv, 0], vectors[nv:, 0])
    largest = jnp.argmax(jnp.abs(u))
    u = jnp.conj(unit(u[largest])) * u
    # The pair's mean: invariant within the cluster, so its gradient is defined.
    return SmoothestField(field=unit(u), solution=u, energy=jnp.mean(values))


@kernel
def _solved_field(A: SparseMatrix, M: SparseMatrix, u: Complex[Array, " nv"]) -> SmoothestField:
    """The `SmoothestField` of the aligned solve's `u`, its energy the Rayleigh quotient `u^H A u / u^H M u`."""
    energy = jnp.real(jnp.vdot(u, A @ u)) / jnp.real(jnp.vdot(u, M @ u))
    return SmoothestField(field=unit(u), solution=u, energy=energy)


def unit(u: Complex[Array, "*shape"]) -> Complex[Array, "*shape"]:
    """`u / |u|`, or 0 where `u = 0`, with finite gradients (the double-where pattern of `ddgjax._numerics`)."""
    return u * safe_reciprocal(safe_sqrt(u.real * u.real + u.imag * u.imag))


def _complex_field(name: str, values, nv: int) -> Complex[Array, " nv"]:
    """`values` as a complex `(nv,)` JAX array, after checking the shape (known under jit too)."""
    if np.shape(values) != (nv,):
        raise DDGInputError(f"{name}: expected shape ({nv},) (one complex number per vertex), got {np.shape(values)}")
    values = jnp.asarray(values)
    if not (jnp.issubdtype(values.dtype, jnp.complexfloating) or jnp.issubdtype(values.dtype, jnp.floating)):
        raise DDGInputError(f"{name}: expected complex (or real) values, got dtype {values.dtype}")
    return values.astype(jnp.result_type(values.dtype, jnp.complex64))


@kernel(static_argnames=("n",))
def _curvature_alignment(mesh: Mesh, angles: Float[Array, "ne 2"], n: int) -> Complex[Array, " nv"]:
    bending = -0.5 * edge_lengths(mesh) * edge_dihedral_angles(mesh)
    # The edge's line direction at both ends: exp(2 i theta) (a line field, n = 2).
    terms = bending[:, None] * jnp.exp(2j * angles)
    q = jax.ops.segment_sum(terms.reshape(-1), mesh.edges.reshape(-1), num_segments=mesh.n_vertices)
    magnitude = safe_sqrt(q.real * q.real + q.imag * q.imag)
    return magnitude * unit(q) ** (n // 2)


def principal_curvature_alignment(mesh: Mesh, *, n: int = 4, boundary_scaling: str = "geodesic") -> Complex[Array, " nv"]:
    """Guidance field of the principal curvature directions, `(nv,)` complex, for `smoothest_field(alignment=...)`.

    From the edge-based shape operator (Cohen-Steiner & Morvan's normal cycle): each edge at vertex
    `i` bends the surface across it by its signed dihedral angle `beta_ij` (`edge_dihedral_angles`,
    positive where convex), so in `i`'s polar coordinates

        q_i = -1/2 sum_j l_ij beta_ij exp(2 i theta_ij)

    is a line field (`n = 2`) along the direction of maximal curvature `k1`, of magnitude about
    `(k1 - k2) A_i` (the traceless part of the integrated shape operator over the vertex's dual cell;
    the minus sign turns the edges' directions, which are the directions of least bending, by 90
    degrees). For even `n` it is returned as `|q| (q / |q|)^(n/2)`: for `n = 4` the cross of both
    principal directions, with the anisotropy as its weight (umbilic and flat regions get ~0 and
    are left to the smoothness). Needs consistently oriented faces (signed dihedral angles).
    Differentiable in the vertex positions.

    Args:
        mesh: the mesh.
        n: an even number of directions (2 or 4 typically; default 4), keyword-only.
        boundary_scaling: the polar coordinates' boundary convention (`ddgjax.fields._connection`).

    Returns:
        `(nv,)` complex array `|q| (q / |q|)^(n/2)`, in each vertex's polar coordinates.

    Reference: D. Cohen-Steiner, J.-M. Morvan, "Restricted Delaunay triangulations and normal cycle"
    (2003); Knoeppel et al. 2013, section 6 (curvature alignment with `q = (k1 - k2) exp(i n phi)`).
    """
    n = check_degree(n)
    if n % 2:
        raise DDGInputError(f"n: principal directions are lines, so they give fields with an even n; got {n}")
    mesh = require_mesh("mesh", mesh)
    mesh.topology.require_oriented("principal_curvature_alignment (signed dihedral angles)")
    return _curvature_alignment(mesh, connection(mesh, boundary_scaling).edge_polar, n=n)
