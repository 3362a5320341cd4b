"""NaN-safe helpers (ddgjax._numerics): values against NumPy, finite (zero) gradients at degenerate input."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ddgjax._numerics import (
    cross2,
    first_quadrant_atan2,
    safe_atan2,
    safe_div,
    safe_norm,
    safe_normalize,
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
    assert np.isnan(first_quadrant_atan2(nan, one))


def test_safe_norm_values_and_zero_gradient_at_zero():
    x = jnp.array([[3.0, 4.0], [0.0, 0.0], [-1.0, 0.0]])
    np.testing.assert_allclose(safe_norm(x), np.linalg.norm(np.asarray(x), axis=1), rtol=1e-15)
    np.testing.assert_allclose(safe_norm(x, axis=0, keepdims=True), np.linalg.norm(np.asarray(x), axis=0, keepdims=True), rtol=1e-15)
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


def test_first_quadrant_atan2_matches_numpy_over_the_quadrant():
    # angles uniformly over [0, pi/2], radii over 24 decades, both branch points (ratio 0.66 and 1)
    rng = np.random.default_rng(0)
    angle = np.concatenate([np.linspace(0, np.pi / 2, 20001), np.arctan([0.66, 1 / 0.66, 1.0]), rng.uniform(0, np.pi / 2, 5000)])
    radius = 10.0 ** rng.uniform(-12, 12, angle.size)
    y, x = radius * np.sin(angle), radius * np.cos(angle)
    x[np.argmin(np.abs(angle - np.pi / 2))] = 0.0  # exactly pi/2
    y = np.concatenate([y, [0.0, 0.0, 5.0, 1e-300, 1.0, 0.66, 1.0, 0.66000000001]])
    x = np.concatenate([x, [0.0, 3.0, 0.0, 1.0, 1e-300, 1.0, 1.0, 1.0]])
    ours = np.asarray(jax.jit(first_quadrant_atan2)(jnp.asarray(y), jnp.asarray(x)))
    reference = np.arctan2(y, x)
    ulp = np.spacing(np.maximum(reference, np.finfo(float).tiny))
    assert np.max(np.abs(ours - reference) / ulp) <= 4  # Cephes: ~2 ulp
    assert ours[-8] == 0.0 and ours[-6] == np.pi / 2 and ours[-2] == np.pi / 4


def test_first_quadrant_atan2_gradients():
    # d atan2(y, x) = (x dy - y dx) / (x^2 + y^2)
    y, x = jnp.array([0.3, 2.0, 1.0, 0.0, 1.0]), jnp.array([1.0, 0.5, 1.0, 1.0, 0.0])
    dy, dx = jax.vmap(jax.grad(first_quadrant_atan2, argnums=(0, 1)))(y, x)
    r2 = np.asarray(x**2 + y**2)
    np.testing.assert_allclose(dy, np.asarray(x) / r2, rtol=1e-14, atol=1e-16)
    np.testing.assert_allclose(dx, -np.asarray(y) / r2, rtol=1e-14, atol=1e-16)
    dy0, dx0 = jax.grad(first_quadrant_atan2, argnums=(0, 1))(0.0, 0.0)
    assert float(dy0) == 0.0 and float(dx0) == 0.0
