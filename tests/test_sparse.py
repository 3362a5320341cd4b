"""Tests for ddgjax.sparse: patterns, products, transposes, exports, lineax operators, autodiff."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import pytest
import scipy.sparse as sp
from jax.test_util import check_grads

from ddgjax._errors import DDGInputError
from ddgjax.sparse import SparseMatrix, SparsityPattern, congruence, diagonal_matrix, find_slots, from_scipy, gather_sum


def _random(shape, density, seed, dense_row=None):
    matrix = sp.random(*shape, density=density, format="lil", random_state=seed)
    if dense_row is not None:  # a high-degree outlier row: exercises the COO tail of the ELL layout
        matrix[dense_row, :] = np.random.default_rng(seed).random(shape[1])
    return matrix.tocsr()


@pytest.fixture(scope="module", params=[((40, 30), None), ((60, 60), 5)], ids=["rect", "tail"])
def pair(request):
    shape, dense_row = request.param
    reference = _random(shape, 0.15, 0, dense_row)
    return from_scipy(reference), reference


def test_products_transpose_and_exports_match_scipy(pair):
    matrix, reference = pair
    rng = np.random.default_rng(1)
    x, block = rng.random(reference.shape[1]), rng.random((reference.shape[1], 4))
    y = rng.random(reference.shape[0])
    # One jitted call: eager dispatch of every small op would dominate the test time.
    products = jax.jit(lambda m, x, block, y: (m @ x, m @ block, m.T @ y, m.T.T @ x, m.row_sums()))
    ax, ablock, aty, attx, sums = products(matrix, x, block, y)
    np.testing.assert_allclose(ax, reference @ x, rtol=1e-13, atol=1e-14)
    np.testing.assert_allclose(ablock, reference @ block, rtol=1e-13, atol=1e-14)
    np.testing.assert_allclose(aty, reference.T @ y, rtol=1e-13, atol=1e-14)
    np.testing.assert_allclose(attx, reference @ x, rtol=1e-13, atol=1e-14)
    np.testing.assert_allclose(sums, np.asarray(reference.sum(axis=1)).ravel(), rtol=1e-13)
    np.testing.assert_array_equal(matrix.todense(), reference.toarray())
    np.testing.assert_array_equal(matrix.to_bcoo().todense(), reference.toarray())
    exported = matrix.to_scipy()
    assert exported.has_canonical_format and exported.nnz == reference.nnz
    assert abs(exported - reference).max() == 0


def test_tail_layout_is_used_for_outlier_rows():
    matrix = from_scipy(_random((60, 60), 0.15, 0, dense_row=5))
    assert matrix.pattern.nnz > matrix.shape[0] * matrix.pattern.width  # a COO tail exists
    assert matrix.pattern.width < 60


def test_csr_pattern_built_from_jax_arrays_and_its_transpose():
    reference = _random((20, 12), 0.3, 3)
    pattern = SparsityPattern(
        rows=jnp.asarray(np.repeat(np.arange(20), np.diff(reference.indptr)), dtype=jnp.int32),
        cols=jnp.asarray(reference.indices, dtype=jnp.int32),
        indptr=jnp.asarray(reference.indptr, dtype=jnp.int32),
        shape=(20, 12),
    )
    matrix = SparseMatrix(jnp.asarray(reference.data), pattern)
    y = np.random.default_rng(0).random(20)
    np.testing.assert_allclose(matrix.T @ y, reference.T @ y, rtol=1e-13)
    np.testing.assert_allclose(jax.jit(lambda m, v: m.T @ v)(matrix, y), reference.T @ y, rtol=1e-13)
    assert abs(matrix.T.to_scipy() - reference.T).max() == 0
    np.testing.assert_allclose(matrix.diagonal(), reference.diagonal())


def test_symmetric_pattern_transpose_is_a_permutation():
    reference = _random((30, 30), 0.2, 4)
    reference = reference + reference.T * 0  # symmetric *pattern*, non-symmetric values
    reference = reference + sp.csr_matrix((np.ones(1), ([0], [1])), shape=(30, 30))
    symmetric_positions = (reference != 0) + (reference.T != 0)
    values = symmetric_positions.astype(float).tocsr()
    values.data = np.random.default_rng(5).random(values.nnz)
    matrix = from_scipy(values)
    assert matrix.pattern.symmetric and matrix.pattern.transpose_pattern is None
    np.testing.assert_array_equal(matrix.T.todense(), values.T.toarray())


def test_from_edges_matches_from_coo():
    edges = np.array([[0, 1], [0, 3], [1, 2], [1, 3], [2, 3], [3, 5]])
    n = 6  # vertex 4 is isolated
    pattern, source = SparsityPattern.from_edges(edges, n)
    diagonal = np.arange(n)
    rows = np.concatenate([diagonal, edges[:, 0], edges[:, 1]])
    cols = np.concatenate([diagonal, edges[:, 1], edges[:, 0]])
    entries = np.arange(1.0, rows.size + 1)
    expected = sp.csr_matrix((entries, (rows, cols)), shape=(n, n)).toarray()
    values = jnp.take(jnp.asarray(entries), jnp.asarray(source), mode="fill", fill_value=0)
    matrix = SparseMatrix(values, pattern)
    np.testing.assert_array_equal(matrix.todense(), expected)
    assert pattern.symmetric and pattern.diagonal_first
    np.testing.assert_array_equal(matrix.T.todense(), expected.T)
    np.testing.assert_array_equal(matrix.diagonal(), np.diag(expected))


def test_arithmetic_and_pattern_mismatch():
    a_ref, b_ref = _random((15, 15), 0.3, 6), _random((15, 15), 0.3, 7)
    a = from_scipy(a_ref)
    b = SparseMatrix(a.values * 3.0 + 1.0 * (a.values != 0), a.pattern)
    np.testing.assert_allclose((a + b).todense(), a.todense() + b.todense())
    np.testing.assert_allclose((a - b).todense(), a.todense() - b.todense())
    np.testing.assert_allclose((2.0 * a - a / 2.0 + (-a) * 0.5).todense(), a.todense())
    same_positions = from_scipy(a_ref)  # another pattern object with equal arrays: accepted
    np.testing.assert_allclose((a + same_positions).todense(), 2 * a.todense())
    with pytest.raises(DDGInputError, match="matching sparsity patterns"):
        a + from_scipy(b_ref)
    with pytest.raises(DDGInputError, match="scalar"):
        a * a
    with pytest.raises(DDGInputError, match="x: expected shape"):
        a @ np.ones(3)


def test_diagonal_matrix():
    values = jnp.asarray([1.0, 2.0, 3.0])
    matrix = diagonal_matrix(values)
    np.testing.assert_array_equal(matrix @ jnp.ones(3), values)
    np.testing.assert_array_equal(matrix @ jnp.ones((3, 2)), jnp.stack([values, values], 1))
    assert matrix.T is matrix
    np.testing.assert_array_equal(matrix.diagonal(), values)
    np.testing.assert_array_equal(matrix.todense(), np.diag(values))


@pytest.fixture(scope="module")
def spd():
    base = _random((25, 25), 0.06, 8)
    reference = (base @ base.T + sp.eye(25)).tocsr()
    return from_scipy(reference), reference


def test_lineax_cg_solves(spd):
    matrix, reference = spd
    b = np.random.default_rng(9).random(25)
    operator = matrix.as_lineax_operator(symmetric=True, positive_semidefinite=True)
    assert lx.is_symmetric(operator) and lx.is_positive_semidefinite(operator)
    solution = lx.linear_solve(operator, jnp.asarray(b), lx.CG(rtol=1e-12, atol=1e-12))
    np.testing.assert_allclose(reference @ solution.value, b, rtol=1e-9)  # CG tolerance 1e-12
    np.testing.assert_allclose(operator.as_matrix(), reference.toarray(), rtol=1e-14)


def test_gradients_through_values_and_rhs(spd):
    matrix, _ = spd
    x = jnp.asarray(np.random.default_rng(10).random((25, 2)))

    def f(values, rhs):
        m = SparseMatrix(values, matrix.pattern)
        return jnp.sum(jnp.sin(m @ rhs)) + jnp.sum((m.T @ rhs) ** 2) + jnp.sum(m.diagonal() ** 3)

    # The product is bilinear: first order in both modes covers its derivative rules.
    check_grads(jax.jit(f), (matrix.values, x), order=1, modes=("fwd", "rev"))
    # d(y^T A x)/dA_ij = y_i x_j at the stored positions.
    y = jnp.asarray(np.random.default_rng(11).random(25))
    grad = jax.grad(lambda v: y @ (SparseMatrix(v, matrix.pattern) @ x[:, 0]))(matrix.values)
    expected = y[matrix.pattern.rows] * x[matrix.pattern.cols, 0]
    real = np.asarray(matrix.values) != 0
    np.testing.assert_allclose(np.asarray(grad)[real], np.asarray(expected)[real], rtol=1e-14)


def test_jit_and_vmap_equal_eager(spd):
    matrix, reference = spd
    xs = jnp.asarray(np.random.default_rng(12).random((3, 25)))
    batched = jax.vmap(lambda x: matrix @ x)(xs)
    np.testing.assert_allclose(batched, (reference @ np.asarray(xs).T).T, rtol=1e-13)
    scales = jnp.asarray([1.0, 2.0, -1.0])
    per_values = jax.vmap(lambda s, x: SparseMatrix(s * matrix.values, matrix.pattern) @ x)(scales, xs)
    np.testing.assert_allclose(per_values, scales[:, None] * batched, rtol=1e-13)
    # XLA may fuse multiply-adds differently under jit: equal to round-off, not bitwise.
    np.testing.assert_allclose(jax.jit(lambda m, x: m @ x)(matrix, xs[0]), matrix @ xs[0], rtol=1e-14)


def test_congruence_matches_scipy_and_refuses_missing_positions():
    rng = np.random.default_rng(13)
    n_rows, n = 30, 12
    cols = np.sort(np.stack([rng.choice(n, 3, replace=False) for _ in range(n_rows)]), axis=1)
    rows = np.repeat(np.arange(n_rows), 3)
    d_ref = sp.csr_matrix((rng.standard_normal(3 * n_rows), (rows, cols.ravel())), shape=(n_rows, n))
    weights = rng.random(n_rows)
    expected = (d_ref.T @ sp.diags(weights) @ d_ref).tocsr()
    target, _ = SparsityPattern.from_coo(*expected.nonzero(), (n, n))
    result = congruence(from_scipy(d_ref), jnp.asarray(weights), target)
    np.testing.assert_allclose(result.todense(), expected.toarray(), rtol=1e-13, atol=1e-15)
    jitted = jax.jit(congruence)(_as_csr_layout(d_ref), jnp.asarray(weights), target)
    np.testing.assert_allclose(jitted.todense(), expected.toarray(), rtol=1e-13, atol=1e-15)
    too_small, _ = SparsityPattern.from_coo(np.arange(n), np.arange(n), (n, n))
    with pytest.raises(DDGInputError, match="lacks"):
        congruence(from_scipy(d_ref), jnp.asarray(weights), too_small)
    slots = find_slots(target, jnp.asarray([0, 1]), jnp.asarray([0, 1]))
    assert int(slots[0]) < target.nnz


def _as_csr_layout(reference: sp.csr_matrix) -> SparseMatrix:
    pattern = SparsityPattern(
        rows=jnp.asarray(np.repeat(np.arange(reference.shape[0]), np.diff(reference.indptr)), dtype=jnp.int32),
        cols=jnp.asarray(reference.indices, dtype=jnp.int32),
        indptr=jnp.asarray(reference.indptr, dtype=jnp.int32),
        shape=reference.shape,
    )
    return SparseMatrix(jnp.asarray(reference.data), pattern)


def test_gather_sum_reverse_mode_is_the_transposed_gather():
    # y[s] = sum_k x[index[s, k]]; index 6 (out of range) pads. transpose_index lists, per x entry,
    # the outputs reading it (pad 4 = n outputs).
    index = jnp.array([[0, 3], [2, 6], [3, 5], [1, 1]])
    transpose_index = jnp.array([[0, 4], [3, 3], [1, 4], [0, 2], [4, 4], [2, 4]])
    x = jnp.linspace(0.5, 2.0, 6)
    weights = jnp.array([1.0, -2.0, 0.5, 3.0])
    plain = lambda x: jnp.sum(weights * jnp.sin(jnp.take(x, index, mode="fill", fill_value=0).sum(1)))
    custom = jax.jit(lambda x: jnp.sum(weights * jnp.sin(gather_sum(x, index, transpose_index))))
    np.testing.assert_allclose(custom(x), plain(x), rtol=1e-15)
    np.testing.assert_allclose(jax.grad(custom)(x), jax.grad(plain)(x), rtol=1e-14)
    batched = jax.vmap(jax.grad(custom))(jnp.stack([x, 2 * x]))
    np.testing.assert_allclose(batched[1], jax.grad(plain)(2 * x), rtol=1e-14)
