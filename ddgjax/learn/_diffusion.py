"""The layers' operations on precomputed `DiffusionOperators`: spectral diffusion, spatial gradients, gradient features.

Each acts on one shape's features, `(nv, C)`; a batch of shapes is `jax.vmap` over operators stacked
by `stack_diffusion_operators` (padded vertices give zeros). Reference: Sharp, Attaiki, Crane,
Ovsjanikov, "DiffusionNet: Discretization Agnostic Learning on Surfaces" (ACM TOG 2022), sections 3.1-3.3.
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from .._errors import DDGInputError
from .._indexing import take_rows
from ._operators import DiffusionOperators


def _check_features(x: Array, operators: DiffusionOperators) -> int:
    """The vertex count, after refusing features whose shape is not `(nv,)` or `(nv, C)`."""
    if not isinstance(operators, DiffusionOperators):
        raise DDGInputError(f"operators: expected ddgjax.learn.DiffusionOperators, got {type(operators).__name__}")
    nv = operators.mass.shape[-1]
    if operators.mass.ndim != 1:
        raise DDGInputError(
            f"operators: expected one shape's operators (mass of shape (nv,)), got mass of shape {operators.mass.shape}; "
            "apply to a stacked batch with jax.vmap"
        )
    if x.ndim not in (1, 2) or x.shape[0] != nv:
        raise DDGInputError(f"x: expected shape ({nv},) or ({nv}, C) for a mesh of {nv} vertices, got {x.shape}")
    return nv


def spectral_diffusion(
    x: Float[ArrayLike, "..."], /, operators: DiffusionOperators, times: Float[ArrayLike, "..."]
) -> Float[Array, "..."]:
    """Heat diffusion of each feature channel for its own time, in the truncated eigenbasis.

    `h_c = Phi diag(exp(-lambda t_c)) Phi^T M x_c`: the heat semigroup `exp(-t M^{-1} L)` (the
    pointwise `exp(t Delta)`) restricted to the first `k` eigenfunctions, applied to channel `c` for
    time `t_c` (DiffusionNet's spectral diffusion, Sharp et al. 2022, eq. 3).

    Args:
        x: `(nv, C)` vertex features (or `(nv,)` with a scalar `times`).
        operators: one shape's `DiffusionOperators`.
        times: `(C,)` diffusion times (a scalar for `(nv,)` features), typically learned. Negative
            times are clamped to 0 (the identity on the span of the basis), as DiffusionNet clamps its
            learned times; the derivative with respect to a negative time is then 0.

    Returns:
        The diffused features, the shape of `x`; differentiable in `x`, `times` and the operators.
    """
    x = jnp.asarray(x)
    _check_features(x, operators)
    times = jnp.asarray(times, dtype=x.dtype)
    expected = () if x.ndim == 1 else (x.shape[1],)
    if times.shape != expected:
        raise DDGInputError(f"times: expected shape {expected} (one time per channel of x), got {times.shape}")
    phi = operators.vectors
    coefficients = phi.T @ (operators.mass[:, None] * x.reshape(x.shape[0], -1))  # [k, C]
    decay = jnp.exp(-operators.values[:, None] * jnp.maximum(times, 0.0).reshape(1, -1))
    return (phi @ (decay * coefficients)).reshape(x.shape)


def spatial_gradients(x: Float[ArrayLike, "..."], /, operators: DiffusionOperators) -> Float[Array, "..."]:
    """Tangent gradients of vertex features: `(nv, C, 2)` (or `(nv, 2)` for `(nv,)` features).

    `grad x_c(i) = sum_j w_ij (x_c[n_ij] - x_c(i))` with `operators.gradient_weights` (the
    least-squares one-ring fit, DiffusionNet's `gradX + i gradY`), in the coordinates of the vertex's
    frame `(operators.frames.e1, operators.frames.e2)`; the 3D vector is `g0 e1 + g1 e2`. Exact for
    functions linear on a flat one-ring. A gather: no sparse matrix.

    Args:
        x: `(nv,)` or `(nv, C)` vertex features (positional-only).
        operators: the shape's `DiffusionOperators` (its `gradient_neighbors`, `gradient_weights`).

    Returns:
        Float array of `x`'s shape plus a last axis of 2: the gradient's `(e1, e2)` coordinates.
    """
    x = jnp.asarray(x)
    _check_features(x, operators)
    values = x.reshape(x.shape[0], -1)
    differences = take_rows(values, operators.gradient_neighbors) - values[:, None, :]  # [i, j, c]
    gradients = jnp.einsum("ijc,ija->ica", differences, operators.gradient_weights)
    return gradients.reshape(*x.shape, 2)


def spatial_gradient_features(
    gradients: Float[ArrayLike, "nv C 2"], a_real: Float[ArrayLike, "C C"], a_imag: Float[ArrayLike, "C C"]
) -> Float[Array, "nv C"]:
    """DiffusionNet's spatial gradient features: `tanh(Re(conj(g_c) (A g)_c))` per vertex and channel.

    With `g = gradients[..., 0] + i gradients[..., 1]` the per-channel tangent gradients as complex
    numbers in each vertex's frame and `A = a_real + i a_imag` a learned `C x C` complex matrix
    acting on the channels (`(A g)_c = sum_d A_cd g_d`), the feature is the real part of the Hermitian
    product, squashed by `tanh` (Sharp et al. 2022, section 3.3). Rotating a vertex's frame
    multiplies all its `g_c` by one unit complex number, which cancels: the features do not depend on
    the choice of frames.

    Args:
        gradients: `(nv, C, 2)` tangent gradients of `C` channels (`spatial_gradients`).
        a_real: `(C, C)` the real part of `A`.
        a_imag: `(C, C)` the imaginary part of `A`.

    Returns:
        `(nv, C)` float array of features in `(-1, 1)`.
    """
    gradients, a_real, a_imag = jnp.asarray(gradients), jnp.asarray(a_real), jnp.asarray(a_imag)
    g_re, g_im = gradients[..., 0], gradients[..., 1]
    ag_re = g_re @ a_real.T - g_im @ a_imag.T
    ag_im = g_re @ a_imag.T + g_im @ a_real.T
    return jnp.tanh(g_re * ag_re + g_im * ag_im)
