"""What matching needs of each shape: the mesh, its lumped mass and the first eigenpairs of its Laplacian.

pyFM's `TriMesh` after `process(k)` holds the same. Functional maps are written in these bases: a
`(k_target, k_source)` matrix `C` takes the coefficients `a = Phi_s^T M_s f` of a function `f` on the
source to those of its image on the target, `C a` (Ovsjanikov et al. 2012, section 4).
"""

from __future__ import annotations

import equinox as eqx
from jaxtyping import Array, Float

from .._errors import DDGInputError
from .._options import LUMPED_MASS_MATRICES, check_mass
from .._results import Solution, outcome
from ..laplacian import IntrinsicTriangulation, laplacian_and_mass
from ..mesh import Mesh, require_mesh
from ..spectral import smallest_eigenpairs


class SpectralShape(eqx.Module):
    """A mesh with its lumped mass and the `k` smallest eigenpairs of `L phi = lambda M phi` (a pytree).

    Attributes:
        mesh: the triangle mesh.
        mass: `(nv,)` the lumped mass (vertex areas) `M`.
        values: `(k,)` the eigenvalues, ascending (the first is 0 on a closed or Neumann mesh).
        vectors: `(nv, k)` the M-orthonormal eigenvectors `Phi` (`Phi^T M Phi = I`).
    """

    mesh: Mesh
    mass: Float[Array, " nv"]
    values: Float[Array, " k"]
    vectors: Float[Array, "nv k"]

    @property
    def k(self) -> int:
        """The number of eigenpairs."""
        return self.values.shape[0]


def spectral_shape(
    mesh: Mesh, k: int, *, mass: str = "voronoi", robust: bool | IntrinsicTriangulation = False, throw: bool = True
) -> SpectralShape | Solution:
    """`SpectralShape` of a mesh: its lumped mass and `k` eigenpairs (`ddgjax.spectral.eigenpairs`).

    `mass`: `"voronoi"` (default) or `"barycentric"` (lumped: point maps and descriptors weigh vertices
    by their areas). `robust=True` uses the intrinsic Delaunay Laplacian and mass (meshes with
    degenerate faces). Differentiable in the vertex positions (`ddgjax.spectral.smallest_eigenpairs`).
    `throw`: a failed eigensolve raises (default) or, with `throw=False`, the shape comes in a
    `ddgjax.Solution`. pyFM: `TriMesh(V, F).process(k, intrinsic=robust)`.
    """
    mesh = require_mesh("mesh", mesh)
    check_mass(mass, LUMPED_MASS_MATRICES)
    L, M = laplacian_and_mass(mesh, mass=mass, robust=robust)
    solution = smallest_eigenpairs(L, M, k, throw=False)
    values, vectors = solution.value
    shape = SpectralShape(mesh=mesh, mass=M.diagonal(), values=values, vectors=vectors)
    return outcome(shape, solution.result, throw, solution.stats)


def require_spectral_shape(name: str, value) -> SpectralShape:
    """`value` if it is a `SpectralShape`, else `DDGInputError` saying how to make one."""
    if not isinstance(value, SpectralShape):
        raise DDGInputError(
            f"{name}: expected a ddgjax.matching.SpectralShape (make one with spectral_shape(mesh, k)), "
            f"got {type(value).__name__}"
        )
    return value
