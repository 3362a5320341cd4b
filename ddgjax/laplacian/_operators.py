"""The Laplacian and mass matrix a problem runs on: the mesh's own, or its intrinsic Delaunay ones (`robust=`).

Solvers built on the Laplacian (eigenpairs, heat-method distance, Poisson) take `robust=False` (the
mesh's cotan Laplacian and `mass_matrix(mesh, mass=mass)`), `robust=True` (the intrinsic Delaunay
Laplacian and mass matrix, whose interior weights are non-negative: the maximum principle holds and
obtuse triangles no longer spoil the solve; Sharp & Crane 2020 call this the "robust" Laplacian), or
an `IntrinsicTriangulation` from `intrinsic_delaunay(mesh)`, made once on the host, which is what
works inside `jit` / `grad` (the flips are host combinatorics).

Degenerate geometry (`ddgjax.mesh._check`, the policy): a face of zero or near-zero area has
infinite or undefined cotangents, and rounding then makes the plain cotan Laplacian indefinite
(eigenvalues of -20 where 0 is right). `robust=False` on concrete positions with such faces raises
`MeshDataError` naming them and the remedies. `robust=True` handles every mesh: the intrinsic
triangulation first mollifies the metric (every edge lengthened by the smallest amount that gives
each triangle a strict triangle inequality with margin `1e-5` of the mean edge length, Sharp & Crane
2020), so every triangle has a positive area, then flips to Delaunay: a positive semidefinite
Laplacian, `robust_laplacian.mesh_laplacian(V, F, mollify_factor=1e-5)` on closed meshes. It also
handles every connectivity: a mesh with a non-manifold edge or inconsistently oriented faces (a
Moebius strip) gets the operators of its tufted cover, halved (`intrinsic_delaunay`), as
robust_laplacian does on every mesh; `robust=False` refuses none of those (the cotan Laplacian is
defined face by face).
"""

from __future__ import annotations

from typing import NamedTuple

from .._errors import DDGInputError, is_traced
from .._options import check_mass
from ..mesh import Mesh
from ..mesh.internal import require_nondegenerate
from ..sparse import SparseMatrix
from ._cotan import cotan_laplacian
from ._intrinsic import IntrinsicTriangulation, intrinsic_delaunay, intrinsic_delaunay_laplacian, intrinsic_delaunay_mass_matrix
from ._mass import mass_matrix


class LaplacianAndMass(NamedTuple):
    """The pair `laplacian_and_mass` returns (unpacks as `L, M = laplacian_and_mass(mesh)`).

    Attributes:
        laplacian: `(nv, nv)` the PSD cotan Laplacian `L`.
        mass: `(nv, nv)` the mass matrix `M`.
    """

    laplacian: SparseMatrix
    mass: SparseMatrix


def laplacian_and_mass(mesh: Mesh, *, mass: str = "voronoi", robust: bool | IntrinsicTriangulation = False) -> LaplacianAndMass:
    r"""`(L, M)`: the cotan Laplacian and the mass matrix of `mesh`, or of its intrinsic Delaunay triangulation.

    `robust=False`: `cotan_laplacian(mesh)` and `mass_matrix(mesh, mass=mass)`, refused
    (`MeshDataError`) on concrete positions with faces of zero or near-zero area; otherwise
    `intrinsic_delaunay_laplacian` and `intrinsic_delaunay_mass_matrix` of one (mollified)
    triangulation, which work on every mesh, non-manifold and non-oriented ones included (the tufted
    cover; module docstring). $\Delta = -M^{-1} L$ is the pointwise Laplace-Beltrami operator.

    Args:
        mesh: the mesh.
        mass: one of `ddgjax.MASS_MATRICES`, `"voronoi"` (default), `"barycentric"` or `"galerkin"`.
        robust: `False`, `True` (flips computed here, on the host: outside `jit`) or an `IntrinsicTriangulation`.

    Returns:
        `LaplacianAndMass(laplacian, mass)`, two `(nv, nv)` `SparseMatrix`es.

    Raises `MeshDataError` for degenerate faces with `robust=False` (above), and as
    `intrinsic_delaunay` does with `robust=True`.

    Reference: Sharp & Crane, "A Laplacian for nonmanifold triangle meshes" (2020). libigl:
    `-igl.cotmatrix(V, F)`, `igl.massmatrix(V, F, type)`; robust_laplacian: `mesh_laplacian(V, F)`.

    Examples:
        >>> import ddgjax
        >>> sphere = ddgjax.mesh.icosphere(3)
        >>> L, M = ddgjax.laplacian.laplacian_and_mass(sphere, mass="voronoi")
        >>> z = sphere.vertices[:, 2]  # an eigenfunction of the unit sphere, eigenvalue 2
        >>> round(float((z @ (L @ z)) / (z @ (M @ z))), 6)
        2.0
    """
    triangulation = resolve_robust(mesh, robust, mass=mass)
    if triangulation is None:
        return LaplacianAndMass(cotan_laplacian(mesh), mass_matrix(mesh, mass=mass))
    return LaplacianAndMass(
        intrinsic_delaunay_laplacian(mesh, triangulation=triangulation),
        intrinsic_delaunay_mass_matrix(mesh, triangulation=triangulation, mass=mass),
    )


def resolve_robust(
    mesh: Mesh, robust: bool | IntrinsicTriangulation, *, mass: str = "voronoi", host_plans: str | None = None
) -> IntrinsicTriangulation | None:
    """The triangulation a `robust=` argument asks for: `None` (the mesh's own, after refusing degenerate
    faces on concrete positions: `MeshDataError`, module docstring), or the intrinsic Delaunay one
    (`True`: flipped here, on the host), after checking `mass`; `DDGInputError` otherwise.
    `host_plans` names a caller that builds host plans (Dirichlet blocks, pins) on the triangulation's
    pattern, which then must be concrete: not a triangulation passed as an argument of a `jit`."""
    check_mass(mass)
    if robust is False:
        require_nondegenerate(mesh)
        return None
    if robust is True:
        robust = intrinsic_delaunay(mesh)
    if not isinstance(robust, IntrinsicTriangulation):
        raise DDGInputError(
            f"robust: expected True, False or an IntrinsicTriangulation (intrinsic_delaunay(mesh)), got {robust!r}"
        )
    if host_plans is not None and is_traced(robust.plan.pattern.rows):
        raise DDGInputError(
            f"robust: {host_plans} builds host plans on the intrinsic triangulation's sparsity pattern, which is traced "
            "when the IntrinsicTriangulation is an argument of your jit; make it outside jit and close over it "
            f"(jax.jit(lambda V: {host_plans}(mesh.with_vertices(V), ..., robust=T))), or pass robust=True outside jit"
        )
    return robust
