"""Tests for ddgjax.optim: the Willmore energy's convergence to 4 pi (sphere) and 2 pi^2 (Clifford torus) and libigl's
formula; PyTorch3D's regularisers on closed-form meshes (the Chamfer distance: tests/test_chamfer.py); gradients
against finite differences; the Large Steps map against dense algebra, and uniform Adam's first step; and the
acceptance runs of `minimize_shape`: the catenoid between two rings, Willmore minimisation of a bumpy sphere at
fixed volume, and a PyTorch3D-style mesh fit."""

from __future__ import annotations

import igl
import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest
import scipy.integrate
import scipy.optimize
from jax.test_util import check_grads

from ddgjax import RESULTS, DDGInputError
from ddgjax.mesh import Mesh, cylinder, grid, icosphere, torus
from ddgjax.optim import (
    adam_uniform,
    chamfer_distance,
    edge_length_loss,
    enclosed_volume,
    laplacian_smoothing_loss,
    large_steps,
    mesh_fitting_loss,
    minimize_shape,
    normal_consistency_loss,
    sample_points,
    total_area,
    willmore_energy,
)
from ddgjax.optim._driver import _run


def _octahedron() -> Mesh:
    V = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float)
    F = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])
    return Mesh.from_arrays(V, F)


def _tetrahedron() -> Mesh:
    V = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], float)
    return Mesh.from_arrays(V, np.array([[0, 1, 2], [0, 2, 3], [0, 3, 1], [1, 3, 2]]))


def _bumpy(mesh: Mesh) -> Mesh:
    V = np.asarray(mesh.vertices)
    x, y, z = V.T
    return mesh.with_vertices(V * (1 + 0.15 * np.sin(3 * x) * np.sin(3 * y) * np.sin(3 * z) + 0.1 * (x * x - y * y))[:, None])


# --- Willmore energy -----------------------------------------------------------------------------


@pytest.mark.slow
def test_willmore_sphere_converges_to_4pi_at_second_order(icosphere2):
    errors = [abs(float(willmore_energy(icosphere(s))) - 4 * np.pi) for s in (2, 3, 4)]
    rates = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    # measured: errors 0.235, 0.0596, 0.0150 (rates 1.98, 1.99): O(h^2), h halving per subdivision
    assert errors[-1] < 0.02
    assert np.all(rates > 1.9)
    scaled = icosphere(2, radius=3.7)
    assert float(willmore_energy(scaled)) == pytest.approx(float(willmore_energy(icosphere2)), rel=1e-12)


@pytest.mark.slow
def test_willmore_torus_closed_form_and_clifford_torus():
    # W(c) = (pi / 2r) int_0^2pi (R + 2 r cos u)^2 / (R + r cos u) du = pi^2 c^2 / sqrt(c^2 - 1), c = R / r.
    for c in (np.sqrt(2), 3.0):
        integral = scipy.integrate.quad(lambda u, c=c: (c + 2 * np.cos(u)) ** 2 / (c + np.cos(u)), 0, 2 * np.pi)[0]
        assert np.pi / 2 * integral == pytest.approx(np.pi**2 * c**2 / np.sqrt(c**2 - 1), rel=1e-10)
    errors = [
        abs(float(willmore_energy(torus(major_radius=np.sqrt(2), minor_radius=1.0, n_major=2 * n, n_minor=n))) - 2 * np.pi**2)
        for n in (24, 48)
    ]
    # measured: 0.228, 0.058 (rate 1.97): the O(h^2) discretisation error, h halving from n = 24 to 48
    assert errors[1] < 0.07 and np.log2(errors[0] / errors[1]) > 1.9


def test_willmore_matches_libigl_formula(icosphere2):
    mesh = _bumpy(icosphere2)
    V, F = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    M = igl.massmatrix(V, F, igl.MASSMATRIX_TYPE_VORONOI).diagonal()
    HN = -(igl.cotmatrix(V, F) @ V) / (2 * M[:, None])  # pointwise H N
    assert float(willmore_energy(mesh)) == pytest.approx(np.sum(np.sum(HN**2, axis=1) * M), rel=1e-10)


def test_willmore_leaves_out_boundary_vertices():
    flat = grid(4, 4)
    assert float(willmore_energy(flat)) == 0.0


# --- regularisers --------------------------------------------------------------------------------


@pytest.mark.slow
def test_regularisers_closed_form():
    octahedron, tetrahedron = _octahedron(), _tetrahedron()
    assert float(edge_length_loss(octahedron)) == pytest.approx(2.0, rel=1e-14)  # every edge has length sqrt 2
    assert float(edge_length_loss(octahedron, target_length=1.0)) == pytest.approx((np.sqrt(2) - 1) ** 2, rel=1e-14)
    # Regular tetrahedron: normals of adjacent faces meet at cos = -1/3.
    assert float(normal_consistency_loss(tetrahedron)) == pytest.approx(4 / 3, rel=1e-14)
    assert float(normal_consistency_loss(grid(5, 5))) == pytest.approx(0.0, abs=1e-15)
    # Octahedron: each vertex's four neighbours are centred on the origin, at distance 1 from it.
    assert float(laplacian_smoothing_loss(octahedron)) == pytest.approx(1.0, rel=1e-14)
    assert float(laplacian_smoothing_loss(octahedron, weights="cotan")) == pytest.approx(1.0, rel=1e-14)


def test_laplacian_smoothing_cotan_matches_libigl_weights(icosphere1):
    mesh = _bumpy(icosphere1)
    V, F = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    L = -igl.cotmatrix(V, F)
    expected = np.mean(np.linalg.norm(L @ V, axis=1) / L.diagonal())
    assert float(laplacian_smoothing_loss(mesh, weights="cotan")) == pytest.approx(expected, rel=1e-12)


@pytest.mark.slow
def test_objective_gradients_against_finite_differences(icosphere1):
    mesh = _bumpy(icosphere1)
    for objective in (
        willmore_energy,
        edge_length_loss,
        lambda m: edge_length_loss(m, target_length=0.5),
        normal_consistency_loss,
        laplacian_smoothing_loss,
    ):
        check_grads(jax.jit(lambda V, f=objective: f(mesh.with_vertices(V))), (mesh.vertices,), order=1, modes=("rev",))


@pytest.mark.slow
def test_laplacian_smoothing_cotan_gradient_holds_the_weights_fixed(icosphere1):
    # PyTorch3D's convention: the cotan weights are constants, so the gradient is that of the same
    # formula with libigl's matrix of the current mesh frozen.
    mesh = _bumpy(icosphere1)
    V, F = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    L = jnp.asarray((-igl.cotmatrix(V, F)).toarray())
    frozen = lambda X: jnp.mean(jnp.linalg.norm(L @ X, axis=1) / jnp.diag(L))
    ours = jax.grad(lambda X: laplacian_smoothing_loss(mesh.with_vertices(X), weights="cotan"))(mesh.vertices)
    np.testing.assert_allclose(ours, jax.grad(frozen)(jnp.asarray(V)), rtol=1e-10, atol=1e-13)


# --- Sampling (the Chamfer distance: tests/test_chamfer.py) --------------------------------------


@pytest.mark.slow
def test_sample_points_on_surface_uniform_and_differentiable(icosphere0, icosphere3):
    sphere = icosphere3
    key = jax.random.key(4)
    sampled = sample_points(sphere, 10000, key=key, return_normals=True)
    points, normals = sampled  # a named result still unpacks
    np.testing.assert_array_equal(sampled.points, sample_points(sphere, 10000, key=key))
    # Points lie on the faces (inside the unit ball, no farther in than the flattest face) with unit normals.
    radii = np.linalg.norm(points, axis=1)
    assert radii.max() <= 1 + 1e-12 and radii.min() > 0.97
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, rtol=1e-12)
    # Area-uniform: the mean of uniform samples of a centred sphere is near 0 (~1/sqrt(n) noise).
    assert np.abs(np.asarray(points).mean(axis=0)).max() < 0.02
    square = grid(3, 3)  # [-1/2, 1/2]^2, uniform samples: mean 0, variance 1/12 per axis
    flat = np.asarray(sample_points(square, 10000, key=key))[:, :2]
    # Monte Carlo noise of 10000 samples: standard deviations 0.003 (mean) and 0.0007 (variance), ~3.5 and 7 sigma
    np.testing.assert_allclose(flat.mean(axis=0), 0.0, atol=0.01)
    np.testing.assert_allclose(flat.var(axis=0), 1 / 12, atol=0.005)  # 7 sigma of 0.0007
    small = icosphere0
    check_grads(lambda V: sample_points(small.with_vertices(V), 50, key=key), (small.vertices,), order=1, modes=("rev",))


# --- Large Steps -----------------------------------------------------------------------------------


def test_large_steps_map_against_dense_algebra(icosphere1):
    mesh = _bumpy(icosphere1)
    V = np.asarray(mesh.vertices)
    for weights, L in (("uniform", None), ("cotan", -igl.cotmatrix(V, np.asarray(mesh.faces)).toarray())):
        if L is None:
            adjacency = np.zeros((len(V), len(V)))
            edges = np.asarray(mesh.edges)
            adjacency[edges[:, 0], edges[:, 1]] = adjacency[edges[:, 1], edges[:, 0]] = 1
            L = np.diag(adjacency.sum(1)) - adjacency
        A = np.eye(len(V)) + 3.0 * L
        reparam = large_steps(mesh, lambda_=3.0, weights=weights)
        U = reparam.to_parameters(mesh.vertices)
        np.testing.assert_allclose(U, A @ V, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(reparam.from_parameters(U), V, rtol=1e-10, atol=1e-12)
        solution = reparam.from_parameters(U, throw=False)  # the solve's outcome, lineax's shape
        assert bool(solution.result == RESULTS.successful) and float(solution.stats["residual"]) < 1e-12
        # The VJP of the solve is the solve of the cotangent (A symmetric).
        g = np.random.default_rng(5).normal(size=V.shape)
        _, vjp = jax.vjp(jax.jit(lambda U, r=reparam: r.from_parameters(U)), U)
        np.testing.assert_allclose(vjp(jnp.asarray(g))[0], np.linalg.solve(A, g), rtol=1e-12, atol=1e-12)


def test_large_steps_fixed_vertices_stay_and_free_block_is_dirichlet(icosphere1):
    mesh = _bumpy(icosphere1)
    fixed = np.array([0, 5, 7])
    reparam = large_steps(mesh, lambda_=2.0, fixed_vertices=fixed)
    U = reparam.to_parameters(mesh.vertices)
    moved = reparam.from_parameters(U + 0.1)
    np.testing.assert_array_equal(np.asarray(moved)[fixed], np.asarray(mesh.vertices)[fixed])
    np.testing.assert_allclose(reparam.from_parameters(U), mesh.vertices, rtol=1e-10, atol=1e-12)


def test_adam_uniform_first_step():
    g = jnp.array([[0.5, -2.0, 1.0], [0.25, 0.0, -1.0]])
    optimizer = adam_uniform(0.1)
    updates, _ = optimizer.update(g, optimizer.init(g), g)
    # Bias-corrected moments after one step are g and g^2: the step is -lr g / max|g|.
    np.testing.assert_allclose(updates, -0.1 * g / (2.0 + 1e-8), rtol=1e-12)


# --- minimize_shape: acceptance runs ---------------------------------------------------------------


def _cylinder(n_theta: int, n_z: int, h: float) -> tuple[Mesh, np.ndarray]:
    """The built-in open cylinder over `z in [-h, h]` and its two boundary rings."""
    mesh = cylinder(n_theta, n_z, radius=1.0, height=2 * h)
    return mesh, np.asarray(mesh.topology.boundary_vertices)


@pytest.mark.slow
def test_catenoid_between_two_rings():
    h = 0.5  # half the ring separation, below the critical 0.6627
    # The stable catenoid r = a cosh(z / a) through both rings: the larger root of a cosh(h / a) = 1.
    a = scipy.optimize.brentq(lambda a: a * np.cosh(h / a) - 1, 0.6, 1.0)
    errors = []
    for n in (16, 32):
        mesh, rings = _cylinder(2 * n, n // 2, h)
        optimizer = adam_uniform(optax.exponential_decay(3e-2, 400, 0.01))
        result = minimize_shape(total_area, mesh, steps=400, optimizer=optimizer, fixed_vertices=rings, progress=False)
        V = np.asarray(result.value)
        np.testing.assert_array_equal(V[rings], np.asarray(mesh.vertices)[rings])
        errors.append(np.abs(np.hypot(V[:, 0], V[:, 1]) - a * np.cosh(V[:, 2] / a)).max())
        assert result.loss_history[-1] < result.loss_history[0]
    # measured: max profile errors 1.35e-3 and 3.6e-4 (rate 1.9): the discretisation error of the minimiser
    assert errors[1] < 5e-4 and errors[1] < errors[0] / 3


@pytest.mark.slow
def test_willmore_minimisation_of_a_bumpy_sphere_at_fixed_volume(icosphere2):
    sphere = icosphere2
    bumpy = _bumpy(sphere)
    volume = float(enclosed_volume(bumpy))
    optimizer = adam_uniform(optax.exponential_decay(3e-2, 1000, 0.01))
    result = minimize_shape(willmore_energy, bumpy, steps=150, optimizer=optimizer, constraint="volume", progress=False)
    V = np.asarray(result.value)
    radii = np.linalg.norm(V - V.mean(axis=0), axis=1)
    # measured: W from 13.96 to 4 pi - 0.24, 0.009 below the discrete energy of the round icosphere(2) itself
    # (4 pi - 0.235, the O(h^2) error of the first test): the discrete minimiser is not exactly the round mesh,
    # and 150 steps do not converge it (radii spread 1.2 %, 0.65 % after 400 steps).
    assert float(result.loss_history[0]) > 13.9
    assert abs(float(result.loss_history[-1]) - float(willmore_energy(sphere))) < 0.02
    assert (radii.max() - radii.min()) / radii.mean() < 0.015
    assert float(enclosed_volume(result.mesh())) == pytest.approx(volume, rel=1e-12)


@pytest.mark.slow
def test_mesh_fitting_chamfer_pytorch3d_style(icosphere2, icosphere4):
    target_mesh = icosphere4
    target_mesh = target_mesh.with_vertices(target_mesh.vertices * jnp.array([1.3, 1.0, 0.7]))
    target = sample_points(target_mesh, 600, key=jax.random.key(1))

    fit = mesh_fitting_loss(target, n_samples=600, edge_weight=0.05)
    points = sample_points(icosphere2, 600, key=jax.random.key(3))
    expected = (
        chamfer_distance(points, target)
        + 0.05 * edge_length_loss(icosphere2)
        + 0.01 * normal_consistency_loss(icosphere2)
        + 0.1 * laplacian_smoothing_loss(icosphere2)
    )
    assert float(fit(icosphere2, jax.random.key(3))) == pytest.approx(float(expected), rel=1e-14)

    source = icosphere2
    optimizer = adam_uniform(optax.exponential_decay(5e-2, 150, 0.1))
    result = minimize_shape(fit, source, steps=150, optimizer=optimizer, key=jax.random.key(0), progress=False)
    reference = sample_points(target_mesh, 2000, key=jax.random.key(8))
    before = float(chamfer_distance(sample_points(source, 2000, key=jax.random.key(7)), reference))
    after = float(chamfer_distance(sample_points(result.mesh(), 2000, key=jax.random.key(7)), reference))
    floor = float(chamfer_distance(sample_points(target_mesh, 2000, key=jax.random.key(7)), reference))
    # measured: 5.0e-2 -> 4.0e-3, against 3.9e-3 between two 2000-point sample sets of the target itself
    # (the sampling floor of this estimate): the fit is as close as the estimate can tell.
    assert before > 0.04 and after < 5e-3 and after < 1.2 * floor
    assert result.loss_history.shape == (151,) and bool(result.result == RESULTS.successful)


@pytest.mark.slow
def test_minimize_shape_vertices_parametrisation_and_chunks():
    mesh, rings = _cylinder(16, 4, 0.5)
    settings = {
        "steps": 23,
        "optimizer": optax.adam(1e-2),
        "parametrization": "vertices",
        "fixed_vertices": rings,
        "progress": False,
    }
    one = minimize_shape(total_area, mesh, chunk_size=23, **settings)
    chunked = minimize_shape(total_area, mesh, chunk_size=5, **settings)  # 5 does not divide 23: the last chunk skips
    np.testing.assert_allclose(chunked.value, one.value, rtol=1e-13, atol=1e-14)
    np.testing.assert_allclose(chunked.loss_history, one.loss_history, rtol=1e-13)
    assert chunked.loss_history.shape == (24,) and float(chunked.loss_history[-1]) == pytest.approx(
        float(total_area(chunked.mesh())), rel=1e-12
    )
    np.testing.assert_array_equal(np.asarray(one.value)[rings], np.asarray(mesh.vertices)[rings])
    # The same loss and optimiser objects reuse the compiled program; the progress bar runs the same chunks.
    compiled = _run._cache_size()
    again = minimize_shape(total_area, mesh, chunk_size=5, **settings)
    assert _run._cache_size() == compiled
    np.testing.assert_array_equal(again.value, chunked.value)
    shown = minimize_shape(total_area, mesh, chunk_size=5, **(settings | {"progress": True}))
    np.testing.assert_array_equal(shown.value, chunked.value)
    np.testing.assert_array_equal(shown.loss_history, chunked.loss_history)


@pytest.mark.parametrize("parametrization", ["vertices", "large_steps"])
@pytest.mark.slow
def test_bounds_keep_an_inflating_sphere_in_the_box(parametrization, icosphere1):
    """Maximising the enclosed volume of a sphere of radius 0.8 inside the box [-1.1, 1.1]^2 x [-1.1, 0.9]:
    every iterate is clipped into it, so the sphere presses against the lid."""
    sphere = icosphere1.with_vertices(0.8 * icosphere1.vertices)  # inside the box
    lower, upper = jnp.array([-1.1, -1.1, -1.1]), jnp.array([1.1, 1.1, 0.9])
    result = minimize_shape(
        lambda mesh: -enclosed_volume(mesh),
        sphere,
        steps=60,
        optimizer=optax.adam(0.05),
        parametrization=parametrization,
        bounds=(lower, upper),
        progress=False,
    )
    V = np.asarray(result.value)
    assert np.all(np.asarray(lower) - 1e-12 <= V) and np.all(np.asarray(upper) + 1e-12 >= V)
    assert V[:, 2].max() == pytest.approx(0.9, abs=1e-12)  # pressed against the lid
    assert float(result.loss_history[-1]) < float(result.loss_history[0])
    with pytest.raises(DDGInputError, match="not with constraint"):
        minimize_shape(lambda m: -enclosed_volume(m), sphere, steps=1, bounds=(lower, upper), constraint="volume")
    with pytest.raises(DDGInputError, match="outside the box"):
        minimize_shape(lambda m: -enclosed_volume(m), sphere, steps=1, bounds=(-0.5, 0.5))


def test_minimize_shape_reports_nonfinite_loss(icosphere1):
    mesh = icosphere1
    # Finite until the sphere has grown past radius 1.05, then NaN.
    loss = lambda m: jnp.where(jnp.max(m.vertices) > 1.05, jnp.nan, -total_area(m))
    settings = {"steps": 40, "parametrization": "vertices", "optimizer": optax.sgd(0.05), "progress": False}
    result = minimize_shape(loss, mesh, throw=False, **settings)
    assert result.result == RESULTS.nonfinite
    # step k updates iterate k - 1: the first steps were finite, and no later step is counted first
    assert 1 < int(result.first_failure_step) <= 40
    assert np.all(np.isfinite(result.value))
    with pytest.raises(Exception, match="NaN or inf"):
        minimize_shape(loss, mesh, **settings)


def test_bad_input(icosphere0):
    mesh = icosphere0
    with pytest.raises(DDGInputError, match="parametrization"):
        minimize_shape(total_area, mesh, steps=1, parametrization="pixels")
    with pytest.raises(DDGInputError, match="fixed_vertices"):
        minimize_shape(total_area, mesh, steps=1, fixed_vertices=[100])
    with pytest.raises(DDGInputError, match="every vertex"):
        large_steps(mesh, fixed_vertices=np.arange(12))
    with pytest.raises(DDGInputError, match="lambda_"):
        large_steps(mesh, lambda_=-1.0)
    with pytest.raises(DDGInputError, match="weights: expected one of"):
        laplacian_smoothing_loss(mesh, weights="cotcurv")
    with pytest.raises(DDGInputError, match="weights: expected one of"):
        large_steps(mesh, weights="cot")
    with pytest.raises(DDGInputError, match="solver: expected one of"):
        minimize_shape(total_area, mesh, steps=1, solver="lu")


def test_chamfer_refuses_mixed_dimensions(without_type_checker):
    with pytest.raises(DDGInputError, match="dimension"):
        chamfer_distance(np.zeros((3, 3)), np.zeros((3, 2)))
    with pytest.raises(DDGInputError, match="Mesh"):
        willmore_energy(np.zeros((3, 3)))
