"""NaN-safe helpers (ddgjax._numerics): values against NumPy, finite (zero) gradients at degenerate input."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ddgjax._numerics import (
    cross2,
    half_angle_ratio,
    safe_atan2,
    safe_div,
    safe_norm,
    safe_normalize,
    safe_reciprocal,
    safe_sqrt,
    signed_angle_2d,
    unsigned_angle,
)


def _finite(tree):
    return all(np.isfinite(np.asarray(leaf)).all() for leaf in jax.tree.leaves(tree))


def test_safe_sqrt_values_and_gradients():
    x = jnp.array([4.0, 2.0, 0.0, -3.0])
    np.testing.assert_array_equal(safe_sqrt(x), [2.0, np.sqrt(2.0), 0.0, 0.0])
    gradient = jax.vmap(jax.grad(safe_sqrt))(x)
    np.testing.assert_allclose(gradient, [0.25, 0.5 / np.sqrt(2.0), 0.0, 0.0], rtol=1e-15)


def test_nonfinite_input_propagates_instead_of_vanishing():
    # A NaN must not become a plausible finite number (DESIGN.md: nothing fails silently with NaN).
    nan, inf, one = jnp.array(jnp.nan), jnp.array(jnp.inf), jnp.array(1.0)
    assert np.isnan(safe_sqrt(nan))
    assert safe_sqrt(inf) == np.inf
    assert np.isnan(safe_norm(jnp.array([1.0, jnp.nan])))
    assert np.isnan(safe_div(one, nan))
    assert np.isnan(safe_atan2(nan, one))
    assert np.isnan(half_angle_ratio(nan))


def test_safe_norm_values_and_zero_gradient_at_zero():
    x = jnp.array([[3.0, 4.0], [0.0, 0.0], [-1.0, 0.0]])
    np.testing.assert_allclose(safe_norm(x), np.linalg.norm(np.asarray(x), axis=1), rtol=1e-15)
    np.testing.assert_allclose(
        safe_norm(x, axis=0, keepdims=True), np.linalg.norm(np.asarray(x), axis=0, keepdims=True), rtol=1e-15
    )
    gradient = jax.jacobian(lambda v: safe_norm(v))(x)  # (3, 3, 2)
    np.testing.assert_allclose(gradient[0, 0], [0.6, 0.8], rtol=1e-15)
    np.testing.assert_array_equal(gradient[1, 1], [0.0, 0.0])
    assert _finite(gradient)


def test_safe_div_values_fill_and_gradients():
    num, den = jnp.array([1.0, 2.0, 3.0]), jnp.array([4.0, 0.0, -2.0])
    np.testing.assert_array_equal(safe_div(num, den), [0.25, 0.0, -1.5])
    np.testing.assert_array_equal(safe_div(num, den, fill=7.0), [0.25, 7.0, -1.5])
    d_num, d_den = jax.vmap(jax.grad(safe_div, argnums=(0, 1)))(num, den)
    np.testing.assert_allclose(d_num, [0.25, 0.0, -0.5], rtol=1e-15)
    np.testing.assert_allclose(d_den, [-1 / 16, 0.0, -0.75], rtol=1e-15)


def test_safe_reciprocal_is_zero_with_zero_gradient_at_zero():
    x = jnp.array([4.0, 0.0, -0.5])
    np.testing.assert_array_equal(safe_reciprocal(x), [0.25, 0.0, -2.0])
    np.testing.assert_allclose(jax.vmap(jax.grad(safe_reciprocal))(x), [-1 / 16, 0.0, -4.0], rtol=1e-15)


@pytest.mark.slow
def test_safe_normalize_values_and_gradients():
    x = jnp.array([[3.0, 4.0], [0.0, 0.0]])
    np.testing.assert_allclose(safe_normalize(x), [[0.6, 0.8], [0.0, 0.0]], rtol=1e-15)
    jacobian = jax.jacobian(safe_normalize)(x)
    # d(x/|x|)/dx = (I - u u^T) / |x|
    u = np.array([0.6, 0.8])
    np.testing.assert_allclose(jacobian[0, :, 0, :], (np.eye(2) - np.outer(u, u)) / 5, rtol=1e-14, atol=1e-17)
    np.testing.assert_array_equal(jacobian[1, :, 1, :], np.zeros((2, 2)))
    assert _finite(jacobian)


def test_cross2_and_safe_atan2():
    a, b = jnp.array([[1.0, 2.0]]), jnp.array([[3.0, -1.0]])
    np.testing.assert_array_equal(cross2(a, b), [-7.0])
    y, x = jnp.array([1.0, -1.0, 0.0, 0.0]), jnp.array([-1.0, -1.0, -2.0, 0.0])
    np.testing.assert_array_equal(safe_atan2(y, x), np.arctan2(np.asarray(y), np.asarray(x)))
    dy, dx = jax.grad(lambda y, x: safe_atan2(y, x), argnums=(0, 1))(0.0, 0.0)
    assert float(dy) == 0.0 and float(dx) == 0.0


def test_signed_and_unsigned_angles():
    phi = np.linspace(-np.pi + 1e-3, np.pi, 41)
    a = jnp.asarray(np.stack([np.cos(0.3 + 0 * phi), np.sin(0.3 + 0 * phi)], 1) * 2.0)
    b = jnp.asarray(np.stack([np.cos(0.3 + phi), np.sin(0.3 + phi)], 1) * 0.5)
    np.testing.assert_allclose(signed_angle_2d(a, b), phi, rtol=1e-14, atol=1e-15)
    np.testing.assert_allclose(unsigned_angle(a, b), np.abs(phi), rtol=1e-14, atol=1e-15)
    a3, b3 = jnp.concatenate([a, jnp.zeros((41, 1))], 1), jnp.concatenate([b, jnp.zeros((41, 1))], 1)
    np.testing.assert_allclose(unsigned_angle(a3, b3), np.abs(phi), rtol=1e-14, atol=1e-15)
    # tiny angles: exact (atan2 form), where arccos of the normalised dot product would give 0
    tiny = jnp.array([[1.0, 1e-12]])
    np.testing.assert_allclose(unsigned_angle(jnp.array([[1.0, 0.0]]), tiny), [1e-12], rtol=1e-14)


@pytest.mark.parametrize("function", [signed_angle_2d, unsigned_angle], ids=["signed", "unsigned"])
def test_angles_have_zero_gradients_at_zero_vectors(function):
    zero, a = jnp.zeros(2), jnp.array([1.0, 2.0])
    for x, y in ((zero, a), (a, zero), (zero, zero)):
        value, gradients = jax.value_and_grad(function, argnums=(0, 1))(x, y)
        assert float(value) == 0.0
        assert _finite(gradients) and all(np.all(np.asarray(g) == 0) for g in gradients)
    a3 = jnp.array([1.0, 2.0, 3.0])
    if function is unsigned_angle:
        # parallel 3D vectors: |a x b| = 0 is the degenerate point of the 3D branch
        assert _finite(jax.grad(function, argnums=(0, 1))(a3, 2 * a3))
        assert _finite(jax.grad(function, argnums=(0, 1))(jnp.zeros(3), a3))


def test_half_angle_ratio_matches_numpy_over_the_quarter_turn():
    # h / sin(h) on [0, pi/2], densely and at the ends; tiny angles need no special case
    h = np.concatenate([np.linspace(0.0, np.pi / 2, 200001), [1e-300, 1e-12, 1e-8, 1e-4, np.pi / 2]])
    ours = np.asarray(jax.jit(half_angle_ratio)(jnp.asarray(np.cos(h))))
    reference = np.where(h > 0, h / np.where(h > 0, np.sin(h), 1.0), 1.0)
    # the reference itself rounds twice (sin, quotient): a few ulps of agreement is all there is
    assert np.max(np.abs(ours / reference - 1)) <= 4 * np.finfo(float).eps
    assert ours[0] == 1.0 and abs(ours[-1] - np.pi / 2) <= 2 * np.spacing(np.pi / 2)


def test_half_angle_ratio_pade_coefficients():
    # The [10/10] Pade approximant of atan(sqrt(u)) / sqrt(u) reproduces the series to order u^20
    # (exact rational arithmetic) and has positive coefficients (no cancellation on u >= 0).
    from fractions import Fraction

    from ddgjax._numerics import _ATAN_DENOMINATOR, _ATAN_NUMERATOR, _atan_pade

    assert all(c > 0 for c in _ATAN_NUMERATOR + _ATAN_DENOMINATOR)
    numerator, denominator = _atan_pade(4)  # small order: check the defining property exactly
    series = [Fraction((-1) ** k, 2 * k + 1) for k in range(9)]
    exact_numerator = [Fraction(c).limit_denominator(10**12) for c in numerator]
    exact_denominator = [Fraction(c).limit_denominator(10**12) for c in denominator]
    for m in range(9):
        product = sum(exact_denominator[j] * series[m - j] for j in range(min(m, 4) + 1))
        expected = exact_numerator[m] if m <= 4 else 0
        assert abs(float(product - expected)) < 1e-12, m


def test_half_angle_ratio_gradient():
    # d/dh (h / sin h) = (sin h - h cos h) / sin^2 h, through the cos h parametrisation
    h = jnp.array([0.3, 1.0, 1.5])
    derivative = jax.vmap(jax.grad(lambda x: half_angle_ratio(jnp.cos(x))))(h)
    expected = (np.sin(h) - h * np.cos(h)) / np.sin(h) ** 2
    np.testing.assert_allclose(derivative, expected, rtol=1e-13)
