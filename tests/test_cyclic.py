"""`cyclic_shift` (ddgjax._cyclic): `jnp.roll` values, and derivatives that are rolls in every mode."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ddgjax import DDGInputError
from ddgjax._cyclic import cyclic_shift, cyclic_shift_p

CASES = [(1, 0), (-1, 0), (3, 0), (2, 1), (-1, -1), (7, 0)]


@pytest.mark.parametrize(("shift", "axis"), CASES)
def test_values_equal_numpy_roll_eager_and_jitted(shift, axis):
    x = np.arange(24.0).reshape(6, 4)
    expected = np.roll(x, shift, axis=axis)
    np.testing.assert_array_equal(cyclic_shift(jnp.asarray(x), shift, axis), expected)
    np.testing.assert_array_equal(jax.jit(lambda v: cyclic_shift(v, shift, axis))(x), expected)


@pytest.mark.parametrize(("shift", "axis"), CASES)
def test_transpose_is_the_opposite_roll(shift, axis):
    x = jnp.arange(24.0).reshape(6, 4)
    cotangent = jnp.sin(jnp.arange(24.0)).reshape(6, 4)
    (transposed,) = jax.linear_transpose(lambda v: cyclic_shift(v, shift, axis), x)(cotangent)
    np.testing.assert_array_equal(transposed, np.roll(cotangent, -shift, axis=axis))
    # ... and the transposed program holds no pad (JAX's own roll transposes into padded copies).
    jaxpr = jax.make_jaxpr(jax.grad(lambda v: jnp.sum(cyclic_shift(v, shift, axis) * cotangent)))(x)
    names = {equation.primitive.name for equation in jaxpr.jaxpr.eqns}
    assert cyclic_shift_p.name in names and "pad" not in names


@pytest.mark.slow
def test_derivatives_match_jnp_roll_in_both_modes_and_nested():
    x = jnp.linspace(-1.0, 2.0, 12).reshape(6, 2)
    weights = jnp.cos(jnp.arange(12.0)).reshape(6, 2)

    def ours(v):
        return jnp.sum(weights * cyclic_shift(jnp.sin(v), 2) ** 2 * cyclic_shift(v, -1))

    def plain(v):
        return jnp.sum(weights * jnp.roll(jnp.sin(v), 2, axis=0) ** 2 * jnp.roll(v, -1, axis=0))

    np.testing.assert_allclose(jax.grad(ours)(x), jax.grad(plain)(x), rtol=1e-14, atol=1e-15)
    direction = jnp.ones_like(x)
    np.testing.assert_allclose(jax.jvp(ours, (x,), (direction,))[1], jax.jvp(plain, (x,), (direction,))[1], rtol=1e-14)
    np.testing.assert_allclose(jax.hessian(ours)(x), jax.hessian(plain)(x), rtol=1e-13, atol=1e-14)
    np.testing.assert_allclose(jax.jacfwd(jax.grad(ours))(x), jax.hessian(plain)(x), rtol=1e-13, atol=1e-14)


@pytest.mark.parametrize("batch_axis", [0, 1, 2])
@pytest.mark.parametrize(("shift", "axis"), [(1, 0), (-2, 1), (1, -1)])
@pytest.mark.slow
def test_vmap_over_any_axis(batch_axis, shift, axis):
    stacked = jnp.moveaxis(jnp.arange(60.0).reshape(3, 5, 4), 0, batch_axis)
    ours = jax.vmap(lambda v: cyclic_shift(v, shift, axis), in_axes=batch_axis)(stacked)
    plain = jax.vmap(lambda v: jnp.roll(v, shift, axis=axis), in_axes=batch_axis)(stacked)
    np.testing.assert_array_equal(ours, plain)
    gradients = jax.vmap(jax.grad(lambda v: jnp.sum(cyclic_shift(v, shift, axis) ** 3)), in_axes=batch_axis)(stacked)
    expected = jax.vmap(jax.grad(lambda v: jnp.sum(jnp.roll(v, shift, axis=axis) ** 3)), in_axes=batch_axis)(stacked)
    np.testing.assert_array_equal(gradients, expected)


def test_refuses_a_scalar_and_a_missing_axis():
    with pytest.raises(DDGInputError, match="axis"):
        cyclic_shift(jnp.array(1.0), 1)
    with pytest.raises(DDGInputError, match="axis"):
        cyclic_shift(jnp.ones((3, 2)), 1, axis=2)
