"""Point-set losses: the Chamfer distance (k-d trees or brute force) and area-uniform point samples of a mesh.

`chamfer_distance` needs each point's nearest neighbour in the other cloud. Two searches, chosen by
`method=` (`NEAREST_NEIGHBOR_METHODS`):

- `"kdtree"`: SciPy's `cKDTree` on the host through `jax.pure_callback` (both trees built at once
  on two threads, queries on every core): `O(n log n)`, the CPU's choice from ~1,000 points up.
- `"brute"`: all pairwise squared distances in JAX, a chunk of rows at a time, so two clouds of 10k
  points need ~`chunk_size * n_b` floats of memory rather than `n_a * n_b`; no host round trip,
  the exact search for an accelerator.
- `"auto"` (default): `"kdtree"` on a CPU backend, `"brute"` on an accelerator and for small clouds
  (at most 2^20 pairs `na * nb`, where it is as fast on a CPU).

Both give the same indices, ties included: an exact tie (equal squared distances, computed
coordinate by coordinate in the points' dtype) goes to the lowest index. The k-d tree finds the
two nearest points; where they are within rounding of a tie, every point of the ball of that
radius is compared the brute force's way. A non-finite point (NaN / inf) is never the nearest
point of a finite one (the loss is then non-finite through its own term).

The search itself is not differentiated (nearest indices are integers); the loss is then
recomputed in JAX from the gathered nearest points, `|a_i - b_{nn(i)}|^2`, so the gradient is
exact where the nearest neighbour is unique (the loss is piecewise smooth: it has kinks where two
candidates tie) and flows to both the query point and its nearest point, as in PyTorch3D.
"""

from __future__ import annotations

import concurrent.futures
import ctypes
import functools
import os
import sys
from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int, PRNGKeyArray

from .._compile import kernel
from .._errors import DDGInputError, check_choice, check_count, check_finite, check_float_shape, is_traced
from .._indexing import take_rows
from .._numerics import safe_normalize
from ..mesh import Mesh, face_area_vectors, face_areas, face_vertex_positions, require_mesh

#: The values of `method=` of `nearest_neighbors` and `chamfer_distance` (module docstring).
NEAREST_NEIGHBOR_METHODS = ("auto", "kdtree", "brute")

# `"auto"` on a CPU keeps the brute force up to this many pairs: measured as fast as the k-d tree at
# 1,000 x 1,000 points and faster below, where the host round trip dominates (benchmarks/README.md).
_SMALL_PAIRS = 1 << 20

# Pairwise distances per chunk: rows * columns stays under this many entries (32 MiB of float64).
_CHUNK_ENTRIES = 1 << 22


def chamfer_distance(
    points_a: Float[ArrayLike, "na d"],
    points_b: Float[ArrayLike, "nb d"],
    *,
    method: str = "auto",
    chunk_size: int | None = None,
) -> Float[Array, ""]:
    """Symmetric Chamfer distance `mean_a min_b |a - b|^2 + mean_b min_a |a - b|^2`, a scalar `()`.

    Squared Euclidean distances, each direction averaged over its points, summed: PyTorch3D's
    `chamfer_distance(a[None], b[None])[0]` with its defaults (`point_reduction="mean"`, squared
    norms). Exact, and differentiable in both point sets (module docstring); works under `jit`,
    `grad` and `vmap`.

    Args:
        points_a: `(na, d)` points (any dimension `d`, e.g. 3).
        points_b: `(nb, d)` points.
        method: the nearest-neighbour search, one of `NEAREST_NEIGHBOR_METHODS`: `"auto"` (default:
            `"kdtree"` on a CPU backend, `"brute"` on an accelerator and up to 2^20 pairs
            `na * nb`), `"kdtree"` (SciPy on the host), `"brute"` (chunked pairwise distances in
            JAX). Both give the same indices, so the same value and gradient.
        chunk_size: `"brute"` only: rows of `points_a` per block of pairwise distances (static);
            default: as many as keep a block under 2^22 entries.

    Returns:
        The Chamfer distance, in squared length units.

    Reference: H. Fan, H. Su, L. Guibas, "A point set generation network for 3D object
    reconstruction from a single image" (CVPR 2017). PyTorch3D: `pytorch3d.loss.chamfer_distance`;
    SciPy: `cKDTree(b).query(a)[0] ** 2` averaged, and the other way round.
    """
    method, rows = _checked(points_a, points_b, method, chunk_size)
    return _chamfer(points_a, points_b, method=method, chunk_size=rows)


class NearestNeighbors(NamedTuple):
    """What `nearest_neighbors` returns (a named tuple: `in_b, in_a = nearest_neighbors(a, b)` still unpacks).

    Attributes:
        nearest_in_b: `(na,)` for each point of `points_a`, the index of its nearest point of `points_b`.
        nearest_in_a: `(nb,)` for each point of `points_b`, the index of its nearest point of `points_a`.
    """

    nearest_in_b: Int[Array, " na"]
    nearest_in_a: Int[Array, " nb"]


def nearest_neighbors(
    points_a: Float[ArrayLike, "na d"],
    points_b: Float[ArrayLike, "nb d"],
    *,
    method: str = "auto",
    chunk_size: int | None = None,
) -> NearestNeighbors:
    """Indices of the nearest point of `points_b` for each point of `points_a`, and the other way round.

    `nearest_in_b[i] = argmin_j |a_i - b_j|^2` and `nearest_in_a[j] = argmin_i |a_i - b_j|^2`
    (squared Euclidean distances, computed coordinate by coordinate); ties go to the lowest index,
    with either method (module docstring). Not differentiable (integer output; the inputs are held
    fixed). Works under `jit` and `vmap` (a batch shares the k-d tree of an unbatched cloud).

    Args:
        points_a: `(na, d)` points.
        points_b: `(nb, d)` points of the same dimension.
        method: `"auto"` (default), `"kdtree"` or `"brute"` (`chamfer_distance`).
        chunk_size: `"brute"` only: rows of `points_a` per block (static); default: blocks under 2^22 entries.

    Returns:
        `NearestNeighbors(nearest_in_b (na,), nearest_in_a (nb,))`, int32.

    Equivalent: `scipy.spatial.cKDTree(points_b).query(points_a)[1]` (and the other way round; its
    ties go to whichever point the tree meets first); PyTorch3D `knn_points(a, b, K=1).idx`.
    """
    method, rows = _checked(points_a, points_b, method, chunk_size)
    return _nearest(points_a, points_b, method=method, chunk_size=rows)


def _checked(points_a, points_b, method: str, chunk_size: int | None) -> tuple[str, int]:
    """The search that runs (`"auto"` resolved) and the brute force's rows per chunk, or `DDGInputError`."""
    _check_points("points_a", points_a)
    _check_points("points_b", points_b)
    (na, d), (nb, d_b) = np.shape(points_a), np.shape(points_b)
    if d != d_b:
        raise DDGInputError(f"points_b: expected points of dimension {d} like points_a, got {d_b}")
    check_choice("method", method, NEAREST_NEIGHBOR_METHODS)
    if method == "auto":
        method = "kdtree" if jax.default_backend() == "cpu" and na * nb > _SMALL_PAIRS else "brute"
    rows = max(1, min(na, _CHUNK_ENTRIES // nb)) if chunk_size is None else check_count("chunk_size", chunk_size)
    return method, min(rows, na)


@kernel(static_argnames=("method", "chunk_size"))
def _chamfer(points_a, points_b, *, method: str, chunk_size: int):
    nearest_in_b, nearest_in_a = _nearest(points_a, points_b, method=method, chunk_size=chunk_size)
    to_b = points_a - take_rows(points_b, nearest_in_b)
    to_a = points_b - take_rows(points_a, nearest_in_a)
    return jnp.mean(jnp.sum(to_b * to_b, axis=-1)) + jnp.mean(jnp.sum(to_a * to_a, axis=-1))


@kernel(static_argnames=("method", "chunk_size"))
def _nearest(points_a, points_b, *, method: str, chunk_size: int) -> NearestNeighbors:
    a = jax.lax.stop_gradient(points_a)
    b = jax.lax.stop_gradient(points_b)
    if method == "kdtree":
        shapes = (jax.ShapeDtypeStruct(a.shape[:1], jnp.int32), jax.ShapeDtypeStruct(b.shape[:1], jnp.int32))
        # "expand_dims": one host call per batch, which builds each distinct cloud's tree once.
        return NearestNeighbors(*jax.pure_callback(_host_nearest, shapes, a, b, vmap_method="expand_dims"))
    return _brute_nearest(a, b, chunk_size)


# --- the brute force -------------------------------------------------------------------------------


def _brute_nearest(a, b, rows: int) -> NearestNeighbors:
    """One pass over row chunks of `a` (a `lax.scan`): each chunk's pairwise squared distances give
    the chunk's row minima and update running column minima."""
    dtype = jnp.result_type(a.dtype, b.dtype, float)
    # A non-finite point moves to the largest float: at infinite distance from every finite point.
    a, b = (jnp.where(jnp.all(jnp.isfinite(x), axis=1, keepdims=True), x, jnp.finfo(dtype).max).astype(dtype) for x in (a, b))
    na, nb = a.shape[0], b.shape[0]
    n_chunks = -(-na // rows)
    # Padding rows (zeros) are masked out of the column minima and cut off the row answers at the end.
    padded = jnp.concatenate([a, jnp.zeros((n_chunks * rows - na, a.shape[1]), a.dtype)])
    row_ids = jnp.arange(rows, dtype=jnp.int32)

    def chunk(carry, start):
        best_sq, best_index = carry
        block = jax.lax.dynamic_slice_in_dim(padded, start, rows)
        # Coordinate by coordinate: exact (no |a|^2 + |b|^2 - 2 a.b cancellation), and on XLA:CPU
        # several times faster than a matrix product with a contraction of length 3.
        d2 = sum((block[:, k, None] - b[None, :, k]) ** 2 for k in range(b.shape[1]))
        d2 = jnp.where((start + row_ids < na)[:, None], d2, jnp.inf)
        row_sq, row_index = _min_and_first_index(d2, axis=1)
        column_sq, column_index = _min_and_first_index(d2, axis=0)
        better = column_sq < best_sq
        carry = (jnp.where(better, column_sq, best_sq), jnp.where(better, start + column_index, best_index))
        return carry, row_index

    start = (jnp.full((nb,), jnp.inf, dtype), jnp.zeros((nb,), jnp.int32))
    (_, nearest_in_a), nearest_in_b = jax.lax.scan(chunk, start, jnp.arange(n_chunks, dtype=jnp.int32) * rows)
    return NearestNeighbors(nearest_in_b.reshape(-1)[:na].astype(jnp.int32), nearest_in_a.astype(jnp.int32))


def _min_and_first_index(d2: Float[Array, "m n"], axis: int) -> tuple[Float[Array, " k"], Int[Array, " k"]]:
    """Minimum along `axis` and the first index attaining it. Two plain reductions: XLA:CPU runs
    them about twice as fast as `argmin`'s variadic (value, index) reduction."""
    smallest = jnp.min(d2, axis=axis, keepdims=True)
    n = d2.shape[axis]
    ids = jnp.expand_dims(jnp.arange(n, dtype=jnp.int32), 1 - axis)
    return jnp.squeeze(smallest, axis), jnp.min(jnp.where(d2 == smallest, ids, n), axis=axis)


# --- the k-d tree (host) ---------------------------------------------------------------------------

# Ball queries resolving near-ties are made a block of rows at a time, under this many candidates.
_TIE_CANDIDATES = 1 << 22


class _Tree(NamedTuple):
    """A cloud's k-d tree over its finite points, with what the tie rule needs."""

    points: np.ndarray  # (n, d) in the dtype distances are compared in
    finite: np.ndarray  # (n,) bool
    tree: object  # cKDTree of the finite points (float64), or None when there are none
    ids: np.ndarray | None  # the finite points' indices in the cloud; None when all are finite


def _host_nearest(a: ArrayLike, b: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """`nearest_neighbors` on the host for `(..., na, d)` and `(..., nb, d)` clouds whose leading
    (batch) axes broadcast: `(..., na)` and `(..., nb)` int32."""
    a, b = np.asarray(a), np.asarray(b)  # JAX hands the callback CPU arrays: views, not copies
    # Distances are compared in the dtype the brute force would use (JAX's promotion of the two).
    dtype = np.result_type(a.dtype, b.dtype)
    dtype = dtype if np.issubdtype(dtype, np.floating) else np.dtype(np.float64)
    a, b = a.astype(dtype, copy=False), b.astype(dtype, copy=False)
    batch = np.broadcast_shapes(a.shape[:-2], b.shape[:-2])
    pick = lambda cloud, index: tuple(i if n > 1 else 0 for i, n in zip(index, cloud.shape[:-2]))
    pairs = [(index, pick(a, index), pick(b, index)) for index in np.ndindex(*batch)]
    wanted = list(dict.fromkeys([("a", ia) for _, ia, _ in pairs] + [("b", ib) for _, _, ib in pairs]))
    # cKDTree releases the GIL: the trees of both clouds are built at once, on the pool's threads.
    built = dict(zip(wanted, _in_pool(lambda key: _build((a if key[0] == "a" else b)[key[1]]), wanted)))
    in_b = np.empty((*batch, a.shape[-2]), np.int32)
    in_a = np.empty((*batch, b.shape[-2]), np.int32)
    for index, ia, ib in pairs:
        in_b[index], in_a[index] = _in_pool(_query, (built["b", ib], built["a", ia]), (built["a", ia], built["b", ib]))
    return in_b, in_a


def _in_pool(function, *iterables) -> list:
    """`map(function, *iterables)` on the pool's threads, each first set to C's default floating-point
    environment: XLA runs callbacks with denormals flushed to zero, threads started there inherit
    it, and then cKDTree's build recurses without end on clouds with repeated coordinates."""
    reset = _default_floating_point()

    def task(*args):
        reset()
        return function(*args)

    return list(_pool(os.getpid()).map(task, *iterables))


@functools.cache
def _pool(process: int) -> concurrent.futures.ThreadPoolExecutor:
    # One per process (a forked child has none of its parent's threads). Its tasks never wait on one
    # another: no deadlock, whichever threads call in.
    return concurrent.futures.ThreadPoolExecutor(max_workers=2, thread_name_prefix="ddgjax-kdtree")


@functools.cache
def _default_floating_point() -> Callable[[], object]:
    """A function setting the calling thread's floating-point environment to C's default (`fesetenv(FE_DFL_ENV)`)."""
    try:
        libc = ctypes.CDLL(None)  # the process's own symbols: the C library's fesetenv
        if sys.platform == "darwin":
            default = ctypes.c_void_p(ctypes.addressof(ctypes.c_char.in_dll(libc, "_FE_DFL_ENV")))
        elif sys.platform.startswith("linux"):
            default = ctypes.c_void_p(-1)  # FE_DFL_ENV of glibc and musl
        else:
            return lambda: None
        fesetenv = libc.fesetenv
    except (OSError, AttributeError, ValueError):
        return lambda: None
    return lambda: fesetenv(default)


def _build(points: np.ndarray) -> _Tree:
    from scipy.spatial import cKDTree  # SciPy loads only when a k-d tree is first used

    finite = np.all(np.isfinite(points), axis=1)
    if finite.all():
        return _Tree(points, finite, cKDTree(np.asarray(points, np.float64)), None)
    ids = np.flatnonzero(finite)
    tree = cKDTree(np.asarray(points[ids], np.float64)) if ids.size else None
    return _Tree(points, finite, tree, ids)


def _query(tree: _Tree, queries: _Tree) -> np.ndarray:
    """For each point of `queries`, the lowest index of its nearest points in `tree` (module docstring)."""
    # As the brute force: a non-finite query's nearest is the first non-finite point (the same largest
    # float), else point 0 (every distance infinite).
    nearest = np.full(len(queries.points), 0 if tree.ids is None else np.argmin(tree.finite), np.int32)
    if tree.tree is None or queries.tree is None:
        return nearest
    # The finite queries in the order of their own tree's leaves: neighbouring queries walk the same
    # branches of the other tree, which saves cache misses on large clouds.
    order = queries.tree.indices
    rows = order if queries.ids is None else queries.ids[order]
    distance, index = tree.tree.query(queries.tree.data[order], k=min(2, tree.tree.n), workers=-1)
    if tree.tree.n == 1:
        found = np.zeros(len(rows), np.int64)
    else:
        found = index[:, 0]
        # Rounding in the brute force's sums is a few eps of the squared distance per coordinate.
        tol = 4 * (queries.points.shape[1] + 2) * np.finfo(tree.points.dtype).eps
        near_tie = distance[:, 1] <= distance[:, 0] * (1 + tol)
        if near_tie.any():
            found[near_tie] = _lowest_of_ties(tree, queries.points[rows[near_tie]], distance[near_tie, 0] * (1 + tol))
    nearest[rows] = found if tree.ids is None else tree.ids[found]
    return nearest


def _lowest_of_ties(tree: _Tree, queries: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """For queries with several candidates within `radii`, the lowest tree index of those at the
    smallest squared distance, computed as the brute force does (coordinate by coordinate)."""
    radii = np.nextafter(radii, np.inf)
    q64 = np.asarray(queries, np.float64)
    counts = tree.tree.query_ball_point(q64, radii, return_length=True, workers=-1)
    points = tree.points if tree.ids is None else tree.points[tree.ids]
    found = np.empty(len(queries), np.int64)
    start = 0
    ends = np.cumsum(counts)
    while start < len(queries):
        # A block of rows with at most _TIE_CANDIDATES candidates (at least one row).
        before = ends[start - 1] if start else 0
        stop = max(start + 1, int(np.searchsorted(ends, before + _TIE_CANDIDATES, side="right")))
        lists = tree.tree.query_ball_point(q64[start:stop], radii[start:stop], workers=-1)
        candidates = np.concatenate(lists).astype(np.int64)
        owner = np.repeat(np.arange(stop - start), counts[start:stop])
        d2 = sum((queries[start:stop][owner, k] - points[candidates, k]) ** 2 for k in range(points.shape[1]))
        offsets = np.concatenate([[0], np.cumsum(counts[start:stop])[:-1]])
        smallest = np.minimum.reduceat(d2, offsets)
        tied = np.where(d2 == smallest[owner], candidates, np.iinfo(np.int64).max)
        found[start:stop] = np.minimum.reduceat(tied, offsets)
        start = stop
    return found


class SampledPoints(NamedTuple):
    """What `sample_points(..., return_normals=True)` returns (a named tuple: `points, normals = ...` still unpacks).

    Attributes:
        points: `(n, 3)` the samples.
        normals: `(n, 3)` the unit normal of each sample's face.
    """

    points: Float[Array, "n 3"]
    normals: Float[Array, "n 3"]


def sample_points(mesh: Mesh, n: int, *, key: PRNGKeyArray, return_normals: bool = False) -> Float[Array, "n 3"] | SampledPoints:
    """`n` points uniformly distributed by area on the surface, differentiable in the vertices.

    Faces are drawn with probability `A_f / sum A` (the draw is not differentiated), and a point in
    face `(p0, p1, p2)` is `(1 - sqrt(r1)) p0 + sqrt(r1)(1 - r2) p1 + sqrt(r1) r2 p2` with
    `r1, r2 ~ U(0, 1)` (uniform on the triangle). For a fixed `key` the faces and barycentric
    coordinates are fixed, so the points are linear in the vertex positions and gradients flow to
    the three corners of each point's face.

    Args:
        mesh: triangle mesh with positive total area.
        n: number of points (static).
        key: a JAX PRNG key (`jax.random.key(0)`); a new key per optimisation step gives new samples.
        return_normals: also return the unit normals of the sampled points' faces.

    Returns:
        `(n, 3)` points, or with `return_normals` `SampledPoints(points, normals)`.

    Reference: G. Turk, "Generating random points in triangles" (Graphics Gems, 1990). PyTorch3D:
    `pytorch3d.ops.sample_points_from_meshes(meshes, n, return_normals=...)`.
    """
    mesh = require_mesh("mesh", mesh)
    n = check_count("n", n)
    face_key, coordinate_key = jax.random.split(key)
    # Inverse-CDF draw of the faces (a binary search per sample; cheaper than a categorical draw,
    # which makes a Gumbel variate per sample and face).
    cumulative = jnp.cumsum(jax.lax.stop_gradient(face_areas(mesh)))
    uniform = jax.random.uniform(face_key, (n,), dtype=cumulative.dtype) * cumulative[-1]
    faces = jnp.minimum(jnp.searchsorted(cumulative, uniform, side="right"), mesh.n_faces - 1)
    r1, r2 = jax.random.uniform(coordinate_key, (2, n), dtype=mesh.vertices.dtype)
    root = jnp.sqrt(r1)
    weights = jnp.stack([1.0 - root, root * (1.0 - r2), root * r2], axis=-1)
    points = jnp.einsum("nk,nkd->nd", weights, take_rows(face_vertex_positions(mesh), faces))
    if not return_normals:
        return points
    return SampledPoints(points, take_rows(safe_normalize(face_area_vectors(mesh)), faces))


def _check_points(name: str, points) -> None:
    """Refuse anything but an `(n, d)` real array with `n >= 1`, and NaN / inf in concrete points."""
    if np.ndim(points) != 2:
        raise DDGInputError(f"{name}: expected an (n, d) array of points, got shape {np.shape(points)}")
    check_float_shape(name, points, (np.shape(points)[1],))
    if is_traced(points):
        return
    # Reduced where the points live: a device array is not copied to the host unless it is refused.
    on_host = not isinstance(points, jax.Array) or jax.default_backend() == "cpu"
    if not (np.all(np.isfinite(points)) if on_host else bool(jnp.all(jnp.isfinite(points)))):
        check_finite(name, np.asarray(points))
