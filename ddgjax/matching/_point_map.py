"""Functional map to point map and back (Ovsjanikov et al. 2012, section 6.1; pyFM `spectral/convert.py`).

A point map lists, for each target vertex, its source vertex. From a functional map `C` (`(k_t, k_s)`)
it is the nearest neighbour of each target vertex's spectral embedding, row `i` of `Phi_t[:, :k_t]`,
among the source vertices' embeddings pushed through `C`, the rows of `Phi_s[:, :k_s] @ C^T`: `C`
maps the delta function at a source vertex (coefficients `Phi_s[j]` up to its mass) to the
coefficients of its image on the target, which should be a delta at the matching target vertex.
The way back, point map to functional map, is the projection `C = Phi_t^T M_t Phi_s[point_map]`.

The searches are an exact chunked brute force (`embedded_nearest`: one matrix product per chunk),
as pyFM's are in more than 8 dimensions (its `kdtree_max_dim`): in the 50-100 dimensions of a
spectral embedding a k-d tree visits nearly every leaf. The matrix products are jitted kernels.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int

from .._compile import kernel
from .._errors import DDGInputError, is_traced
from ._shape import SpectralShape, require_spectral_shape


def check_functional_map(name: str, C, source: SpectralShape, target: SpectralShape) -> tuple[int, int]:
    """`(k_t, k_s)` of a `(k_t, k_s)` real functional map that fits the shapes' bases, else `DDGInputError`."""
    shape = np.shape(C)
    dtype = C.dtype if hasattr(C, "dtype") else np.asarray(C).dtype
    if len(shape) != 2 or min(shape) < 1 or not np.issubdtype(dtype, np.floating):
        raise DDGInputError(f"{name}: expected a (k_target, k_source) floating-point matrix, got shape {shape}, dtype {dtype}")
    k_t, k_s = shape
    if k_t > target.k or k_s > source.k:
        raise DDGInputError(
            f"{name}: a ({k_t}, {k_s}) functional map needs at least {k_t} target and {k_s} source eigenpairs, "
            f"the shapes have {target.k} and {source.k}: make them with spectral_shape(mesh, k) for a larger k"
        )
    if not is_traced(C) and not np.all(np.isfinite(np.asarray(C))):
        raise DDGInputError(f"{name}: expected finite entries, got NaN/inf")
    return k_t, k_s


def check_basis_size(name: str, value, available: int, shape_name: str) -> int:
    """A basis size `1 <= value <= available` (`None`: all of them), else `DDGInputError`."""
    if value is None:
        return available
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or not 1 <= value <= available:
        raise DDGInputError(
            f"{name}: expected an integer in [1, {available}] (the {shape_name} shape's eigenpairs), got {value!r}"
        )
    return int(value)


def point_map(C: Float[ArrayLike, "k_t k_s"], /, source: SpectralShape, target: SpectralShape) -> Int[Array, " n_target"]:
    """For each target vertex, its source vertex under the functional map `C`: `(n_target,)` int32.

    `point_map[i] = argmin_j |Phi_t[i, :k_t] - (Phi_s[:, :k_s] C^T)[j]|^2`: the nearest source vertex
    in the spectral embedding, `C` carrying the source's (module docstring). Exact nearest neighbours,
    ties to the lowest index (`ddgjax.optim.nearest_neighbors`). Works under `jit`; not
    differentiable (integer output).

    Args:
        C: `(k_t, k_s)` functional map from the source to the target, `k_t <= target.k`, `k_s <= source.k`.
        source: the source `SpectralShape`.
        target: the target `SpectralShape`.

    Returns:
        `(n_target,)` source vertex indices.

    Reference: M. Ovsjanikov et al., "Functional maps: a flexible representation of maps between
    shapes" (SIGGRAPH 2012), section 6.1. pyFM: `spectral.FM_to_p2p(C, Phi_s, Phi_t)` (its default,
    `use_adj=False`).
    """
    source = require_spectral_shape("source", source)
    target = require_spectral_shape("target", target)
    check_functional_map("C", C, source, target)
    return _point_map(jnp.asarray(C), source.vectors, target.vectors)


@kernel
def _point_map(C, source_vectors, target_vectors):
    return embedded_nearest(C, source_vectors[:, : C.shape[1]], target_vectors[:, : C.shape[0]])


def embedded_nearest(C, source_vectors, target_vectors):
    """Nearest row of `source_vectors @ C^T` to each row of `target_vectors` (the bases as wide as `C`).

    Zero columns on both sides (a basis padded to a fixed width) leave the distances unchanged.
    Spectral embeddings have tens to hundreds of dimensions, where a k-d tree degenerates to a scan
    and `ddgjax.optim.nearest_neighbors`'s coordinate-by-coordinate distances are slow: here
    `|p|^2 - 2 t.p` (`|t|^2` is the same along a row) comes from one matrix product per chunk of
    target rows, as pyFM's and scikit-learn's brute force do. Ties go to the lowest index.
    """
    points = source_vectors @ C.T
    targets = jnp.asarray(target_vectors, points.dtype)
    n_target, n_source = targets.shape[0], points.shape[0]
    rows = max(1, min(n_target, _CHUNK_ENTRIES // n_source))
    n_chunks = -(-n_target // rows)
    padded = jnp.concatenate([targets, jnp.zeros((n_chunks * rows - n_target, targets.shape[1]), targets.dtype)])
    squared = jnp.sum(points * points, axis=1)

    def nearest(block):
        return jnp.argmin(squared[None, :] - 2.0 * (block @ points.T), axis=1).astype(jnp.int32)

    return jax.lax.map(nearest, padded.reshape(n_chunks, rows, -1)).reshape(-1)[:n_target]


# Distances per chunk of target rows: under this many entries (32 MiB of float64).
_CHUNK_ENTRIES = 1 << 22


def functional_map_from_point_map(
    point_map: Int[ArrayLike, " n_target"],
    source: SpectralShape,
    target: SpectralShape,
    *,
    k_source: int | None = None,
    k_target: int | None = None,
) -> Float[Array, "k_target k_source"]:
    """The functional map of a point map: `C = Phi_t^T M_t Phi_s[point_map]`, `(k_target, k_source)`.

    A point map pulls a source function `f` back to `f[point_map]` on the target; in the bases its
    matrix is the mass-weighted projection above, `C_ab = <phi_t^a, phi_s^b o point_map>_{M_t}`.
    The mass-weighted projection, rather than pyFM's default least-squares fit
    `lstsq(Phi_t, Phi_s[point_map])`, because the target basis is M-orthonormal (`Phi_t^T M_t Phi_t = I`):
    the projection is then the exact least-squares solution in the target's L2 inner product, one
    matrix product with no pseudo-inverse. Differentiable in the bases and masses (the point map
    is held fixed); works under `jit`.

    Args:
        point_map: `(n_target,)` for each target vertex its source vertex.
        source: the source `SpectralShape`.
        target: the target `SpectralShape`.
        k_source: source basis size (default: all of `source.k`).
        k_target: target basis size (default: all of `target.k`).

    Returns:
        `(k_target, k_source)` functional map from the source to the target.

    pyFM: `spectral.p2p_to_FM(point_map, Phi_s[:, :k_source], Phi_t[:, :k_target], A2=M_t)`.
    """
    source = require_spectral_shape("source", source)
    target = require_spectral_shape("target", target)
    check_point_map("point_map", point_map, source, target)
    k_s = check_basis_size("k_source", k_source, source.k, "source")
    k_t = check_basis_size("k_target", k_target, target.k, "target")
    return project_point_map(jnp.asarray(point_map), source.vectors[:, :k_s], target.vectors[:, :k_t], target.mass)


def check_point_map(name: str, point_map, source: SpectralShape, target: SpectralShape) -> None:
    """Refuse anything but `(n_target,)` integers in `[0, n_source)` (values checked when concrete)."""
    n_s, n_t = source.vectors.shape[0], target.vectors.shape[0]
    dtype = point_map.dtype if hasattr(point_map, "dtype") else np.asarray(point_map).dtype
    if np.shape(point_map) != (n_t,) or not np.issubdtype(dtype, np.integer):
        raise DDGInputError(
            f"{name}: expected ({n_t},) integers (a source vertex for each target vertex), "
            f"got shape {np.shape(point_map)}, dtype {dtype}"
        )
    if not is_traced(point_map):
        values = np.asarray(point_map)
        if values.size and (values.min() < 0 or values.max() >= n_s):
            raise DDGInputError(
                f"{name}: expected source vertex indices in [0, {n_s}), got values in [{values.min()}, {values.max()}]"
            )


@kernel
def project_point_map(point_map, source_vectors, target_vectors, target_mass):
    """`Phi_t^T (M_t Phi_s[point_map])` for bases already cut to the functional map's size."""
    return target_vectors.T @ (target_mass[:, None] * source_vectors[point_map])
