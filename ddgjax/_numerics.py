"""NaN-safe numerical helpers shared by every module.

All of them use the "double where" pattern: the unsafe branch of a `jnp.where` still gets
differentiated, so its *input* is first replaced by a harmless value wherever the result would be
discarded. This keeps values **and gradients** finite on degenerate geometry (zero-length edges,
zero-area triangles, coincident curve points). See DESIGN.md, Numerics.
"""

from __future__ import annotations

from fractions import Fraction

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


def safe_reciprocal(x: Float[Array, "..."]) -> Float[Array, "..."]:
    """`1 / x`, or 0 where `x == 0` (a zero-length edge, a zero-area face), with finite gradients."""
    return safe_div(jnp.ones_like(x), x)


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
    """Angle in `[0, pi]` between two 2-D or 3-D vectors, `atan2(|a x b|, a . b)`.

    `|a x b|` comes from the cross product itself (not `sqrt(|a|^2 |b|^2 - (a.b)^2)`, which cancels
    for small angles), so the angle is accurate near 0 and pi alike (DESIGN.md, Numerics).
    """
    sin_part = jnp.abs(cross2(a, b)) if a.shape[-1] == 2 else safe_norm(jnp.cross(a, b))
    return safe_atan2(sin_part, jnp.sum(a * b, axis=-1))


def _atan_pade(order: int) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """Numerator and denominator coefficients (ascending) of the `[order/order]` Pade approximant of `atan(sqrt(u)) / sqrt(u)`.

    From the series `atan(w) / w = sum_k (-1)^k u^k / (2k + 1)`, `u = w^2`: the denominator `D`
    (with `D_0 = 1`) makes the coefficients `order + 1 .. 2 order` of `series * D` vanish (a linear
    system, solved in exact rational arithmetic), and the numerator is the truncated product. All
    coefficients come out positive, so evaluating them on `u >= 0` has no cancellation.
    Reference: G. A. Baker, P. Graves-Morris, "Pade Approximants", 2nd ed. (1996), ch. 1.
    """
    series = [Fraction((-1) ** k, 2 * k + 1) for k in range(2 * order + 1)]
    # Rows m = order+1 .. 2 order: sum_{j=1..order} D_j series[m - j] = -series[m].
    system = [[series[m - j] for j in range(1, order + 1)] + [-series[m]] for m in range(order + 1, 2 * order + 1)]
    for column in range(order):
        pivot = next(row for row in range(column, order) if system[row][column] != 0)
        system[column], system[pivot] = system[pivot], system[column]
        for row in range(order):
            if row != column and system[row][column] != 0:
                factor = system[row][column] / system[column][column]
                system[row] = [a - factor * b for a, b in zip(system[row], system[column])]
    denominator = [Fraction(1)] + [system[j][order] / system[j][j] for j in range(order)]
    numerator = [sum(denominator[j] * series[m - j] for j in range(m + 1)) for m in range(order + 1)]
    return tuple(map(float, numerator)), tuple(map(float, denominator))


# Order 10: largest relative error of N(u) / D(u) against atan(sqrt(u)) / sqrt(u) on [0, 1] is
# 1.4e-16 (measured with 50-digit arithmetic, tests/test_numerics.py checks against NumPy).
_ATAN_NUMERATOR, _ATAN_DENOMINATOR = _atan_pade(10)


def _polynomial(coefficients: tuple[float, ...], x: Float[Array, "..."]) -> Float[Array, "..."]:
    """Horner evaluation of `sum_k coefficients[k] x^k` (ascending coefficients)."""
    result = jnp.full_like(x, coefficients[-1])
    for c in coefficients[-2::-1]:
        result = result * x + c
    return result


def half_angle_ratio(cosine: Float[Array, "..."]) -> Float[Array, "..."]:
    """`h / sin(h)` for an angle `h` in `[0, pi/2]` given `cos(h) >= 0` alone: no arctangent, one division.

    With `w = tan(h/2)`, `u = w^2 = (1 - cos h) / (1 + cos h)` in `[0, 1]`, `h = 2 atan(w)` and
    `sin h = 2 w / (1 + w^2)`, so `h / sin h = (1 + u) g(u)` with `g(u) = atan(sqrt(u)) / sqrt(u)`,
    evaluated by its `[10/10]` Pade approximant `N(u) / D(u)` (`_atan_pade`; relative error
    <= 1.4e-16 on `[0, 1]`):

        h / sin h = (1 + u) N(u) / D(u),   u = (1 - cos h) / (1 + cos h).

    `1 - cos h` cancels for small `h`, but only in absolute terms: `u` keeps an absolute error of
    about one ulp of 1, and `h / sin h = 1 + u / 3 + ...`, so the result stays within a few ulps
    (tests/test_numerics.py; no small-angle special case). It is the ratio
    `kappa^A / kappa^B = (theta/2) / sin(theta/2)` of the curve flows, `h = |theta| / 2`, computed from
    multiply-adds: XLA lowers a float64 arctangent to a scalar libm call on CPU, so the flows avoid
    it; needing only the cosine saves the flow step a reduction.
    Inputs slightly off `[0, 1]` (rounding) are harmless: `u` stays near `[0, 1]`.

    Args:
        cosine: `cos(h)`, in `[0, 1]`.

    Returns:
        `h / sin(h)`, same shape.
    """
    u = (1.0 - cosine) / (1.0 + cosine)
    return (1.0 + u) * _polynomial(_ATAN_NUMERATOR, u) / _polynomial(_ATAN_DENOMINATOR, u)
