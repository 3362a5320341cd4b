"""The obstacle problem: a Dirichlet energy minimised under a lower bound, with jaxopt's L-BFGS-B.

optimistix has no bound-constrained minimiser; jaxopt's `LBFGSB` is the route the library's
dependencies give for it. The reference is independent: the exact discrete solution by a
primal-dual active-set method (Hintermüller, Ito & Kunisch 2002) with SciPy's `spsolve`, checked
against the Karush-Kuhn-Tucker conditions.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import jaxopt
import numpy as np
import pytest
import scipy.sparse.linalg as spla

from ddgjax.laplacian import cotan_laplacian, mass_matrix
from ddgjax.mesh import disk
from ddgjax.sparse import dirichlet_blocks, dirichlet_plan

MESH = disk(10)  # the unit disk
LOAD = -8.0  # a downward load: the free membrane would sag to -2 (1 - r^2) at the centre
OBSTACLE = -0.5  # the plane it rests on


def _system():
    """`(L_ff, b)`: the free-free block of the cotan Laplacian (boundary fixed at 0) and `(M f)_f`."""
    L = cotan_laplacian(MESH)
    plan = dirichlet_plan(L, MESH.topology.boundary_vertices)
    L_ff, _ = dirichlet_blocks(L, plan)
    b = (mass_matrix(MESH) @ jnp.full(MESH.n_vertices, LOAD))[plan.free]
    return L_ff, b


def _active_set_solution(L_ff, b):
    """The exact minimiser of `1/2 u^T L u - b^T u` subject to `u >= OBSTACLE` (primal-dual active set, SciPy)."""
    A = L_ff.to_scipy().tocsc()
    b = np.asarray(b)
    psi = np.full(b.size, OBSTACLE)
    u, multiplier = psi.copy(), np.zeros(b.size)
    for _ in range(50):
        active = multiplier - (u - psi) > 0
        free = ~active
        u = psi.copy()
        u[free] = spla.spsolve(A[free][:, free], b[free] - A[free][:, active] @ psi[active])
        new_multiplier = A @ u - b
        new_multiplier[free] = 0.0
        if np.array_equal(active, new_multiplier - (u - psi) > 0):
            return u
        multiplier = new_multiplier
    raise AssertionError("the active-set method did not settle")


@pytest.mark.slow
def test_obstacle_problem_with_jaxopt_lbfgsb_matches_the_active_set_solution():
    L_ff, b = _system()
    exact = _active_set_solution(L_ff, b)
    contact = np.isclose(exact, OBSTACLE, rtol=0, atol=1e-12)
    assert 0 < contact.sum() < exact.size  # the membrane touches the obstacle on a disk, not everywhere

    energy = lambda u: 0.5 * jnp.vdot(u, L_ff @ u) - jnp.vdot(b, u)
    solver = jaxopt.LBFGSB(fun=energy, tol=1e-9, maxiter=2000)  # its error in u ~1e-6: below
    bounds = (jnp.full(b.shape, OBSTACLE), jnp.full(b.shape, jnp.inf))
    u, state = jax.jit(lambda u0: solver.run(u0, bounds=bounds))(jnp.zeros_like(b))
    assert int(state.iter_num) < 2000
    # L-BFGS-B stops at a projected-gradient norm of 1e-9; the energy's condition number (~1e3 here)
    # bounds the error in u by about 1e-6.
    np.testing.assert_allclose(u, exact, rtol=0, atol=1e-6)
    # Karush-Kuhn-Tucker: feasible, the gradient vanishes off the contact set and pushes into the
    # obstacle (non-negative multiplier) on it.
    gradient = np.asarray(L_ff @ u - b)
    assert np.all(np.asarray(u) >= OBSTACLE)
    scale = np.abs(np.asarray(b)).max()
    assert np.abs(gradient[~contact]).max() < 1e-6 * scale
    assert gradient[contact].min() > -1e-6 * scale
