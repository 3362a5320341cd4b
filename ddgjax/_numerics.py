"""NaN-safe numerical helpers shared by every module.

All of them use the "double where" pattern: the unsafe branch of a `jnp.where` still gets
differentiated, so its *input* is first replaced by a harmless value wherever the result would be
discarded. This keeps values **and gradients** finite on degenerate geometry (zero-length edges,
zero-area triangles, coincident curve points). See DESIGN.md, Numerics.
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Float


def safe_sqrt(x: Float[Array, "..."]) -> Float[Array, "..."]:
    """`sqrt(max(x, 0))` with a zero (not infinite) gradient at `x <= 0`."""
    positive = x > 0
    return jnp.where(positive, jnp.sqrt(jnp.where(positive, x, 1.0)), 0.0)


def safe_norm(x: Float[Array, "... d"], axis: int = -1, keepdims: bool = False) -> Float[Array, "..."]:
    """Euclidean norm along `axis`; value 0 and gradient 0 at the zero vector."""
    return safe_sqrt(jnp.sum(x * x, axis=axis, keepdims=keepdims))


def safe_div(num: Float[Array, "..."], den: Float[Array, "..."], fill: float = 0.0) -> Float[Array, "..."]:
    """`num / den`, or `fill` where `den == 0`, with finite gradients everywhere."""
    nonzero = den != 0
    return jnp.where(nonzero, num / jnp.where(nonzero, den, 1.0), fill)


def safe_normalize(x: Float[Array, "... d"], axis: int = -1) -> Float[Array, "... d"]:
    """`x / |x|`, or the zero vector where `|x| == 0`, with finite gradients."""
    return safe_div(x, safe_norm(x, axis=axis, keepdims=True))


def cross2(a: Float[Array, "... 2"], b: Float[Array, "... 2"]) -> Float[Array, "..."]:
    """z-component of the cross product of two plane vectors, `a_x b_y - a_y b_x`."""
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def safe_atan2(y: Float[Array, "..."], x: Float[Array, "..."]) -> Float[Array, "..."]:
    """`atan2(y, x)` that returns 0 with a zero gradient at `x = y = 0` (plain atan2 gives NaN)."""
    zero = (x == 0) & (y == 0)
    return jnp.where(zero, 0.0, jnp.arctan2(y, jnp.where(zero, 1.0, x)))


def signed_angle_2d(a: Float[Array, "... 2"], b: Float[Array, "... 2"]) -> Float[Array, "..."]:
    """Signed angle from plane vector `a` to `b`, counterclockwise positive, in `(-pi, pi]`.

    `atan2(a x b, a . b)`: exact for angles near 0 and pi, unlike `arccos` (DESIGN.md, Numerics).
    """
    return safe_atan2(cross2(a, b), jnp.sum(a * b, axis=-1))


def unsigned_angle(a: Float[Array, "... d"], b: Float[Array, "... d"]) -> Float[Array, "..."]:
    """Angle in `[0, pi]` between vectors of any dimension, `atan2(|a x b|, a . b)`.

    `|a x b|` is computed as `sqrt(|a|^2 |b|^2 - (a.b)^2)` only in 2D/3D via the cross product, so
    it has no cancellation for small angles.
    """
    if a.shape[-1] == 2:
        sin_part = jnp.abs(cross2(a, b))
    else:
        sin_part = safe_norm(jnp.cross(a, b))
    return safe_atan2(sin_part, jnp.sum(a * b, axis=-1))
