"""The tufted intrinsic Delaunay triangulation of a point cloud, built on the host, replayed in JAX.

Sharp & Crane 2020 (section 5.7), robust_laplacian's `point_cloud_laplacian`, in these steps:

1. the `k` nearest neighbours of each point (itself excluded; SciPy's `cKDTree`);
2. a normal per point by PCA: the direction of least spread of the neighbours about their mean
   (robust_laplacian 1.1's);
3. the neighbours projected to the point's tangent plane, and the triangles of the 2-D Delaunay
   triangulation of the point and its projected neighbours that have the point as a corner (its
   1-ring). Vectorised over all points at once: an inversion about the point maps the circles
   through it to lines, so a triangle `(0, a, b)` has an empty circumcircle exactly when the inverted
   `a*`, `b*` are consecutive corners of the convex hull of the inverted neighbours with the origin
   on the hull's side of the line `a* b*`. The neighbours are sorted by angle (inversion keeps
   angles) and a Graham scan of every point at once pops the reflex corners of that star polygon,
   starting from a hull corner: the nearest neighbour, or, where an angular gap of about `pi` or
   more opens (a boundary, robust_laplacian's test), the neighbour after it. Consecutive hull
   corners less than `pi` apart (seen from the point) give the triangles. robust_laplacian walks
   the angular order with an `O(k^2)` emptiness test per point and a `1e-4` tolerance on the
   circumcircles; both give the Delaunay 1-ring in general position (the same `L` to 1e-15 on a
   jittered icosphere) and may differ on nearly co-circular neighbours (1-2% of the triangles of
   uniform samples), where either choice is a Delaunay 1-ring;
4. the union of all points' triangles, each kept as often as it appears (a triangle found by its
   three corners is there three times), is a non-manifold mesh; its edge lengths are mollified
   (`ddgjax.laplacian._intrinsic`: every edge lengthened by the smallest `delta` giving each triangle
   the triangle inequality with margin `mollify_factor` times the mean edge length), then its
   *tufted cover* is built: two copies of every triangle, one per orientation, glued around each
   edge in the angular order of the triangles about it (geometry-central
   `buildIntrinsicTuftedCover`), a closed oriented surface; then intrinsic Delaunay edge flips
   (`ddgjax.laplacian._intrinsic`'s rounds of independent flips). Steps 4's cover and flips are
   `ddgjax.laplacian._tufted`'s, which also serves `intrinsic_delaunay` on non-manifold meshes. Around an edge, triangles at the
   same angle (copies of one triangle) are glued in list order; geometry-central's order there is
   its sort's, so near coincident points, where such ties and flips interact, the two covers may
   differ (both intrinsic Delaunay: every weight `>= 0`; 10% of the entries of `L` on 2,000 uniform
   samples, with the same spectrum to 1e-3);
5. `L` and `M` (lumped, a third of each triangle's area per corner) of that cover, divided by 2
   (the cover has every triangle twice) and by 3 (each triangle is there about three times), as
   geometry-central `buildTuftedLaplacian` and robust_laplacian do.

Steps 1-4 depend on the positions only through comparisons and run once on the host; the result, a
`PointCloudTriangulation`, replays the metric in JAX: the squared lengths of the mesh's edges from
the positions, the mollification, and the recorded flips (`ddgjax.laplacian._intrinsic`'s replay
kernel), so `L` and `M` are differentiable functions of the positions for the fixed neighbourhood
graph and flips (exact away from the measure-zero positions where a comparison ties).

References: N. Sharp, K. Crane, "A Laplacian for nonmanifold triangle meshes", Computer Graphics
Forum 39(5) (SGP 2020). robust_laplacian `point_cloud_laplacian(P, mollify_factor=1e-5, n_neighbors=30)`;
potpourri3d `PointCloudLocalTriangulation(P).get_local_triangulation()` (the local triangles).
"""

from __future__ import annotations

import equinox as eqx
import numpy as np
import scipy.spatial
from jaxtyping import Array, ArrayLike, Float, Int

from .._compile import device_array
from .._errors import DDGInputError, check_count, check_finite, check_float_shape, is_traced
from ..laplacian import TriangulationPlan, triangulation_plan
from ..laplacian.internal import replayed_lengths_sq, tufted_delaunay

# robust_laplacian's thresholds, relative to the neighbourhood radius (its farthest neighbour): a
# neighbour this close to the centre is pushed out to it, and two neighbours within this angle
# (seen from the centre, radians) form no triangle.
_COINCIDENT = 1e-7
_COLLINEAR = 1e-5


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
    """`(n, k)` the `k` nearest other points of each point, nearest first (SciPy `cKDTree`, every core).

    A point is not its own neighbour, also where coincident points tie with it (geometry-central's
    `NearestNeighborFinder.kNearestNeighbors(i, k)`).
    """
    n = points.shape[0]
    _, found = scipy.spatial.cKDTree(points).query(points, k=n_neighbors + 1, workers=-1)
    others = found != np.arange(n)[:, None]
    # Each row holds its own index at most once: drop it, or the farthest when a tie hid it.
    others[others.all(axis=1), -1] = False
    return found[others].reshape(n, n_neighbors).astype(np.int32)


def _host_normals(points: np.ndarray, neighbors: np.ndarray) -> np.ndarray:
    """`(n, 3)` PCA normals (module docstring, step 2), on the host: the triangulation's tangent planes."""
    around = points[neighbors]
    centred = around - around.mean(axis=1, keepdims=True)
    _, vectors = np.linalg.eigh(np.einsum("nki,nkj->nij", centred, centred))
    return vectors[:, :, 0]


def local_triangles(points: np.ndarray, neighbors: np.ndarray) -> np.ndarray:
    """`(nf, 3)` the union of each point's local Delaunay 1-ring triangles `(i, a, b)` (module docstring, step 3).

    Counterclockwise about each point's normal; a triangle found from several of its corners is
    listed once per corner (robust_laplacian keeps them all).
    """
    n, k = neighbors.shape
    normals = _host_normals(points, neighbors)
    # An orthonormal tangent basis per point: any one serves (only angles and circles are compared).
    helper = np.where(np.abs(normals[:, :1]) < 0.9, np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, 1.0, 0.0]]))
    e1 = np.cross(normals, helper)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(normals, e1)
    offsets = points[neighbors] - points[:, None, :]
    x, y = np.einsum("nkd,nd->nk", offsets, e1), np.einsum("nkd,nd->nk", offsets, e2)
    radius_sq = x * x + y * y
    scale = np.sqrt(radius_sq.max(axis=1, keepdims=True))
    # Neighbours (nearly) at the centre are pushed out to a tiny distance, spread by index, as robust_laplacian does.
    close = radius_sq < (_COINCIDENT * scale) ** 2
    if close.any():
        spread = 2.0 * np.pi * np.arange(k) / k
        angle = np.where(radius_sq > 0, np.arctan2(y, x), spread)
        pushed = (1.0 + np.arange(k) / k) * scale * _COINCIDENT * 10.0
        x, y = np.where(close, pushed * np.cos(angle), x), np.where(close, pushed * np.sin(angle), y)
        radius_sq = x * x + y * y
    angles = np.arctan2(y, x)
    order = np.argsort(angles, axis=1, kind="stable")
    rows = np.arange(n)[:, None]
    angles = angles[rows, order]
    # A gap of about pi or more between angularly consecutive neighbours is the boundary (robust_laplacian's test):
    # the scan then starts after it and does not close; otherwise it starts at the nearest neighbour (a hull corner).
    gaps = np.diff(angles, axis=1, append=angles[:, :1] + 2.0 * np.pi)
    widest = np.argmax(gaps, axis=1)
    boundary = gaps[np.arange(n), widest] > np.pi - _COLLINEAR
    nearest = np.argmin(radius_sq[rows, order], axis=1)
    first = np.where(boundary, (widest + 1) % k, nearest)
    order = order[rows, (first[:, None] + np.arange(k)) % k]
    x, y, radius_sq = x[rows, order], y[rows, order], radius_sq[rows, order]
    # Inverted about the centre, the 1-ring is the hull of these (docstring), found by a Graham scan of every row at once.
    u, v = x / radius_sq, y / radius_sq
    unit_x, unit_y = x / np.sqrt(radius_sq), y / np.sqrt(radius_sq)
    # Flat (row-major) copies: one 1-d gather per quantity is several times faster than 2-d fancy indexing.
    flat_u, flat_v, flat_ux, flat_uy = (np.ravel(a) for a in (u, v, unit_x, unit_y))
    stack = np.zeros((n, k + 1), dtype=np.int64)  # flat indices into the row-major (n, k) arrays
    stack[:, 0] = np.arange(n) * k
    size = np.ones(n, dtype=np.int64)
    every = np.arange(n)
    for j in range(1, k + 1):
        live = every if j < k else every[~boundary]
        q = live * k + j % k
        while live.size:
            top, below = stack[live, size[live] - 1], stack[live, size[live] - 2]
            ut, vt, ub, vb, uq, vq = flat_u[top], flat_v[top], flat_u[below], flat_v[below], flat_u[q], flat_v[q]
            # Pop a top inside the triangle (centre, below, q): a right or no turn, below and q less than pi apart.
            turn = (ut - ub) * (vq - vt) - (vt - vb) * (uq - ut)
            within_pi = flat_ux[below] * flat_uy[q] - flat_uy[below] * flat_ux[q] > 0
            pop = (size[live] >= 2) & (turn <= 0) & within_pi
            size[live[pop]] -= 1
            pushed = ~pop
            stack[live[pushed], size[live[pushed]]] = q[pushed]
            size[live[pushed]] += 1
            live, q = live[pop], q[pop]
    stack %= k  # back to slots (entries past each size are unused)
    # Consecutive hull corners less than pi apart (seen from the centre) form a triangle with it.
    a, b = stack[:, :-1], stack[:, 1:]
    cross = unit_x[rows, a] * unit_y[rows, b] - unit_y[rows, a] * unit_x[rows, b]
    keep = (np.arange(k)[None, :] < size[:, None] - 1) & (cross > _COLLINEAR)
    point, slot = np.nonzero(keep)
    sorted_neighbors = neighbors[rows, order]
    return np.stack([point, sorted_neighbors[point, a[point, slot]], sorted_neighbors[point, b[point, slot]]], axis=1).astype(
        np.int32
    )


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
