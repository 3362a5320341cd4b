"""The problem layer on tet meshes: `solve_poisson`, `harmonic_interpolation`, `eigenpairs` and `heat_distance`
take a `ddgjax.volume.TetMesh`. References: libigl's tet operators solved by SciPy, the unit ball's closed
forms with fitted rates, finite differences for the gradients in the vertex positions, bad input."""

from __future__ import annotations

import igl
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ddgjax import DDGInputError, MeshDataError
from ddgjax.geodesics import heat_distance, heat_distance_solver
from ddgjax.pde import harmonic_interpolation, solve_poisson
from ddgjax.spectral import eigenpairs
from ddgjax.volume import divergence, gradient, mass_matrix, tet_ball, tet_box, tet_volumes

from finite_differences import central_difference

jax.config.update("jax_enable_x64", True)

#: libigl's mass matrix types for ddgjax's `mass=` names on tets.
IGL_MASS = {
    "voronoi": igl.MASSMATRIX_TYPE_VORONOI,
    "barycentric": igl.MASSMATRIX_TYPE_BARYCENTRIC,
    "galerkin": igl.MASSMATRIX_TYPE_FULL,
}

#: Zeros of the spherical Bessel functions: `j_0` (`pi`), `j_1` (`4.4934`) and `j_1'` (`2.0816`).
J0_ZERO, J1_ZERO, J1_PRIME_ZERO = np.pi, 4.493409457909064, 2.081575977818101


def _libigl_operators(tet_mesh, mass: str) -> tuple[sp.csc_matrix, sp.csc_matrix]:
    V, T = np.asarray(tet_mesh.vertices, dtype=float), np.asarray(tet_mesh.tets)
    return sp.csc_matrix(-igl.cotmatrix(V, T)), sp.csc_matrix(igl.massmatrix(V, T, IGL_MASS[mass]))


def _radii(tet_mesh) -> np.ndarray:
    return np.linalg.norm(np.asarray(tet_mesh.vertices), axis=1)


def _rate(h, errors) -> float:
    return float(np.polyfit(np.log(h), np.log(errors), 1)[0])


# ---------------------------------------------------------------------------------------------------------- Poisson


@pytest.mark.parametrize("mass", ["voronoi", "barycentric", "galerkin"])
def test_poisson_matches_scipy_on_libigls_tet_operators(mass):
    """`L phi = -M rho` with boundary values, against `spsolve` of libigl's `-cotmatrix` and `massmatrix`."""
    tet_mesh = tet_ball(3)
    V = np.asarray(tet_mesh.vertices)
    rng = np.random.default_rng(0)
    rho = np.stack([np.sin(3 * V[:, 0]) + V[:, 1] * V[:, 2], rng.normal(size=tet_mesh.n_vertices)], axis=1)
    fixed = tet_mesh.topology.boundary_vertices
    values = np.stack([V[fixed, 0] ** 2, np.cos(V[fixed, 2])], axis=1)
    phi = np.asarray(solve_poisson(tet_mesh, rho, fixed_vertices=fixed, fixed_values=values, mass=mass))

    L, M = _libigl_operators(tet_mesh, mass)
    free = np.setdiff1d(np.arange(tet_mesh.n_vertices), fixed)
    rhs = -(M @ rho)[free] - L[free][:, fixed] @ values
    expected = np.zeros_like(rho)
    expected[fixed] = values
    expected[free] = spla.spsolve(L[free][:, free], rhs)
    np.testing.assert_allclose(phi, expected, rtol=0, atol=1e-10 * np.abs(expected).max())


def test_poisson_without_fixed_vertices_is_the_zero_mean_solution():
    """Neumann everywhere: `rho` made compatible (its mean removed), `phi` of zero mean, `L phi = -M rho` to round-off."""
    tet_mesh = tet_box(3)
    rho = np.asarray(tet_mesh.vertices)[:, 0] ** 3 + 0.3
    phi = np.asarray(solve_poisson(tet_mesh, rho, mass="barycentric"))
    L, M = _libigl_operators(tet_mesh, "barycentric")
    mass = M.diagonal()
    compatible = rho - mass @ rho / mass.sum()
    assert abs(mass @ phi) < 1e-14
    np.testing.assert_allclose(L @ phi, -(M @ compatible), rtol=0, atol=1e-12)


def test_harmonic_interpolation_reproduces_a_linear_function():
    """Linear functions are harmonic on any tet mesh (linear finite elements): boundary values give them back exactly."""
    tet_mesh = tet_ball(3)
    V = np.asarray(tet_mesh.vertices)
    linear = V @ np.array([[1.0, -0.5], [2.0, 0.25], [-3.0, 1.0]]) + np.array([0.5, -1.0])
    fixed = tet_mesh.topology.boundary_vertices
    phi = np.asarray(harmonic_interpolation(tet_mesh, fixed_vertices=fixed, fixed_values=linear[fixed]))
    # 1e-12 with a direct solve (CPU); the CG a GPU defaults to stops at a relative residual of 1e-10.
    np.testing.assert_allclose(phi, linear, rtol=0, atol=1e-12 if jax.default_backend() == "cpu" else 1e-9)


def _ball_poisson_error(n_layers: int) -> float:
    """Mass-weighted L2 error of `-Delta u = 1`, `u = 0` on the sphere, against `(1 - r^2) / 6`."""
    tet_mesh = tet_ball(n_layers)
    fixed = tet_mesh.topology.boundary_vertices
    u = np.asarray(solve_poisson(tet_mesh, -np.ones(tet_mesh.n_vertices), fixed_vertices=fixed))
    error = u - (1 - _radii(tet_mesh) ** 2) / 6
    return float(np.sqrt(error @ (mass_matrix(tet_mesh).to_scipy() @ error)))


def test_poisson_in_the_ball_is_close_to_the_closed_form():
    # Second order in h = 1 / n_layers (the slow test fits the rate); 3.1e-4 at n_layers = 8.
    assert _ball_poisson_error(4) < 1.2e-3


@pytest.mark.slow
def test_poisson_in_the_ball_converges_at_second_order():
    layers = np.array([8, 12, 16])
    errors = [_ball_poisson_error(n) for n in layers]
    # Measured 1.87 over these sizes (2.0 in the asymptotic range, tet_ball's docstring).
    assert _rate(1.0 / layers, errors) > 1.75, errors


@pytest.mark.slow
def test_poisson_gradients_match_finite_differences():
    """`J = sum w phi` of a Dirichlet problem: its gradient in the vertex positions and in `rho`, against central differences."""
    tet_mesh = tet_ball(4)  # as in the closed-form test: the same compiled programs
    V0 = np.asarray(tet_mesh.vertices)
    rng = np.random.default_rng(1)
    fixed = tet_mesh.topology.boundary_vertices
    weights = rng.normal(size=tet_mesh.n_vertices)
    rho0 = 1.0 + V0[:, 1] ** 2 + np.sin(3 * V0[:, 0])

    def objective(V, rho):
        return jnp.sum(weights * solve_poisson(tet_mesh.with_vertices(V), rho, fixed_vertices=fixed))

    grad_V, grad_rho = jax.grad(objective, argnums=(0, 1))(jnp.asarray(V0), jnp.asarray(rho0))
    np.testing.assert_allclose(jax.jit(objective)(V0, rho0), objective(V0, rho0), rtol=1e-12)
    dV, drho = rng.normal(size=V0.shape), rng.normal(size=rho0.shape)
    eps = 1e-6
    fd_V = central_difference(lambda V: objective(V, rho0), V0, dV, eps)
    fd_rho = central_difference(lambda rho: objective(V0, rho), rho0, drho, eps)
    # Central differences with eps = 1e-6: truncation ~eps^2, round-off ~1e-16 / eps relative.
    np.testing.assert_allclose(float(jnp.sum(grad_V * dV)), float(fd_V), rtol=1e-7)
    np.testing.assert_allclose(float(jnp.sum(grad_rho * drho)), float(fd_rho), rtol=1e-7)  # FD rounding ~1e-10


@pytest.mark.slow
def test_poisson_on_degenerate_tets_keeps_values_and_gradients_finite():
    """The ball's centre moved onto a neighbour: every tet around that edge has exactly zero volume."""
    tet_mesh = tet_ball(4)  # as in the gradient test: the same compiled programs
    V = np.asarray(tet_mesh.vertices).copy()
    neighbour = int(np.asarray(tet_mesh.edges)[np.asarray(tet_mesh.edges)[:, 0] == 0][0, 1])
    V[0] = V[neighbour]
    flat = (np.asarray(tet_mesh.tets) == 0).any(axis=1) & (np.asarray(tet_mesh.tets) == neighbour).any(axis=1)
    assert np.all(np.asarray(tet_volumes(tet_mesh.with_vertices(V)))[flat] == 0.0)
    fixed = tet_mesh.topology.boundary_vertices

    def objective(V):
        return jnp.sum(solve_poisson(tet_mesh.with_vertices(V), -jnp.ones(V.shape[0]), fixed_vertices=fixed) ** 2)

    value, gradient = jax.value_and_grad(objective)(jnp.asarray(V))
    assert np.isfinite(value) and np.isfinite(np.asarray(gradient)).all()


def test_degenerate_tets_are_refused_on_concrete_positions():
    """No robust= remedy in 3-D: the problem layer names the flat tets and what to do."""
    tet_mesh = tet_ball(4)
    V = np.asarray(tet_mesh.vertices).copy()
    neighbour = int(np.asarray(tet_mesh.edges)[np.asarray(tet_mesh.edges)[:, 0] == 0][0, 1])
    V[0] = V[neighbour]
    fixed = tet_mesh.topology.boundary_vertices
    flat_mesh = tet_mesh.with_vertices(V)
    for call in (
        lambda: solve_poisson(flat_mesh, -jnp.ones(V.shape[0]), fixed_vertices=fixed),
        lambda: eigenpairs(flat_mesh, 3),
        lambda: heat_distance(flat_mesh, [1]),
    ):
        with pytest.raises(MeshDataError, match="zero or near-zero volume"):
            call()


def test_poisson_refuses_robust_and_bad_fixed_vertices_on_a_tet_mesh():
    tet_mesh = tet_ball(2)
    rho = np.zeros(tet_mesh.n_vertices)
    with pytest.raises(DDGInputError, match="robust"):
        solve_poisson(tet_mesh, rho, robust=True)
    with pytest.raises(DDGInputError, match="robust"):
        harmonic_interpolation(tet_mesh, fixed_vertices=np.array([0]), fixed_values=np.array([1.0]), robust=True)
    with pytest.raises(DDGInputError, match="fixed_vertices"):
        solve_poisson(tet_mesh, rho, fixed_vertices=np.array([0, tet_mesh.n_vertices]), fixed_values=np.array([0.0, 1.0]))
    with pytest.raises(DDGInputError, match="rho"):
        solve_poisson(tet_mesh, np.zeros(tet_mesh.n_vertices + 1))


# ------------------------------------------------------------------------------------------------------ eigenpairs


@pytest.mark.parametrize("boundary", ["neumann", "dirichlet"])
def test_eigenpairs_match_scipy_on_libigls_tet_operators(boundary):
    tet_mesh = tet_ball(3)
    values, vectors = eigenpairs(tet_mesh, 6, boundary=boundary)
    L, M = _libigl_operators(tet_mesh, "voronoi")
    free = np.arange(tet_mesh.n_vertices)
    if boundary == "dirichlet":
        free = np.setdiff1d(free, tet_mesh.topology.boundary_vertices)
        assert np.abs(np.asarray(vectors)[tet_mesh.topology.boundary_vertices]).max() == 0
    expected = np.sort(spla.eigsh(L[free][:, free], 6, M[free][:, free], sigma=-1e-3)[0])
    np.testing.assert_allclose(np.asarray(values), expected, rtol=1e-10, atol=1e-10)
    vectors = np.asarray(vectors)[free]
    gram = vectors.T @ (M[free][:, free] @ vectors)
    np.testing.assert_allclose(gram, np.eye(6), rtol=0, atol=1e-10)


@pytest.mark.slow
def test_eigenvalues_of_the_ball_converge_to_spherical_bessel_zeros():
    layers = np.array([6, 8, 12])
    dirichlet, neumann = [], []
    for n in layers:
        tet_mesh = tet_ball(int(n))
        dirichlet.append(np.asarray(eigenpairs(tet_mesh, 4, boundary="dirichlet").values))
        neumann.append(np.asarray(eigenpairs(tet_mesh, 4).values))
    dirichlet, neumann = np.array(dirichlet), np.array(neumann)
    first = np.abs(dirichlet[:, 0] - J0_ZERO**2)
    second = np.abs(dirichlet[:, 1:4] - J1_ZERO**2).max(axis=1)
    first_nonzero = np.abs(neumann[:, 1:4] - J1_PRIME_ZERO**2).max(axis=1)
    assert np.abs(neumann[:, 0]).max() < 1e-10
    # Measured at n = 12: 0.051, 0.18, 0.0041 (pi^2 = 9.87, 20.19, 4.333); rates about 2.
    assert first[-1] < 0.06 and second[-1] < 0.2 and first_nonzero[-1] < 0.005, (first, second, first_nonzero)
    for errors in (first, second, first_nonzero):
        assert _rate(1.0 / layers, errors) > 1.7, errors


def test_eigenpairs_refuse_robust_on_a_tet_mesh():
    with pytest.raises(DDGInputError, match="robust"):
        eigenpairs(tet_ball(2), 3, robust=True)


# ------------------------------------------------------------------------------------------------------ heat method


def _ball_distance_error(n_layers: int) -> float:
    """Largest error of the heat distance from the ball's centre (vertex 0) against the radius."""
    tet_mesh = tet_ball(n_layers)
    distance = np.asarray(heat_distance(tet_mesh, [0]))
    return float(np.abs(distance - _radii(tet_mesh)).max())


@pytest.mark.slow
def test_heat_distance_from_the_centre_of_the_ball():
    tet_mesh = tet_ball(4)
    solver = heat_distance_solver(tet_mesh)
    distance = np.asarray(solver.distance([0]))
    assert distance[0] == 0 and distance.min() == 0
    # First order in h: 0.058 at n_layers = 4, 0.029 at 8.
    assert np.abs(distance - _radii(tet_mesh)).max() < 0.07
    np.testing.assert_allclose(np.asarray(heat_distance(tet_mesh, [0])), distance, rtol=0, atol=1e-12)
    # The heat method's own sweeps (kept `V_t grad phi_k`) against ddgjax.volume's gradient and divergence.
    steps = solver.steps([0])
    grad_u = np.asarray(gradient(tet_mesh, steps.heat))
    expected_field = -grad_u / np.linalg.norm(grad_u, axis=1, keepdims=True)
    np.testing.assert_allclose(np.asarray(steps.field), expected_field, rtol=0, atol=1e-12)
    expected_divergence = np.asarray(divergence(tet_mesh, steps.field))
    np.testing.assert_allclose(np.asarray(steps.divergence), expected_divergence, rtol=0, atol=1e-14)


@pytest.mark.slow
def test_heat_distance_in_the_ball_converges():
    layers = np.array([4, 8, 12])
    errors = [_ball_distance_error(int(n)) for n in layers]
    # The heat method is first order (t = h^2 smoothing); measured 0.058, 0.029, 0.019.
    assert errors[0] > errors[1] > errors[2] and _rate(1.0 / layers, errors) > 0.8, errors


@pytest.mark.slow
def test_heat_distance_gradient_matches_finite_differences():
    tet_mesh = tet_ball(4)  # as in the test above: the same compiled programs
    V0 = np.asarray(tet_mesh.vertices)
    weights = np.random.default_rng(2).normal(size=tet_mesh.n_vertices)

    def objective(V):
        return jnp.sum(weights * heat_distance(tet_mesh.with_vertices(V), [0]))

    gradient = jax.grad(objective)(jnp.asarray(V0))
    direction = np.random.default_rng(3).normal(size=V0.shape)
    eps = 1e-6
    fd = central_difference(objective, V0, direction, eps)
    # Central differences with eps = 1e-6 (truncation ~eps^2, round-off ~1e-16 / eps relative).
    np.testing.assert_allclose(float(jnp.sum(gradient * direction)), float(fd), rtol=1e-6)


def test_heat_distance_refuses_robust_and_points_inside_cells_on_a_tet_mesh():
    tet_mesh = tet_ball(2)
    with pytest.raises(DDGInputError, match="robust"):
        heat_distance(tet_mesh, [0], robust=True)
    with pytest.raises(DDGInputError, match="sources"):
        heat_distance(tet_mesh, (np.array([0]), np.full((1, 3), 1 / 3)))
    with pytest.raises(DDGInputError, match="sources"):
        heat_distance(tet_mesh, [tet_mesh.n_vertices])
