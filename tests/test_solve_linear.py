"""Tests for ddgjax.solve.linear_solve: every backend against SciPy, implicit derivatives against finite
differences, jit / vmap / scan, complex Hermitian systems, and failures through the results convention."""

from __future__ import annotations

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ddgjax import RESULTS, DDGInputError
from ddgjax.laplacian import cotan_laplacian, mass_matrix
from ddgjax.mesh import disk
from ddgjax.solve import _linear, amg_hierarchy, factorize, linear_solve
from ddgjax.solve._linear import _real_form
from ddgjax.sparse import SparseMatrix, from_scipy

from conftest import unit_icosphere
from finite_differences import central_difference

# Backends: the methods, and CG with the AMG V-cycle as preconditioner ("cg-amg"; in the slow tier,
# pyproject.toml: its programs, the AMG hierarchy included, take the longest to compile).
METHODS = ("cholesky", "superlu", "cg", pytest.param("cg-amg", marks=pytest.mark.slow), "pyamg")
ITERATIVE = ("cg", "cg-amg", "pyamg")


def _options(backend: str, A: SparseMatrix) -> dict:
    """`linear_solve` keywords of a backend; the AMG hierarchy is built here, outside any trace."""
    if backend == "cg-amg":
        system = _real_form(A) if jnp.iscomplexobj(A.values) else A
        return {"solver": "cg", "preconditioner": amg_hierarchy(system, max_coarse=30)}
    return {"solver": backend}


SPHERE = unit_icosphere(2)
DISK = disk(6)

# One compiled program per backend and shape for the whole call (the AMG hierarchy of "cg-amg" included),
# shared by the tests. `options` is `_options(...)`: its strings are static.
_solve = eqx.filter_jit(lambda A, b, options: linear_solve(A, b, **options))


def _heat_operator(mesh, t=1e-2):
    return mass_matrix(mesh) + t * cotan_laplacian(mesh)


def _dirichlet_block(mesh):
    """The cotan Laplacian on the interior vertices of a mesh with boundary (SciPy slicing), and the interior."""
    interior = np.setdiff1d(np.arange(mesh.n_vertices), mesh.topology.boundary_vertices)
    block = cotan_laplacian(mesh).to_scipy()[interior][:, interior]
    return from_scipy(block, positive_semidefinite=True), interior


def _rhs(n, seed=0, k=None):
    shape = (n,) if k is None else (n, k)
    return jnp.asarray(np.random.default_rng(seed).standard_normal(shape))


@pytest.mark.parametrize("method", METHODS + ("auto",))
def test_solves_match_scipy_spsolve(method):
    for A in (_heat_operator(SPHERE), _dirichlet_block(DISK)[0]):
        options = {"solver": "auto"} if method == "auto" else _options(method, A)
        reference = A.to_scipy().tocsc()
        b = _rhs(A.shape[0])
        solution = _solve(A, b, options)
        assert solution.result == RESULTS.successful
        expected = spla.spsolve(reference, np.asarray(b))
        # CG stops at a relative residual of 1e-10; the error is that times the condition number at most.
        np.testing.assert_allclose(solution.value, expected, rtol=0, atol=1e-8 * np.abs(expected).max())
        assert solution.residual < 1e-9  # CG's stopping test |r| <= 1e-10 |b|, plus the round-off of |A x - b|
        # The stats an entry point reports: the relative residual as SciPy computes it, and the CG steps.
        measured = np.linalg.norm(reference @ np.asarray(solution.value) - np.asarray(b)) / np.linalg.norm(np.asarray(b))
        # A residual is a cancelling difference: the two summation orders differ by ~1e-16 |A||x|, which is ~1e-6
        # of CG's residual of ~1e-10 and all of a direct solve's (~1e-16, hence atol).
        np.testing.assert_allclose(solution.stats["residual"], measured, rtol=1e-6, atol=1e-15)
        assert solution.stats["num_steps"] == solution.num_steps
        B = _rhs(A.shape[0], seed=1, k=3)
        block = _solve(A, B, options).value
        assert block.shape == B.shape
        # CG's 1e-10 relative residual as above, per column; scaled by the single solution's size, x10 for three columns.
        np.testing.assert_allclose(block, spla.spsolve(reference, np.asarray(B)), rtol=0, atol=1e-8 * np.abs(expected).max() * 10)


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.slow
def test_jit_vmap_and_scan(method):
    A = _heat_operator(SPHERE)
    options = _options(method, A)
    b = _rhs(A.shape[0])
    eager = linear_solve(A, b, **options).value
    jitted = _solve(A, b, options).value
    np.testing.assert_allclose(jitted, eager, rtol=0, atol=1e-12)
    batch = jnp.stack([b, -2 * b])
    batched = jax.vmap(lambda b: linear_solve(A, b, **options).value)(batch)
    np.testing.assert_allclose(batched[1], -2 * eager, rtol=0, atol=1e-10)
    # Ten implicit heat steps (M + t L) u_{k+1} = M u_k as one compiled scan, against SciPy's loop.
    M = mass_matrix(SPHERE)

    def step(u, _):
        return linear_solve(A, M @ u, **options).value, None

    final, _ = jax.jit(lambda u: jax.lax.scan(step, u, None, length=10))(b)
    u, lu = np.asarray(b), spla.splu(A.to_scipy().tocsc())
    for _ in range(10):
        u = lu.solve(M.to_scipy() @ u)
    # Ten CG solves to a relative residual of 1e-10 each: the errors add up to ~1e-9.
    np.testing.assert_allclose(final, u, rtol=0, atol=1e-9 * np.abs(u).max())


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.slow
def test_a_kept_factorisation_solves_many_right_hand_sides(method):
    A = _heat_operator(SPHERE)
    options = _options(method, A)
    factorization = jax.jit(lambda A: factorize(A, **options))(A)
    lu = spla.splu(A.to_scipy().tocsc())
    for seed, k in ((0, None), (1, 4)):
        b = _rhs(A.shape[0], seed, k)
        expected = lu.solve(np.asarray(b))
        # CG stops at a relative residual of 1e-10; M + t L is well conditioned (~2): an error of ~2e-10.
        np.testing.assert_allclose(factorization.solve(b).value, expected, rtol=0, atol=1e-9 * np.abs(expected).max())
    # 100 implicit heat steps (M + t L) u_{k+1} = M u_k with one factorisation, as one compiled scan.
    M = mass_matrix(SPHERE)

    def heat(u):
        return jax.lax.scan(lambda u, _: (factorization.solve(M @ u).value, None), u, None, length=100)[0]

    u = np.asarray(_rhs(A.shape[0]))
    final = jax.jit(heat)(jnp.asarray(u))
    for _ in range(100):
        u = lu.solve(M.to_scipy() @ u)
    # Each CG step stops at a relative residual of 1e-10; over 100 steps the errors add up to ~1e-8.
    np.testing.assert_allclose(final, u, rtol=0, atol=(1e-7 if method in ITERATIVE else 1e-9) * np.abs(u).max())

    # Differentiable through the kept factorisation, in b and in the matrix values.
    def loss(values, b):
        kept = factorize(SparseMatrix(values, A.pattern, symmetric=True), **options)
        return jnp.sum(jnp.sin(kept.solve(b).value))

    # One compiled program, for the gradients and for the four losses of the finite differences (an
    # eager call would trace and compile CG's loop anew each time).
    value_and_grad = jax.jit(jax.value_and_grad(loss, argnums=(0, 1)))
    b = _rhs(A.shape[0], 5)
    _, (grad_values, grad_b) = value_and_grad(A.values, b)
    direction = _symmetric_direction(A, 6)
    db = direction[: b.shape[0]]
    finite_values = central_difference(lambda values: value_and_grad(values, b)[0], A.values, direction)
    finite_b = central_difference(lambda b: value_and_grad(A.values, b)[0], b, db)
    # Central differences with step 1e-6 (truncation ~1e-12, rounding ~1e-10 relative) of a loss whose CG
    # solves are accurate to their rtol of 1e-10 only: that error over the step 2e-6 bounds the agreement.
    np.testing.assert_allclose(jnp.vdot(grad_values, direction), finite_values, rtol=1e-6)
    np.testing.assert_allclose(jnp.vdot(grad_b, db), finite_b, rtol=1e-6)  # CG's 1e-10 over the step 2e-6


def _symmetric_direction(A: SparseMatrix, seed: int) -> jax.Array:
    """A random perturbation of `A.values` that keeps the matrix symmetric (same pattern)."""
    direction = _rhs(A.pattern.nnz, seed)
    return 0.5 * (direction + SparseMatrix(direction, A.pattern).T.values)


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.slow
def test_gradients_in_b_and_values_match_finite_differences(method, icosphere1):
    A = _heat_operator(icosphere1)
    options = _options(method, A)
    b = _rhs(A.shape[0])

    def loss(values, b):
        x = linear_solve(SparseMatrix(values, A.pattern, symmetric=True), b, **options).value
        return jnp.sum(jnp.sin(x)) + 0.5 * jnp.sum(x * x)

    def dense_loss(matrix, b):
        x = jnp.linalg.solve(matrix, b)
        return jnp.sum(jnp.sin(x)) + 0.5 * jnp.sum(x * x)

    grad_values, grad_b = jax.jit(jax.grad(loss, argnums=(0, 1)))(A.values, b)
    # The adjoint solve of CG stops at a relative residual of 1e-10; the dense LU one is exact to ~1e-14.
    np.testing.assert_allclose(grad_b, jax.grad(dense_loss, argnums=1)(A.todense(), b), rtol=1e-8, atol=1e-10)
    for seed in (1, 2):
        direction = _symmetric_direction(A, seed)
        dense_direction = SparseMatrix(direction, A.pattern).todense()
        _, expected = jax.jvp(lambda D: dense_loss(D, b), (A.todense(),), (dense_direction,))
        # The dense reference solves with LU: both agree to ~1e-12 relative; 1e-8 leaves room for CG's 1e-10 tolerance.
        np.testing.assert_allclose(jnp.vdot(grad_values, direction), expected, rtol=1e-8)


@pytest.mark.slow
def test_gradient_in_the_vertex_positions_matches_finite_differences(icosphere1):
    mesh = icosphere1
    b = _rhs(mesh.n_vertices)

    def loss(V):
        moved = mesh.with_vertices(V)
        A = mass_matrix(moved) + 0.1 * cotan_laplacian(moved)
        return jnp.sum(linear_solve(A, b).value ** 2)

    # One compiled program, for the gradient and for both losses of the finite difference.
    value_and_grad = jax.jit(jax.value_and_grad(loss))
    V = mesh.vertices
    _, gradient = value_and_grad(V)
    direction = _rhs(V.size, seed=3).reshape(V.shape)
    finite = central_difference(lambda V: value_and_grad(V)[0], V, direction)
    # Central differences with step 1e-6: truncation ~1e-12, rounding ~1e-10 relative (measured 3.5e-10 with
    # CHOLMOD, a CPU's "auto"); on an accelerator "auto" is CG, whose 1e-10 relative error in the loss
    # varies with the position and is divided by the step.
    np.testing.assert_allclose(jnp.vdot(gradient, direction), finite, rtol=1e-7)


def test_cg_that_does_not_converge_is_reported():
    A = _heat_operator(SPHERE, t=1.0)
    b = _rhs(A.shape[0])
    solution = linear_solve(A, b, solver="cg", max_steps=2, throw=False)
    assert solution.result == RESULTS.max_steps_reached and int(solution.num_steps) == 2
    with pytest.raises(eqx.EquinoxRuntimeError, match="max_steps"):
        linear_solve(A, b, solver="cg", max_steps=2)
    with pytest.raises(Exception, match="max_steps"):  # under jit: raised by the XLA runtime, same message
        jax.jit(lambda b: linear_solve(A, b, solver="cg", max_steps=2).value)(b)


@pytest.mark.parametrize("method", ("cholesky", "superlu", "cg"))
def test_eager_solves_reuse_their_compiled_programs(method):
    """An eager `linear_solve` runs two compiled programs (the host factor's and the solve's, one per
    factorisation kind and shape), not one dispatch per operation: new values and a new right-hand side
    on the same pattern compile nothing."""
    A = _heat_operator(SPHERE, t=1.0)
    b = _rhs(A.shape[0])
    linear_solve(A, b, solver=method)
    programs = (_linear._solve._cache_size(), _linear._factor._cache_size())
    again = linear_solve(2.0 * A, 2.0 * b, solver=method)
    assert (_linear._solve._cache_size(), _linear._factor._cache_size()) == programs
    # CG's rtol 1e-10 for both solves, times the condition number of M + L (~70).
    np.testing.assert_allclose(again.value, linear_solve(A, b, solver=method).value, rtol=1e-8)


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.slow
def test_singular_system_with_incompatible_rhs_is_reported_not_hidden(method):
    options = _options(method, cotan_laplacian(SPHERE))
    # A closed surface's Laplacian is singular (constants); a right-hand side with a nonzero mean has no solution.
    # CHOLMOD may stop at the zero pivot (`not_positive_definite`) or round past it and return a
    # non-solution (`singular`); the iterative methods miss the tolerance: never a silent answer.
    L = cotan_laplacian(SPHERE)
    b = jnp.ones(SPHERE.n_vertices)
    solution = linear_solve(L, b, **options, throw=False, max_steps=200)
    assert solution.result != RESULTS.successful
    with pytest.raises(eqx.EquinoxRuntimeError, match="positive definite|does not solve|max_steps"):
        linear_solve(L, b, **options, max_steps=200)


def test_bad_input(without_type_checker):
    A = _heat_operator(SPHERE)
    b = _rhs(A.shape[0])
    cases = [
        (lambda: linear_solve(A.to_scipy(), b), "A: expected a ddgjax SparseMatrix"),
        (lambda: linear_solve(from_scipy(A.to_scipy()[:, :-1]), b), "A: expected a square matrix"),
        (lambda: linear_solve(SparseMatrix(A.values, A.pattern), b), "A: expected a symmetric matrix"),
        (lambda: linear_solve(A, b[:-1]), r"b: expected shape \(162,\) or \(162, k\), got \(161,\)"),
        (lambda: jax.jit(lambda b: linear_solve(A, b).value)(b[:-1]), r"b: expected shape \(162,\)"),
        (lambda: linear_solve(A, b, solver="lu"), "solver: expected one of 'auto', 'cholesky', 'superlu', 'cg', 'pyamg'"),
        (lambda: linear_solve(A, b, solver="cg", max_steps=0), "max_steps: expected an integer >= 1"),
        (lambda: linear_solve(A, b, solver="cg", preconditioner="ilu"), "preconditioner: expected one of 'jacobi', 'amg'"),
        (lambda: linear_solve(A, b, solver="superlu", preconditioner="amg"), "preconditioner: only solver='cg'"),
    ]
    for call, message in cases:
        with pytest.raises(DDGInputError, match=message):
            call()


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.slow
def test_forward_mode_and_hessian_vector_products(method, icosphere1):
    A = _heat_operator(icosphere1)
    options = _options(method, A)
    b = _rhs(A.shape[0])
    direction = _symmetric_direction(A, 7)

    def loss(values, b):
        return jnp.sum(jnp.sin(linear_solve(SparseMatrix(values, A.pattern, symmetric=True), b, **options).value))

    def dense_loss(values, b):
        return jnp.sum(jnp.sin(jnp.linalg.solve(SparseMatrix(values, A.pattern).todense(), b)))

    # The directional derivative in the values and the forward-over-reverse Hessian-vector product in b
    # (what a Newton-Krylov step through a solve uses), as one compiled program per loss.
    @functools.partial(jax.jit, static_argnums=0)
    def derivatives(loss, values, b):
        jvp = jax.jvp(lambda v: loss(v, b), (values,), (direction,))[1]
        return jvp, jax.jvp(jax.grad(lambda b: loss(values, b)), (b,), (b,))[1]

    (ours, ours_hvp), (expected, expected_hvp) = (derivatives(f, A.values, b) for f in (loss, dense_loss))
    # The tangent and adjoint solves of CG stop at a relative residual of 1e-10, the dense LU ones are exact.
    np.testing.assert_allclose(ours, expected, rtol=1e-8)
    np.testing.assert_allclose(ours_hvp, expected_hvp, rtol=1e-8, atol=1e-12)  # two CG solves, each to 1e-10


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.slow
def test_right_hand_sides_with_zeros_and_float32_systems(method):
    A = _heat_operator(SPHERE)
    single = SparseMatrix(A.values.astype(jnp.float32), A.pattern, symmetric=True, positive_semidefinite=True)
    options = _options(method, single)
    # Exact zeros in b (a point source): a norm-wise stopping test, not an entrywise one.
    b = jnp.zeros(A.shape[0]).at[:3].set(1.0)
    solution = _solve(A, b, options)
    # CG's stopping test |r| <= 1e-10 |b|, plus the round-off of |A x - b|.
    assert solution.result == RESULTS.successful and solution.residual < 1e-9
    assert _solve(A, jnp.zeros_like(b), options).result == RESULTS.successful
    # A float32 system keeps its dtype (CHOLMOD solves it in float64); float32 round-off sets the tolerances.
    solution = jax.jit(lambda A, b: linear_solve(A, b, **options, rtol=1e-6, residual_tolerance=1e-5))(
        single, b.astype(jnp.float32)
    )
    assert solution.value.dtype == jnp.float32 and solution.result == RESULTS.successful


def _connection_heat_operator(mesh, t=0.1, seed=0):
    """`M + t L_theta`: the cotan Laplacian with each edge's weight turned by a random angle (antisymmetric),
    the Laplacian of a random connection, so complex Hermitian positive semidefinite; plus the mass, definite."""
    L = cotan_laplacian(mesh).to_scipy().tocoo()
    n = mesh.n_vertices
    angles = np.random.default_rng(seed).uniform(-np.pi, np.pi, (n, n))
    angles = np.triu(angles, 1) - np.triu(angles, 1).T
    connection = sp.coo_matrix((L.data * np.exp(1j * angles[L.row, L.col]), (L.row, L.col)), shape=L.shape)
    return from_scipy(mass_matrix(mesh).to_scipy() + t * connection, positive_semidefinite=True)


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.slow
def test_complex_hermitian_systems_match_scipy_and_differentiate(method, icosphere1):
    A = _connection_heat_operator(icosphere1)
    assert A.hermitian and not A.symmetric
    options = _options(method, A)
    n = A.shape[0]
    rng = np.random.default_rng(4)
    b = jnp.asarray(rng.standard_normal((n, 2)) + 1j * rng.standard_normal((n, 2)))
    expected = spla.spsolve(A.to_scipy().tocsc(), np.asarray(b))
    solution = _solve(A, b, options)
    assert solution.value.dtype == jnp.complex128 and solution.result == RESULTS.successful
    # CG on the real form stops at a relative residual of 1e-10; the error is that times the condition number.
    np.testing.assert_allclose(solution.value, expected, rtol=0, atol=1e-8 * np.abs(expected).max())
    # A real matrix with a complex right-hand side: the real and imaginary parts as two real columns (CG's bound as above).
    B = _heat_operator(icosphere1)
    np.testing.assert_allclose(
        _solve(B, b[:, 0], _options(method, B)).value,
        spla.spsolve(B.to_scipy().tocsc(), np.asarray(b[:, 0])),
        rtol=0,
        atol=1e-8 * np.abs(expected).max(),  # CG's 1e-10 times the condition number
    )

    # Derivatives in the complex values and right-hand side against the dense complex solve.
    def loss(values, b, solve):
        x = solve(values, b)
        return jnp.sum(jnp.abs(x) ** 2 + jnp.real(x) * jnp.imag(x))

    ours = lambda values, b: linear_solve(SparseMatrix(values, A.pattern, hermitian=True), b, **options).value
    dense = lambda values, b: jnp.linalg.solve(SparseMatrix(values, A.pattern).todense(), b)
    direction = _rhs(A.pattern.nnz, 8) + 1j * _rhs(A.pattern.nnz, 9)
    direction = 0.5 * (direction + SparseMatrix(direction, A.pattern).T.values.conj())  # stays Hermitian
    db = jnp.asarray(rng.standard_normal((n, 2)) + 1j * rng.standard_normal((n, 2)))
    tangents = (direction, db)

    # Forward and reverse mode of each loss as one compiled program.
    @functools.partial(jax.jit, static_argnums=0)
    def derivatives(solve, values, b):
        jvp = jax.jvp(lambda v, b: loss(v, b, solve), (values, b), tangents)[1]
        return jvp, jax.grad(lambda v, b: loss(v, b, solve), argnums=(0, 1))(values, b)

    expected, _ = derivatives(dense, A.values, b)
    derivative, (grad_values, grad_b) = derivatives(ours, A.values, b)
    # The tangent and adjoint solves of CG on the real form (relative residual 1e-10, times its condition
    # number) against the dense complex LU solve; both modes alike.
    np.testing.assert_allclose(derivative, expected, rtol=1e-7)
    # Reverse mode: JAX's gradient g of a real function of complex inputs gives the derivative Re(sum(g * dz)).
    np.testing.assert_allclose(jnp.real(jnp.sum(grad_values * direction) + jnp.sum(grad_b * db)), expected, rtol=1e-7)


@pytest.mark.slow  # the fast tier's time limit (its checks run in the full suite)
def test_kept_factorisations_are_analysed_apart_and_answer_as_one_shot_solves(monkeypatch):
    """`factorize` outside `jit` (a kept factorisation) is analysed simplicial under a pattern of its own,
    `linear_solve` as CHOLMOD chooses (`_linear.cholmod_analysis`): the same answers as SciPy's, and
    the process-wide switch is set for each block and restored to the enclosing one's mode after it."""
    sparsax = pytest.importorskip("sparsax")
    modes = []
    monkeypatch.setattr(_linear, "_supernodal_setter", lambda: modes.append)
    anchor = factorize(_heat_operator(DISK), solver="cholesky")  # alive: ddgjax empties no sparsax cache meanwhile
    random = sp.random(300, 300, density=0.02, random_state=np.random.default_rng(7))
    A = from_scipy((random + random.T + 20.0 * sp.identity(300)).tocsr())  # a pattern no other test analyses
    b = _rhs(A.shape[0])
    expected = spla.spsolve(A.to_scipy().tocsc(), np.asarray(b))
    del modes[:]
    before = sparsax.cache_size()
    one_shot = linear_solve(A, b, solver="cholesky").value
    assert set(modes) == {1} and modes  # "auto" throughout, the default mode restored
    del modes[:]
    kept = factorize(A, solver="cholesky")
    assert modes == [0, 1]  # simplicial for the host check (which analyses), then restored
    assert sparsax.cache_size() == before + 2  # two analyses of one matrix: the kept one has a pattern of its own
    assert anchor.result == RESULTS.successful
    np.testing.assert_allclose(one_shot, expected, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(kept.solve(b).value, expected, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(kept.solve(jnp.stack([b, 2 * b], axis=1)).value[:, 1], 2 * expected, rtol=1e-12)
    with _linear.cholmod_analysis("simplicial"):
        linear_solve(A, b, solver="cholesky")
        assert modes[-1] == 0  # linear_solve's "auto" block restored the enclosing "simplicial"
        traced = jax.jit(lambda A, b: factorize(A, solver="cholesky").solve(b).value)(A, b)  # analysed apart, traced
    assert modes[-1] == 1
    np.testing.assert_allclose(traced, expected, rtol=1e-12, atol=1e-14)
    with pytest.raises(DDGInputError, match="mode"), _linear.cholmod_analysis("supernodal"):
        pass
