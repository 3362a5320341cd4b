"""Point-set losses: the Chamfer distance (dense, chunked) and area-uniform point samples of a mesh.

`chamfer_distance` finds nearest neighbours by brute force: all pairwise squared distances, a chunk
of rows at a time, so two clouds of 10k points each need ~`chunk_size * n_b` floats of memory rather
than `n_a * n_b`; on a GPU this is the fastest exact search for clouds of this size. The search
itself is not differentiated (nearest indices are integers); the loss is then recomputed from the
gathered nearest points, `|a_i - b_{nn(i)}|^2`, so the gradient is exact where the nearest neighbour
is unique (the loss is piecewise smooth: it has kinks where two candidates tie) and flows to both
the query point and its nearest point, as in PyTorch3D.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float, Int, PRNGKeyArray

from .._errors import DDGInputError, check_count, check_float_shape
from .._indexing import take_rows
from .._numerics import safe_normalize
from ..mesh import Mesh, face_area_vectors, face_areas, face_vertex_positions, require_mesh

# Pairwise distances per chunk: rows * columns stays under this many entries (32 MiB of float64).
_CHUNK_ENTRIES = 1 << 22


def chamfer_distance(
    points_a: Float[ArrayLike, "na d"], points_b: Float[ArrayLike, "nb d"], *, chunk_size: int | None = None
) -> Float[Array, ""]:
    """Symmetric Chamfer distance `mean_a min_b |a - b|^2 + mean_b min_a |a - b|^2`, a scalar `()`.

    Squared Euclidean distances, each direction averaged over its points, summed: PyTorch3D's
    `chamfer_distance(a[None], b[None])[0]` with its defaults (`point_reduction="mean"`, squared
    norms). Differentiable in both point sets (module docstring); exact (brute force, chunked).

    Args:
        points_a: `(na, d)` points (any dimension `d`, e.g. 3).
        points_b: `(nb, d)` points.
        chunk_size: rows of `points_a` per block of pairwise distances (static); default: as many as
            keep a block under 2^22 entries.

    Returns:
        The Chamfer distance, in squared length units.

    Reference: H. Fan, H. Su, L. Guibas, "A point set generation network for 3D object
    reconstruction from a single image" (CVPR 2017). PyTorch3D: `pytorch3d.loss.chamfer_distance`.
    """
    nearest_in_b, nearest_in_a = nearest_neighbors(points_a, points_b, chunk_size=chunk_size)
    points_a, points_b = jnp.asarray(points_a), jnp.asarray(points_b)
    to_b = points_a - take_rows(points_b, nearest_in_b)
    to_a = points_b - take_rows(points_a, nearest_in_a)
    return jnp.mean(jnp.sum(to_b * to_b, axis=-1)) + jnp.mean(jnp.sum(to_a * to_a, axis=-1))


class NearestNeighbors(NamedTuple):
    """What `nearest_neighbors` returns (a named tuple: `in_b, in_a = nearest_neighbors(a, b)` still unpacks).

    Attributes:
        nearest_in_b: `(na,)` for each point of `points_a`, the index of its nearest point of `points_b`.
        nearest_in_a: `(nb,)` for each point of `points_b`, the index of its nearest point of `points_a`.
    """

    nearest_in_b: Int[Array, " na"]
    nearest_in_a: Int[Array, " nb"]


def nearest_neighbors(
    points_a: Float[ArrayLike, "na d"], points_b: Float[ArrayLike, "nb d"], *, chunk_size: int | None = None
) -> NearestNeighbors:
    """Indices of the nearest point of `points_b` for each point of `points_a`, and the other way round.

    `nearest_in_b[i] = argmin_j |a_i - b_j|^2` and `nearest_in_a[j] = argmin_i |a_i - b_j|^2`
    (squared Euclidean distances, computed coordinate by coordinate). One pass of brute force over
    row chunks of `points_a` (a `lax.scan`): each chunk's pairwise squared distances give the chunk's
    row minima and update running column minima. Ties go to the lowest index. Not differentiable
    (integer output; the inputs are held fixed).

    Args:
        points_a: `(na, d)` points.
        points_b: `(nb, d)` points of the same dimension.
        chunk_size: rows of `points_a` per block (static); default: blocks under 2^22 entries.

    Returns:
        `NearestNeighbors(nearest_in_b (na,), nearest_in_a (nb,))`, int32.

    Equivalent: `scipy.spatial.cKDTree(points_b).query(points_a)[1]` (and the other way round);
    PyTorch3D `knn_points(a, b, K=1).idx`.
    """
    _check_points("points_a", points_a)
    _check_points("points_b", points_b)
    if points_a.shape[1] != points_b.shape[1]:
        raise DDGInputError(f"points_b: expected points of dimension {points_a.shape[1]} like points_a, got {points_b.shape[1]}")
    a = jax.lax.stop_gradient(jnp.asarray(points_a))
    b = jax.lax.stop_gradient(jnp.asarray(points_b))
    na, nb = a.shape[0], b.shape[0]
    rows = max(1, min(na, _CHUNK_ENTRIES // max(nb, 1))) if chunk_size is None else check_count("chunk_size", chunk_size)
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

    start = (jnp.full((nb,), jnp.inf, a.dtype), jnp.zeros((nb,), jnp.int32))
    (_, nearest_in_a), nearest_in_b = jax.lax.scan(chunk, start, jnp.arange(n_chunks, dtype=jnp.int32) * rows)
    return NearestNeighbors(nearest_in_b.reshape(-1)[:na].astype(jnp.int32), nearest_in_a.astype(jnp.int32))


def _min_and_first_index(d2: Float[Array, "m n"], axis: int) -> tuple[Float[Array, " k"], Int[Array, " k"]]:
    """Minimum along `axis` and the first index attaining it. Two plain reductions: XLA:CPU runs
    them about twice as fast as `argmin`'s variadic (value, index) reduction."""
    smallest = jnp.min(d2, axis=axis, keepdims=True)
    n = d2.shape[axis]
    ids = jnp.expand_dims(jnp.arange(n, dtype=jnp.int32), 1 - axis)
    return jnp.squeeze(smallest, axis), jnp.min(jnp.where(d2 == smallest, ids, n), axis=axis)


class SampledPoints(NamedTuple):
    """What `sample_points(..., return_normals=True)` returns (a named tuple: `points, normals = ...` still unpacks).

    Attributes:
        points: `(n, 3)` the samples.
        normals: `(n, 3)` the unit normal of each sample's face.
    """

    points: Float[Array, "n 3"]
    normals: Float[Array, "n 3"]


def sample_points(mesh: Mesh, n: int, key: PRNGKeyArray, *, return_normals: bool = False) -> Float[Array, "n 3"] | SampledPoints:
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
    if jnp.ndim(points) != 2:
        raise DDGInputError(f"{name}: expected an (n, d) array of points, got shape {jnp.shape(points)}")
    check_float_shape(name, points, (jnp.shape(points)[1],))
