"""`take_rows` / `take_rows_or_zero` (ddgjax._indexing): `x[index]` without index normalisation."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ddgjax._indexing import take_rows, take_rows_or_zero

RNG = np.random.default_rng(7)
X_SHAPES = [(9,), (9, 3), (9, 2, 4)]
INDEX_SHAPES = [(5,), (4, 3), (2, 3, 2)]


@pytest.mark.parametrize("x_shape", X_SHAPES)
@pytest.mark.parametrize("index_shape", INDEX_SHAPES)
@pytest.mark.slow
def test_values_equal_numpy_indexing_eager_and_jitted(x_shape, index_shape):
    x = RNG.standard_normal(x_shape)
    index = RNG.integers(0, x_shape[0], size=index_shape).astype(np.int32)
    np.testing.assert_array_equal(take_rows(jnp.asarray(x), index), x[index])
    np.testing.assert_array_equal(jax.jit(take_rows)(x, index), x[index])
    np.testing.assert_array_equal(jax.jit(take_rows_or_zero)(x, index), x[index])


def test_or_zero_reads_zero_at_padding_indices():
    x = jnp.arange(1.0, 13.0).reshape(4, 3)
    index = jnp.array([[0, 4], [3, 100], [4, 2]], dtype=jnp.int32)
    expected = np.where((np.asarray(index) < 4)[..., None], np.asarray(x)[np.minimum(index, 3)], 0.0)
    np.testing.assert_array_equal(take_rows_or_zero(x, index), expected)
    np.testing.assert_array_equal(take_rows_or_zero(x, index), jnp.take(x, index, axis=0, mode="fill", fill_value=0))


@pytest.mark.parametrize("gather", [take_rows, take_rows_or_zero])
@pytest.mark.slow
def test_derivatives_and_vmap_match_plain_indexing(gather):
    x = jnp.linspace(-1.0, 2.0, 12).reshape(6, 2)
    index = jnp.array([[5, 0, 0], [2, 3, 5]], dtype=jnp.int32)
    weights = jnp.cos(jnp.arange(12.0)).reshape(2, 3, 2)

    def loss(gather_fn, v):
        return jnp.sum(weights * gather_fn(v, index) ** 2)

    plain = lambda v, i: v[i]
    np.testing.assert_allclose(jax.grad(lambda v: loss(gather, v))(x), jax.grad(lambda v: loss(plain, v))(x), rtol=1e-15)
    tangent = jnp.sin(jnp.arange(12.0)).reshape(6, 2)
    np.testing.assert_allclose(jax.jvp(lambda v: gather(v, index), (x,), (tangent,))[1], tangent[index], rtol=1e-15)
    batch = jnp.stack([x, 2 * x, -x])
    np.testing.assert_array_equal(jax.vmap(lambda v: gather(v, index))(batch), batch[:, index])
    indices = jnp.stack([index, index[::-1], 5 - index])
    np.testing.assert_array_equal(jax.vmap(lambda i: gather(x, i))(indices), x[indices])
