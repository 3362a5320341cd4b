"""`ddgjax.optim.minimize_energy`: Newton with the sparse Hessian, against SciPy's sparse solves of the same systems."""

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ddgjax import DDGInputError
from ddgjax.dec import gradient as face_gradients
from ddgjax.laplacian import cotan_laplacian, mass_matrix
from ddgjax.mesh import disk, face_areas
from ddgjax.optim import minimize_energy
from ddgjax.pde import dirichlet_energy, screened_dirichlet_energy

DISK = disk(6)
BOUNDARY = np.asarray(DISK.topology.boundary_vertices)
FREE = np.setdiff1d(np.arange(DISK.n_vertices), BOUNDARY)
L_DISK = cotan_laplacian(DISK).to_scipy().tocsr()
XY = np.asarray(DISK.vertices[:, :2])


def harmonic(u):
    return dirichlet_energy(DISK, u)


def dirichlet_reference(values):
    """The minimiser of `1/2 u^T L u` with `u = values` on the boundary: `L_ff u_f = -L_fb g` by SciPy."""
    u = np.zeros((DISK.n_vertices,) + values.shape[1:])
    u[BOUNDARY] = values
    rhs = -(L_DISK[FREE][:, BOUNDARY] @ values)
    u[FREE] = spla.spsolve(L_DISK[FREE][:, FREE].tocsc(), rhs).reshape(rhs.shape)
    return u


@pytest.mark.slow
def test_dirichlet_with_boundary_values_is_one_step_and_the_direct_answer():
    g = XY[BOUNDARY, 0] ** 2 - XY[BOUNDARY, 1] ** 2
    solution = minimize_energy(harmonic, jnp.zeros(DISK.n_vertices), mesh=DISK, fixed_vertices=BOUNDARY, fixed_values=g)
    assert isinstance(solution, optx.Solution) and solution.result == optx.RESULTS.successful
    assert int(solution.stats["num_steps"]) == 1  # one factorisation: the chord step confirms it
    assert solution.value.dtype == jnp.float64
    np.testing.assert_allclose(solution.value, dirichlet_reference(g), rtol=0, atol=1e-12)
    np.testing.assert_array_equal(solution.value[BOUNDARY], g)


@pytest.mark.slow
def test_screened_poisson_on_a_closed_surface_matches_spsolve(icosphere2):
    sphere = icosphere2
    s = 3.0
    rho = jnp.asarray(np.random.default_rng(0).standard_normal(sphere.n_vertices))
    M = mass_matrix(sphere)

    def energy(u, rho):
        return screened_dirichlet_energy(sphere, u, s) - jnp.vdot(u, M @ rho)

    solution = minimize_energy(energy, jnp.zeros(sphere.n_vertices), mesh=sphere, args=(rho,))
    A = (cotan_laplacian(sphere).to_scipy() + s * M.to_scipy()).tocsc()
    reference = spla.spsolve(A, M.to_scipy() @ np.asarray(rho))
    assert int(solution.stats["num_steps"]) == 1
    np.testing.assert_allclose(solution.value, reference, rtol=0, atol=1e-12 * np.abs(reference).max())


@pytest.mark.slow
def test_vector_values_with_coupled_coordinates():
    # E(u) = 1/2 sum_c u_c^T L u_c + 1/2 sum_i m_i u_i^T B u_i - <u, f>: the Hessian kron(L, I) + kron(M, B)
    # couples the two coordinates of each vertex, which the d x d blocks of the pattern must hold.
    mass = np.asarray(mass_matrix(DISK).row_sums())
    B = np.array([[2.0, 0.7], [0.7, 1.0]])
    f = np.random.default_rng(1).standard_normal((DISK.n_vertices, 2))
    fixed = BOUNDARY[::3]
    g = np.stack([XY[fixed, 0], XY[fixed, 1] ** 2], axis=1)

    def energy(u):
        coupling = 0.5 * jnp.sum(mass[:, None] * u * (u @ B))
        return dirichlet_energy(DISK, u) + coupling - jnp.vdot(u, f)

    solution = minimize_energy(energy, jnp.zeros((DISK.n_vertices, 2)), mesh=DISK, fixed_vertices=fixed, fixed_values=g)
    H = (sp.kron(L_DISK, sp.identity(2)) + sp.kron(sp.diags(mass), B)).tocsr()
    n = DISK.n_vertices
    fixed_rows = (fixed[:, None] * 2 + np.arange(2)).ravel()
    free_rows = np.setdiff1d(np.arange(2 * n), fixed_rows)
    x = np.zeros(2 * n)
    x[fixed_rows] = g.ravel()
    x[free_rows] = spla.spsolve(
        H[free_rows][:, free_rows].tocsc(), f.ravel()[free_rows] - H[free_rows][:, fixed_rows] @ g.ravel()
    )
    assert int(solution.stats["num_steps"]) == 1
    np.testing.assert_allclose(solution.value, x.reshape(n, 2), rtol=0, atol=1e-12)


@pytest.mark.slow
def test_p_dirichlet_energy_converges_to_a_zero_gradient():
    # The notebook's regularised p-Dirichlet energy (p = 3) with screening: strictly convex, not quadratic.
    areas = face_areas(DISK)
    mass = mass_matrix(DISK)
    f = jnp.asarray(XY[:, 0] + 2 * XY[:, 1] ** 2)

    def energy(u):
        squared = jnp.sum(face_gradients(DISK, u) ** 2, axis=-1)
        return jnp.sum(areas * (squared + 1e-2) ** 1.5) / 3 + 2.0 * jnp.vdot(u, mass @ u) - jnp.vdot(u, mass @ f)

    solution = minimize_energy(energy, jnp.zeros(DISK.n_vertices), mesh=DISK, rtol=1e-12, atol=1e-12)
    steps = int(solution.stats["num_steps"])
    assert 1 < steps < 10
    assert float(jnp.abs(jax.grad(energy)(solution.value)).max()) < 1e-13
    newton = optx.root_find(lambda u, _: jax.grad(energy)(u), optx.Newton(1e-12, 1e-12), jnp.zeros(DISK.n_vertices), max_steps=50)
    np.testing.assert_allclose(solution.value, newton.value, rtol=0, atol=1e-12)
    assert steps < int(newton.stats["num_steps"])  # a chord step per factorisation


@pytest.mark.slow
def test_under_jit_with_traced_fixed_values_and_a_pattern():
    g = XY[BOUNDARY, 0] * XY[BOUNDARY, 1]
    pattern = cotan_laplacian(DISK).pattern

    @jax.jit
    def solve(values):
        return minimize_energy(
            harmonic, jnp.zeros(DISK.n_vertices), pattern=pattern, fixed_vertices=BOUNDARY, fixed_values=values
        ).value

    np.testing.assert_allclose(solve(jnp.asarray(g)), dirichlet_reference(g), rtol=0, atol=1e-12)


@pytest.mark.slow
def test_derivative_of_the_minimiser_in_the_fixed_values():
    # d sum(u) / d g = 1 - L_bf L_ff^{-1} 1 (implicit function theorem, by SciPy) at every g: u is linear in g.
    g = jnp.asarray(XY[BOUNDARY, 0])
    total = jax.grad(
        lambda g: jnp.sum(
            minimize_energy(harmonic, jnp.zeros(DISK.n_vertices), mesh=DISK, fixed_vertices=BOUNDARY, fixed_values=g).value
        )
    )(g)
    expected = 1 - L_DISK[BOUNDARY][:, FREE] @ spla.spsolve(L_DISK[FREE][:, FREE].tocsc(), np.ones(FREE.size))
    np.testing.assert_allclose(total, expected, rtol=0, atol=1e-11)


@pytest.mark.slow
def test_fixed_values_default_to_x0s():
    x0 = jnp.asarray(XY[:, 0] ** 3)
    solution = minimize_energy(harmonic, x0, mesh=DISK, fixed_vertices=BOUNDARY)
    np.testing.assert_allclose(solution.value, dirichlet_reference(np.asarray(x0)[BOUNDARY]), rtol=0, atol=1e-12)


@pytest.mark.slow
def test_an_indefinite_hessian_is_reported():
    def concave(u):
        return -dirichlet_energy(DISK, u)

    x0 = jnp.asarray(XY[:, 0])
    with pytest.raises(Exception, match="must be positive definite"):
        minimize_energy(concave, x0, mesh=DISK, fixed_vertices=BOUNDARY)
    solution = minimize_energy(concave, x0, mesh=DISK, fixed_vertices=BOUNDARY, throw=False)
    assert solution.result == optx.RESULTS.singular
    np.testing.assert_array_equal(solution.value, x0)  # the failed step is not applied


@pytest.mark.slow
def test_running_out_of_steps_is_reported():
    def quartic(u):
        return dirichlet_energy(DISK, u) + jnp.sum(u**4 + u**2) - jnp.sum(u)

    solution = minimize_energy(quartic, jnp.zeros(DISK.n_vertices), mesh=DISK, max_steps=1, throw=False)
    assert solution.result == optx.RESULTS.nonlinear_max_steps_reached
    with pytest.raises(Exception, match="max_steps"):
        minimize_energy(quartic, jnp.zeros(DISK.n_vertices), mesh=DISK, max_steps=1)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"x0": jnp.zeros(DISK.n_vertices - 1)}, "x0: expected .* rows"),
        ({"x0": jnp.zeros(DISK.n_vertices, jnp.int32)}, "x0: expected an .* floating-point"),
        ({"x0": jnp.zeros((DISK.n_vertices, 2, 2))}, "x0: expected an"),
        ({"fixed_vertices": [0, DISK.n_vertices]}, r"fixed_vertices: vertex indices must lie in \[0, "),
        ({"fixed_vertices": [-1]}, "fixed_vertices: vertex indices must lie"),
        ({"fixed_vertices": [3, 3]}, "fixed_vertices: expected distinct"),
        ({"fixed_vertices": np.arange(DISK.n_vertices)}, "fixed_vertices: every vertex is fixed"),
        ({"fixed_vertices": [0.5]}, "fixed_vertices: expected a 1-d integer"),
        ({"fixed_vertices": [0, 1], "fixed_values": jnp.zeros(3)}, r"fixed_values: expected shape \(2,\)"),
        ({"fixed_values": jnp.zeros(3)}, "fixed_values: given without fixed_vertices"),
        ({"energy": lambda u: u**2}, "energy: expected .* scalar, got shape"),
        ({"energy": lambda u: (u**2).sum().astype(jnp.int32)}, "energy: expected .* floating-point scalar"),
        ({"mesh": None}, "mesh, pattern: pass exactly one"),
        ({"pattern": cotan_laplacian(DISK).pattern}, "mesh, pattern: pass exactly one"),
        ({"mesh": None, "pattern": np.eye(3)}, "pattern: expected the square SparsityPattern"),
        ({"mesh": np.zeros((3, 3))}, "mesh: expected a ddgjax Mesh"),
        ({"args": jnp.zeros(3)}, "args: expected a tuple"),
        ({"solver": "lu"}, "solver: expected one of"),
    ],
)
def test_bad_input_raises_ddg_input_error(kwargs, match, without_type_checker):
    call = {"energy": harmonic, "x0": jnp.zeros(DISK.n_vertices), "mesh": DISK} | kwargs
    with pytest.raises(DDGInputError, match=match):
        minimize_energy(call.pop("energy"), call.pop("x0"), **call)
