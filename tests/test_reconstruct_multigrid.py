"""The screened system of a Poisson reconstruction and its multigrid V-cycle (ddgjax/reconstruct/_multigrid.py),
against the same system assembled and solved by SciPy."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ddgjax.reconstruct import reconstruction_grid
from ddgjax.reconstruct._indicator import _pcg, cell_corners
from ddgjax.reconstruct._multigrid import prolong, restrict, screened_system


def sphere_points(n: int, seed: int = 0) -> np.ndarray:
    directions = np.random.default_rng(seed).standard_normal((n, 3))
    return directions / np.linalg.norm(directions, axis=1, keepdims=True)


def scipy_system(flat: np.ndarray, weights: np.ndarray, screening_weight: float, n: int) -> sp.csr_matrix:
    """`L_h + w S^T S` by SciPy: the 7-point stencil on flat offsets +-1, +-n, +-n^2 (cyclic), plus the screening."""
    size = n**3
    nodes = np.arange(size)
    rows, cols, values = [nodes], [nodes], [np.full(size, 6.0)]
    for offset in (1, n, n * n):
        for sign in (1, -1):
            rows.append(nodes)
            cols.append((nodes + sign * offset) % size)
            values.append(np.full(size, -1.0))
    laplacian = sp.csr_matrix((np.concatenate(values), (np.concatenate(rows), np.concatenate(cols))), shape=(size, size))
    m = flat.shape[0]
    evaluation = sp.csr_matrix((weights.ravel(), (np.repeat(np.arange(m), 8), flat.ravel())), shape=(m, size))
    return (laplacian + screening_weight * (evaluation.T @ evaluation)).tocsr()


def small_system(depth: int = 4, count: int = 600):
    points = sphere_points(count)
    grid = reconstruction_grid(points, depth=depth)
    n = 1 << depth
    flat, weights = cell_corners(jnp.asarray(points), grid.origin, grid.spacing, n)
    return np.asarray(flat), np.asarray(weights), n


def test_the_operator_is_scipys_assembled_matrix():
    flat, weights, n = small_system()
    operator, _ = screened_system(jnp.asarray(flat), jnp.asarray(weights), 3.0, n, 1.0)
    x = np.random.default_rng(1).standard_normal(n**3)
    expected = scipy_system(flat, weights, 3.0, n) @ x
    np.testing.assert_allclose(np.asarray(operator(jnp.asarray(x))), expected, rtol=1e-12, atol=1e-12)


def test_prolongation_is_the_transpose_of_restriction_times_8():
    rng = np.random.default_rng(2)
    coarse, fine = rng.standard_normal((4, 4, 4)), rng.standard_normal((8, 8, 8))
    left = float(jnp.vdot(prolong(jnp.asarray(coarse)), fine))
    right = 8 * float(jnp.vdot(coarse, restrict(jnp.asarray(fine))))
    np.testing.assert_allclose(left, right, rtol=1e-12)
    np.testing.assert_allclose(np.asarray(prolong(jnp.ones((4, 4, 4)))), 1.0)  # interpolation keeps constants
    np.testing.assert_allclose(np.asarray(restrict(jnp.ones((8, 8, 8)))), 1.0)


def test_the_v_cycle_is_a_symmetric_positive_definite_map():
    # Conjugate gradients need a symmetric positive definite preconditioner; the cycle runs in float32, so its
    # symmetry holds to float32's rounding.
    flat, weights, n = small_system()
    _, preconditioner = screened_system(jnp.asarray(flat), jnp.asarray(weights), 3.0, n, 1.0)
    rng = np.random.default_rng(3)
    u, v = (jnp.asarray(rng.standard_normal(n**3)) for _ in range(2))
    left, right = float(jnp.vdot(u, preconditioner(v))), float(jnp.vdot(preconditioner(u), v))
    np.testing.assert_allclose(left, right, rtol=1e-5)  # float32's rounding, summed over 4096 nodes
    for w in (u, v):
        assert float(jnp.vdot(w, preconditioner(w))) > 0


def test_preconditioned_cg_matches_scipys_direct_solve_in_few_steps():
    flat, weights, n = small_system(depth=4, count=1500)
    operator, preconditioner = screened_system(jnp.asarray(flat), jnp.asarray(weights), 3.0, n, 1.0)
    b = np.random.default_rng(4).standard_normal(n**3)
    x, steps = jax.jit(lambda b: _pcg(operator, preconditioner, b, 1e-10, 200))(jnp.asarray(b))
    expected = spla.spsolve(scipy_system(flat, weights, 3.0, n).tocsc(), b)
    np.testing.assert_allclose(np.asarray(x), expected, rtol=1e-7, atol=1e-7 * np.abs(expected).max())  # CG stops at 1e-10 of |b|
    # The V-cycle keeps the count near what it is at depth 8 (8-11 steps to 1e-4; here to 1e-10).
    assert int(steps) <= 30, int(steps)
