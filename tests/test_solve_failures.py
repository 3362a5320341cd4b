"""Failures of every backend of ddgjax.solve through the results convention: indefinite, singular and
non-finite systems give a `RESULTS` item (no raw error), raise the same way with `throw=True` eagerly and
under `jit`, and leave the process usable; `vmap` over vertex positions with a shared right-hand side;
mixed dtypes; the float32 warning and messages."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import textwrap
import warnings

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ddgjax import RESULTS, DDGInputError
from ddgjax.laplacian import cotan_laplacian, mass_matrix
from ddgjax.solve import PrecisionWarning, SparseCholesky, _linear, amg_hierarchy, factorize, linear_solve
from ddgjax.sparse import SparseMatrix, SparsityPattern, from_scipy

from conftest import unit_icosphere

METHODS = ("cholesky", "superlu", "cg", "pyamg")
MESH = unit_icosphere(1)
A = mass_matrix(MESH) + 0.1 * cotan_laplacian(MESH)
B = jnp.asarray(np.random.default_rng(0).standard_normal(MESH.n_vertices))
# The error bound of a solve against SciPy, relative to the solution's largest entry: CG (and pyamg's) stop at
# |r| <= 1e-10 |b| (default rtol), so |x - x*|_inf <= |x - x*|_2 <= cond(A) 1e-10 |x*|_2 <= cond 1e-10 sqrt(n) |x*|_inf,
# with cond(M + 0.1 L) <= 2.74 (scaled copies down to 1.45) and n = 42: 1.8e-9 (measured <= 5.2e-11).
# The direct solves agree to ~1e-15.
SOLVE_ERROR = 2e-9

# What each failure's message says (words of its `RESULTS` item's message), by the item's name.
MESSAGES = {
    "not_positive_definite": "must be positive definite",
    "singular": "does not solve the system",
    "nonfinite": "NaN or inf",
}


def _on_pattern(values) -> SparseMatrix:
    """A matrix on `A`'s pattern with the same static flags as every other case, so one compiled program serves all."""
    return SparseMatrix(values, A.pattern, symmetric=True)


def _singular(A: SparseMatrix) -> SparseMatrix:
    """`A` with vertex 0's row and column zeroed: exactly singular, positive semidefinite."""
    touches = (A.pattern.rows == 0) | (A.pattern.cols == 0)
    return _on_pattern(jnp.where(touches, 0.0, A.values))


def _with_nan(A: SparseMatrix) -> SparseMatrix:
    return _on_pattern(A.values.at[5].set(jnp.nan))


# name: (matrix, right-hand side, {method: the expected `RESULTS` item's name}); a missing method means
# "solves it" (the backends that do not need definiteness solve an indefinite nonsingular system), None
# "any failure" (CG breaks down on the zero row).
CASES = {
    "indefinite": (_on_pattern(-A.values), B, {"cholesky": "not_positive_definite"}),
    "singular": (_singular(A), B, {"cholesky": "not_positive_definite", "superlu": "singular", "cg": None, "pyamg": None}),
    "nan_matrix": (_with_nan(A), B, dict.fromkeys(METHODS, "nonfinite")),
    "nan_rhs": (_on_pattern(A.values), B.at[0].set(jnp.nan), dict.fromkeys(METHODS, "nonfinite")),
}


@pytest.mark.parametrize("method", METHODS)
def test_failures_are_results_and_raise_alike_eagerly_and_under_jit(method):
    # One compiled program per backend for every case (same shapes).
    jitted = jax.jit(lambda A, b: linear_solve(A, b, solver=method).value)
    for name, (matrix, b, expected) in CASES.items():
        solution = linear_solve(matrix, b, solver=method, throw=False)
        if method not in expected:
            assert solution.result == RESULTS.successful, name
            reference = spla.spsolve(matrix.to_scipy().tocsc(), np.asarray(b))
            # SOLVE_ERROR: CG's stopping residual times the condition number
            np.testing.assert_allclose(solution.value, reference, rtol=0, atol=SOLVE_ERROR * np.abs(reference).max())
            continue
        assert solution.result != RESULTS.successful, name
        if expected[method] is not None:
            assert solution.result == getattr(RESULTS, expected[method]), name
        message = MESSAGES.get(expected[method], "|".join(MESSAGES.values()))
        # ddgjax's convention (docs/conventions.md): equinox's error eagerly, the XLA runtime's under a
        # plain jax.jit, with the same message; both are RuntimeErrors.
        with pytest.raises(eqx.EquinoxRuntimeError, match=message):
            linear_solve(matrix, b, solver=method)
        with pytest.raises(jax.errors.JaxRuntimeError, match=message):
            jax.block_until_ready(jitted(matrix, b))
    assert issubclass(eqx.EquinoxRuntimeError, RuntimeError) and issubclass(jax.errors.JaxRuntimeError, RuntimeError)
    # The process stays usable: a good system solves, eagerly and under the same jit.
    reference = spla.spsolve(A.to_scipy().tocsc(), np.asarray(B))
    good = _on_pattern(A.values)
    for value in (linear_solve(good, B, solver=method).value, jitted(good, B)):
        # SOLVE_ERROR: CG's stopping residual times the condition number
        np.testing.assert_allclose(value, reference, rtol=0, atol=SOLVE_ERROR * np.abs(reference).max())


@pytest.mark.parametrize("method", METHODS)
def test_a_failed_factorisation_is_kept_and_its_solves_are_nan(method):
    for matrix, expected in ((_with_nan(A), RESULTS.nonfinite), (-A, RESULTS.not_positive_definite)):
        if method != "cholesky" and expected == RESULTS.not_positive_definite:
            continue  # only CHOLMOD needs definiteness
        factorization = factorize(matrix, solver=method)
        assert factorization.result == expected
        solution = factorization.solve(B, throw=False)
        assert solution.result == expected and np.all(np.isnan(solution.value))
    assert factorize(A, solver=method).result == RESULTS.successful


# CG and pyamg batch through plain JAX and `pure_callback`; CHOLMOD and SuperLU are the fast tier's, with one level.
@pytest.mark.parametrize("nested", (False, pytest.param(True, marks=pytest.mark.slow)))
@pytest.mark.parametrize(
    "method", ("cholesky", "superlu", pytest.param("cg", marks=pytest.mark.slow), pytest.param("pyamg", marks=pytest.mark.slow))
)
def test_vmap_over_vertex_positions_with_a_shared_right_hand_side(method, nested):
    """Batched matrix values with an unbatched `b` (and an unbatched block `b`), against a loop, under one
    (or two nested) levels of `vmap`; a member with NaN positions fails alone."""
    scales = (1.0, 1.5, 2.0)
    positions = jnp.stack([MESH.vertices * s for s in scales] + [MESH.vertices.at[0, 0].set(jnp.nan)])
    block = jnp.stack([B, -2.0 * B], axis=1)

    def solve(V):
        moved = MESH.with_vertices(V)
        system = mass_matrix(moved) + 0.1 * cotan_laplacian(moved)
        one, two = (linear_solve(system, b, solver=method, throw=False) for b in (B, block))
        return one.value, two.value, one.result

    def batched(positions):
        if not nested:
            return jax.vmap(solve)(positions)
        twice = jax.vmap(jax.vmap(solve))(positions.reshape(2, 2, *positions.shape[1:]))
        return jax.tree.map(lambda x: x.reshape(4, *x.shape[2:]), twice)

    vector, matrix, result = jax.jit(batched)(positions)
    np.testing.assert_array_equal(result == RESULTS.nonfinite, [False, False, False, True])
    np.testing.assert_array_equal(result == RESULTS.successful, [True, True, True, False])
    for k, scale in enumerate(scales):
        moved = MESH.with_vertices(MESH.vertices * scale)
        system = (mass_matrix(moved) + 0.1 * cotan_laplacian(moved)).to_scipy().tocsc()
        expected = spla.spsolve(system, np.asarray(block))
        # CG stops at a relative residual of 1e-10; the error is that times the condition number at most (SOLVE_ERROR).
        np.testing.assert_allclose(vector[k], expected[:, 0], rtol=0, atol=SOLVE_ERROR * np.abs(expected).max())
        np.testing.assert_allclose(matrix[k], expected, rtol=0, atol=SOLVE_ERROR * np.abs(expected).max())


@pytest.mark.parametrize(
    "method", ("cholesky", "cg", pytest.param("superlu", marks=pytest.mark.slow), pytest.param("pyamg", marks=pytest.mark.slow))
)
def test_mixed_dtypes_are_promoted(method):
    reference = spla.spsolve(A.to_scipy().tocsc(), np.asarray(B.astype(jnp.float32), np.float64))
    solution = linear_solve(A, B.astype(jnp.float32), solver=method)
    assert solution.value.dtype == jnp.float64 and solution.result == RESULTS.successful
    np.testing.assert_allclose(solution.value, reference, rtol=0, atol=SOLVE_ERROR * np.abs(reference).max())  # CG's bound
    complex_b = B.astype(jnp.complex64) * (1 + 2j)
    assert linear_solve(A, complex_b, solver=method).value.dtype == jnp.complex128


def test_a_pattern_without_its_whole_diagonal_is_reported_or_refused():
    # The (1, 1) entry is not stored: CHOLMOD's stand-in factor cannot be the identity on the pattern's slots.
    gapped = from_scipy(sp.csr_matrix(np.array([[2.0, 1.0, 0.0], [1.0, 0.0, 1.0], [0.0, 1.0, 2.0]])))
    assert linear_solve(gapped, jnp.ones(3), solver="cholesky", throw=False).result == RESULTS.not_positive_definite
    np.testing.assert_allclose(linear_solve(gapped, jnp.ones(3), solver="superlu").value, [0.5, 0.0, 0.5], atol=1e-15)
    # Fewer stored entries than rows: an empty row, singular whatever the values.
    sparse = SparsityPattern(
        rows=jnp.array([0, 1]), cols=jnp.array([1, 0]), indptr=None, shape=(3, 3), layout="coo", symmetric=True
    )
    with pytest.raises(DDGInputError, match="A: stores 2 entries for 3 rows"):
        linear_solve(SparseMatrix(jnp.ones(2), sparse, symmetric=True), jnp.ones(3), solver="cholesky")


def test_nonfinite_messages_speak_of_the_solve_not_of_flows():
    with pytest.raises(eqx.EquinoxRuntimeError, match="NaN or inf") as raised:
        linear_solve(A, B.at[0].set(jnp.inf), solver="superlu")
    assert re.search(r"\bflows?\b", str(raised.value)) is None


def test_amg_on_nan_values_reports_instead_of_raising_from_pyamg():
    solution = linear_solve(_with_nan(A), B, solver="cg", preconditioner="amg", throw=False)
    assert solution.result == RESULTS.nonfinite
    with pytest.raises(DDGInputError, match="A: expected finite values"):
        amg_hierarchy(_with_nan(A))


def test_lineax_gets_singular_for_a_matrix_cholmod_cannot_factor():
    operator = lx.FunctionLinearOperator(lambda v: -(A @ v), jax.ShapeDtypeStruct(B.shape, B.dtype))
    solution = lx.linear_solve(operator, B, SparseCholesky(A.pattern, solver="cholesky"), throw=False)
    assert solution.result == lx.RESULTS.singular


def test_a_float32_system_warns_once():
    single = SparseMatrix(A.values.astype(jnp.float32), A.pattern, symmetric=True, positive_semidefinite=True)
    _linear._warn_low_precision.cache_clear()  # once per process: this test starts the count again
    with pytest.warns(PrecisionWarning, match="jax_enable_x64"):
        # float32 round-off (eps 6e-8 times the condition number) cannot meet the float64 defaults.
        linear_solve(single, B.astype(jnp.float32), solver="superlu", residual_tolerance=1e-5)
    with warnings.catch_warnings():
        warnings.simplefilter("error", PrecisionWarning)
        linear_solve(single, B.astype(jnp.float32), solver="cg", rtol=1e-6, residual_tolerance=1e-5)  # float32 round-off
        linear_solve(A, B, solver="superlu")


@pytest.mark.slow
def test_float32_without_x64_warns_once_and_failures_name_the_precision():
    """With x64 off (a fresh process: the suite turns it on), float32 geometry warns once, and a failed solve
    says that float32 may be the cause and how to enable float64."""
    script = textwrap.dedent(
        """
        import warnings
        import jax.numpy as jnp
        from ddgjax.laplacian import cotan_laplacian, mass_matrix
        from ddgjax.mesh import icosphere
        from ddgjax.solve import PrecisionWarning, linear_solve

        mesh = icosphere(2)
        assert mesh.vertices.dtype == jnp.float32
        L = cotan_laplacian(mesh)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            for t in (0.1, 0.2):
                linear_solve(mass_matrix(mesh) + t * L, jnp.ones(mesh.n_vertices), residual_tolerance=1e-4)
            try:  # a closed surface's Laplacian and a right-hand side with a nonzero mean: no solution
                linear_solve(L, jnp.ones(mesh.n_vertices))
            except RuntimeError as error:
                print("MESSAGE", " ".join(str(error).split()))
        print("WARNINGS", sum(issubclass(w.category, PrecisionWarning) for w in caught))
        """
    )
    environment = {**os.environ, "JAX_ENABLE_X64": "0"}
    run = subprocess.run([sys.executable, "-c", script], env=environment, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    lines = dict(line.split(" ", 1) for line in run.stdout.splitlines() if line.startswith(("MESSAGE", "WARNINGS")))
    assert lines["WARNINGS"] == "1"
    assert "float32" in lines["MESSAGE"] and "jax_enable_x64" in lines["MESSAGE"]
