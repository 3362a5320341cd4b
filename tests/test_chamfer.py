"""Tests for the Chamfer distance and nearest neighbours (ddgjax/optim/_chamfer.py): both searches (the host k-d
tree and the brute force) against dense NumPy argmins and SciPy's cKDTree; ties and duplicate points to the lowest
index with either; values and gradients against NumPy's analytic gradient and finite differences; jit, grad, vmap;
2-D and float32 points; non-finite points and malformed input."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads
from scipy.spatial import cKDTree

from ddgjax import DDGInputError
from ddgjax.optim import _chamfer, chamfer_distance, nearest_neighbors

METHODS = ("kdtree", "brute")
# The brute force compiles a program per shape: its runs of the heavier tests are slow ones.
METHODS_SLOW_BRUTE = ("kdtree", pytest.param("brute", marks=pytest.mark.slow))


def _dense_reference(a, b):
    """Nearest indices both ways (first index on ties, as `np.argmin`) and the Chamfer distance, in NumPy."""
    d2 = sum((a[:, None, k] - b[None, :, k]) ** 2 for k in range(a.shape[1]))
    return d2.argmin(1), d2.argmin(0), d2.min(1).mean() + d2.min(0).mean()


def _analytic_gradient(a, b):
    """`(dC/da, dC/db)` of the Chamfer distance with cKDTree's nearest points (no ties), in NumPy."""
    in_b, in_a = cKDTree(b).query(a)[1], cKDTree(a).query(b)[1]
    to_b, to_a = a - b[in_b], b - a[in_a]
    grad_a, grad_b = 2 * to_b / len(a), 2 * to_a / len(b)
    np.add.at(grad_a, in_a, -2 * to_a / len(b))
    np.add.at(grad_b, in_b, -2 * to_b / len(a))
    return grad_a, grad_b


def _grid(n, d):
    return np.stack(np.meshgrid(*[np.arange(float(n))] * d, indexing="ij"), -1).reshape(-1, d)


def _assert_nearest(a, b, **options):
    in_b, in_a, expected = _dense_reference(np.asarray(a, np.float64), np.asarray(b, np.float64))
    nearest = nearest_neighbors(a, b, **options)
    np.testing.assert_array_equal(nearest.nearest_in_b, in_b)
    np.testing.assert_array_equal(nearest.nearest_in_a, in_a)
    assert nearest.nearest_in_b.dtype == jnp.int32
    return expected


@pytest.mark.parametrize("method", METHODS_SLOW_BRUTE)
def test_nearest_and_value_against_numpy_and_ckdtree(method):
    rng = np.random.default_rng(0)
    for na, nb, d in ((301, 157, 3), (1, 40, 3), (40, 1, 3), (200, 300, 2), (50, 60, 5)):
        a, b = rng.normal(size=(na, d)), rng.normal(size=(nb, d))
        expected = _assert_nearest(a, b, method=method)
        assert float(chamfer_distance(a, b, method=method)) == pytest.approx(expected, rel=1e-13)
        # The peer: cKDTree's distances, squared and averaged.
        peer = np.mean(cKDTree(b).query(a)[0] ** 2) + np.mean(cKDTree(a).query(b)[0] ** 2)
        assert float(chamfer_distance(a, b, method=method)) == pytest.approx(peer, rel=1e-12)
    assert float(chamfer_distance(a, a, method=method)) == 0.0
    nn_b, nn_a = nearest_neighbors(a, b, method=method)  # a named result still unpacks
    np.testing.assert_array_equal(nn_a, _dense_reference(a, b)[1])


@pytest.mark.slow  # the fast tier's time limit (its checks run in the full suite)
def test_brute_force_chunks():
    rng = np.random.default_rng(1)
    a, b = rng.normal(size=(301, 3)), rng.normal(size=(157, 3))
    for chunk in (1, 64, 301, 1000):
        expected = _assert_nearest(a, b, method="brute", chunk_size=chunk)
        assert float(chamfer_distance(a, b, method="brute", chunk_size=chunk)) == pytest.approx(expected, rel=1e-13)


def test_auto_is_the_kdtree_on_cpu_above_a_million_pairs():
    a, b = np.zeros((1025, 3)), np.zeros((1024, 3))
    assert jax.default_backend() == "cpu"
    uses_the_tree = lambda a, b, **options: (
        "pure_callback" in str(jax.make_jaxpr(lambda a, b: chamfer_distance(a, b, **options))(a, b))
    )
    assert uses_the_tree(a, b) and uses_the_tree(a, b, method="kdtree") and uses_the_tree(a[:30], b[:30], method="kdtree")
    assert not uses_the_tree(a[:1024], b) and not uses_the_tree(a, b, method="brute")


@pytest.mark.parametrize("method", METHODS)
def test_ties_and_duplicates_go_to_the_lowest_index(method):
    # Integer grids: every distance is exact, so half-integer offsets tie between 2, 4 or 8 grid points, and
    # repeated grid points tie at distance zero.
    grid = _grid(4, 3)
    b = np.concatenate([grid, grid[::-1], grid[:10]])
    a = np.concatenate([grid + 0.5, grid, grid + np.array([0.5, 0.0, 0.0]), grid[::-1] + 0.25])
    _assert_nearest(a, b, method=method)
    _assert_nearest(b, a, method=method)
    _assert_nearest(a[:1], b, method=method)
    rng = np.random.default_rng(3)
    for d in (2, 3):  # small integer clouds: many duplicates and ties
        a, b = rng.integers(0, 4, size=(300, d)).astype(float), rng.integers(0, 4, size=(200, d)).astype(float)
        _assert_nearest(a, b, method=method)
    a = np.repeat(rng.normal(size=(20, 2)), 5, axis=0)[rng.permutation(100)]  # each point five times
    _assert_nearest(a, a, method=method)
    assert float(chamfer_distance(a, a, method=method)) == 0.0


def test_ties_in_blocks_of_candidates(monkeypatch):
    # Many tied candidates: the near-tie resolution runs in blocks of rows (here tiny ones).
    monkeypatch.setattr(_chamfer, "_TIE_CANDIDATES", 7)
    b = np.repeat(_grid(3, 2), 4, axis=0)[::-1].copy()
    a = np.concatenate([_grid(3, 2) + 0.5, _grid(3, 2)])
    _assert_nearest(a, b, method="kdtree")


def test_kdtree_equals_brute_force_on_random_clouds():
    rng = np.random.default_rng(4)
    for n in (10, 500, 3000):
        a, b = rng.normal(size=(n, 3)), rng.uniform(-2, 2, size=(n // 2 + 1, 3))
        b[::7] = a[: len(b[::7])]  # coincident points across the clouds
        kdtree, brute = nearest_neighbors(a, b, method="kdtree"), nearest_neighbors(a, b, method="brute")
        np.testing.assert_array_equal(kdtree.nearest_in_b, brute.nearest_in_b)
        np.testing.assert_array_equal(kdtree.nearest_in_a, brute.nearest_in_a)


def test_float32_points():
    rng = np.random.default_rng(5)
    a, b = rng.normal(size=(400, 3)).astype(np.float32), rng.normal(size=(300, 3)).astype(np.float32)
    kdtree, brute = nearest_neighbors(a, b, method="kdtree"), nearest_neighbors(a, b, method="brute")
    np.testing.assert_array_equal(kdtree.nearest_in_b, brute.nearest_in_b)
    np.testing.assert_array_equal(kdtree.nearest_in_a, brute.nearest_in_a)
    value = chamfer_distance(a, b)
    assert value.dtype == jnp.float32
    # float32 sums of 700 squared distances: round-off of a few float32 eps.
    assert float(value) == pytest.approx(_dense_reference(a.astype(float), b.astype(float))[2], rel=1e-5)


@pytest.mark.parametrize("method", METHODS_SLOW_BRUTE)
def test_gradient_against_numpy_and_finite_differences(method):
    rng = np.random.default_rng(6)
    a, b = rng.normal(size=(400, 3)), rng.normal(size=(250, 3))
    grad_a, grad_b = jax.jit(jax.grad(lambda a, b: chamfer_distance(a, b, method=method), argnums=(0, 1)))(a, b)
    expected_a, expected_b = _analytic_gradient(a, b)
    np.testing.assert_allclose(grad_a, expected_a, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(grad_b, expected_b, rtol=1e-12, atol=1e-15)
    a, b = jnp.asarray(a[:40]), jnp.asarray(b[:30])
    # A small step: the loss has kinks where a nearest neighbour changes, and a large random step crosses some.
    check_grads(jax.jit(lambda a, b: chamfer_distance(a, b, method=method)), (a, b), order=1, modes=("rev",), eps=1e-6)
    # Moving b onto a's points zeroes the a->b term's gradient on those points.
    assert np.all(np.isfinite(jax.grad(lambda a: chamfer_distance(a, a, method=method))(a)))


def test_gradient_at_ties_is_the_same_with_either_method():
    grid = _grid(3, 3)
    a, b = grid + 0.5, np.concatenate([grid, grid])
    grads = [jax.grad(lambda a, b, m=m: chamfer_distance(a, b, method=m), argnums=(0, 1))(a, b) for m in METHODS]
    for kdtree, brute in zip(*grads):
        np.testing.assert_array_equal(kdtree, brute)


@pytest.mark.parametrize("method", METHODS)
def test_jit_and_vmap(method):
    rng = np.random.default_rng(7)
    A, B = rng.normal(size=(4, 60, 3)), rng.normal(size=(3, 45, 3))
    b = B[0]
    one = lambda a, b: chamfer_distance(a, b, method=method)
    expected = np.array([float(chamfer_distance(a, b, method="brute")) for a in A])
    np.testing.assert_allclose(jax.jit(jax.vmap(one, in_axes=(0, None)))(A, b), expected, rtol=1e-14)
    np.testing.assert_allclose(jax.vmap(one, in_axes=(None, 0))(b, A), expected, rtol=1e-14)
    np.testing.assert_allclose(jax.vmap(one)(A[:3], B), [float(one(a, b)) for a, b in zip(A[:3], B)], rtol=1e-14)
    # Nested: every pair of a batch of A and a batch of B.
    nested = jax.jit(jax.vmap(jax.vmap(lambda a, b: nearest_neighbors(a, b, method=method).nearest_in_a, (0, None)), (None, 0)))
    indices = nested(A, B)
    assert indices.shape == (3, 4, 45)
    for j, b in enumerate(B):
        for i, a in enumerate(A):
            np.testing.assert_array_equal(indices[j, i], _dense_reference(a, b)[1])
    grads = jax.jit(jax.vmap(jax.grad(one), in_axes=(0, None)))(A, b)
    for a, grad in zip(A, grads):
        np.testing.assert_allclose(grad, _analytic_gradient(a, b)[0], rtol=1e-12, atol=1e-15)


def test_non_finite_points():
    rng = np.random.default_rng(8)
    a, b = rng.normal(size=(50, 3)), rng.normal(size=(40, 3))
    bad = a.copy()
    bad[3, 1], bad[7, 0] = np.nan, np.inf
    with pytest.raises(DDGInputError, match=r"points_a: expected finite coordinates.*\[3, 7\]"):
        chamfer_distance(bad, b)
    with pytest.raises(DDGInputError, match="points_b: expected finite"):
        nearest_neighbors(b, jnp.asarray(bad), method="brute")
    # Under jit the values are not inspected: the loss is NaN, and a non-finite point is never a finite one's nearest.
    finite = np.all(np.isfinite(bad), axis=1)
    for method in METHODS:
        assert np.isnan(jax.jit(lambda a, b, m=method: chamfer_distance(a, b, method=m))(bad, b))
        in_b, in_a = jax.jit(lambda a, b, m=method: nearest_neighbors(a, b, method=m))(bad, b)
        np.testing.assert_array_equal(in_b[finite], _dense_reference(a[finite], b)[0])
        np.testing.assert_array_equal(np.flatnonzero(finite)[_dense_reference(a[finite], b)[1]], in_a)
    both = [jax.jit(lambda a, b, m=m: nearest_neighbors(a, b, method=m))(bad, bad[::-1]) for m in METHODS]
    for kdtree, brute in zip(*both):
        np.testing.assert_array_equal(kdtree, brute)


def test_bad_input(without_type_checker):
    points = np.zeros((3, 3))
    with pytest.raises(DDGInputError, match="dimension"):
        chamfer_distance(points, np.zeros((3, 2)))
    with pytest.raises(DDGInputError, match=r"points_a: expected an \(n, d\) array"):
        chamfer_distance(np.zeros(3), points)
    with pytest.raises(DDGInputError, match=r"points_b: expected an \(n, d\) array"):
        nearest_neighbors(points, np.zeros((2, 3, 3)))
    with pytest.raises(DDGInputError, match="points_b: expected at least 1 rows"):
        chamfer_distance(points, np.zeros((0, 3)))
    with pytest.raises(DDGInputError, match="method: expected one of 'auto', 'kdtree', 'brute'"):
        chamfer_distance(points, points, method="kd-tree")
    with pytest.raises(DDGInputError, match="chunk_size"):
        nearest_neighbors(points, points, method="brute", chunk_size=0)
    with pytest.raises(DDGInputError, match="points_a: expected a real"):
        chamfer_distance(points.astype(complex), points)
