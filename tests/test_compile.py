"""`kernel` (ddgjax._compile), the one way ddgjax compiles its kernels: static arguments by name, meshes
without their topology (one program per size), argument types checked, orientation checked, XLA:CPU
options at top level only."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import ddgjax
from ddgjax._compile import CPU_OPTIONS, at_top_level, kernel
from ddgjax.curves import Curve
from ddgjax.mesh import Mesh

cpu_only = pytest.mark.skipif(jax.default_backend() != "cpu", reason="the tuned programs are compiled for CPU only")


def _squared_lengths(v):
    return jnp.sum(v * v, axis=-1)  # a size-2 reduction: what XLA:CPU hands to YNNPACK on large arrays


def _relabelled(mesh: Mesh, seed: int) -> Mesh:
    """The same surface with its vertices renumbered: the same sizes, another connectivity."""
    V, F = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    permutation = np.random.default_rng(seed).permutation(V.shape[0])
    return Mesh.from_arrays(V[permutation], np.argsort(permutation)[F])


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
    options = ddgjax.cpu_compiler_options(extra={"xla_cpu_no_such_option_in_any_xla": "1"})
    assert "xla_cpu_no_such_option_in_any_xla" not in options
    assert set(options) <= set(CPU_OPTIONS)
    # ... and what is left compiles: the public recipe for a user's own jit.
    compiled = jax.jit(lambda v: _squared_lengths(v), compiler_options=ddgjax.cpu_compiler_options() or None)
    np.testing.assert_array_equal(compiled(jnp.ones((4, 2))), 2.0)


def test_static_arguments_by_name_work_positionally_and_by_keyword():
    traces = []

    @kernel(static_argnames=("power",))
    def power_of(x, power):
        traces.append(power)
        return x**power

    assert float(power_of(jnp.float64(2.0), 3)) == 8.0
    assert float(power_of(jnp.float64(3.0), 3)) == 27.0  # the same static value: no new trace
    assert float(power_of(jnp.float64(2.0), 2)) == 4.0
    assert traces == [3, 2] and power_of._cache_size() == 2
    assert float(power_of(jnp.float64(2.0), power=2)) == 4.0  # by keyword too (JAX keys keyword calls apart)


def test_a_second_mesh_of_the_same_size_compiles_nothing(icosphere1, icosphere2):
    seen = []

    @kernel
    def summary(mesh):
        seen.append(mesh.topology)
        return jnp.sum(mesh.vertices[mesh.faces[:, 0]]) + mesh.n_edges

    first = icosphere2
    second = _relabelled(first, seed=0)
    assert second.topology != first.topology
    for mesh in (first, second, first.with_vertices(2 * first.vertices)):
        expected = np.sum(np.asarray(mesh.vertices)[np.asarray(mesh.faces)[:, 0]]) + mesh.n_edges
        np.testing.assert_allclose(summary(mesh), expected, rtol=1e-14)
    assert seen == [None] and summary._cache_size() == 1  # one trace, one program, no topology inside
    summary(icosphere1)  # another size: another program
    assert summary._cache_size() == 2


def test_a_mesh_or_curve_parameter_refuses_anything_else(without_type_checker, icosphere0):
    @kernel
    def on_mesh(mesh):
        return jnp.sum(mesh.vertices)

    @kernel
    def on_curve(curve):
        return jnp.sum(curve.points)

    mesh = icosphere0
    for wrong in (np.asarray(mesh.vertices), (np.asarray(mesh.vertices), np.asarray(mesh.faces)), "mesh.obj"):
        with pytest.raises(ddgjax.DDGInputError, match=r"mesh: expected a ddgjax Mesh.*Mesh\.from_arrays"):
            on_mesh(wrong)
    with pytest.raises(ddgjax.DDGInputError, match="curve"):
        on_curve(np.zeros((5, 2)))
    square = Curve(jnp.asarray([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]))
    np.testing.assert_array_equal(on_curve(square), 4.0)
    assert on_mesh._cache_size() == 0  # refused before tracing


def test_orientation_is_checked_on_every_call(icosphere1):
    @kernel(requires_orientation="the_operation")
    def oriented_only(mesh):
        return jnp.sum(mesh.vertices)

    mesh = icosphere1
    F = np.asarray(mesh.faces).copy()
    F[0] = F[0, ::-1]
    flipped = Mesh.from_arrays(np.asarray(mesh.vertices), F)  # the same sizes: the compiled program would fit
    oriented_only(mesh)
    with pytest.raises(ddgjax.MeshDataError, match="the_operation.*consistently oriented"):
        oriented_only(flipped)
    with pytest.raises(ddgjax.MeshDataError, match="consistently oriented"):
        jax.jit(oriented_only)(flipped)  # the topology is static in a caller's jit: checked while tracing


@cpu_only
def test_cpu_options_are_chosen_at_top_level_only():
    """`extra_cpu_options` is consulted for a top-level call (each distinct set of options its own
    program) and never under a caller's transformation, whose program the kernel is traced into.
    (That the options remove XLA's YNNPACK fusions, and how much faster that is, benchmarks/laplacian.py
    prints: a property of XLA's compiled code, not of ddgjax's behaviour.)"""
    consulted = []

    def choose(x, power):
        consulted.append(power)
        return {"xla_cpu_enable_fast_min_max": "false"} if power > 2 else {}

    cube = kernel(lambda x, power: x**power, static_argnames=("power",), extra_cpu_options=choose)
    points = jnp.asarray(np.random.default_rng(1).random(300))
    np.testing.assert_allclose(cube(points, 3), np.asarray(points) ** 3, rtol=1e-15)
    np.testing.assert_allclose(cube(points, power=2), np.asarray(points) ** 2, rtol=1e-15)
    assert consulted == [3, 2]
    programs = cube._cache_size()
    np.testing.assert_allclose(jax.jit(cube, static_argnames="power")(points, 3), np.asarray(points) ** 3, rtol=1e-15)
    np.testing.assert_allclose(jax.vmap(lambda x: cube(x, 3))(points[None])[0], np.asarray(points) ** 3, rtol=1e-15)
    np.testing.assert_allclose(jax.grad(lambda p: jnp.sum(cube(p, 2)))(points), 2 * np.asarray(points), rtol=1e-15)
    assert consulted == [3, 2] and cube._cache_size() == programs  # nested calls: nothing chosen, nothing compiled


@pytest.mark.parametrize("extra", ["xla_cpu_use_xnnpack", {"xla_cpu_use_xnnpack": False}, {1: "a"}])
def test_malformed_extra_options_are_refused(extra):
    with pytest.raises(ddgjax.DDGInputError, match="extra"):
        ddgjax.cpu_compiler_options(extra=extra)


def test_a_kernel_keeps_a_bounded_number_of_programs_and_frees_the_others(monkeypatch):
    """One program per argument signature, the `PROGRAMS_PER_KERNEL` most recent kept: a stream of new
    sizes does not add programs forever (issue 22), and a dropped program is released by JAX's caches
    (they are keyed weakly on the function each program was compiled from)."""
    import gc
    import weakref

    from ddgjax import _compile

    monkeypatch.setattr(_compile, "PROGRAMS_PER_KERNEL", 3)
    compiled_from = []
    fresh = _compile._fresh
    monkeypatch.setattr(_compile, "_fresh", lambda function: compiled_from.append(fresh(function)) or compiled_from[-1])
    double = kernel(lambda x: 2.0 * x)
    for n in range(10, 16):
        np.testing.assert_array_equal(double(np.ones(n)), 2.0 * np.ones(n))
    assert double._cache_size() == 3 and len(compiled_from) == 6
    dropped = [weakref.ref(function) for function in compiled_from[:3]]
    compiled_from.clear()
    gc.collect()
    assert all(reference() is None for reference in dropped)  # nothing in JAX holds the evicted programs
    np.testing.assert_array_equal(double(np.ones(15)), 2.0 * np.ones(15))  # the most recent: no new program
    assert double._cache_size() == 3 and not compiled_from


def test_static_arguments_passed_by_position_select_programs_by_value():
    power_of = kernel(lambda x, power: x**power, static_argnames=("power",))
    x = np.arange(4.0)
    np.testing.assert_array_equal(power_of(x, 2), x**2)
    np.testing.assert_array_equal(power_of(x, 3), x**3)
    np.testing.assert_array_equal(power_of(x, 2), x**2)
    assert power_of._cache_size() == 2
