"""Tests for ddgjax.pde.mean_curvature_flow: the DDG exercises' reference (plain and modified), the
shrinking sphere against its discrete and smooth radius, volume and area, gradients against finite
differences, saved states, jit, bad input."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ddgjax import RESULTS, DDGInputError
from ddgjax.mesh import Mesh, enclosed_volume, torus
from ddgjax.pde import MeanCurvatureFlowResult, mean_curvature_flow

from conftest import read_ddg_reference
from finite_differences import central_difference


@pytest.mark.parametrize("modified, tag", [(False, "mcf"), (True, "mmcf")])
@pytest.mark.slow
def test_matches_the_ddg_exercises_reference(modified, tag):
    """test-flow-soln.txt: `steps` steps of (M + tau (L + 1e-8 I)) f' = M f (their `h` is our `tau`), M
    barycentric (the DDG exercises' massMatrix), M and L rebuilt each step (mcf) or L frozen at the start and M rebuilt
    (mmcf, Kazhdan et al.), then translated so the unweighted vertex mean is 0. Their test asks each
    vertex to be within 1e-6; their input carries single-precision rounding, we are within ~1.5e-7."""
    data = read_ddg_reference("test-flow-soln.txt")
    mesh = Mesh.from_arrays(data["v"], data["f"].astype(np.int64) - 1)
    tau, steps = float(data["h"][0, 0]), int(data["steps"][0, 0])
    result = mean_curvature_flow(mesh, tau=tau, steps=steps, modified=modified, mass="barycentric", shift=1e-8)
    final = np.asarray(result.value)
    final = final - final.mean(axis=0)
    # The reference's own threshold; its single-precision input leaves us ~1.5e-7 off.
    assert np.linalg.norm(final - data[tag], axis=1).max() < 1e-6
    # Without the 1e-8 shift the answer moves by ~1e-5: the reference depends on it.
    plain = np.asarray(mean_curvature_flow(mesh, tau=tau, steps=steps, modified=modified, mass="barycentric").value)
    assert np.linalg.norm(plain - plain.mean(axis=0) - data[tag], axis=1).max() > 1e-6


@pytest.mark.slow
def test_sphere_shrinks_at_the_discrete_and_the_smooth_rate(icosphere3):
    """On a sphere each step gives r_{n+1} (1 + 2 tau / r_n^2) = r_n (M, L of the surface the step starts
    on), and r(t)^2 = r_0^2 - 4 t for the smooth flow (r' = -2 / r): first order in tau (measured 0.98).

    Every run takes the same 32 steps, saving every 8th state (one compiled program for the three step
    sizes): the run of step tau = T / k reaches t = T after k steps, saved state k / 8, and goes on to
    32 tau <= 4 T = 0.2, while the sphere (r^2 = 1 - 4 t) still has r > 0.4."""
    mesh = icosphere3
    T, steps, every = 0.05, 32, 8
    errors, sizes = [], []
    for k in (8, 16, 32):
        tau = T / k
        plain = mean_curvature_flow(mesh, tau=tau, steps=steps, save_every=every)
        radii = np.linalg.norm(np.asarray(plain.vertices), axis=-1)
        r = 1.0
        for n in range(steps):
            r = r / (1 + 2 * tau / r**2)
            if (n + 1) % every == 0:
                # The icosphere's vertices are not all alike: the spread is the spatial error.
                np.testing.assert_allclose(radii[(n + 1) // every], r, rtol=0, atol=5e-5)
        sizes.append(tau)
        errors.append(abs(radii[k // every].mean() - np.sqrt(1 - 4 * T)))
    rate = np.polyfit(np.log(sizes), np.log(errors), 1)[0]
    assert 0.9 < rate < 1.1, (rate, errors)  # backward Euler: first order in tau, measured 0.98
    # The cotan L is scale invariant: on a round sphere the plain and modified flows shrink alike (up to
    # the icosphere's spatial error; its vertices also slide a little, differently in each).
    modified = mean_curvature_flow(mesh, tau=tau, steps=steps, save_every=every, modified=True)
    # the icosphere's spatial error, as for the radii above
    np.testing.assert_allclose(np.linalg.norm(np.asarray(modified.vertices), axis=-1), radii, rtol=0, atol=5e-5)


@pytest.mark.slow
def test_volume_and_area_decrease():
    mesh = torus(major_radius=1.0, minor_radius=0.4, n_major=24, n_minor=12)
    V = np.asarray(mesh.vertices)
    bumpy = mesh.with_vertices(V * (1 + 0.1 * np.sin(3 * V[:, :1]) * np.cos(2 * V[:, 1:2])))
    for modified in (False, True):
        result = mean_curvature_flow(bumpy, tau=2e-3, steps=20, save_every=2, modified=modified)
        assert isinstance(result, MeanCurvatureFlowResult) and result.vertices.shape == (11, mesh.n_vertices, 3)
        np.testing.assert_allclose(result.times, 2e-3 * 2 * np.arange(11), rtol=1e-15)
        assert np.all(np.diff(np.asarray(result.volume)) < 0)
        assert np.all(np.diff(np.asarray(result.area)) < 0)
        np.testing.assert_allclose(result.volume[-1], enclosed_volume(result.mesh()), rtol=1e-15)
        assert float(result.volume[0]) == pytest.approx(float(enclosed_volume(bumpy)), rel=1e-15)


@pytest.mark.slow
def test_saved_states_continue_each_other_and_jit_equals_eager(icosphere1):
    mesh = icosphere1.with_vertices(np.asarray(icosphere1.vertices) * np.array([1.0, 0.8, 1.3]))
    every = mean_curvature_flow(mesh, tau=0.01, steps=4, save_every=1)
    # The plain flow depends only on the current surface: restarting from a saved state continues it
    # (the modified one keeps the initial L, so it would not). The same steps and saves as `every` (one
    # compiled program): its state 2 is every's state 4.
    restarted = mean_curvature_flow(every.mesh(2), tau=0.01, steps=4, save_every=1)
    np.testing.assert_allclose(restarted.vertices[2], every.value, rtol=0, atol=1e-15)
    # Saving only the first and last states (the default), under the caller's jit: the same states, to
    # round-off (the kernel is compiled into the caller's program, and rounds differently: 1e-14).
    once = jax.jit(lambda V, tau: mean_curvature_flow(mesh.with_vertices(V), tau=tau, steps=4).vertices)(mesh.vertices, 0.01)
    np.testing.assert_allclose(once, every.vertices[::4], rtol=0, atol=1e-14)


@pytest.mark.parametrize("modified", [False, True])
@pytest.mark.slow
def test_gradients_with_respect_to_initial_vertices_and_tau(modified, icosphere1):
    mesh = icosphere1
    rng = np.random.default_rng(3)
    V = mesh.vertices * jnp.asarray([1.0, 0.8, 1.3]) + 0.05 * jnp.asarray(rng.standard_normal(mesh.vertices.shape))
    weights = jnp.asarray(rng.standard_normal(V.shape))

    def loss(V, tau):
        final = mean_curvature_flow(mesh.with_vertices(V), tau=tau, steps=3, modified=modified).value
        return jnp.sum(weights * final) + jnp.sum(final**2)

    # One compiled program, for the gradients and for the four losses of the finite differences.
    value_and_grad = jax.jit(jax.value_and_grad(loss, argnums=(0, 1)))
    tau = jnp.asarray(0.02)
    _, gradients = value_and_grad(V, tau)
    directions = (jnp.asarray(rng.standard_normal(V.shape)), jnp.asarray(1.0))
    losses = (lambda W: value_and_grad(W, tau)[0], lambda t: value_and_grad(V, t)[0])
    for k, (argument, direction, function) in enumerate(zip((V, tau), directions, losses)):
        finite = central_difference(function, argument, direction, eps=1e-6)
        # Central differences with step 1e-6: truncation ~1e-12, rounding ~1e-10 relative.
        np.testing.assert_allclose(jnp.vdot(gradients[k], direction), finite, rtol=1e-6)


@pytest.mark.slow
def test_a_failed_step_is_reported_and_ends_the_flow(icosphere1):
    mesh = icosphere1
    # Non-finite input can only arrive traced (`Mesh` refuses it otherwise): state 0 fails, no step runs.
    flow = jax.jit(
        lambda V, throw: mean_curvature_flow(mesh.with_vertices(V), tau=0.01, steps=4, save_every=2, throw=throw),
        static_argnums=1,
    )
    broken = mesh.vertices.at[3, 0].set(jnp.nan)
    result = flow(broken, False)
    assert bool(result.result == RESULTS.nonfinite) and int(result.first_failure_step) == 0
    np.testing.assert_array_equal(result.vertices[1:], result.vertices[:1].repeat(2, axis=0))
    with pytest.raises(jax.errors.JaxRuntimeError, match="NaN or inf"):
        jax.block_until_ready(flow(broken, True).vertices)
    fine = mean_curvature_flow(mesh, tau=0.01, steps=4)
    assert bool(fine.result == RESULTS.successful) and int(fine.first_failure_step) == 5  # one past the last step


@pytest.mark.slow
def test_progress_bar_path_matches_the_pure_path(capsys, icosphere1):
    mesh = icosphere1
    for mass in ("voronoi", "galerkin"):
        pure = mean_curvature_flow(mesh, tau=0.01, steps=4, save_every=2, mass=mass, modified=True)
        shown = mean_curvature_flow(mesh, tau=0.01, steps=4, save_every=2, mass=mass, modified=True, progress=True)
        np.testing.assert_array_equal(shown.vertices, pure.vertices)
        np.testing.assert_array_equal(shown.area, pure.area)
    assert "mean curvature flow" in capsys.readouterr().err


def test_bad_input(without_type_checker, icosphere0):
    mesh = icosphere0
    cases = [
        (lambda: mean_curvature_flow(np.zeros((3, 3)), tau=0.1, steps=1), "mesh: expected a ddgjax Mesh"),
        (lambda: mean_curvature_flow(mesh, tau=0.1, steps=0), "steps: expected an integer >= 1"),
        (lambda: mean_curvature_flow(mesh, tau=0.1, steps=4, save_every=3), "save_every: expected a divisor of steps"),
        (lambda: mean_curvature_flow(mesh, tau=-0.1, steps=1), "tau: expected a finite time step > 0"),
        (lambda: mean_curvature_flow(mesh, tau=np.nan, steps=1), "tau: expected a finite time step > 0"),
        (lambda: mean_curvature_flow(mesh, tau=0.0, steps=1), "tau: expected a finite time step > 0"),
        (lambda: mean_curvature_flow(mesh, tau=np.ones(2), steps=1), "tau: expected a real scalar"),
        (lambda: mean_curvature_flow(mesh, tau=0.1, steps=1, shift=-1.0), "shift: expected a finite real number >= 0"),
        (lambda: mean_curvature_flow(mesh, tau=0.1, steps=1, mass="lumped"), "mass: expected one of"),
        (lambda: mean_curvature_flow(mesh, tau=0.1, steps=1, modified=1), "modified: expected one of"),
        (lambda: mean_curvature_flow(mesh, tau=0.1, steps=1, solver="lu"), "solver: expected one of"),
        (lambda: mean_curvature_flow(mesh, tau=0.1, steps=1, progress="yes"), "progress: expected True or False"),
    ]
    for call, message in cases:
        with pytest.raises(DDGInputError, match=message):
            call()
