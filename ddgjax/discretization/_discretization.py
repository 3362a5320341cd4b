"""`discretize`: a domain, with `mass=` and `robust=`, as the problem layer solves on it (one object, every domain).

The problem layer (`ddgjax.pde`'s Poisson and harmonic problems, `ddgjax.spectral.eigenpairs`, every heat
method in `ddgjax.geodesics`, the learning operators and the fluid basis) needs the same things of a
domain: its weak Laplacian `L` and mass matrix `M`, the sparsity pattern its host plans are built on, and,
for a surface with `robust=`, the intrinsic Delaunay triangulation they came from. `discretize` builds
them once, checks `mass=` and `robust=` the same way for all of them, and is the one place where the kind
of domain matters:

- a triangle `Mesh`: `ddgjax.laplacian.laplacian_and_mass`: `robust=False` refuses degenerate faces on
  concrete positions (`MeshDataError`) and gives the cotan Laplacian and mass matrix; `robust=True` (or
  an `IntrinsicTriangulation`) the intrinsic Delaunay ones (mollified; the tufted cover, halved, on
  non-manifold meshes).
- a `ddgjax.volume.TetMesh`: `robust=False` only (no intrinsic Delaunay retriangulation in 3-D), degenerate
  tets refused on concrete positions; `L`, `M` from `ddgjax.volume`.

The per-cell pieces of a domain that a kernel needs (its cells, their measure-weighted hat gradients, the
edge lengths) are `cells`, `cell_measure_gradients` and `domain_edge_lengths`, which work on the arrays a
kernel traces. Reference: libigl builds `cotmatrix` / `massmatrix` from `(V, F)` or `(V, T)` alike;
geometry-central's `IntrinsicGeometryInterface` plays this part for surfaces.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from .._errors import MeshDataError, first_indices, is_traced
from .._numerics import safe_div, safe_sqrt
from .._options import check_mass
from ..laplacian import IntrinsicTriangulation, laplacian_and_mass
from ..laplacian.internal import resolve_robust, vertex_plan
from ..mesh import Mesh, edge_lengths, face_areas, face_areas_from_lengths_sq, face_hat_gradients
from ..sparse import SparseMatrix, SparsityPattern
from ..volume import TetMesh, tet_hat_gradients, tet_plan, tet_volumes
from ..volume import cotan_laplacian as tet_cotan_laplacian
from ..volume import edge_lengths as tet_edge_lengths
from ..volume import mass_matrix as tet_mass_matrix
from ..volume.internal import require_tet_problem


class Discretization(eqx.Module):
    """A domain as the problem layer solves on it (module docstring).

    Attributes:
        domain: the `Mesh` or `TetMesh` (with its topology).
        laplacian: `(nv, nv)` the PSD weak Laplacian `L` (cotan, or intrinsic Delaunay with `robust=`).
        mass: `(nv, nv)` the mass matrix `M` of `mass=`.
        triangulation: the `IntrinsicTriangulation` `L` and `M` come from, or None (the domain's own cells).
        pattern: `laplacian`'s vertex-vertex sparsity pattern from the host-built plan: what host plans
            (Dirichlet blocks, pins) are built on. Concrete inside a caller's `jit`, where `laplacian`'s own
            pattern is traced, unless the triangulation itself is an argument of that `jit`.
    """

    domain: Mesh | TetMesh
    laplacian: SparseMatrix
    mass: SparseMatrix
    triangulation: IntrinsicTriangulation | None
    pattern: SparsityPattern


def discretize(
    mesh: Mesh | TetMesh, *, mass: str = "voronoi", robust: bool | IntrinsicTriangulation = False, caller: str | None = None
) -> Discretization:
    r"""`L`, `M` (and the intrinsic triangulation) of a triangle or tet mesh, checked as every problem checks them.

    $$\Delta = -M^{-1} L, \qquad L \succeq 0,\ L \mathbf{1} = 0$$

    Args:
        mesh: a `ddgjax.Mesh` or a `ddgjax.volume.TetMesh`.
        mass: one of `ddgjax.MASS_MATRICES` (`"voronoi"`, the default, `"barycentric"`, `"galerkin"`).
        robust: `False`, `True` or an `IntrinsicTriangulation` (triangle meshes only; module docstring).
        caller: the public function asking, named in the error when it builds host plans on a traced
            triangulation (`robust=` given as an argument of a `jit`).

    Returns:
        `Discretization(domain, laplacian, mass, triangulation, pattern)`; `L == -igl.cotmatrix(V, F)` (or
        `(V, T)`), `M == igl.massmatrix(V, F, MASSMATRIX_TYPE_VORONOI)` by default; with `robust=True` and
        `mass="barycentric"`, `robust_laplacian.mesh_laplacian(V, F)`'s pair. Differentiable in the vertex
        positions (under `jit`, `grad`, `vmap`; the host work, checks and flips, runs before).

    Raises:
        DDGInputError: `mesh` neither kind, a bad `mass` or `robust`. `MeshDataError`: NaN / inf
            positions, degenerate faces (with `robust=False`), degenerate or inverted tets, on concrete positions.

    Examples:
        >>> import ddgjax
        >>> from ddgjax.discretization import discretize
        >>> d = discretize(ddgjax.mesh.icosphere(1), mass="barycentric")
        >>> d.laplacian.shape, d.mass.shape, d.triangulation is None
        ((42, 42), (42, 42), True)
    """
    mesh = require_domain("mesh", mesh)
    check_mass(mass)
    _require_finite_positions(mesh)
    return _BUILDERS[type(mesh)](mesh, mass, robust, caller)


def _require_finite_positions(mesh: Mesh | TetMesh) -> None:
    """`MeshDataError` naming the vertices with NaN / inf coordinates, when they are concrete: positions set past
    `with_vertices`' check (`eqx.tree_at`) would otherwise surface as an eigensolver or solver failure."""
    if is_traced(mesh.vertices):
        return  # under jit the values are unknown: a failure is reported through `throw=` (`RESULTS.nonfinite`)
    bad = ~np.isfinite(np.asarray(mesh.vertices)).all(axis=1)
    if bad.any():
        raise MeshDataError(
            f"{type(mesh).parameter_name}: {int(bad.sum())} of its {bad.size} vertices have NaN or inf coordinates "
            f"(vertices {first_indices(bad)}), so no Laplacian or mass can be built; give them finite positions "
            "(with_vertices checks new positions; eqx.tree_at does not)"
        )


def require_domain(name: str, value) -> Mesh | TetMesh:
    """`value` if the problem layer solves on it (a `Mesh` or a `TetMesh`), else `DDGInputError` naming the argument."""
    if type(value) in _BUILDERS:
        return value
    return Mesh.require(name, value)  # its message, with the hint for a (vertices, faces) pair


def _surface(mesh: Mesh, mass: str, robust, caller: str | None) -> Discretization:
    triangulation = resolve_robust(mesh, robust, mass=mass, host_plans=caller)
    plan = vertex_plan(mesh) if triangulation is None else triangulation.plan
    laplacian, mass_matrix = laplacian_and_mass(mesh, mass=mass, robust=False if triangulation is None else triangulation)
    return Discretization(domain=mesh, laplacian=laplacian, mass=mass_matrix, triangulation=triangulation, pattern=plan.pattern)


def _solid(tet_mesh: TetMesh, mass: str, robust, caller: str | None) -> Discretization:
    require_tet_problem(tet_mesh, robust)
    laplacian, mass_matrix = tet_cotan_laplacian(tet_mesh), tet_mass_matrix(tet_mesh, mass=mass)
    return Discretization(
        domain=tet_mesh, laplacian=laplacian, mass=mass_matrix, triangulation=None, pattern=tet_plan(tet_mesh).pattern
    )


_BUILDERS = {Mesh: _surface, TetMesh: _solid}


def cells(domain: Mesh | TetMesh, triangulation: IntrinsicTriangulation | None = None) -> Int[Array, "nc k"]:
    """The top-dimensional cells: a triangle mesh's faces `(nf, 3)` (its intrinsic triangulation's faces when
    one is given), a tet mesh's tets `(nt, 4)` (works in kernels)."""
    if triangulation is not None:
        return triangulation.faces
    return domain.tets if isinstance(domain, TetMesh) else domain.faces


def cell_measure_gradients(domain: Mesh | TetMesh, triangulation: IntrinsicTriangulation | None = None) -> Float[Array, "nc k d"]:
    """`A_f grad phi_k` per face and corner, or `V_t grad phi_k` per tet and vertex: the weak gradient's blocks.

    On a mesh, `(nf, 3, 3)` in world coordinates. With an intrinsic triangulation, `(nf, 3, 2)` on its faces
    (`cells(domain, triangulation)`), from their (mollified, flipped) edge lengths alone, in each face's own
    layout (`intrinsic_measure_gradients`), divided by the number of sheets as its operators are: a face
    of zero area in the mesh then contributes nothing ill-conditioned (its normal, its `1 / A`).
    """
    if triangulation is not None:
        return intrinsic_measure_gradients(triangulation.face_lengths_sq(domain)) / triangulation.sheets
    if isinstance(domain, TetMesh):
        return tet_volumes(domain)[:, None, None] * tet_hat_gradients(domain)
    return face_areas(domain)[:, None, None] * face_hat_gradients(domain)


def intrinsic_measure_gradients(face_lengths_sq: Float[Array, "nf 3"]) -> Float[Array, "nf 3 2"]:
    """`A_f grad phi_k = J e_k / 2` of triangles given by their squared edge lengths, in a planar layout per face.

    Corner 0 at the origin, corner 1 on the positive x axis, corner 2 above it: `p1 = (c, 0)`,
    `p2 = ((b^2 + c^2 - a^2) / (2 c), 2 A / c)` with `a, b, c` the lengths opposite corners 0, 1, 2
    (`face_lengths_sq`'s columns); `e_k` is the edge opposite corner `k`, counterclockwise
    (`p2 - p1`, `p0 - p2`, `p1 - p0`), and `J` the rotation by +90 degrees. Only the area's square root
    and `1 / c` divide, and a mollified triangle (`ddgjax.laplacian.intrinsic_delaunay`) has `A > 0`, `c > 0`.
    A function's gradient `sum_k u_k A grad phi_k` and the divergence's corner terms live in the same
    layout, so nothing needs the faces' positions in space (Sharp & Crane 2020, the heat method on an
    intrinsic triangulation).
    """
    a_sq, b_sq, c_sq = face_lengths_sq[:, 0], face_lengths_sq[:, 1], face_lengths_sq[:, 2]
    c = safe_sqrt(c_sq)
    area = face_areas_from_lengths_sq(face_lengths_sq)
    x = safe_div(b_sq + c_sq - a_sq, 2.0 * c)
    y = safe_div(2.0 * area, c)
    zero = jnp.zeros_like(c)
    corners = jnp.stack([jnp.stack([zero, zero], -1), jnp.stack([c, zero], -1), jnp.stack([x, y], -1)], axis=1)
    opposite = jnp.roll(corners, -2, axis=1) - jnp.roll(corners, -1, axis=1)  # e_k = p_{k+2} - p_{k+1}
    return 0.5 * jnp.stack([-opposite[..., 1], opposite[..., 0]], axis=-1)


def domain_edge_lengths(domain: Mesh | TetMesh) -> Float[Array, " ne"]:
    """The lengths of the domain's edges (the heat methods' time scale is their mean, squared)."""
    return tet_edge_lengths(domain) if isinstance(domain, TetMesh) else edge_lengths(domain)
