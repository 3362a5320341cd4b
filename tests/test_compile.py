"""`tuned_jit` (ddgjax._compile): top-level CPU calls compile with ddgjax's XLA options, nested ones stay plain."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import ddgjax
from ddgjax._compile import CPU_OPTIONS, at_top_level, tuned_jit

cpu_only = pytest.mark.skipif(jax.default_backend() != "cpu", reason="the tuned programs are compiled for CPU only")


def _squared_lengths(v):
    return jnp.sum(v * v, axis=-1)  # a size-2 reduction: what XLA:CPU hands to YNNPACK on large arrays


def test_at_top_level_is_false_under_every_transformation():
    seen = []

    def probe(x):
        seen.append(at_top_level())
        return x

    assert at_top_level()
    jax.jit(probe)(1.0)
    jax.grad(probe)(1.0)
    jax.vmap(probe)(jnp.ones(2))
    assert seen == [False, False, False]


def test_unknown_options_are_left_out():
    options = ddgjax.cpu_compiler_options({"xla_cpu_no_such_option_in_any_xla": "1"})
    assert "xla_cpu_no_such_option_in_any_xla" not in options
    assert set(options) <= set(CPU_OPTIONS)
    # ... and what is left compiles: the public recipe for a user's own jit.
    kernel = jax.jit(lambda v: _squared_lengths(v), compiler_options=ddgjax.cpu_compiler_options() or None)
    np.testing.assert_allclose(kernel(jnp.ones((4, 2))), 2.0)


@cpu_only
def test_top_level_call_runs_the_tuned_program_without_ynn_fusions():
    kernel = tuned_jit(lambda v: _squared_lengths(v))  # a function of its own: JAX shares caches per function
    points = jnp.asarray(np.random.default_rng(0).random((50_000, 2)))
    np.testing.assert_allclose(kernel(points), np.sum(np.asarray(points) ** 2, axis=1), rtol=1e-15)
    assert kernel.plain._cache_size() == 0 and len(kernel.tuned_versions) == 1
    (tuned,) = kernel.tuned_versions.values()
    assert "__ynn_fusion" not in tuned.lower(points).compile().as_text()
    assert kernel._cache_size() == 1


def test_nested_calls_use_the_plain_program_and_agree():
    kernel = tuned_jit(lambda v: _squared_lengths(v))
    points = jnp.asarray(np.random.default_rng(1).random((300, 2)))
    expected = np.sum(np.asarray(points) ** 2, axis=1)
    np.testing.assert_allclose(jax.jit(kernel)(points), expected, rtol=1e-15)
    np.testing.assert_allclose(jax.vmap(kernel)(points[None])[0], expected, rtol=1e-15)
    np.testing.assert_allclose(jax.grad(lambda p: jnp.sum(kernel(p)))(points), 2 * np.asarray(points), rtol=1e-15)
    assert kernel.tuned_versions == {}  # every call was nested: no tuned program was made


def test_static_arguments_by_name_work_positionally_and_extra_options_make_versions():
    calls = []

    def choose(x, power):
        calls.append(power)
        return {"xla_disable_hlo_passes": "cpu-parallel-task-assigner"} if power > 2 else {}

    kernel = tuned_jit(lambda x, power: x**power, static_argnames=("power",), extra_cpu_options=choose)
    assert float(kernel(jnp.float64(2.0), 3)) == 8.0
    assert float(kernel(jnp.float64(2.0), power=2)) == 4.0
    assert calls == [3, 2]
    assert len(kernel.tuned_versions) == (2 if jax.default_backend() == "cpu" else 0)


@pytest.mark.parametrize("extra", ["xla_cpu_use_xnnpack", {"xla_cpu_use_xnnpack": False}, {1: "a"}])
def test_malformed_extra_options_are_refused(extra):
    with pytest.raises(ddgjax.DDGInputError, match="extra"):
        ddgjax.cpu_compiler_options(extra)
