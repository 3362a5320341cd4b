"""`method="auto"` of ddgjax.solve.linear_solve: which backend runs, by installation, size and trace."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.sparse.linalg as spla

from ddgjax.laplacian import cotan_laplacian, mass_matrix
from ddgjax.mesh import icosphere
from ddgjax.solve import _linear, linear_solve

MESH = icosphere(2)
A = mass_matrix(MESH) + 0.1 * cotan_laplacian(MESH)
B = jnp.asarray(np.random.default_rng(0).standard_normal(MESH.n_vertices))


def test_auto_takes_cholmod_where_installed_else_superlu_then_pyamg_by_size(monkeypatch):
    expected = spla.spsolve(A.to_scipy().tocsc(), np.asarray(B))
    assert linear_solve(A, B).method == ("cholesky" if _linear._has_sparsax() else "superlu")
    monkeypatch.setattr(_linear, "_has_sparsax", lambda: False)  # the bare install
    small = linear_solve(A, B)
    assert small.method == "superlu"
    monkeypatch.setattr(_linear, "SUPERLU_LIMIT", MESH.n_vertices - 1)  # this system counts as large
    large = linear_solve(A, B)
    assert large.method == "pyamg" and int(large.num_steps) > 0
    for solution in (small, large):
        np.testing.assert_allclose(solution.value, expected, rtol=0, atol=1e-8 * np.abs(expected).max())


@pytest.mark.slow
def test_auto_on_an_accelerator_is_cg_with_amg_outside_a_trace_and_jacobi_inside(monkeypatch):
    assert linear_solve(A, B, preconditioner="amg").method == "cg"  # a preconditioner asks for CG anywhere
    monkeypatch.setattr(_linear.jax, "default_backend", lambda: "gpu")
    assert _linear._choose("auto", None, A) == ("cg", "amg")  # concrete values: the hierarchy is built
    chosen = []
    jax.jit(lambda A: chosen.append(_linear._choose("auto", None, A)) or A.values)(A)
    assert chosen == [("cg", "jacobi")]  # traced values: no host-built hierarchy
    expected = spla.spsolve(A.to_scipy().tocsc(), np.asarray(B))
    for solve in (linear_solve, jax.jit(linear_solve)):
        solution = solve(A, B)
        assert solution.method == "cg" and int(solution.num_steps) > 0
        np.testing.assert_allclose(solution.value, expected, rtol=0, atol=1e-8 * np.abs(expected).max())
