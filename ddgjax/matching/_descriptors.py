"""Multiscale spectral descriptors of a `SpectralShape`: wave and heat kernel signatures, as pyFM computes them.

pyFM's `FunctionalMapping.preprocess(n_descr, descr_type, landmarks)`: the signature at `n_descr`
scales (`auto_WKS` / `auto_HKS` on the first `k_descr` eigenpairs, each scale divided by its total
spectral weight), followed, when landmarks are given, by the landmark signatures
`sum_i w_i(s) phi_i(l) phi_i(x)` (one column per landmark and scale), and every column divided by its
M-norm `sqrt(f^T M f)`.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int

from .._compile import device_array, kernel
from .._errors import DDGInputError, check_choice
from ..spectral.internal import wave_kernel_energies, wave_kernel_weights
from ._shape import SpectralShape, require_spectral_shape

DESCRIPTOR_KINDS = ("wks", "hks")


def descriptors(
    shape: SpectralShape,
    *,
    kind: str = "wks",
    n_descriptors: int = 100,
    landmarks: Int[ArrayLike, " p"] | None = None,
    k: int | None = None,
) -> Float[Array, "nv d"]:
    """Multiscale WKS or HKS descriptors of a shape, each column of unit M-norm, `(nv, d)`.

    With `Phi, lambda` the first `k` eigenpairs and `s` the
    `n_descriptors` scales, column `s` is `f_s(x) = sum_i w_i(s) phi_i(x)^2 / sum_i w_i(s)`:

    - `kind="wks"` (Aubry et al. 2011): `w_i(e) = exp(-(e - log lambda_i)^2 / (2 sigma^2))` on pyFM's
      `auto_WKS` log-energy grid (`ddgjax.spectral.wave_kernel_signature`; the zero eigenvalue left out);
    - `kind="hks"` (Sun et al. 2009): `w_i(t) = exp(-t lambda_i)` at `n_descriptors` times spaced
      geometrically on `[4 ln 10 / lambda_max, 4 ln 10 / lambda_1]` (pyFM's `auto_HKS`).

    With `p` `landmarks`, `p * n_descriptors` columns follow, the landmark
    signatures `f_{l,s}(x) = sum_i w_i(s) phi_i(l) phi_i(x) / sum_i w_i(s)`, ordered landmark-major
    (column `n_descriptors + l * n_descriptors + s`). Finally every column is divided by
    `sqrt(f^T M f)`, so `d = n_descriptors (1 + p)`.

    Differentiable in the shape's eigenpairs and mass (a plain JAX function), under `jit` too.
    pyFM: `FunctionalMapping(m1, m2).preprocess(n_descr=n_descriptors, descr_type="WKS", landmarks=...,
    k_descr=k)`'s `descr1` (pyFM's defaults: `k_descr=128`, no subsampling).

    Args:
        shape: the `SpectralShape` (`spectral_shape(mesh, k)`).
        kind: `"wks"` (default) or `"hks"` (keyword-only).
        n_descriptors: the number of scales, `>= 1` (keyword-only; default 100).
        landmarks: `(p,)` vertex indices whose landmark signatures are appended (keyword-only); `None` (default):
            none, `p = 0`.
        k: the number of eigenpairs used, `2 <= k <= shape.k` (keyword-only); `None` (default): all the shape's.

    Returns:
        `(nv, n_descriptors (1 + p))` float array, each column of unit M-norm.
    """
    shape = require_spectral_shape("shape", shape)
    kind = check_choice("kind", kind, DESCRIPTOR_KINDS)
    if not isinstance(n_descriptors, (int, np.integer)) or n_descriptors < 1:
        raise DDGInputError(f"n_descriptors: expected a positive integer, got {n_descriptors!r}")
    requested = k
    k = shape.k if requested is None else requested
    if not isinstance(k, (int, np.integer)) or not 2 <= k <= shape.k:
        raise DDGInputError(
            f"k: expected an integer in [2, {shape.k}] (the shape's eigenpairs; compute more with "
            f"`spectral_shape(mesh, k)`), got {requested!r}"
        )
    landmarks = None if landmarks is None else _landmarks(landmarks, shape.vectors.shape[0])
    return _descriptor_columns(shape.mass, shape.values, shape.vectors, landmarks, k=k, kind=kind, n_descriptors=n_descriptors)


@kernel(static_argnames=("k", "kind", "n_descriptors"))
def _descriptor_columns(mass, values, vectors, landmarks, *, k: int, kind: str, n_descriptors: int) -> Float[Array, "nv d"]:
    """`descriptors` after its checks, on the shape's arrays (a kernel: one program, not one per operation)."""
    values, vectors = values[:k], vectors[:, :k]
    weights = _scale_weights(values, kind, n_descriptors)  # (n_descriptors, k)
    weights = weights / jnp.sum(weights, axis=1, keepdims=True)
    columns = [(vectors**2) @ weights.T]
    if landmarks is not None:
        # (p, n_descriptors, nv) -> landmark-major columns, as pyFM's `lm_WKS` / `lm_HKS` order them.
        at_landmarks = jnp.einsum("sk,pk,nk->psn", weights, vectors[landmarks], vectors)
        columns.append(at_landmarks.reshape(-1, vectors.shape[0]).T)
    descriptors = jnp.concatenate(columns, axis=1)
    return descriptors / jnp.sqrt(mass @ descriptors**2)


def _scale_weights(values: Float[Array, " k"], kind: str, n: int) -> Float[Array, "n k"]:
    """The spectral weights `w_i(s)` of each scale: WKS bands or HKS exponentials on pyFM's grids."""
    if kind == "wks":
        energies, sigma = wave_kernel_energies(values, n)
        return wave_kernel_weights(values, energies, sigma)
    magnitudes = jnp.abs(values)
    ordered = jnp.sort(magnitudes)
    times = jnp.geomspace(4 * np.log(10) / ordered[-1], 4 * np.log(10) / ordered[1], n)
    return jnp.exp(-times[:, None] * magnitudes[None, :])


def _landmarks(landmarks, nv: int) -> Int[Array, " p"]:
    indices = np.asarray(landmarks)
    if indices.ndim != 1 or not np.issubdtype(indices.dtype, np.integer) or indices.size == 0:
        raise DDGInputError(f"landmarks: expected a non-empty (p,) array of vertex indices, got shape {indices.shape}")
    if indices.min() < 0 or indices.max() >= nv:
        raise DDGInputError(f"landmarks: vertex indices must lie in [0, {nv}), got {indices.min()}..{indices.max()}")
    return device_array(indices)
