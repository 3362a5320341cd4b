"""Tangent fields interpolated from a few vertices with the connection Laplacian (a Dirichlet problem).

    minimise u^H A u  subject to  u_c = values,   i.e.   A_ff u_f = -A_fc u_c,

the discrete harmonic extension in the connection (Knoeppel et al. 2013, section 6.1: fixed
directions as hard constraints). The free-free block is Hermitian positive definite when every
component of the mesh holds a constrained vertex and the connection Laplacian is (e.g. Delaunay
meshes); it is solved once with `ddgjax.solve.linear_solve`, differentiable in the values and the
vertex positions by implicit differentiation.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Complex, Inexact, Int

from .._errors import DDGInputError
from ..mesh import Mesh, require_mesh
from ..solve import linear_solve
from ..sparse import SparseMatrix, dirichlet_blocks, dirichlet_plan
from ._connection import check_boundary
from ._laplacian import check_degree, connection_laplacian


def interpolate_field(
    mesh: Mesh,
    vertices: Int[ArrayLike, " n_fixed"],
    values: Inexact[ArrayLike, " n_fixed"],
    *,
    n: int = 1,
    boundary: str = "geodesic",
    method: str = "auto",
) -> Complex[Array, " nv"]:
    """The smoothest `n`-direction field taking the given values at the given vertices, `(nv,)` complex.

    Minimises `u^H A u` (`A = connection_laplacian(mesh, n=n, boundary=boundary)`) with `u` fixed at
    `vertices` (module docstring). Values are `n`-th powers in the vertices' polar coordinates
    (`ddgjax.fields._connection`; a 3D tangent vector `v` at vertex `i` is
    `(v . e1 + i v . e2)^n` with `(e1, e2)` from `tangent_bases`); magnitudes are interpolated
    too (normalise the result, `u / |u|`, for directions). On a flat region with `boundary="unscaled"`
    a single constraint gives the constant field. Differentiable in `values` and the vertex positions.

    Args:
        mesh: the mesh (manifold, consistently oriented).
        vertices: `(n_fixed,)` distinct vertex indices, at least one per connected component.
        values: `(n_fixed,)` complex values at them.
        n: number of directions (keyword-only).
        boundary: `"geodesic"` (default) or `"unscaled"`.
        method: the `linear_solve` backend.

    Reference: Knoeppel et al. 2013, section 6.1; N. Sharp, Y. Soliman, K. Crane, "The vector heat
    method" (2019), whose vector diffusion `(M + t A) u = u_0` approaches this as `t` grows
    (potpourri3d `MeshVectorHeatSolver.transport_tangent_vectors` normalises magnitudes separately).
    libigl: `igl.harmonic` is the scalar counterpart.
    """
    mesh = require_mesh("mesh", mesh)
    n = check_degree(n)
    check_boundary(boundary)
    fixed = np.asarray(vertices)
    if fixed.ndim != 1 or fixed.size == 0 or not np.issubdtype(fixed.dtype, np.integer):
        raise DDGInputError(
            f"vertices: expected a non-empty 1-d integer array of vertex indices, got shape {fixed.shape} dtype {fixed.dtype}"
        )
    outside = (fixed < 0) | (fixed >= mesh.n_vertices)
    if outside.any():
        raise DDGInputError(f"vertices: indices must lie in [0, {mesh.n_vertices}), got {fixed[outside][:5].tolist()}")
    if np.unique(fixed).size != fixed.size:
        raise DDGInputError("vertices: expected distinct vertices, got repeated ones")
    if np.shape(values) != fixed.shape:
        raise DDGInputError(f"values: expected shape {fixed.shape} (one complex number per vertex), got {np.shape(values)}")
    values = jnp.asarray(values)
    values = values.astype(jnp.result_type(values.dtype, jnp.complex64))
    A = connection_laplacian(mesh, n=n, boundary=boundary)
    plan = dirichlet_plan(A.pattern, fixed)
    if plan.free.shape[0] == 0:
        return values[np.argsort(fixed)]
    # The blocks and the join are gathers of the real and imaginary parts (`gather_sum` is typed real).
    real, imaginary = (dirichlet_blocks(SparseMatrix(part, A.pattern), plan) for part in (A.values.real, A.values.imag))
    free_free = SparseMatrix(
        real[0].values + 1j * imaginary[0].values, plan.free_free, hermitian=True, positive_semidefinite=True
    )
    free_fixed = SparseMatrix(real[1].values + 1j * imaginary[1].values, plan.free_fixed)
    free_values = linear_solve(free_free, -(free_fixed @ values), method=method).value
    return jax.lax.complex(plan.join(free_values.real, values.real), plan.join(free_values.imag, values.imag))
