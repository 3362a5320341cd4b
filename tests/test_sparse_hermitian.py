"""Complex Hermitian `SparseMatrix`: the `hermitian` flag, `self_adjoint`, `conj` / `H`, products and
flags through arithmetic, lineax CG, autodiff; SciPy / NumPy are the reference."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import pytest
import scipy.sparse as sp
from jax.test_util import check_grads

from ddgjax import DDGInputError
from ddgjax.sparse import SparseMatrix, SparsityPattern, diagonal_matrix, from_scipy, identity, nonnegative

from finite_differences import central_difference

N = 30


def _complex_random(shape, density, seed):
    real = sp.random(*shape, density=density, format="csr", random_state=seed)
    imaginary = real.copy()
    imaginary.data = np.random.default_rng(seed + 100).standard_normal(real.nnz)
    return (real + 1j * imaginary).tocsr()


@pytest.fixture(scope="module")
def hpd():
    """A complex Hermitian positive definite matrix `B + B^H + c I` (Gershgorin: `c` > every row sum)."""
    base = _complex_random((N, N), 0.15, 0)
    hermitian = base + base.conj().T
    shift = np.abs(hermitian).sum(axis=1).max() + 1.0
    reference = (hermitian + shift * sp.eye(N)).tocsr()
    return from_scipy(reference, positive_semidefinite=True), reference


def _csr_layout(reference: sp.csr_matrix, **flags) -> SparseMatrix:
    """The same entries on a `"csr"` pattern built from JAX arrays (the `segment_sum` / COO-swap code paths)."""
    pattern = SparsityPattern(
        rows=jnp.asarray(np.repeat(np.arange(reference.shape[0]), np.diff(reference.indptr)), dtype=jnp.int32),
        cols=jnp.asarray(reference.indices, dtype=jnp.int32),
        indptr=jnp.asarray(reference.indptr, dtype=jnp.int32),
        shape=reference.shape,
    )
    return SparseMatrix(jnp.asarray(reference.data), pattern, **flags)


def _flags(matrix: SparseMatrix) -> tuple[bool, bool, bool, bool]:
    return (matrix.symmetric, matrix.hermitian, matrix.positive_semidefinite, matrix.negative_semidefinite)


def test_from_scipy_detects_hermitian_not_symmetric(hpd):
    matrix, reference = hpd
    assert np.iscomplexobj(reference.data) and abs(reference - reference.conj().T).max() == 0
    assert matrix.dtype == jnp.complex128
    assert _flags(matrix) == (False, True, True, False) and matrix.self_adjoint
    # Complex symmetric, not Hermitian: symmetric only, and it cannot be flagged semidefinite.
    base = _complex_random((N, N), 0.15, 1)
    complex_symmetric = (base + base.T).tocsr()
    assert abs(complex_symmetric - complex_symmetric.conj().T).max() > 0
    flagged = from_scipy(complex_symmetric)
    assert flagged.symmetric and not flagged.hermitian and not flagged.self_adjoint
    with pytest.raises(DDGInputError, match="not Hermitian"):
        from_scipy(complex_symmetric, positive_semidefinite=True)
    # A real matrix: symmetric as before, never flagged hermitian, yet self-adjoint.
    real = from_scipy((sp.random(N, N, density=0.1, random_state=2) + sp.eye(N)).tocsr())
    real_symmetric = from_scipy((real.to_scipy() + real.to_scipy().T).tocsr(), positive_semidefinite=False)
    assert not real.symmetric and not real.hermitian and not real.self_adjoint
    assert real_symmetric.symmetric and not real_symmetric.hermitian and real_symmetric.self_adjoint


@pytest.mark.slow
def test_products_transposes_and_exports_match_scipy(hpd):
    matrix, reference = hpd
    rng = np.random.default_rng(3)
    x_complex = rng.standard_normal(N) + 1j * rng.standard_normal(N)
    x_real = rng.standard_normal(N)
    block_complex = rng.standard_normal((N, 3)) + 1j * rng.standard_normal((N, 3))
    block_real = rng.standard_normal((N, 3))
    rect_reference = _complex_random((N, 20), 0.2, 4)  # non-square: a transposed pattern of its own
    rect = from_scipy(rect_reference)
    csr = _csr_layout(reference, hermitian=True)

    @jax.jit  # one compiled call per matrix: eager dispatch of every small op would dominate the test time
    def everything(m, xs):
        products = [m @ x[: m.shape[1]] for x in xs]
        dense = [d.todense() for d in (m, m.T, m.H, m.conj(), m.T.T, m.H.H)]
        return products, dense, m.diagonal(), m.row_sums()

    for m, ref in ((matrix, reference), (csr, reference), (rect, rect_reference)):
        xs = (x_complex, x_real, block_complex, block_real)
        products, dense, diagonal, sums = everything(m, xs)
        for product, x in zip(products, xs, strict=True):
            np.testing.assert_allclose(product, ref @ x[: ref.shape[1]], rtol=1e-13, atol=1e-13)
        np.testing.assert_allclose(m @ x_real[: ref.shape[1]], ref @ x_real[: ref.shape[1]], rtol=1e-13, atol=1e-13)  # eager
        expected = (ref, ref.T, ref.conj().T, ref.conj(), ref, ref)
        for result, reference_dense in zip(dense, expected, strict=True):
            np.testing.assert_array_equal(result, reference_dense.toarray())
        for result, reference_sparse in ((m.T, ref.T), (m.H, ref.conj().T)):
            assert abs(result.to_scipy() - reference_sparse).max() == 0
        np.testing.assert_array_equal(diagonal, ref.diagonal()[: min(ref.shape)])
        np.testing.assert_allclose(sums, np.asarray(ref.sum(axis=1)).ravel(), rtol=1e-13, atol=1e-14)
        assert m.to_scipy().dtype == np.complex128 and m.nnz == ref.nnz
        assert abs(m.to_scipy() - ref).max() == 0
    # The Hermitian fast paths: A.H is A, A.T is conj(A) on the same pattern with the flags kept.
    assert matrix.H is matrix and matrix.T.pattern is matrix.pattern and _flags(matrix.T) == _flags(matrix)
    assert _flags(matrix.conj()) == _flags(matrix)
    # A real matrix: conj is itself; a complex symmetric one is its own transpose, not its own H.
    real = from_scipy(sp.random(N, N, density=0.1, random_state=5).tocsr())
    assert real.conj() is real and abs(real.H.to_scipy() - real.to_scipy().T).max() == 0
    base = _complex_random((N, N), 0.15, 6)
    complex_symmetric = from_scipy((base + base.T).tocsr())
    assert complex_symmetric.T is complex_symmetric
    assert abs(complex_symmetric.H.to_scipy() - complex_symmetric.to_scipy().conj()).max() == 0
    # A symmetric pattern with non-Hermitian values: the transpose is the slot permutation.
    general = from_scipy((base + 2j * base.T).tocsr())  # A_ij = b_ij + 2i b_ji: neither symmetric nor Hermitian
    assert general.pattern.symmetric and not general.hermitian
    np.testing.assert_array_equal(general.H.todense(), general.to_scipy().conj().T.toarray())


def test_flags_through_arithmetic(hpd):
    matrix, reference = hpd
    other = from_scipy(reference + reference * (0.5 + 0.0j), positive_semidefinite=True)  # another Hermitian PD
    assert _flags(matrix + other) == (False, True, True, False)
    assert _flags(matrix - other) == (False, True, False, False)  # a difference proves no sign
    assert _flags(-matrix) == (False, True, False, True)
    assert _flags(2.0 * matrix) == (False, True, True, False)
    assert _flags(matrix / 4.0) == (False, True, True, False)
    assert _flags(-2.0 * matrix) == (False, True, False, True)
    assert _flags(0.0 * matrix) == (False, True, True, True)
    assert _flags(1j * matrix) == (False, False, False, False)  # i A is skew-Hermitian
    assert _flags(matrix * (2.0 + 0.0j)) == (False, False, False, False)  # a complex scalar proves nothing
    assert not (matrix + 1j * matrix).hermitian
    np.testing.assert_allclose((1j * matrix).todense(), 1j * reference.toarray(), rtol=1e-15)
    np.testing.assert_allclose((matrix - 0.5 * other).todense(), (reference - 0.5 * other.to_scipy()).toarray(), rtol=1e-15)
    # A complex symmetric non-Hermitian summand: neither flag survives.
    symmetric_values = ((1 + 2j) * (matrix + matrix.T)).values  # (1 + 2i) 2 Re(A): A == A.T, not Hermitian
    complex_symmetric = SparseMatrix(symmetric_values, matrix.pattern, symmetric=True)
    assert _flags(matrix + complex_symmetric) == (False, False, False, False)
    # Re(A) on A's pattern: real symmetric positive definite (x^T Re(A) x = x^H A x for real x).
    # Times i: complex symmetric, no longer Hermitian nor PSD.
    real_reference = reference.real.tocsr()
    real = SparseMatrix(jnp.real(matrix.values), matrix.pattern, symmetric=True, positive_semidefinite=True)
    assert _flags(real) == (True, False, True, False) and _flags(1j * real) == (True, False, False, False)
    # Real symmetric + complex Hermitian: complex Hermitian (the real one counts as Hermitian).
    mixed = real + matrix
    assert mixed.dtype == jnp.complex128 and _flags(mixed) == (False, True, True, False)
    np.testing.assert_allclose(mixed.todense(), (real_reference + reference).toarray(), rtol=1e-15)
    # Shifts: a real one keeps hermitian (and PSD for s >= 0), a complex one drops it.
    assert _flags(matrix.shifted(2.0)) == (False, True, True, False)
    assert _flags(matrix.shifted(-2.0)) == (False, True, False, False)
    assert _flags(matrix.shifted(1j)) == (False, False, False, False)
    shifted_real = real.shifted(0.5j)  # a real matrix becomes complex (symmetric, not Hermitian)
    assert shifted_real.dtype == jnp.complex128 and _flags(shifted_real) == (True, False, False, False)
    assert abs(shifted_real.to_scipy() - (real_reference + 0.5j * sp.eye(N))).max() < 1e-15
    assert abs(matrix.shifted(2.0).to_scipy() - (reference + 2.0 * sp.eye(N))).max() < 1e-15
    assert _flags(matrix + 3.0 * identity(N)) == (False, True, True, False)
    # A complex diagonal onto a real matrix (ELL diagonal-first and CSR patterns): the sum is complex.
    diagonal = np.random.default_rng(7).standard_normal(N) * (1 + 1j)
    complex_diagonal = SparseMatrix(jnp.asarray(diagonal), SparsityPattern.diagonal(N), symmetric=True)
    for real_matrix in (real, _csr_layout(real_reference, symmetric=True)):
        for total, expected in (
            (real_matrix + complex_diagonal, real_reference + sp.diags(diagonal)),
            (complex_diagonal - real_matrix, sp.diags(diagonal) - real_reference),
        ):
            assert total.dtype == jnp.complex128 and _flags(total) == (True, False, False, False)
            assert abs(total.to_scipy() - expected).max() < 1e-15


def test_traced_real_scalars_keep_hermitian_and_real_mass_plus_complex_laplacian(hpd):
    matrix, reference = hpd
    rng = np.random.default_rng(8)
    mass_values = rng.random(N) + 0.5
    mass = diagonal_matrix(jnp.asarray(mass_values), positive_semidefinite=True)
    rhs = jnp.asarray(rng.standard_normal(N) + 1j * rng.standard_normal(N))

    @jax.jit
    def flags_and_values(t):
        plain, declared = t * matrix, nonnegative(t) * matrix
        step = mass + nonnegative(t) * matrix
        flags = {name: _flags(m) for name, m in (("t A", plain), ("nonnegative(t) A", declared), ("M + t A", step))}
        flags["M + t A dtype"] = step.dtype == jnp.complex128
        flags["t A shifted"] = _flags(plain.shifted(t))
        return flags, step.values

    flags, values = flags_and_values(0.25)
    flags = jax.tree_util.tree_map(bool, flags)
    assert flags["t A"] == (False, True, False, False)  # real dtype: Hermitian; no provable sign
    assert flags["nonnegative(t) A"] == (False, True, True, False)
    assert flags["M + t A"] == (False, True, True, False) and flags["M + t A dtype"]
    assert flags["t A shifted"] == (False, True, False, False)
    step = SparseMatrix(values, matrix.pattern)
    expected = (sp.diags(mass_values) + 0.25 * reference).tocsr()
    assert abs(step.to_scipy() - expected).max() < 1e-14
    # The heat step M + t A goes into lineax CG with t traced.
    solve = jax.jit(
        lambda t, b: (
            lx.linear_solve((mass + nonnegative(t) * matrix).as_lineax_operator(), b, lx.CG(rtol=1e-12, atol=1e-12)).value
        )
    )
    solution = solve(0.25, rhs)
    # lineax's CG stops at |r_i| <= 1e-12 (1 + |b_i|) (its recursive residual): measured 7.8e-14.
    np.testing.assert_allclose(expected @ np.asarray(solution), rhs, rtol=1e-11, atol=1e-11)


def test_check_init_and_self_adjoint(hpd):
    matrix, reference = hpd
    base = _complex_random((N, N), 0.15, 9)
    complex_symmetric = from_scipy((base + base.T + sp.eye(N)).tocsr())
    with pytest.raises(DDGInputError, match="complex semidefinite SparseMatrix must also be flagged hermitian"):
        SparseMatrix(complex_symmetric.values, complex_symmetric.pattern, symmetric=True, positive_semidefinite=True)
    with pytest.raises(DDGInputError, match="flagged hermitian"):
        SparseMatrix(matrix.values, matrix.pattern, negative_semidefinite=True)
    rect = SparsityPattern.from_coo(np.array([0, 1, 2]), np.array([0, 1, 0]), (3, 2))[0]
    with pytest.raises(DDGInputError, match="hermitian: a hermitian matrix must be square"):
        SparseMatrix(jnp.ones(rect.nnz, jnp.complex128), rect, hermitian=True)
    with pytest.raises(DDGInputError, match="must also be flagged symmetric"):  # the real case, as before
        SparseMatrix(jnp.real(matrix.values), matrix.pattern, positive_semidefinite=True)
    # Complex values pass the run-time type checker as they are.
    assert SparseMatrix(matrix.values, matrix.pattern, hermitian=True, positive_semidefinite=True).self_adjoint
    real_values = jnp.real(matrix.values)  # real part of a Hermitian matrix: real symmetric
    real_symmetric = SparseMatrix(real_values, matrix.pattern, symmetric=True, positive_semidefinite=True)
    real_general = from_scipy(sp.random(N, N, density=0.1, random_state=10).tocsr())
    real_hermitian = SparseMatrix(real_values, matrix.pattern, hermitian=True, positive_semidefinite=True)
    assert real_symmetric.self_adjoint and not real_symmetric.hermitian
    assert not real_general.self_adjoint
    assert matrix.self_adjoint and not complex_symmetric.self_adjoint
    # A real matrix flagged hermitian: the same as symmetric (transpose, H, lineax tag).
    assert real_hermitian.self_adjoint and real_hermitian.T is real_hermitian and real_hermitian.H is real_hermitian
    assert lx.is_symmetric(real_hermitian.as_lineax_operator())
    assert _flags(1j * real_hermitian) == (True, False, False, False)
    np.testing.assert_allclose(real_hermitian.todense(), np.real(reference.toarray()), rtol=1e-15)


@pytest.mark.slow  # the fast tier's time limit (its checks run in the full suite)
def test_lineax_tags_and_cg_on_complex_hermitian(hpd):
    matrix, reference = hpd
    operator = matrix.as_lineax_operator()
    # lineax's symmetric_tag means A == A.T: not given to a complex Hermitian matrix.
    assert not lx.is_symmetric(operator) and lx.is_positive_semidefinite(operator)
    assert lx.is_negative_semidefinite((-matrix).as_lineax_operator())
    np.testing.assert_allclose(operator.as_matrix(), reference.toarray(), rtol=1e-15)
    rng = np.random.default_rng(11)
    b = jnp.asarray(rng.standard_normal(N) + 1j * rng.standard_normal(N))
    solution = lx.linear_solve(operator, b, lx.CG(rtol=1e-10, atol=1e-10))
    # CG stops at |r_i| <= 1e-10 (1 + |b_i|) on its recursive residual, which the true one follows up to
    # rounding: measured 6.8e-11.
    np.testing.assert_allclose(reference @ np.asarray(solution.value), b, rtol=1e-9, atol=1e-9)
    # A complex symmetric matrix does get lineax's symmetric tag (it is A == A.T).
    base = _complex_random((N, N), 0.15, 12)
    assert lx.is_symmetric(from_scipy((base + base.T).tocsr()).as_lineax_operator())


@pytest.mark.slow
def test_gradients_with_complex_values(hpd):
    matrix, reference = hpd
    rng = np.random.default_rng(13)
    x = rng.standard_normal(N) + 1j * rng.standard_normal(N)

    def quadratic(z):
        return jnp.real(jnp.vdot(z, matrix @ z))  # x^H A x, real for a Hermitian A

    gradient = np.asarray(jax.grad(quadratic)(jnp.asarray(x)))
    # JAX's gradient of a real function of z = a + ib is df/da - i df/db; here df/da + i df/db = 2 A x.
    np.testing.assert_allclose(gradient, np.conj(2 * (reference @ x)), rtol=1e-13)
    # Central differences are exact for a quadratic: only round-off (~1e-16 |f| / step) is left.
    quadratic_jit, step = jax.jit(quadratic), 1e-2
    for k in (0, 7, N - 1):
        unit = np.zeros(N)
        unit[k] = 1.0
        along_real = central_difference(quadratic_jit, x, unit, step)
        along_imaginary = central_difference(quadratic_jit, x, 1j * unit, step)
        np.testing.assert_allclose(along_real, gradient[k].real, rtol=1e-10, atol=1e-10)
        np.testing.assert_allclose(along_imaginary, -gradient[k].imag, rtol=1e-10, atol=1e-10)
    # Through complex values and right-hand side together (forward and reverse).
    pattern = matrix.pattern
    check_grads(
        jax.jit(lambda v, z: jnp.sum(jnp.abs(SparseMatrix(v, pattern, hermitian=True) @ z) ** 2)),
        (matrix.values, jnp.asarray(x)),
        order=1,
        modes=("fwd", "rev"),
    )


def test_dataclass_replace_and_pytree_flags(hpd):
    matrix, _ = hpd
    plain = dataclasses.replace(matrix, hermitian=False, positive_semidefinite=False)
    # Static flags: different pytree structures, equal leaves.
    assert jax.tree_util.tree_structure(plain) != jax.tree_util.tree_structure(matrix)
    assert not lx.is_positive_semidefinite(plain.as_lineax_operator())
    np.testing.assert_array_equal(plain.T.todense(), matrix.T.todense())  # the permutation path gives the same
