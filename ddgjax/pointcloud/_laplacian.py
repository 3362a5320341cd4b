"""The point-cloud Laplacian and mass matrix (Sharp & Crane 2020), and PCA normals, differentiable in the points.

`point_cloud_laplacian(points)` is robust_laplacian's `point_cloud_laplacian(P, n_neighbors=30)`:
the cotan Laplacian and lumped mass of the tufted intrinsic Delaunay triangulation of the local
triangulations (`ddgjax.pointcloud._triangulation`), divided by 6. The neighbourhoods and flips are
found once on the host; the values are the lengths core of `ddgjax.laplacian`
(`cotan_laplacian_from_lengths_sq`, `mass_matrix_from_lengths_sq` on the cover's
`triangulation_plan`) applied to the replayed squared lengths, so `L` and `M` are JAX functions of
the positions (jit, grad, vmap with `triangulation=`).

Sign: `L` is positive semidefinite, `(L u)_i = sum_j w_ij (u_i - u_j)` with `w_ij >= 0`, as the
conventions' cotan Laplacian; robust_laplacian's `L` is PSD too, so `L == robust_laplacian`'s (no
sign change), and the pointwise Laplace-Beltrami operator is `-M^{-1} L`.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .._compile import kernel
from .._errors import DDGInputError, is_traced
from .._indexing import take_rows
from ..laplacian import LaplacianAndMass, TriangulationPlan, cotan_laplacian_from_lengths_sq, mass_matrix_from_lengths_sq
from ..sparse import SparseMatrix, diagonal_matrix
from ._triangulation import (
    PointCloudTriangulation,
    check_neighbors,
    check_points,
    nearest_neighbor_graph,
    point_cloud_triangulation,
)

# The cover holds every local triangle twice (two orientations) and each about three times (once per corner).
_COVER_MULTIPLICITY = 6.0


def point_cloud_laplacian(
    points: ArrayLike,
    *,
    n_neighbors: int = 30,
    mollify_factor: float = 1e-5,
    triangulation: PointCloudTriangulation | None = None,
) -> LaplacianAndMass:
    r"""The point-cloud Laplacian `L` and lumped mass `M` of Sharp & Crane 2020 (robust_laplacian's construction).

    `L` is the cotan Laplacian and `M` the barycentric lumped mass (a third of each triangle's area to
    each corner) of the mollified tufted intrinsic Delaunay triangulation of the points' local
    Delaunay triangulations (`point_cloud_triangulation`), both divided by 6 (the cover holds each
    local triangle twice, and each about three times), as robust_laplacian. `L` is positive
    semidefinite with non-negative edge weights (the maximum principle), $L\mathbf{1} = 0$; robust_laplacian's
    `L` has the same sign, so `L == robust_laplacian.point_cloud_laplacian(P)[0]` where the local
    triangulations agree (they differ only on nearly co-circular neighbourhoods: `_triangulation`).
    $\Delta = -M^{-1} L$ approximates the Laplace-Beltrami operator of the sampled surface. Differentiable in
    `points` for the fixed neighbourhood graph and flips: build `triangulation` once, then call this
    inside `jit` / `grad` with it.

    Args:
        points: `(n, 3)` finite positions.
        n_neighbors: the neighbourhood size, `2 <= k <= n - 1` (keyword-only; default 30, robust_laplacian's).
        mollify_factor: the intrinsic mollification margin relative to the mean edge length
            (keyword-only; default `1e-5`, robust_laplacian's).
        triangulation: `point_cloud_triangulation(points, ...)` to reuse (keyword-only; needed under
            `jit` / `grad`), or `None` to build it here (then `n_neighbors` and `mollify_factor` apply).

    Returns:
        `LaplacianAndMass(laplacian, mass)`, `(n, n)` `SparseMatrix`es: `laplacian` symmetric PSD,
        `mass` diagonal positive.

    Raises `DDGInputError` for a bad shape, NaN / inf, a bad `n_neighbors`, traced points without a
    `triangulation`, or a `triangulation` of another cloud.

    Reference: N. Sharp, K. Crane, "A Laplacian for nonmanifold triangle meshes" (SGP 2020).
    robust_laplacian: `L, M = point_cloud_laplacian(P, mollify_factor=1e-5, n_neighbors=30)`.

    Examples:
        >>> import jax.numpy as jnp
        >>> import ddgjax
        >>> points = ddgjax.mesh.icosphere(3).vertices
        >>> L, M = ddgjax.pointcloud.point_cloud_laplacian(points, n_neighbors=10)
        >>> L.shape, bool(jnp.allclose(L @ jnp.ones(642), 0.0))
        ((642, 642), True)
        >>> z = points[:, 2]  # an eigenfunction of the unit sphere, eigenvalue 2
        >>> round(float((z @ (L @ z)) / (z @ (M @ z))), 2)
        2.0
    """
    triangulation = _triangulation_for(points, triangulation, n_neighbors=n_neighbors, mollify_factor=mollify_factor)
    return _operators(*_point_cloud_values(check_points(points), triangulation), triangulation)


def laplacian_and_mass_from_lengths_sq(lengths_sq, triangulation: PointCloudTriangulation) -> LaplacianAndMass:
    """`point_cloud_laplacian`'s `(L, M)` from the cover's replayed squared lengths (`face_lengths_sq`)."""
    return _operators(*_cover_values(lengths_sq, triangulation.plan), triangulation)


# One program per cloud size from the points to both operators' values, where the replay, `L`, `M` and
# the two divisions were five kept per size (issue 41; figures: benchmarks/README.md, "Memory").
@kernel
def _point_cloud_values(points: Float[Array, "n 3"], triangulation: PointCloudTriangulation):
    return _cover_values(triangulation.face_lengths_sq(points), triangulation.plan)


@kernel
def _cover_values(lengths_sq: Float[Array, "n_cover 3"], plan: TriangulationPlan):
    """The values of `L` (on `plan.pattern`) and of the diagonal `M` of the cover, divided by its multiplicity."""
    L = cotan_laplacian_from_lengths_sq(lengths_sq, plan) / _COVER_MULTIPLICITY
    M = mass_matrix_from_lengths_sq(lengths_sq, plan, mass="barycentric") / _COVER_MULTIPLICITY
    return L.values, M.values


def _operators(laplacian, mass, triangulation: PointCloudTriangulation) -> LaplacianAndMass:
    """`(L, M)` as `SparseMatrix`es from `_cover_values`' values, flagged as `L / 6` and `M / 6` are."""
    L = SparseMatrix(laplacian, triangulation.plan.pattern, symmetric=True, positive_semidefinite=True)
    return LaplacianAndMass(L, diagonal_matrix(mass, positive_semidefinite=True))


def point_cloud_normals(points: ArrayLike, *, n_neighbors: int = 30, neighbors=None) -> Float[Array, "n 3"]:
    """`(n, 3)` unit PCA normals: the direction of least spread of each point's `k` nearest neighbours.

    The eigenvector of the smallest eigenvalue of `sum_j (p_j - c)(p_j - c)^T` over the neighbours
    `j`, with `c` their mean (translation invariant; `point_cloud_laplacian`'s tangent planes follow
    robust_laplacian 1.1 instead, whose `c` is their sum over `k + 1`). Not oriented: each normal's sign is
    arbitrary (consistent orientation needs a global propagation, e.g. along a minimum spanning
    tree; not done here). Differentiable in `points` for the fixed neighbourhoods where the two
    smallest eigenvalues differ (pass `neighbors` under `jit` / `grad`).

    Args:
        points: `(n, 3)` finite positions.
        n_neighbors: the neighbourhood size `k` (keyword-only; default 30).
        neighbors: `(n, k)` neighbour indices to use (e.g. `point_cloud_triangulation(points).neighbors`),
            or `None` to find the `k` nearest on the host (keyword-only).

    Returns:
        `(n, 3)` unit normals.

    Open3D `estimate_normals`; robust_laplacian's `generate_normals` (about the offset centroid above).
    """
    points = check_points(points)
    if neighbors is None:
        if is_traced(points):
            raise DDGInputError(
                "points: the neighbourhoods are found on the host and need concrete positions; pass neighbors= "
                "(e.g. point_cloud_triangulation(points).neighbors) under jit / grad"
            )
        n_neighbors = check_neighbors(points.shape[0], n_neighbors)
        neighbors = nearest_neighbor_graph(np.asarray(points, dtype=np.float64), n_neighbors)
    neighbors = jnp.asarray(neighbors)
    if neighbors.ndim != 2 or neighbors.shape[0] != points.shape[0] or not jnp.issubdtype(neighbors.dtype, jnp.integer):
        raise DDGInputError(f"neighbors: expected an ({points.shape[0]}, k) integer array, got shape {neighbors.shape}")
    return _normals(points, neighbors)


@kernel
def _normals(points, neighbors):
    around = take_rows(points, neighbors.reshape(-1)).reshape(*neighbors.shape, 3)
    centred = around - jnp.mean(around, axis=1, keepdims=True)
    _, vectors = jnp.linalg.eigh(jnp.einsum("nki,nkj->nij", centred, centred))
    return vectors[:, :, 0]


def _triangulation_for(points, triangulation, **options) -> PointCloudTriangulation:
    if triangulation is None:
        return point_cloud_triangulation(points, **options)
    if not isinstance(triangulation, PointCloudTriangulation):
        raise DDGInputError(
            f"triangulation: expected a PointCloudTriangulation from point_cloud_triangulation(points), "
            f"got {type(triangulation).__name__}"
        )
    return triangulation
