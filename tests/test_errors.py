"""Tests for ddgjax._errors (the shared validators) and ddgjax._results (the results convention)."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ddgjax import RESULTS, DDGInputError
from ddgjax._errors import check_choice, check_float_shape
from ddgjax._results import raise_if_failed


def test_check_choice_accepts_the_choices_and_numpy_scalars():
    assert check_choice("kind", "A", ("A", "B")) == "A"
    assert check_choice("rescale", None, (None, "length")) is None
    assert check_choice("degree", np.int64(1), (0, 1, 2)) == 1 and type(check_choice("degree", np.int64(1), (0, 1, 2))) is int


@pytest.mark.parametrize("value", [True, "a", 1.0, np.array([1, 2]), jnp.asarray(1), None])
def test_check_choice_refuses_anything_else_naming_the_argument(value):
    with pytest.raises(DDGInputError, match=r"degree: expected one of 0, 1, 2, got "):
        check_choice("degree", value, (0, 1, 2))


def test_check_float_shape_works_on_traced_arrays():
    def shaped(x):
        check_float_shape("vertices", x, (3,))
        return x

    jax.jit(shaped)(jnp.zeros((4, 3)))
    with pytest.raises(DDGInputError, match=r"vertices: expected shape \(n, 3\), got \(4, 2\)"):
        jax.jit(shaped)(jnp.zeros((4, 2)))


def test_results_convention_raises_only_when_asked_and_only_on_failure():
    def run(x, throw):
        result = RESULTS.where(x > 0, RESULTS.self_intersection, RESULTS.successful)
        return raise_if_failed(x, result, throw), result

    value, result = eqx.filter_jit(run)(jnp.asarray(-1.0), True)
    assert result == RESULTS.successful and value == -1.0
    value, result = eqx.filter_jit(run)(jnp.asarray(1.0), False)  # throw=False: inspect the result
    assert result == RESULTS.self_intersection
    with pytest.raises(eqx.EquinoxRuntimeError, match="not simple"):
        eqx.filter_jit(run)(jnp.asarray(1.0), True)
    with pytest.raises(eqx.EquinoxRuntimeError, match="not simple"):  # under vmap: any failed member raises
        jax.vmap(lambda x: run(x, True)[0])(jnp.asarray([-1.0, 1.0]))
