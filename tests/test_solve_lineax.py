"""Tests for ddgjax.solve.SparseCholesky: the matrix recovered from products by colouring, lineax and
optimistix calling ddgjax's solves (Newton on quadratic and non-quadratic energies), derivatives."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ddgjax import DDGInputError
from ddgjax.dec import gradient
from ddgjax.laplacian import cotan_laplacian, mass_matrix
from ddgjax.mesh import face_areas, torus
from ddgjax.pde import screened_dirichlet_energy
from ddgjax.solve import SparseCholesky, linear_solve
from ddgjax.solve._lineax import column_colouring, matrix_from_products
from ddgjax.sparse import from_scipy

from conftest import unit_icosphere

MESH = unit_icosphere(3)
L, M = cotan_laplacian(MESH), mass_matrix(MESH)
RHO = jnp.asarray(np.random.default_rng(0).standard_normal(MESH.n_vertices))

# The recovery as one compiled program per pattern (op-by-op dispatch would compile every small step).
_recover = jax.jit(lambda A, colouring: matrix_from_products(A.pattern, colouring, lambda v: A @ v))


def test_colouring_recovers_the_matrix_from_products():
    for A in (L, mass_matrix(torus(major_radius=12, minor_radius=8), mass="galerkin"), M + 0.3 * L):
        colouring = column_colouring(A.pattern)
        recovered = _recover(A, colouring)
        assert abs(recovered.to_scipy() - A.to_scipy()).max() < 1e-14 * abs(A.to_scipy()).max()
        # Distance-2 colours of a triangle mesh: about the largest closed neighbourhood's size, not n.
        assert colouring.seeds.shape[0] <= 25
    # A random symmetric pattern with a long row (an ELL tail).
    dense = sp.random(40, 40, density=0.1, random_state=1) + sp.diags(np.arange(40.0) + 1)
    dense = dense + dense.T
    dense = dense.tolil()
    dense[0, :] = 1.0
    dense[:, 0] = 1.0
    A = from_scipy(dense.tocsr())
    recovered = _recover(A, column_colouring(A.pattern))
    assert abs(recovered.to_scipy() - A.to_scipy()).max() < 1e-13


@pytest.mark.slow
def test_lineax_solves_and_differentiates_with_it():
    A = M + 0.1 * L
    operator = lx.FunctionLinearOperator(lambda v: A @ v, jax.ShapeDtypeStruct((MESH.n_vertices,), RHO.dtype))
    solver = SparseCholesky(A.pattern)
    solution = lx.linear_solve(operator, RHO, solver)
    np.testing.assert_allclose(solution.value, spla.spsolve(A.to_scipy().tocsc(), np.asarray(RHO)), rtol=0, atol=1e-12)
    grad = jax.grad(lambda b: jnp.sum(lx.linear_solve(operator, b, solver).value ** 2))(RHO)
    expected = jax.grad(lambda b: jnp.sum(linear_solve(A, b).value ** 2))(RHO)
    np.testing.assert_allclose(grad, expected, rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("method", ["cholesky", "cg"])
@pytest.mark.slow
def test_newton_on_a_quadratic_energy_is_the_direct_solve(method):
    """Screened Poisson: the minimiser of 1/2 phi^T (L + sM) phi - phi^T M rho solves (L + sM) phi = M rho."""
    screening = 2.0
    newton = optx.Newton(rtol=1e-12, atol=1e-12, linear_solver=SparseCholesky(L.pattern, solver=method))

    def minimiser(rho):
        gradient_of_energy = jax.grad(lambda phi, _: screened_dirichlet_energy(MESH, phi, screening) - jnp.vdot(phi, M @ rho))
        return optx.root_find(gradient_of_energy, newton, jnp.zeros_like(rho), max_steps=5).value

    direct = linear_solve(L + screening * M, M @ RHO).value
    np.testing.assert_allclose(minimiser(RHO), direct, rtol=0, atol=1e-10 * np.abs(direct).max())

    def loss(rho):  # a loss of the minimiser, and the minimiser
        phi = minimiser(rho)
        return jnp.sum(phi**2), phi

    # Under jit, with optimistix's implicit derivative of the root through ddgjax's solve: one program
    # gives the minimiser and the gradient of the loss.
    (_, jitted), grad = jax.jit(jax.value_and_grad(loss, has_aux=True))(RHO)
    np.testing.assert_allclose(jitted, direct, rtol=0, atol=1e-10 * np.abs(direct).max())
    expected = jax.grad(lambda rho: jnp.sum(linear_solve(L + screening * M, M @ rho).value ** 2))(RHO)
    np.testing.assert_allclose(grad, expected, rtol=1e-10, atol=1e-12)  # measured 4e-15 (either backend)


@pytest.mark.slow
def test_newton_iterates_on_a_non_quadratic_energy():
    """A regularised p-Dirichlet energy (p = 3) plus screening: Newton converges in a few steps."""
    areas = face_areas(MESH)

    def energy(phi, _):
        squared = jnp.sum(gradient(MESH, phi) ** 2, axis=-1)
        return jnp.sum(areas * (squared + 1e-2) ** 1.5) / 3 + jnp.vdot(phi, M @ phi) - jnp.vdot(phi, M @ RHO)

    newton = optx.Newton(rtol=1e-10, atol=1e-10, linear_solver=SparseCholesky(L.pattern))
    solution = optx.root_find(jax.grad(energy), newton, jnp.zeros(MESH.n_vertices), max_steps=30)
    assert int(solution.stats["num_steps"]) <= 12
    assert float(jnp.abs(jax.grad(energy)(solution.value, None)).max()) < 1e-12


def test_bad_input(without_type_checker):
    with pytest.raises(DDGInputError, match="pattern: expected a ddgjax SparsityPattern"):
        SparseCholesky(L)
    with pytest.raises(DDGInputError, match="solver: expected one of"):
        SparseCholesky(L.pattern, solver="lu")
    operator = lx.FunctionLinearOperator(lambda v: v, jax.ShapeDtypeStruct((5,), RHO.dtype))
    with pytest.raises(DDGInputError, match=r"operator: SparseCholesky expects an operator on \(642,\) vectors"):
        lx.linear_solve(operator, jnp.ones(5), SparseCholesky(L.pattern))
