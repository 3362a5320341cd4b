"""`solver="auto"` of ddgjax.solve.linear_solve: which backend runs, by installation, size and trace."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.sparse.linalg as spla

from ddgjax.laplacian import cotan_laplacian, mass_matrix
from ddgjax.solve import _linear, linear_solve

from conftest import unit_icosphere

MESH = unit_icosphere(2)
A = mass_matrix(MESH) + 0.1 * cotan_laplacian(MESH)
B = jnp.asarray(np.random.default_rng(0).standard_normal(MESH.n_vertices))


def test_auto_takes_cholmod_where_installed_else_superlu_then_pyamg_by_size(monkeypatch):
    expected = spla.spsolve(A.to_scipy().tocsc(), np.asarray(B))
    assert linear_solve(A, B).solver == ("cholesky" if _linear._has_sparsax() else "superlu")
    monkeypatch.setattr(_linear, "_has_sparsax", lambda: False)  # the bare install
    small = linear_solve(A, B)
    assert small.solver == "superlu"
    monkeypatch.setattr(_linear, "SUPERLU_LIMIT", MESH.n_vertices - 1)  # this system counts as large
    large = linear_solve(A, B)
    assert large.solver == "pyamg" and int(large.num_steps) > 0
    for solution in (small, large):
        # pyamg's CG stops at linear_solve's default relative residual 1e-10, times A's condition number.
        np.testing.assert_allclose(solution.value, expected, rtol=0, atol=1e-8 * np.abs(expected).max())


def test_one_solve_above_the_iterative_limit_takes_pyamg_and_a_kept_factorisation_stays_direct(monkeypatch):
    """`linear_solve` (one solve) turns to pyamg's CG above `ITERATIVE_LIMIT` unknowns whatever is installed;
    `factorize`, whose cost many solves share, keeps the direct backend."""
    expected = spla.spsolve(A.to_scipy().tocsc(), np.asarray(B))
    direct = "cholesky" if _linear._has_sparsax() else "superlu"
    monkeypatch.setattr(_linear, "ITERATIVE_LIMIT", MESH.n_vertices - 1)  # this system counts as large
    one = linear_solve(A, B, rtol=1e-12)
    assert one.solver == "pyamg" and int(one.num_steps) > 0
    # CG to a relative residual of 1e-12 (rtol above) times A's condition number; SuperLU's round-off.
    np.testing.assert_allclose(one.value, expected, rtol=0, atol=1e-9 * np.abs(expected).max())
    kept = _linear.factorize(A)
    assert kept.solver == direct
    assert _linear.auto_solver(MESH.n_vertices, one_shot=True) == "pyamg"
    assert _linear.auto_solver(MESH.n_vertices - 1, one_shot=True) == direct
    # Rows of a volume (a 3-D neighbourhood graph, a tetrahedral mesh) fill in faster: iterative from fewer unknowns.
    monkeypatch.setattr(_linear, "ITERATIVE_LIMIT", 10**9)
    limit = _linear.VOLUME_ITERATIVE_LIMIT
    assert _linear.auto_solver(limit + 1, one_shot=True, entries_per_row=13.0) == "pyamg"
    assert _linear.auto_solver(limit + 1, one_shot=True, entries_per_row=7.0) == direct
    assert _linear.auto_solver(limit + 1, entries_per_row=13.0) == direct  # kept: factorised


def test_pyamg_strength_auto_is_symmetric_on_an_m_matrix_and_evolution_otherwise(monkeypatch):
    """The sign rule of `pyamg_solver(strength="auto")` (amg_hierarchy's default), seen in what reaches pyamg."""
    import pyamg

    from ddgjax.solve import _amg

    seen = []
    original = pyamg.smoothed_aggregation_solver
    monkeypatch.setattr(pyamg, "smoothed_aggregation_solver", lambda *a, **k: seen.append(k["strength"]) or original(*a, **k))
    m_matrix = A.to_scipy().tocsr()  # icosphere: no obtuse angle, so no positive off-diagonal entry
    assert _amg.is_m_matrix(m_matrix)
    positive = m_matrix.tolil()
    positive[0, 1] = positive[1, 0] = 1e-3  # one positive coupling (an obtuse pair of angles)
    positive = positive.tocsr()
    assert not _amg.is_m_matrix(positive)
    _amg.pyamg_solver(m_matrix, strength="auto")
    _amg.pyamg_solver(positive, strength="auto")
    _amg.pyamg_solver(positive)  # the host backend's default: pyamg's
    assert seen == ["symmetric", "evolution", "symmetric"]


@pytest.mark.slow
def test_auto_on_an_accelerator_is_cg_with_amg_outside_a_trace_and_jacobi_inside(monkeypatch):
    assert linear_solve(A, B, preconditioner="amg").solver == "cg"  # a preconditioner asks for CG anywhere
    monkeypatch.setattr(_linear.jax, "default_backend", lambda: "gpu")
    assert _linear._choose("auto", None, A, one_shot=True) == ("cg", "amg")  # concrete values: the hierarchy is built
    chosen = []
    jax.jit(lambda A: chosen.append(_linear._choose("auto", None, A, one_shot=True)) or A.values)(A)
    assert chosen == [("cg", "jacobi")]  # traced values: no host-built hierarchy
    expected = spla.spsolve(A.to_scipy().tocsc(), np.asarray(B))
    for solve in (linear_solve, jax.jit(linear_solve)):
        solution = solve(A, B)
        assert solution.solver == "cg" and int(solution.num_steps) > 0
        # CG stops at linear_solve's default relative residual 1e-10, times A's condition number.
        np.testing.assert_allclose(solution.value, expected, rtol=0, atol=1e-8 * np.abs(expected).max())
