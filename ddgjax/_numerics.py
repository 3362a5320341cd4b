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
    """`sqrt(max(x, 0))` with a zero (not infinite) gradient at `x <= 0`; NaN stays NaN.

    The test is `x <= 0`, not `x > 0`, so that a NaN (for which both are false) reaches `sqrt` and
    propagates instead of turning into a plausible 0 (DESIGN.md: nothing fails silently).
    """
    nonpositive = x <= 0
    return jnp.where(nonpositive, 0.0, jnp.sqrt(jnp.where(nonpositive, 1.0, x)))


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


# Cephes `atan` (S. Moshier, cephes/double/atan.c): `atan(z) ~ z + z^3 P(z^2) / Q(z^2)` on
# |z| <= 0.66, relative error ~2e-16.
_ATAN_P = (-8.750608600031904122785e-1, -1.615753718733365076637e1, -7.500855792314704667340e1,
           -1.228866684490136173410e2, -6.485021904942025371773e1)
_ATAN_Q = (1.0, 2.485846490142306297962e1, 1.650270098316988542046e2, 4.328810604912902668951e2,
           4.853903996359136964868e2, 1.945506571482613964425e2)


def _polynomial(coefficients: tuple[float, ...], x: Float[Array, "..."]) -> Float[Array, "..."]:
    """Horner evaluation, highest degree first."""
    result = jnp.full_like(x, coefficients[0])
    for c in coefficients[1:]:
        result = result * x + c
    return result


def first_quadrant_atan2(y: Float[Array, "..."], x: Float[Array, "..."]) -> Float[Array, "..."]:
    """`atan2(y, x)` for `x, y >= 0`, an angle in `[0, pi/2]`, from multiply-adds only (fast on CPU).

    XLA lowers float64 `atan2` to a scalar libm call (~17 ns per element on CPU, 8x NumPy); this
    vectorises. With `r = min(x, y) / max(x, y)` in `[0, 1]`: `atan(r)` from Cephes' rational
    approximation `z + z^3 P(z^2) / Q(z^2)`, directly for `r <= 0.66` and as
    `pi/4 + atan((r - 1) / (r + 1))` above; then `pi/2 - atan(r)` when `y > x`. Error within a few
    ulps of `jnp.arctan2` on the whole quadrant. Returns 0 with a zero gradient at `x = y = 0`
    (like `safe_atan2`). Negative inputs are outside its domain (use `safe_atan2`).

    Reference: S. L. Moshier, Cephes Math Library, `atan.c`.
    """
    swap = y > x
    ratio = safe_div(jnp.where(swap, x, y), jnp.where(swap, y, x))  # in [0, 1]
    shifted = ratio > 0.66
    z = jnp.where(shifted, (ratio - 1) / (ratio + 1), ratio)
    z2 = z * z
    angle = z + z * z2 * _polynomial(_ATAN_P, z2) / _polynomial(_ATAN_Q, z2)
    angle = jnp.where(shifted, jnp.pi / 4 + angle, angle)
    return jnp.where(swap, jnp.pi / 2 - angle, angle)
