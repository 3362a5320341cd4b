"""Tests for ddgjax.sparse: patterns, products, transposes, exports, lineax operators, autodiff."""

from __future__ import annotations

import dataclasses
import re

import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import pytest
import scipy.sparse as sp
from jax.test_util import check_grads
from jaxtyping import TypeCheckError

from ddgjax import DDGInputError
from ddgjax.sparse import (
    NonNegative,
    SparseMatrix,
    SparsityPattern,
    congruence,
    congruence_plan,
    diagonal_matrix,
    from_scipy,
    gather_sum,
    identity,
    nonnegative,
)

# jax.test_util.check_grads compares with central finite differences of step 1e-4: their truncation
# error is ~1e-8 relative, so its float64 default tolerance (1e-5) is used; exact derivative
# identities are checked to round-off separately.


def primitives(jaxpr) -> set[str]:
    """Names of the primitives in a printed jaxpr (nested ones too)."""
    return set(re.findall(r"=\s+([A-Za-z_][\w\-]*)", str(jaxpr)))


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


@pytest.mark.slow
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
    # The stored row-major ELL index is the slot-major one transposed; an ELL pattern made by hand
    # (no stored index) gives the same product.
    pattern = matrix.pattern
    first, n_rows = int(pattern.diagonal_first), matrix.shape[0]
    slot_major = np.asarray(pattern.cols[: n_rows * pattern.width]).reshape(pattern.width, n_rows)
    np.testing.assert_array_equal(pattern.row_cols, slot_major[first:].T)
    by_hand = SparseMatrix(matrix.values, dataclasses.replace(pattern, row_cols=None))
    np.testing.assert_array_equal(products(by_hand, x, block, y)[0], ax)
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
    assert abs(matrix.T.T.to_scipy() - reference).max() == 0
    np.testing.assert_allclose(matrix.T.T @ np.ones(12), reference @ np.ones(12), rtol=1e-13)
    np.testing.assert_allclose(matrix.diagonal(), reference.diagonal())
    # DESIGN.md: no sort or search of a fixed pattern at run time.
    assert not {"sort", "while"} & primitives(jax.make_jaxpr(lambda m, v: m.T @ v)(matrix, y))


def test_symmetric_pattern_transpose_is_a_permutation():
    reference = _random((30, 30), 0.2, 4)
    reference = reference + reference.T * 0  # symmetric *pattern*, non-symmetric values
    reference = reference + sp.csr_matrix((np.ones(1), ([0], [1])), shape=(30, 30))
    symmetric_positions = (reference != 0) + (reference.T != 0)
    values = symmetric_positions.astype(float).tocsr()
    values.data = np.random.default_rng(5).random(values.nnz)
    matrix = from_scipy(values)
    assert matrix.pattern.symmetric and matrix.pattern.transpose_pattern is None
    assert not matrix.symmetric  # a symmetric pattern, not symmetric values
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
    x = np.arange(1.0, n + 1)
    np.testing.assert_allclose(matrix @ x, expected @ x, rtol=1e-15)


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
    with pytest.raises(DDGInputError, match=r"x: expected shape \(15,\) or \(15, k\), got \(3,\)"):
        a @ np.ones(3)
    with pytest.raises(DDGInputError, match=r"x: expected shape \(15,\) or \(15, k\), got \(3,\)"):
        jax.jit(lambda m, x: m @ x)(a, jnp.ones(3))  # the same message under jit


@pytest.mark.parametrize("other", ["ddgjax", "scipy", "bcoo"])
def test_sparse_sparse_products_are_refused_as_such(other, without_type_checker):
    a = from_scipy(_random((15, 15), 0.3, 6))
    b = {"ddgjax": a, "scipy": a.to_scipy(), "bcoo": a.to_bcoo()}[other]
    with pytest.raises(DDGInputError, match="sparse-sparse products are not supported"):
        a @ b


def test_conversion_to_a_dense_array_is_refused_with_what_to_call():
    a = from_scipy(_random((15, 15), 0.3, 6))
    for convert in (np.asarray, jnp.asarray, np.array):
        with pytest.raises(DDGInputError, match=r"not a dense array; use A\.todense\(\)"):
            convert(a)


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
    return from_scipy(reference, positive_semidefinite=True), reference


@pytest.mark.slow  # the fast tier's time limit (its checks run in the full suite)
def test_lineax_cg_solves(spd):
    matrix, reference = spd
    b = np.random.default_rng(9).random(25)
    operator = matrix.as_lineax_operator()  # tags from the matrix's own flags
    assert lx.is_symmetric(operator) and lx.is_positive_semidefinite(operator)
    solution = lx.linear_solve(operator, jnp.asarray(b), lx.CG(rtol=1e-12, atol=1e-12))
    np.testing.assert_allclose(reference @ solution.value, b, rtol=1e-9)  # CG tolerance 1e-12
    np.testing.assert_allclose(operator.as_matrix(), reference.toarray(), rtol=1e-14)


@pytest.mark.slow
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


@pytest.mark.slow
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


def test_eager_product_is_one_compiled_call_per_structure(spd):
    """Eager `A @ x` runs one cached program: a second matrix on the same pattern (new values) and
    a NumPy right-hand side reuse it; nothing is compiled per matrix."""
    from ddgjax.sparse._matrix import _compiled_product

    def programs():
        return _compiled_product._cache_size()

    matrix, reference = spd
    x = np.random.default_rng(14).random(25)
    np.testing.assert_allclose(matrix @ x, reference @ x, rtol=1e-13)
    compiled = programs()
    doubled = SparseMatrix(
        2 * matrix.values, matrix.pattern, symmetric=matrix.symmetric, positive_semidefinite=matrix.positive_semidefinite
    )
    np.testing.assert_allclose(doubled @ jnp.asarray(x), 2 * (reference @ x), rtol=1e-13)
    assert programs() == compiled


@pytest.mark.slow
def test_congruence_matches_scipy_and_refuses_missing_positions():
    rng = np.random.default_rng(13)
    n_rows, n = 30, 12
    cols = np.sort(np.stack([rng.choice(n, 3, replace=False) for _ in range(n_rows)]), axis=1)
    rows = np.repeat(np.arange(n_rows), 3)
    d_ref = sp.csr_matrix((rng.standard_normal(3 * n_rows), (rows, cols.ravel())), shape=(n_rows, n))
    weights = rng.random(n_rows)
    expected = (d_ref.T @ sp.diags(weights) @ d_ref).tocsr()
    target, _ = SparsityPattern.from_coo(*expected.nonzero(), (n, n))
    plan = congruence_plan(cols, target)
    ell = from_scipy(d_ref)  # ELL of width 3, values row by row in column-major storage
    result = congruence(ell, jnp.asarray(weights), target, plan)
    np.testing.assert_allclose(result.todense(), expected.toarray(), rtol=1e-13, atol=1e-15)
    assert result.symmetric
    jitted = jax.jit(congruence)(_as_csr_layout(d_ref), jnp.asarray(weights), target, plan)
    np.testing.assert_allclose(jitted.todense(), expected.toarray(), rtol=1e-13, atol=1e-15)
    # No search or sort at run time: gathers and one sorted segment_sum.
    jaxpr = jax.make_jaxpr(congruence)(_as_csr_layout(d_ref), jnp.asarray(weights), target, plan)
    assert not {"sort", "while"} & primitives(jaxpr)
    # Linear in the weights, bilinear in D's values: forward and reverse mode.
    f = lambda w, v: jnp.sum(jnp.sin(congruence(SparseMatrix(v, ell.pattern), w, target, plan).values))
    check_grads(jax.jit(f), (jnp.asarray(weights), ell.values), order=1, modes=("fwd", "rev"))
    too_small, _ = SparsityPattern.from_coo(np.arange(n), np.arange(n), (n, n))
    with pytest.raises(DDGInputError, match="lacks"):
        congruence_plan(cols, too_small)
    with pytest.raises(DDGInputError, match="other columns"):
        congruence(ell, jnp.asarray(weights), target, congruence_plan(cols[::-1], target))
    with pytest.raises(DDGInputError, match="congruence: expected"):
        congruence(ell, jnp.asarray(weights[:-1]), target, plan)


def test_slots_host_lookup():
    reference = _random((20, 20), 0.2, 14) + sp.eye(20)
    matrix = from_scipy(reference)
    rows, cols = reference.nonzero()
    slots = matrix.pattern.slots(rows, cols)
    np.testing.assert_array_equal(np.asarray(matrix.values)[slots], np.asarray(reference[rows, cols]).ravel())
    absent = np.flatnonzero(reference.toarray().ravel() == 0)[:3]
    assert np.all(matrix.pattern.slots(absent // 20, absent % 20) == matrix.pattern.nnz)
    assert matrix.pattern.slots(np.array([-1, 20]), np.array([0, 0])).tolist() == [matrix.pattern.nnz] * 2


def _as_csr_layout(reference: sp.csr_matrix) -> SparseMatrix:
    pattern = SparsityPattern(
        rows=jnp.asarray(np.repeat(np.arange(reference.shape[0]), np.diff(reference.indptr)), dtype=jnp.int32),
        cols=jnp.asarray(reference.indices, dtype=jnp.int32),
        indptr=jnp.asarray(reference.indptr, dtype=jnp.int32),
        shape=reference.shape,
    )
    return SparseMatrix(jnp.asarray(reference.data), pattern)


# y[s] = sum_k x[index[s, k]]; index 6 (out of range) pads. TRANSPOSE_INDEX lists, per x entry, the
# outputs reading it (pad 4 = number of outputs).
INDEX = jnp.array([[0, 3], [2, 6], [3, 5], [1, 1]])
TRANSPOSE_INDEX = jnp.array([[0, 4], [3, 3], [1, 4], [0, 2], [4, 4], [2, 4]])
WEIGHTS = jnp.array([1.0, -2.0, 0.5, 3.0])


def _plain(x):
    return jnp.sum(WEIGHTS * jnp.sin(jnp.take(x, INDEX, axis=0, mode="fill", fill_value=0).sum(1)))


def _custom(x):
    return jnp.sum(WEIGHTS * jnp.sin(gather_sum(x, INDEX, TRANSPOSE_INDEX)))


@pytest.mark.slow
def test_gather_sum_all_modes_equal_the_plain_gather():
    x = jnp.linspace(0.5, 2.0, 6)
    v = jnp.cos(jnp.arange(6.0))

    @jax.jit
    def compare(x, v):
        """Each derivative of the primitive next to the same derivative of the plain gather."""
        hvp = lambda f: jax.jvp(jax.grad(f), (x,), (v,))[1]  # forward-over-reverse
        return {
            "value": (_custom(x), _plain(x)),
            "grad": (jax.grad(_custom)(x), jax.grad(_plain)(x)),
            "jvp": (jax.jvp(_custom, (x,), (v,))[1], jax.jvp(_plain, (x,), (v,))[1]),
            "jacfwd of grad": (jax.jacfwd(jax.grad(_custom))(x), jax.hessian(_plain)(x)),
            "hvp": (hvp(_custom), hvp(_plain)),
            "vmap of grad": tuple(jax.vmap(jax.grad(f))(jnp.stack([x, 2 * x])) for f in (_custom, _plain)),
        }

    for name, (custom, plain) in compare(x, v).items():
        np.testing.assert_allclose(custom, plain, rtol=1e-14, atol=1e-15, err_msg=name)
    check_grads(jax.jit(_custom), (x,), order=2, modes=("fwd", "rev"))
    # Trailing axes of x are carried along: (n, 2) -> (m, 2).
    block = jnp.stack([x, -x], axis=1)
    np.testing.assert_allclose(gather_sum(block, INDEX, TRANSPOSE_INDEX)[:, 1], -gather_sum(x, INDEX, TRANSPOSE_INDEX))


def test_gather_sum_transpose_is_a_gather_not_a_scatter():
    x = jnp.linspace(0.5, 2.0, 6)
    for jaxpr in (
        jax.make_jaxpr(jax.grad(_custom))(x),
        jax.make_jaxpr(jax.linear_transpose(lambda x: gather_sum(x, INDEX, TRANSPOSE_INDEX), x))(jnp.ones(4)),
    ):
        assert "scatter-add" not in primitives(jaxpr) and "ddgjax_gather_sum" in primitives(jaxpr)
    hvp = jax.make_jaxpr(lambda x, v: jax.jvp(jax.grad(_custom), (x,), (v,))[1])(x, x)
    assert "scatter-add" not in primitives(hvp)


def test_gather_sum_with_constant_indices_equals_indices_as_arguments():
    """A user's jit closes over host-built indices (an operator plan) as constants: the result, and
    its gradient, are those of the same indices passed as arguments. (That XLA keeps the fusion
    boundaries around the gather in both cases is a speed property, printed by
    `benchmarks/laplacian.py`, not asserted on compiled text here.)"""
    x = jnp.linspace(0.5, 2.0, 6)
    constant = jax.jit(jax.value_and_grad(lambda x: jnp.sum(gather_sum(jnp.sin(x), INDEX, TRANSPOSE_INDEX) ** 2)))
    argument = jax.jit(jax.value_and_grad(lambda x, i, t: jnp.sum(gather_sum(jnp.sin(x), i, t) ** 2)))
    for a, b in zip(constant(x), argument(x, INDEX, TRANSPOSE_INDEX)):
        np.testing.assert_array_equal(a, b)


def test_gather_sum_vmap_over_index_arrays():
    # A second incidence: the outputs in reverse order.
    index = jnp.stack([INDEX, INDEX[::-1]])
    transpose_index = jnp.stack([TRANSPOSE_INDEX, jnp.where(TRANSPOSE_INDEX < 4, 3 - TRANSPOSE_INDEX, 4)])
    xs = jnp.stack([jnp.linspace(0.5, 2.0, 6), jnp.linspace(-1.0, 1.0, 6)])

    def loss(x, i, t):
        return jnp.sum(WEIGHTS * jnp.sin(gather_sum(x, i, t)))

    def plain(x, i):
        return jnp.sum(WEIGHTS * jnp.sin(jnp.take(x, i, axis=0, mode="fill", fill_value=0).sum(1)))

    @jax.jit
    def compare(xs, index, transpose_index):
        values = (jax.vmap(loss)(xs, index, transpose_index), jax.vmap(plain)(xs, index))
        grads = (
            jax.vmap(jax.grad(loss), in_axes=(None, 0, 0))(xs[0], index, transpose_index),
            jax.vmap(jax.grad(plain), in_axes=(None, 0))(xs[0], index),
        )
        return values, grads

    for custom, expected in compare(xs, index, transpose_index):
        np.testing.assert_allclose(custom, expected, rtol=1e-14)


def test_gather_sum_bad_input():
    # jaxtyping's run-time checker (active in the tests) would catch these first; the function under
    # it raises DDGInputError, as users without the checker see.
    unchecked = getattr(gather_sum, "__wrapped__", gather_sum)
    with pytest.raises(DDGInputError, match="index: expected a 2-d integer array"):
        unchecked(jnp.ones(6), jnp.ones((4, 2)), TRANSPOSE_INDEX)
    with pytest.raises(DDGInputError, match="same n"):
        unchecked(jnp.ones(5), INDEX, TRANSPOSE_INDEX)
    with pytest.raises((DDGInputError, TypeCheckError)):
        gather_sum(jnp.ones(5), INDEX, TRANSPOSE_INDEX)


def test_structure_flags_follow_arithmetic(spd):
    matrix, _ = spd  # symmetric positive definite
    general = SparseMatrix(jnp.asarray(np.random.default_rng(15).random(matrix.pattern.nnz)), matrix.pattern)
    assert matrix.symmetric and matrix.positive_semidefinite and not general.symmetric
    assert (2.0 * matrix).positive_semidefinite and (matrix + matrix / 3.0).positive_semidefinite
    assert (-matrix).negative_semidefinite and not (-matrix).positive_semidefinite
    assert (matrix * -2.0).negative_semidefinite and (matrix - 2.0 * matrix).symmetric
    assert not (matrix - 0.5 * matrix).positive_semidefinite  # a difference is not provably semidefinite
    assert (matrix - (-matrix)).positive_semidefinite
    assert not (matrix + general).symmetric
    traced = jax.jit(lambda t, m: (t * m).values.sum() * 0 + int((t * m).positive_semidefinite))(2.0, matrix)
    assert traced == 0  # a traced scalar cannot be proven nonnegative: only `symmetric` survives
    assert jax.jit(lambda t, m: jnp.asarray(int((t * m).symmetric)))(2.0, matrix) == 1
    assert lx.is_negative_semidefinite((-matrix).as_lineax_operator())
    assert lx.is_positive_semidefinite((2.0 * matrix).as_lineax_operator())
    assert not lx.is_symmetric(general.as_lineax_operator())
    assert lx.is_positive_semidefinite(general.as_lineax_operator(symmetric=True, positive_semidefinite=True))
    assert matrix.T is matrix  # a symmetric matrix is its own transpose
    with pytest.raises(DDGInputError, match="semidefinite"):
        SparseMatrix(general.values, general.pattern, positive_semidefinite=True)
    with pytest.raises(DDGInputError, match="not symmetric"):
        from_scipy(_random((25, 25), 0.2, 15), positive_semidefinite=True)
    with pytest.raises(DDGInputError, match="values: expected shape"):
        SparseMatrix(general.values[:-1], general.pattern)


@pytest.mark.slow
def test_adding_a_diagonal_matches_scipy():
    base = _random((30, 30), 0.15, 16)
    square = from_scipy(base + base.T + sp.eye(30))  # host pattern with the diagonal stored first
    assert square.pattern.diagonal_first
    rng = np.random.default_rng(17)
    d = diagonal_matrix(jnp.asarray(rng.random(30)), positive_semidefinite=True)
    reference = square.to_scipy()
    diag_ref = d.to_scipy()
    for result, expected in (
        (square + d, reference + diag_ref),
        (d + square, reference + diag_ref),
        (square - 0.5 * d, reference - 0.5 * diag_ref),
        (d - 2.0 * square, diag_ref - 2.0 * reference),
        (d + d, 2.0 * diag_ref),
    ):
        assert abs(result.to_scipy() - expected).max() < 1e-14
    assert (square + d).pattern is square.pattern and (d + d).pattern.is_diagonal
    # Under jit and differentiated through both value arrays.
    sum_jit = jax.jit(lambda a, b: (a + 3.0 * b) @ jnp.ones(30))
    np.testing.assert_allclose(sum_jit(square, d), (reference + 3.0 * diag_ref) @ np.ones(30), rtol=1e-14)
    check_grads(
        lambda v, w: jnp.sum(jnp.sin((SparseMatrix(v, square.pattern) + diagonal_matrix(w)).values)),
        (square.values, d.values),
        order=1,
    )
    # A CSR pattern holding its whole diagonal (e.g. built from JAX arrays).
    csr = _as_csr_layout((base + sp.eye(30)).tocsr())
    assert abs((csr + d).to_scipy() - (csr.to_scipy() + diag_ref)).max() < 1e-14
    np.testing.assert_allclose(jax.jit(lambda a, b: (a - b).values)(csr, d), (csr - d).values)
    # Patterns without a full diagonal cannot take it.
    no_diagonal = from_scipy(sp.csr_matrix((np.ones(3), ([0, 1, 2], [1, 2, 0])), shape=(30, 30)))
    with pytest.raises(DDGInputError, match="whole diagonal"):
        no_diagonal + d
    with pytest.raises(DDGInputError, match="lacks diagonal"):
        _as_csr_layout(sp.csr_matrix((np.ones(3), ([0, 1, 2], [1, 2, 0])), shape=(30, 30))) + d
    # Passed into jit, the pattern is only known when the program runs: the outcome missing_diagonal.
    with pytest.raises(Exception, match="lacks diagonal entries"):
        jax.jit(lambda a, b: (a + b).values)(
            _as_csr_layout(sp.csr_matrix((np.ones(3), ([0, 1, 2], [1, 2, 0])), shape=(30, 30))), d
        )
    with pytest.raises(DDGInputError, match="equal shapes"):
        square + diagonal_matrix(jnp.ones(29))


def test_nnz_counts_distinct_positions_as_scipy(pair):
    matrix, reference = pair
    assert matrix.nnz == reference.nnz == matrix.to_scipy().nnz < matrix.pattern.nnz  # ELL padding left out
    assert matrix.T.nnz == matrix.nnz
    # Static on host-built patterns: known inside jit, where the pattern arrays are traced.
    assert jax.jit(lambda m: jnp.asarray(m.nnz))(matrix) == reference.nnz
    # A hand-made pattern without the count: counted on the host, refused under jit.
    by_hand = SparseMatrix(matrix.values, dataclasses.replace(matrix.pattern, n_entries=None, row_cols=None))
    assert by_hand.nnz == reference.nnz
    with pytest.raises(DDGInputError, match="concrete"):
        jax.jit(lambda m: jnp.asarray(m.nnz))(by_hand)
    csr = _as_csr_layout(reference)
    assert csr.nnz == csr.T.nnz == reference.nnz
    assert jax.jit(lambda m: jnp.asarray(m.T.nnz))(csr) == reference.nnz
    assert diagonal_matrix(jnp.ones(7)).nnz == 7


def test_nnz_and_export_of_explicit_zeros_and_empty_rows():
    # SciPy counts explicitly stored zeros; an empty row has no entries (its ELL padding is no entry).
    reference = sp.csr_matrix((np.array([0.0, 2.0, 3.0]), ([0, 0, 2], [0, 3, 1])), shape=(4, 4))
    matrix = from_scipy(reference)
    assert matrix.nnz == reference.nnz == 3
    exported = matrix.to_scipy()
    assert exported.nnz == 3 and exported.has_canonical_format
    np.testing.assert_array_equal(exported.indptr, reference.indptr)
    np.testing.assert_array_equal(exported.indices, reference.indices)
    np.testing.assert_array_equal(exported.data, reference.data)
    rows, cols, slot = matrix.pattern.entries()  # the distinct positions, in CSR order
    np.testing.assert_array_equal(rows, np.repeat(np.arange(4), np.diff(reference.indptr)))
    np.testing.assert_array_equal(cols, reference.indices)
    np.testing.assert_array_equal(np.asarray(matrix.values)[slot], reference.data)
    assert matrix.pattern.slots(np.array([1, 3]), np.array([0, 0])).tolist() == [matrix.pattern.nnz] * 2  # padding only


@pytest.fixture(scope="module")
def disk_operators():
    from ddgjax.laplacian import cotan_laplacian, mass_matrix
    from ddgjax.mesh import disk

    mesh = disk()
    return mesh, cotan_laplacian(mesh), mass_matrix(mesh), mass_matrix(mesh, mass="galerkin")


@pytest.mark.slow  # the fast tier's time limit (its checks run in the full suite)
def test_nonnegative_traced_scalar_keeps_the_psd_flag_into_lineax_cg(disk_operators):
    from scipy.sparse.linalg import spsolve

    _, laplacian, mass, galerkin = disk_operators
    rhs = jnp.asarray(np.random.default_rng(18).random(laplacian.shape[0]))

    @jax.jit
    def heat_step(t, rhs):
        operator = (mass + nonnegative(t) * laplacian).as_lineax_operator()
        assert lx.is_positive_semidefinite(operator)  # static: decided while tracing
        return lx.linear_solve(operator, rhs, lx.CG(rtol=1e-13, atol=1e-13)).value

    for t in (0.0, 0.05, 2.0):
        expected = spsolve((mass.to_scipy() + t * laplacian.to_scipy()).tocsc(), np.asarray(rhs))
        np.testing.assert_allclose(heat_step(t, rhs), expected, rtol=1e-10, atol=1e-12)  # CG tolerance 1e-13
    # A negative or NaN value reaches the run-time check instead of a mis-tagged operator.
    for bad in (-0.1, np.nan):
        with pytest.raises(Exception, match="negative or NaN"):
            heat_step(bad, rhs).block_until_ready()
    with pytest.raises(Exception, match="negative or NaN"):  # any member of a batch
        jax.vmap(heat_step, in_axes=(0, None))(jnp.asarray([0.1, -0.1]), rhs).block_until_ready()


@pytest.mark.slow  # the fast tier's time limit (its checks run in the full suite)
def test_nonnegative_products_flags_and_checks(disk_operators):
    _, laplacian, mass, galerkin = disk_operators
    x = jnp.asarray(np.random.default_rng(19).random(laplacian.shape[0]))

    def flags(matrix):
        return (matrix.symmetric, matrix.positive_semidefinite, matrix.negative_semidefinite)

    @jax.jit
    def products(t):
        wrapped = nonnegative(t)
        results = {
            "t * L": t * laplacian,
            "nonnegative(t) * L": wrapped * laplacian,
            "L * nonnegative(t)": laplacian * wrapped,
            "L / nonnegative(t)": laplacian / wrapped,
            "-(nonnegative(t) * L)": -(wrapped * laplacian),
            "M - nonnegative(t) * (-L)": mass - wrapped * (-laplacian),
            "G + nonnegative(t) * L": galerkin + wrapped * laplacian,  # one shared pattern
        }
        return {name: (flags(matrix), matrix @ x) for name, matrix in results.items()}

    out = jax.tree_util.tree_map(np.asarray, products(0.5))
    dense = np.asarray(laplacian.to_scipy() @ np.asarray(x))
    expected = {
        "t * L": ((True, False, False), 0.5 * dense),  # a plain traced scalar proves no sign
        "nonnegative(t) * L": ((True, True, False), 0.5 * dense),
        "L * nonnegative(t)": ((True, True, False), 0.5 * dense),
        "L / nonnegative(t)": ((True, True, False), 2.0 * dense),
        "-(nonnegative(t) * L)": ((True, False, True), -0.5 * dense),
        "M - nonnegative(t) * (-L)": ((True, True, False), np.asarray(mass @ x) + 0.5 * dense),
        "G + nonnegative(t) * L": ((True, True, False), np.asarray(galerkin @ x) + 0.5 * dense),
    }
    for name, (flag_values, product) in expected.items():
        assert tuple(bool(f) for f in out[name][0]) == flag_values, name
        # atol: rows of L x cancel (L 1 = 0), so small entries carry round-off of the O(1) terms.
        np.testing.assert_allclose(out[name][1], product, rtol=1e-13, atol=1e-14, err_msg=name)
    # Concrete scalars: as before, and nonnegative() checks them at once.
    assert (2.0 * laplacian).positive_semidefinite and (-2.0 * laplacian).negative_semidefinite
    assert (0.0 * laplacian).positive_semidefinite and (0.0 * laplacian).negative_semidefinite
    assert (nonnegative(3.0) * laplacian).positive_semidefinite
    assert nonnegative(nonnegative(1.0)).value == 1.0
    with pytest.raises(DDGInputError, match=r"value: nonnegative\(\) needs a value >= 0, got -1.0"):
        nonnegative(-1.0)
    with pytest.raises(DDGInputError, match="got nan"):
        nonnegative(np.nan)
    with pytest.raises(DDGInputError, match="needs a value >= 0"):
        NonNegative(jnp.asarray(-1.0))  # the type checks a concrete value itself
    # Differentiable in the scalar: d/dt of x^T (M + t L) x is x^T L x.
    quadratic = lambda t: x @ ((mass + nonnegative(t) * laplacian) @ x)
    np.testing.assert_allclose(jax.grad(quadratic)(0.3), x @ (laplacian @ x), rtol=1e-13)
    check_grads(jax.jit(quadratic), (0.3,), order=1, modes=("fwd", "rev"))


@pytest.mark.slow  # the fast tier's time limit (its checks run in the full suite)
def test_shifted_and_identity_match_scipy(disk_operators):
    _, laplacian, _, _ = disk_operators
    n = laplacian.shape[0]
    reference = laplacian.to_scipy()
    for shift in (0.0, 0.7, -0.2):
        expected = reference + shift * sp.identity(n)
        shifted = laplacian.shifted(shift)
        assert shifted.pattern is laplacian.pattern
        assert abs(shifted.to_scipy() - expected).max() < 1e-15
        assert abs((laplacian + shift * identity(n)).to_scipy() - expected).max() < 1e-15
        assert shifted.positive_semidefinite == (shift >= 0) == (laplacian + shift * identity(n)).positive_semidefinite
    assert (-laplacian).shifted(-1.0).negative_semidefinite and not (-laplacian).shifted(1.0).negative_semidefinite

    @jax.jit
    def traced(s):
        plain, declared = laplacian.shifted(s), laplacian.shifted(nonnegative(s))
        via_identity = laplacian + nonnegative(s) * identity(n)
        flags = [m.positive_semidefinite for m in (plain, declared, via_identity)]
        return jnp.asarray(flags), plain.values, declared.values, via_identity.values

    flags, *values = traced(0.25)
    assert flags.tolist() == [False, True, True]  # a plain traced shift proves no sign
    for v in values:
        np.testing.assert_allclose(v, laplacian.shifted(0.25).values, rtol=1e-15)
    with pytest.raises(Exception, match="negative or NaN"):
        traced(-0.25)[1].block_until_ready()
    check_grads(
        lambda v, s: jnp.sum(jnp.sin(SparseMatrix(v, laplacian.pattern).shifted(s).values)), (laplacian.values, 0.3), order=1
    )
    # A CSR pattern holding its diagonal; patterns without it and non-square matrices are refused.
    base = _random((12, 12), 0.3, 20) + sp.eye(12)
    csr = _as_csr_layout(base.tocsr())
    assert abs(csr.shifted(2.0).to_scipy() - (base + 2.0 * sp.eye(12))).max() < 1e-15
    no_diagonal = from_scipy(sp.csr_matrix((np.ones(3), ([0, 1, 2], [1, 2, 0])), shape=(12, 12)))
    with pytest.raises(DDGInputError, match=r"A\.shifted\(s\): adding a diagonal needs a pattern that stores the whole diagonal"):
        no_diagonal.shifted(1.0)
    with pytest.raises(DDGInputError, match=r"A: A\.shifted\(s\) needs a square matrix, got shape \(40, 30\)"):
        from_scipy(_random((40, 30), 0.15, 0)).shifted(1.0)
    with pytest.raises(DDGInputError, match="shift: A.shifted"):
        laplacian.shifted(jnp.ones(2))
    assert identity(4).positive_semidefinite and identity(4, dtype=jnp.float32).dtype == jnp.float32
    with pytest.raises(DDGInputError, match="n: expected an integer >= 1"):
        identity(0)


def test_nonnegative_refuses_what_is_not_a_real_scalar(without_type_checker):
    with pytest.raises(DDGInputError, match=r"value: expected a real scalar, got shape \(2,\)"):
        nonnegative(jnp.ones(2))
    with pytest.raises(DDGInputError, match="dtype complex"):
        nonnegative(1j)
