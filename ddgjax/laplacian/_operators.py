"""The Laplacian and mass matrix a problem runs on: the mesh's own, or its intrinsic Delaunay ones (`robust=`).

Solvers built on the Laplacian (eigenpairs, heat-method distance) take `robust=False` (the mesh's
cotan Laplacian and `mass_matrix(mesh, kind=mass)`), `robust=True` (the intrinsic Delaunay Laplacian
and lumped mass, whose interior weights are non-negative: the maximum principle holds and obtuse
triangles no longer spoil the solve; Sharp & Crane 2020 call this the "robust" Laplacian), or an
`IntrinsicTriangulation` from `intrinsic_delaunay(mesh)`, made once on the host, which is what
works inside `jit` / `grad` (the flips are host combinatorics).
"""

from __future__ import annotations

from .._errors import DDGInputError, check_choice
from ..mesh import Mesh
from ..sparse import SparseMatrix
from ._cotan import cotan_laplacian
from ._intrinsic import IntrinsicTriangulation, intrinsic_delaunay, intrinsic_delaunay_laplacian, intrinsic_delaunay_mass_matrix
from ._mass import mass_matrix


def laplacian_and_mass(
    mesh: Mesh, *, mass: str = "voronoi", robust: bool | IntrinsicTriangulation = False
) -> tuple[SparseMatrix, SparseMatrix]:
    """`(L, M)`: the cotan Laplacian and the mass matrix of `mesh`, or of its intrinsic Delaunay triangulation (module docstring).

    Args:
        mesh: the mesh.
        mass: `"voronoi"`, `"barycentric"` or (not with `robust`) `"galerkin"`.
        robust: `False`, `True` (flips computed here, on the host: outside `jit`) or an `IntrinsicTriangulation`.
    """
    triangulation = resolve_robust(mesh, robust, mass=mass)
    if triangulation is None:
        return cotan_laplacian(mesh), mass_matrix(mesh, kind=mass)
    return (
        intrinsic_delaunay_laplacian(mesh, triangulation=triangulation),
        intrinsic_delaunay_mass_matrix(mesh, triangulation=triangulation, kind=mass),
    )


def resolve_robust(mesh: Mesh, robust: bool | IntrinsicTriangulation, *, mass: str = "voronoi") -> IntrinsicTriangulation | None:
    """The triangulation a `robust=` argument asks for: `None` (the mesh's own), or the intrinsic Delaunay
    one (`True`: flipped here, on the host), checked against `mass`; `DDGInputError` otherwise."""
    check_choice("mass", mass, ("voronoi", "barycentric", "galerkin"))
    if robust is False:
        return None
    if robust is True:
        robust = intrinsic_delaunay(mesh)
    if not isinstance(robust, IntrinsicTriangulation):
        raise DDGInputError(
            f"robust: expected True, False or an IntrinsicTriangulation (intrinsic_delaunay(mesh)), got {robust!r}"
        )
    if mass == "galerkin":
        raise DDGInputError("mass: the intrinsic Delaunay mass matrix is lumped; use 'voronoi' or 'barycentric' with robust=")
    return robust
