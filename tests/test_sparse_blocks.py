"""Tests for ddgjax.sparse.dirichlet_plan / dirichlet_blocks: free-free and free-fixed blocks for Dirichlet conditions."""

from __future__ import annotations

import re

import igl
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.sparse as sp
from jax.test_util import check_grads
from scipy.sparse.linalg import spsolve

from ddgjax import DDGInputError
from ddgjax.laplacian import cotan_laplacian, mass_matrix
from ddgjax.mesh import disk, grid
from ddgjax.sparse import DirichletBlocks, DirichletPlan, SparseMatrix, dirichlet_blocks, dirichlet_plan, from_scipy

# jax.test_util.check_grads compares with central finite differences of step 1e-4: their truncation
# error is ~1e-8 relative, so its float64 default tolerance (1e-5) is used.


def _random_spd(n: int, seed: int) -> sp.csr_matrix:
    base = sp.random(n, n, density=0.08, random_state=seed, format="csr")
    return (base @ base.T + sp.eye(n)).tocsr()


def _cases():
    mesh = disk()
    rng = np.random.default_rng(0)
    # Fixed indices in a shuffled order: the columns of A_fc follow the caller's order.
    shuffled = rng.permutation(40)[:12]
    return {
        "disk": (cotan_laplacian(mesh), mesh.topology.boundary_vertices),
        "spd": (from_scipy(_random_spd(40, 1), positive_semidefinite=True), shuffled),
    }


CASES = _cases()


@pytest.fixture(params=list(CASES), scope="module")
def case(request):
    matrix, fixed = CASES[request.param]
    return matrix, np.asarray(fixed), dirichlet_plan(matrix, fixed)


def _scipy_blocks(reference: sp.csr_matrix, fixed: np.ndarray):
    free = np.setdiff1d(np.arange(reference.shape[0]), fixed)
    return free, reference[free][:, free], reference[free][:, fixed]


def test_blocks_equal_scipy_slicing(case):
    matrix, fixed, plan = case
    free, ff_ref, fc_ref = _scipy_blocks(matrix.to_scipy(), fixed)
    np.testing.assert_array_equal(plan.free, free)
    np.testing.assert_array_equal(plan.fixed, fixed)
    free_free, free_fixed = dirichlet_blocks(matrix, plan)
    assert free_free.shape == (free.size, free.size) and free_fixed.shape == (free.size, fixed.size)
    # Gathers of the stored values: equal bit for bit, with the same stored positions.
    assert abs(free_free.to_scipy() - ff_ref).max() == 0 and abs(free_fixed.to_scipy() - fc_ref).max() == 0
    assert free_free.nnz == ff_ref.nnz and free_fixed.nnz == fc_ref.nnz
    assert free_free.symmetric and free_free.positive_semidefinite and free_free.pattern.symmetric
    assert not free_fixed.symmetric and not free_fixed.positive_semidefinite
    assert free_free.pattern.diagonal_first  # the diagonal survives, so A_ff.shifted(s) works
    x = np.random.default_rng(2).random((fixed.size, 2))
    np.testing.assert_allclose(free_fixed @ x, fc_ref @ x, rtol=1e-14)
    np.testing.assert_allclose(free_fixed.T @ (free_fixed @ x), fc_ref.T @ (fc_ref @ x), rtol=1e-13)
    # The indices alone build the same plan on the host; the blocks are named.
    by_indices = dirichlet_blocks(matrix, fixed)
    assert isinstance(by_indices, DirichletBlocks) and by_indices._fields == ("free_free", "free_fixed")
    for block, expected in zip((by_indices.free_free, by_indices.free_fixed), (free_free, free_fixed)):
        np.testing.assert_array_equal(block.values, expected.values)


def test_blocks_under_jit_and_vmap_with_new_values(case):
    matrix, fixed, plan = case
    rng = np.random.default_rng(3)
    reference = matrix.to_scipy()
    # New values on the same positions (symmetric, as the flags promise).
    new_reference = reference.copy()
    new_reference.data = rng.random(reference.nnz)
    new_reference = (new_reference + new_reference.T).tocsr()
    slots = matrix.pattern.slots(*new_reference.nonzero())
    new_values = jnp.zeros(matrix.pattern.nnz).at[slots].set(np.asarray(new_reference[new_reference.nonzero()]).ravel())
    new_matrix = SparseMatrix(new_values, matrix.pattern, symmetric=True)
    _, ff_ref, fc_ref = _scipy_blocks(new_reference, fixed)

    @jax.jit
    def blocks(matrix, plan):
        return dirichlet_blocks(matrix, plan)

    free_free, free_fixed = blocks(new_matrix, plan)
    assert abs(free_free.to_scipy() - ff_ref).max() == 0 and abs(free_fixed.to_scipy() - fc_ref).max() == 0
    # The plan built inside a trace from a pattern the trace closes over (concrete), as for a mesh's operator.
    closed_over = jax.jit(lambda v: dirichlet_blocks(SparseMatrix(v, matrix.pattern), fixed)[0].values)
    np.testing.assert_array_equal(closed_over(new_values), free_free.values)
    scales = jnp.asarray([1.0, -2.0])
    batched = jax.vmap(lambda s: dirichlet_blocks(SparseMatrix(s * new_values, matrix.pattern), plan)[1].values)(scales)
    np.testing.assert_array_equal(batched, scales[:, None] * free_fixed.values)
    # No search or sort at run time, and no scatter in the reverse pass.
    f = lambda v: jnp.sum(jnp.sin(dirichlet_blocks(SparseMatrix(v, matrix.pattern), plan)[0].values))
    names = set(re.findall(r"=\s+([A-Za-z_][\w\-]*)", str(jax.make_jaxpr(jax.grad(f))(new_values))))
    assert not {"sort", "while", "scatter-add", "scatter"} & names


@pytest.mark.slow
def test_gradients_of_block_values_against_finite_differences(case):
    matrix, fixed, plan = case
    rng = np.random.default_rng(4)
    x_free, x_fixed = jnp.asarray(rng.random(plan.free.shape[0])), jnp.asarray(rng.random(fixed.size))

    def energy(values):
        free_free, free_fixed = dirichlet_blocks(SparseMatrix(values, matrix.pattern, symmetric=True), plan)
        return x_free @ (free_free @ x_free) + jnp.sum(jnp.sin(free_fixed @ x_fixed)) + jnp.sum(free_free.values**3)

    # The blocks are linear in the values: first order in both modes covers their derivative rules.
    check_grads(jax.jit(energy), (matrix.values,), order=1, modes=("fwd", "rev"))
    # Exact: d(x_f^T A_ff x_f)/dA_ij = x_i x_j at free-free positions, 0 elsewhere.
    grad = jax.grad(lambda v: x_free @ (dirichlet_blocks(SparseMatrix(v, matrix.pattern), plan)[0] @ x_free))(matrix.values)
    rows, cols, slot = matrix.pattern.entries()
    position = np.full(matrix.shape[0], -1)
    position[np.asarray(plan.free)] = np.arange(plan.free.shape[0])
    inside = (position[rows] >= 0) & (position[cols] >= 0)
    expected = np.zeros(matrix.pattern.nnz)
    expected[slot[inside]] = np.asarray(x_free)[position[rows[inside]]] * np.asarray(x_free)[position[cols[inside]]]
    np.testing.assert_allclose(grad, expected, rtol=1e-14, atol=0)


def test_harmonic_extension_matches_igl_min_quad_with_fixed():
    """`L_ff u_f = -B_f - L_fc u_c`: libigl's `min_quad_with_fixed` on the same energy; linear data is harmonic on a flat mesh."""
    mesh = grid(6, 5)
    laplacian, mass = cotan_laplacian(mesh), mass_matrix(mesh)
    boundary = mesh.topology.boundary_vertices[::-1]  # any order
    plan = dirichlet_plan(laplacian, boundary)
    free_free, free_fixed = dirichlet_blocks(laplacian, plan)
    vertices = np.asarray(mesh.vertices)
    linear = 0.3 + 2.0 * vertices[:, 0] - 1.5 * vertices[:, 1]
    u_free = spsolve(free_free.to_scipy().tocsc(), -(free_fixed @ linear[boundary]))
    np.testing.assert_allclose(plan.join(u_free, linear[boundary]), linear, rtol=1e-12, atol=1e-12)
    # A Poisson right-hand side: minimise 1/2 u^T L u - u^T M rho with u = g on the boundary.
    rho = np.sin(3 * vertices[:, 0]) * np.cos(2 * vertices[:, 1])
    linear_term = -(mass @ jnp.asarray(rho))
    values = np.cos(vertices[boundary, 0])
    u_free = spsolve(free_free.to_scipy().tocsc(), -np.asarray(linear_term)[np.asarray(plan.free)] - free_fixed @ values)
    ours = np.asarray(plan.join(u_free, values))
    theirs = igl.min_quad_with_fixed(
        laplacian.to_scipy().tocsc(), np.asarray(linear_term)[:, None], boundary.astype(np.int64), values[:, None]
    )
    np.testing.assert_allclose(ours, theirs[:, 0], rtol=1e-12, atol=1e-13)


@pytest.mark.slow  # the fast tier's time limit (its checks run in the full suite)
def test_join_places_values_and_differentiates():
    matrix = from_scipy(_random_spd(10, 5))
    plan = dirichlet_plan(matrix.pattern, np.array([7, 2, 4]))
    joined = plan.join(jnp.arange(7.0), jnp.asarray([-7.0, -2.0, -4.0]))
    np.testing.assert_array_equal(joined, [0.0, 1.0, -2.0, 2.0, -4.0, 3.0, 4.0, -7.0, 5.0, 6.0])
    block = plan.join(jnp.ones((7, 2)), jnp.zeros((3, 2)))
    assert block.shape == (10, 2) and block[np.array([2, 4, 7])].sum() == 0
    weights = jnp.arange(1.0, 11.0)
    check_grads(lambda a, b: jnp.sum(weights * jnp.sin(plan.join(a, b))), (jnp.ones(7), jnp.ones(3)), order=1)
    with pytest.raises(DDGInputError, match=r"expected shapes \(7, \.\.\.\) and \(3, \.\.\.\)"):
        plan.join(jnp.ones(7), jnp.ones(4))


def test_no_fixed_index_and_uncoupled_fixed_indices():
    reference = _random_spd(12, 6)
    matrix = from_scipy(reference, positive_semidefinite=True)
    free_free, free_fixed = dirichlet_blocks(matrix, np.array([], dtype=np.int64))
    assert abs(free_free.to_scipy() - reference).max() == 0
    assert free_fixed.shape == (12, 0) and free_fixed.nnz == 0
    np.testing.assert_array_equal(free_fixed @ jnp.zeros(0), np.zeros(12))
    assert free_fixed.to_scipy().shape == (12, 0)
    # A fixed index with no coupling to the free ones: an empty A_fc of the right shape.
    isolated = sp.block_diag([reference, sp.eye(1)]).tocsr()
    free_free, free_fixed = dirichlet_blocks(from_scipy(isolated), np.array([12]))
    assert free_fixed.shape == (12, 1) and free_fixed.nnz == 0 and free_fixed.to_scipy().nnz == 0
    np.testing.assert_array_equal(free_fixed @ jnp.ones(1), np.zeros(12))
    assert abs(free_free.to_scipy() - reference).max() == 0


def test_bad_input(without_type_checker):
    matrix = from_scipy(_random_spd(10, 7))
    for fixed, message in (
        (np.array([3, 10]), r"fixed: indices must lie in \[0, 10\); out of range at positions \[1\]"),
        (np.array([-1, 2]), r"out of range at positions \[0\]"),
        (np.array([3, 5, 3, 5]), r"fixed: indices must be distinct; repeated at positions \[2, 3\]"),
        (np.array([[1, 2]]), r"fixed: expected a 1-d integer array of indices, got shape \(1, 2\)"),
        (np.array([1.0, 2.0]), r"fixed: expected a 1-d integer array of indices, got shape \(2,\) dtype float64"),
        (np.array([True, False]), "dtype bool"),
        (np.arange(10), r"fixed: all 10 indices are fixed, so no free index is left"),
    ):
        with pytest.raises(DDGInputError, match=message):
            dirichlet_plan(matrix, fixed)
    with pytest.raises(DDGInputError, match=r"matrix: Dirichlet blocks need a square matrix, got shape \(10, 8\)"):
        dirichlet_plan(from_scipy(sp.random(10, 8, density=0.3, random_state=0)), np.array([1]))
    with pytest.raises(DDGInputError, match="matrix: expected a SparseMatrix or its SparsityPattern, got csr_matrix"):
        dirichlet_plan(matrix.to_scipy(), np.array([1]))
    with pytest.raises(DDGInputError, match="matrix: expected a SparseMatrix, got csr_matrix"):
        dirichlet_blocks(matrix.to_scipy(), np.array([1]))
    with pytest.raises(DDGInputError, match="fixed: the fixed indices decide the block shapes"):
        jax.jit(lambda fixed: dirichlet_blocks(matrix, fixed)[0].values)(jnp.array([1, 2]))
    with pytest.raises(DDGInputError, match="concrete"):  # a traced pattern cannot be searched on the host
        jax.jit(lambda m: dirichlet_blocks(m, np.array([1, 2]))[0].values)(matrix)
    plan = dirichlet_plan(matrix, np.array([1, 2]))
    with pytest.raises(DDGInputError, match=r"plan: built for an \(10, 10\) pattern"):
        dirichlet_blocks(from_scipy(_random_spd(11, 7)), plan)
    # Same shape and storage length, other positions: found when the pattern is concrete.
    other = from_scipy(_random_spd(10, 7)[::-1, ::-1])
    assert other.pattern.nnz == matrix.pattern.nnz
    with pytest.raises(DDGInputError, match="plan: built for a matrix with other stored positions"):
        dirichlet_blocks(other, plan)
    assert isinstance(plan, DirichletPlan)
