"""The tufted intrinsic Delaunay triangulation of a point cloud, built on the host, replayed in JAX.

Sharp & Crane 2020 (section 5.7): robust_laplacian 1.1's `point_cloud_laplacian`, step for step, so
that the operators equal its own entry by entry (to round-off) wherever its choices are decided by
the data, and its tie-breaking is replayed where they are not:

1. the `k` nearest neighbours of each point, itself excluded, ties (duplicated points, grids) in
   nanoflann's order (`_kdtree`: SciPy finds them, a replica of nanoflann's tree orders the ties);
2. a normal per point: the smallest left singular vector of the neighbours' offsets from
   `sum_j p_j / (k + 1)` (robust_laplacian's centroid, over `k + 1` though only the `k` neighbours
   are summed), signed as Eigen's `JacobiSVD` signs it (`_jacobi_svd`): the sign decides which way
   step 3's walk turns, and so which of nearly co-circular triangles it keeps;
3. the neighbours projected to geometry-central's tangent basis of that normal; those within `1e-7`
   of the farthest neighbour's projected distance pushed out to `1e-6` of it; sorted by angle
   (`std::sort`, its order among equal angles replayed: `ddgjax._stdsort`); a walk from the nearest
   neighbour (or, after an angular gap of at least `pi - 1e-5` between sorted neighbours, from the
   neighbour after it, without closing the fan) that joins the current neighbour to the first one
   after it, not within `1e-5` radians, whose circumcircle with the point holds no other neighbour
   by more than `1e-4` of the farthest distance, and goes on from there: the point's fan
   `(i, a, b)` (`local_triangles`);
4. the union of all fans, each triangle kept as often as it is found, is a non-manifold mesh; its
   edge lengths are mollified (`ddgjax.laplacian._intrinsic`: every edge lengthened by the smallest
   `delta` giving each triangle the triangle inequality with margin `mollify_factor` times the mean
   edge length), then its tufted cover is built and flipped to intrinsic Delaunay
   (`ddgjax.laplacian._tufted`: triangles glued around each edge in geometry-central's angular order,
   its ties and NaN angles as its sort leaves them; an edge is flipped where its cotan weight is below
   `-1e-6`, its `flipToDelaunay` tolerance);
5. `L` and `M` (lumped, a third of each triangle's area per corner) of that cover, divided by 2
   (the cover has every triangle twice) and by 3 (each triangle is there about three times), as
   geometry-central `buildTuftedLaplacian` and robust_laplacian do.

What remains different: the flips run in rounds of independent flips, geometry-central's one at a
time from a queue. Where both end Delaunay but differently (quads within the tolerance of
co-circular, at coincident points), `L` agrees to 1e-10 and `M` moves area between the coincident
copies (the sum over them agrees): 30 of 2,500 rows of `M` on 2,000 samples of spot with 500 of them
duplicated; none on 50,000 bunny samples, mesh-vertex clouds or coplanar points. A point in no
triangle keeps an empty row and a zero mass here, where robust_laplacian strips it and gives it
`L_ii = 1` and a thousandth of the smallest mass.

Steps 1-4 depend on the positions only through comparisons and run once on the host; the result, a
`PointCloudTriangulation`, replays the metric in JAX: the squared lengths of the mesh's edges from
the positions, the mollification, and the recorded flips (`ddgjax.laplacian._intrinsic`'s replay
kernel), so `L` and `M` are differentiable functions of the positions for the fixed neighbourhood
graph and flips (exact away from the measure-zero positions where a comparison ties).

References: N. Sharp, K. Crane, "A Laplacian for nonmanifold triangle meshes", Computer Graphics
Forum 39(5) (SGP 2020). robust_laplacian `point_cloud_laplacian(P, mollify_factor=1e-5, n_neighbors=30)`
(its `point_cloud_utilities.cpp`: `generate_knn`, `generate_normals`, `generate_coords_projection`,
`build_delaunay_triangulations`); potpourri3d `PointCloudLocalTriangulation(P)` builds fans too, by
another walk (geometry-central `buildLocalTriangulations`).
"""

from __future__ import annotations

import equinox as eqx
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int

from .._compile import device_array
from .._errors import DDGInputError, check_count, check_finite, check_float_shape, is_traced
from .._stdsort import std_sort_order
from ..laplacian import TriangulationPlan, triangulation_plan
from ..laplacian.internal import replayed_lengths_sq, tufted_delaunay
from ._jacobi_svd import smallest_left_singular_vectors
from ._kdtree import nanoflann_neighbors

# robust_laplacian's thresholds: a neighbour closer to the centre than this (relative to the farthest
# neighbour's projected distance) is pushed out; two neighbours within this angle (radians, seen from
# the centre) form no triangle; a circumcircle is empty when no neighbour is inside it by more than
# this (relative, as the first).
_COINCIDENT = 1e-7
_COLLINEAR = 1e-5
_OUTSIDE = 1e-4


class PointCloudTriangulation(eqx.Module):
    """A point cloud's tufted intrinsic Delaunay triangulation (module docstring), replayable in JAX.

    Made by `point_cloud_triangulation(points)`. Pass it as `triangulation=` to the operators to reuse
    it, inside `jit` and `grad` too.

    Attributes:
        neighbors: `(n, k)` each point's `k` nearest neighbours, nearest first.
        plan: the flipped cover's faces `(n_cover, 3)` and the storage plan of their operators.
        edges: `(ne, 2)` the distinct point pairs joined by a local triangle's edge.
        face_edges: `(nf, 3)` the distinct edge opposite each corner of the local triangles (what the
            mollification reads).
        flip_slots: `(n_steps, 5, width)` the replay's flips (`ddgjax.laplacian.IntrinsicTriangulation`).
        face_length_slots: `(n_cover, 3)` where the replay keeps the length of each cover face's edges.
        n_points: the number of points (static).
        mollify_factor: the mollification margin relative to the mean edge length (static).
    """

    neighbors: Int[Array, "n k"]
    plan: TriangulationPlan
    edges: Int[Array, "ne 2"]
    face_edges: Int[Array, "nf 3"]
    flip_slots: Int[Array, "n_steps 5 width"]
    face_length_slots: Int[Array, "n_cover 3"]
    n_points: int = eqx.field(static=True)
    mollify_factor: float = eqx.field(static=True)

    @property
    def faces(self) -> Int[Array, "n_cover 3"]:
        """`(n_cover, 3)` the faces of the flipped tufted cover (a Delta-complex on the points)."""
        return self.plan.faces

    def face_lengths_sq(self, points: ArrayLike) -> Float[Array, "n_cover 3"]:
        """`(n_cover, 3)` squared intrinsic length of the edge opposite each corner of `self.faces`.

        The local triangles' squared edge lengths from `points`, mollified, then the flips replayed:
        differentiable in `points` under jit, grad and vmap.
        """
        points = check_points(points)
        if points.shape[0] != self.n_points:
            raise DDGInputError(
                f"points: the triangulation was built for {self.n_points} points, got {points.shape[0]}; "
                "build it with point_cloud_triangulation(points) for this cloud"
            )
        return replayed_lengths_sq(
            points, self.edges, self.face_edges, self.flip_slots, self.face_length_slots, mollify_factor=self.mollify_factor
        )


def check_points(points) -> Float[Array, "n 3"]:
    """`points` as a JAX array after refusing a shape other than `(n, 3)`, `n >= 1`, and NaN / inf in concrete values."""
    check_float_shape("points", points, (3,))
    if not is_traced(points):
        check_finite("points", np.asarray(points))
    points = device_array(points)
    return points if np.issubdtype(points.dtype, np.floating) else points.astype(float)


def check_neighbors(n_points: int, n_neighbors) -> int:
    """`n_neighbors` checked: an integer in `[2, n - 1]` (a point has `n - 1` others)."""
    n_neighbors = check_count("n_neighbors", n_neighbors, minimum=2)
    if n_neighbors > n_points - 1:
        raise DDGInputError(
            f"n_neighbors: expected at most n - 1 = {n_points - 1} (the other points of a cloud of {n_points}), "
            f"got {n_neighbors}; pass a smaller n_neighbors or more points"
        )
    return n_neighbors


def nearest_neighbor_graph(points: np.ndarray, n_neighbors: int) -> np.ndarray:
    """`(n, k)` the `k` nearest other points of each point, nearest first, ties in nanoflann's order (`_kdtree`).

    Its `k + 1` nearest with the point itself taken out, or the farthest where coincident points hid it
    (geometry-central's `NearestNeighborFinder.kNearestNeighbors(i, k)`).
    """
    n = points.shape[0]
    found = nanoflann_neighbors(points, n_neighbors)
    others = found != np.arange(n)[:, None]
    # Each row holds its own index at most once: drop it, or the farthest when a tie hid it.
    others[others.all(axis=1), -1] = False
    return found[others].reshape(n, n_neighbors).astype(np.int32)


def tangent_coordinates(points: np.ndarray, neighbors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`(x, y)` `(n, k)`: each point's neighbours projected to its tangent plane (module docstring, steps 2-3).

    The normal is the smallest left singular vector of the offsets `p_j - c` from `c = sum_j p_j / (k + 1)`
    (robust_laplacian's centroid: the neighbours' sum over `k + 1`), with Eigen's sign (`_jacobi_svd`);
    the tangent basis is geometry-central's `Vector3::buildTangentBasis` of it, and each offset
    `p_j - p_i` loses its normal component before its two coordinates are taken.
    """
    n, k = neighbors.shape
    around = points[neighbors]
    centroid = around.sum(axis=1) / (k + 1)
    normals = smallest_left_singular_vectors(np.swapaxes(around - centroid[:, None, :], 1, 2))
    test = np.where(np.abs(normals[:, :1]) > 0.9, [[0.0, 1.0, 0.0]], [[1.0, 0.0, 0.0]])
    basis_x = _normalized(np.cross(test, normals))
    basis_y = _normalized(np.cross(normals, basis_x))
    offsets = around - points[:, None, :]
    offsets = offsets - normals[:, None, :] * _dot(normals[:, None, :], offsets)[..., None]
    return _dot(basis_x[:, None, :], offsets), _dot(basis_y[:, None, :], offsets)


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    # Summed left to right, as geometry-central's `dot`: the walk's decisions compare such values.
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]


def _normalized(vectors: np.ndarray) -> np.ndarray:
    return vectors * (1.0 / np.sqrt(_dot(vectors, vectors)))[..., None]


def local_triangles(points: np.ndarray, neighbors: np.ndarray) -> np.ndarray:
    """`(nf, 3)` the union of each point's local triangles `(i, a, b)` (module docstring, step 3), robust_laplacian's.

    Point after point, each point's triangles in the order its walk finds them (the tufted cover's ties
    follow this order); a triangle found from several of its corners is listed once per corner.
    """
    n, k = neighbors.shape
    x, y = tangent_coordinates(points, neighbors)
    scale = np.sqrt(x[:, -1] ** 2 + y[:, -1] ** 2)  # the farthest neighbour's projected distance
    radius = np.sqrt(x * x + y * y)
    close = radius < scale[:, None] * _COINCIDENT
    if close.any():
        # Pushed out along their own direction, or (where they sit on the centre) one spread by index.
        with np.errstate(divide="ignore", invalid="ignore"):
            inverse = 1.0 / radius
            direction_x, direction_y = x * inverse, y * inverse
        undefined = ~(np.isfinite(direction_x) & np.isfinite(direction_y))
        spread = 2.0 * np.pi * np.arange(k) / k
        direction_x = np.where(undefined, np.cos(spread), direction_x)
        direction_y = np.where(undefined, np.sin(spread), direction_y)
        pushed = (1.0 + np.arange(k) / k) * scale[:, None] * _COINCIDENT * 10.0
        x, y = np.where(close, pushed * direction_x, x), np.where(close, pushed * direction_y, y)
        radius = np.sqrt(x * x + y * y)
    nearest = np.argmin(radius, axis=1)
    angles = np.arctan2(y, x)
    order = angular_order(angles)
    rows = np.arange(n)[:, None]
    sorted_angles = angles[rows, order]
    # The widest gap between angular neighbours, the wrap-around one left out (robust_laplacian's loop never
    # counts it); one of about pi or more is the boundary, and the walk starts after it and does not close.
    gaps = np.diff(sorted_angles, axis=1)
    widest = np.argmax(gaps, axis=1)
    boundary = gaps[rows[:, 0], widest] > np.pi - _COLLINEAR
    first = np.where(boundary, widest + 1, np.argmax(order == nearest[:, None], axis=1))
    order = order[rows, (first[:, None] + np.arange(k)) % k]
    # The walk reads the neighbours in their walking order: slot s of a row is its s-th neighbour from the start.
    x, y = x[rows, order], y[rows, order]
    with np.errstate(divide="ignore", invalid="ignore"):
        inverse = 1.0 / np.sqrt(x * x + y * y)
    flat_x, flat_y, flat_ux, flat_uy = (np.ravel(a) for a in (x, y, x * inverse, y * inverse))
    last = np.where(boundary, k, k + 1)
    tolerance = scale * _OUTSIDE
    start, end, count = np.zeros(n, dtype=np.int64), np.ones(n, dtype=np.int64), np.zeros(n, dtype=np.int64)
    found: list[tuple[np.ndarray, ...]] = []
    live = np.flatnonzero(np.isfinite(scale) & (scale > 0))  # no triangle at a hopeless neighbourhood
    while live.size:
        # Flat (row-major) indices: 1-d gathers are several times faster than 2-d fancy indexing.
        a, b = live * k + start[live], live * k + end[live] % k
        ax, ay, bx, by = flat_x[a], flat_y[a], flat_x[b], flat_y[b]
        adx, ady, bdx, bdy = flat_ux[a], flat_uy[a], flat_ux[b], flat_uy[b]
        collinear = np.abs(adx * bdy - ady * bdx) < _COLLINEAR
        # The circumcentre meets the two bisectors, as geometry-central's `rayRayIntersection` does.
        v1x, v1y = 0.5 * ax - 0.5 * bx, 0.5 * ay - 0.5 * by
        # Collinear pairs (refused below) divide by zero here.
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (bdy * v1y - -bdx * v1x) / (bdy * -adx + -bdx * -ady)
            centre_x, centre_y = 0.5 * ax + t * -ady, 0.5 * ay + t * adx
            circumradius = np.sqrt(centre_x * centre_x + centre_y * centre_y)
            distance_sq = (centre_x[:, None] - np.take(x, live, axis=0)) ** 2 + (
                centre_y[:, None] - np.take(y, live, axis=0)
            ) ** 2
        local = np.arange(live.size) * k
        distance_sq.ravel()[local + a % k] = np.inf
        distance_sq.ravel()[local + b % k] = np.inf
        # Accepted when no other neighbour is inside the circle by more than the tolerance.
        accept = ~collinear & (np.sqrt(distance_sq.min(axis=1)) + tolerance[live] > circumradius)
        taken = live[accept]
        found.append((taken, count[taken], a[accept] % k, b[accept] % k))
        count[taken] += 1
        start[taken] = end[taken]
        missed = live[~accept]
        end[missed] += 1
        exhausted = missed[end[missed] >= last[missed]]
        start[exhausted] += 1
        end[taken], end[exhausted] = start[taken] + 1, start[exhausted] + 1
        live = live[start[live] < k]
    point, sequence, a, b = (np.concatenate(parts) for parts in zip(*found)) if found else (np.zeros(0, np.int64),) * 4
    listed = np.lexsort((sequence, point))
    point, a, b = point[listed], a[listed], b[listed]
    walked = neighbors[rows, order]
    return np.stack([point, walked[point, a], walked[point, b]], axis=1).astype(np.int32)


def angular_order(angles: np.ndarray) -> np.ndarray:
    """`(n, k)` each row's slots by increasing angle, equal angles where libstdc++'s `std::sort` leaves them.

    robust_laplacian sorts the slots `0..k-1` with `std::sort` (not stable); rows without equal angles
    need no more than NumPy's sort, the others are sorted as libstdc++ does (`ddgjax._stdsort`).
    """
    order = np.argsort(angles, axis=1, kind="stable")
    ordered = np.take_along_axis(angles, order, axis=1)
    for row in np.flatnonzero(np.any(ordered[:, 1:] == ordered[:, :-1], axis=1)):
        order[row] = std_sort_order(angles[row].tolist())
    return order


def point_cloud_triangulation(
    points: ArrayLike, *, n_neighbors: int = 30, mollify_factor: float = 1e-5
) -> PointCloudTriangulation:
    """Build a point cloud's tufted intrinsic Delaunay triangulation on the host (module docstring, steps 1-4).

    Once per cloud (the neighbourhoods and flips depend on the positions); pass the result as
    `triangulation=` to `point_cloud_laplacian` and the heat method to reuse it, or to use them
    inside `jit` / `grad` (the positions may then move: the graph and flips stay fixed).

    Args:
        points: `(n, 3)` concrete, finite positions.
        n_neighbors: the neighbourhood size `k`, `2 <= k <= n - 1` (robust_laplacian's default 30).
        mollify_factor: the mollification margin relative to the mean edge length, `>= 0`
            (robust_laplacian's `mollify_factor`, default `1e-5`).

    Returns:
        `PointCloudTriangulation`.

    Raises `DDGInputError` for a bad shape, NaN / inf, traced points, or a bad `n_neighbors` /
    `mollify_factor`. robust_laplacian builds the same operators without keeping the triangulation.
    """
    points = check_points(points)
    if is_traced(points):
        raise DDGInputError(
            "points: point_cloud_triangulation builds the neighbourhoods and flips on the host and needs concrete "
            "positions; build it outside jit / grad and pass triangulation= to the operators"
        )
    n = points.shape[0]
    n_neighbors = check_neighbors(n, n_neighbors)
    if not (np.isscalar(mollify_factor) and np.isreal(mollify_factor) and np.isfinite(mollify_factor) and mollify_factor >= 0):
        raise DDGInputError(f"mollify_factor: expected a finite number >= 0 (default 1e-5), got {mollify_factor!r}")
    host = np.asarray(points, dtype=np.float64)
    neighbors = nearest_neighbor_graph(host, n_neighbors)
    faces = local_triangles(host, neighbors)
    if faces.shape[0] == 0:
        raise DDGInputError("points: the cloud has no local triangle (every neighbourhood is degenerate: coincident points?)")
    cover = tufted_delaunay(host, faces, float(mollify_factor))
    return PointCloudTriangulation(
        neighbors=device_array(neighbors),
        plan=triangulation_plan(cover.faces, n),
        edges=device_array(cover.edges),
        face_edges=device_array(cover.face_edges),
        flip_slots=device_array(cover.flip_slots),
        face_length_slots=device_array(cover.face_length_slots),
        n_points=n,
        mollify_factor=float(mollify_factor),
    )
