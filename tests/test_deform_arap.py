"""`ddgjax.deform.arap`: libigl's spokes ARAP, monotone energy, rigid motions, outcomes, implicit gradients, errors."""

from __future__ import annotations

import equinox as eqx
import igl
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ddgjax import RESULTS, DDGInputError, Solution
from ddgjax.deform import arap
from ddgjax.mesh import cylinder

from finite_differences import central_difference
from mesh_union import disjoint_union


def _twisted(n_around=12, n_along=8, angle=0.6, shift=(0.4, 0.0, -0.3)):
    """A cylinder, its bottom ring held, its top ring twisted by `angle` about z and moved by `shift`."""
    mesh = cylinder(n_around, n_along)
    rest = np.asarray(mesh.vertices)
    handles = np.concatenate([np.arange(n_around), np.arange(rest.shape[0] - n_around, rest.shape[0])])
    c, s = np.cos(angle), np.sin(angle)
    rotation = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    values = rest[handles].copy()
    values[n_around:] = values[n_around:] @ rotation.T + np.asarray(shift)
    return mesh, handles, values


def _libigl_arap(mesh, handles, values, initial, steps):
    data = igl.ARAPData()
    data.energy = igl.ARAP_ENERGY_TYPE_SPOKES
    data.max_iter = steps
    rest = np.asarray(mesh.vertices, np.float64)
    igl.arap_precomputation(rest, np.asarray(mesh.faces, np.int64), 3, np.asarray(handles, np.int32), data)
    return igl.arap_solve(np.asarray(values, np.float64), data, np.asarray(initial, np.float64))


def _diagonal(mesh):
    rest = np.asarray(mesh.vertices)
    return np.linalg.norm(rest.max(axis=0) - rest.min(axis=0))


@pytest.mark.slow
def test_matches_libigl_spokes_converged():
    """Converged, the same minimum as libigl's `arap_solve` (spokes energy) iterated to convergence, from the
    default start (rest positions with the handles moved) and from a given one."""
    mesh, handles, values = _twisted()
    start = np.asarray(mesh.vertices).copy()
    start[handles] = values
    solution = arap(mesh, fixed_vertices=handles, fixed_values=values, rtol=1e-12, max_steps=5000, throw=False)
    assert solution.result == RESULTS.successful
    assert int(solution.stats["num_steps"]) > 10 and float(solution.stats["relative_change"]) <= 1e-12
    expected = _libigl_arap(mesh, handles, values, start, 1000)
    # libigl's arap_solve fits the rotations in single precision (`fit_rotations(S, true, R)`, a float 3x3 SVD):
    # its minimum sits ~1e-7 of the diagonal from ours (measured 7.7e-8 from either start; 1000 vs 3000 of its
    # steps change 4e-9).
    np.testing.assert_allclose(np.asarray(solution.value), expected, atol=1e-6 * _diagonal(mesh))
    # A different start (the rest shape scaled about the bottom ring), passed to both.
    other = np.asarray(mesh.vertices) * np.array([1.0, 1.0, 1.1])
    ours = arap(mesh, fixed_vertices=handles, fixed_values=values, initial=other, rtol=1e-12, max_steps=5000)
    other[handles] = values
    # libigl's single-precision rotations again: ~1e-7 of the diagonal apart.
    np.testing.assert_allclose(np.asarray(ours), _libigl_arap(mesh, handles, values, other, 1000), atol=1e-6 * _diagonal(mesh))


@pytest.mark.slow  # the fast tier's time limit (its checks run in the full suite)
def test_energy_does_not_increase_and_handles_are_exact():
    """Each local-global step lowers `E_hat(V') = min_R E(V', R)` or keeps it; the handles are where they were put."""
    mesh, handles, values = _twisted()
    energies = []
    for steps in range(1, 9):
        solution = arap(mesh, fixed_vertices=handles, fixed_values=values, max_steps=steps, throw=False)
        assert int(solution.stats["num_steps"]) == steps
        energies.append(float(solution.stats["energy"]))
        np.testing.assert_array_equal(np.asarray(solution.value)[handles], values)
    assert np.all(np.diff(energies) <= 1e-12 * energies[0]), energies
    assert energies[-1] < 0.9 * energies[0]


def test_rigid_motion_of_all_handles_moves_the_mesh_rigidly():
    """Handles moved by one rotation and translation: the answer is the rigidly moved rest mesh, energy 0."""
    mesh, handles, _ = _twisted()
    rest = np.asarray(mesh.vertices)
    axis = np.array([1.0, 2.0, 0.5]) / np.linalg.norm([1.0, 2.0, 0.5])
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    rotation = np.eye(3) + np.sin(0.8) * k + (1 - np.cos(0.8)) * k @ k
    moved = rest @ rotation.T + np.array([0.3, -1.0, 2.0])
    solution = arap(mesh, fixed_vertices=handles, fixed_values=moved[handles], rtol=1e-12, throw=False)
    assert solution.result == RESULTS.successful
    # Stopped when a step moves < 1e-12 of the diagonal: measured 4e-12 from the rigid motion.
    np.testing.assert_allclose(np.asarray(solution.value), moved, atol=1e-10 * _diagonal(mesh))
    assert float(solution.stats["energy"]) < 1e-18


def test_not_converged_is_reported():
    """One step does not meet `rtol`: `max_steps_reached` with `throw=False`, an error with `throw=True`."""
    mesh, handles, values = _twisted()
    solution = arap(mesh, fixed_vertices=handles, fixed_values=values, max_steps=1, throw=False)
    assert isinstance(solution, Solution)
    assert solution.result == RESULTS.max_steps_reached
    assert int(solution.stats["num_steps"]) == 1 and float(solution.stats["relative_change"]) > 1e-8  # default rtol
    with pytest.raises(eqx.EquinoxRuntimeError, match="max_steps"):
        arap(mesh, fixed_vertices=handles, fixed_values=values, max_steps=1)


@pytest.mark.slow
def test_gradients_match_finite_differences():
    """Implicit derivatives (reverse and forward) in the handle positions and the rest shape against central
    differences of the tightly converged answer."""
    mesh, handles, values = _twisted(n_around=8, n_along=5, angle=0.4)
    rest = np.asarray(mesh.vertices)
    weights = np.random.default_rng(0).normal(size=rest.shape)

    def loss(values, rest):
        deformed = arap(mesh.with_vertices(rest), fixed_vertices=handles, fixed_values=values, rtol=1e-14, max_steps=20000)
        return jnp.sum(weights * deformed)

    grad_values, grad_rest = jax.grad(loss, argnums=(0, 1))(jnp.asarray(values), jnp.asarray(rest))
    rng = np.random.default_rng(1)
    d_values, d_rest = rng.normal(size=values.shape), rng.normal(size=rest.shape)
    fd_values = central_difference(lambda v: loss(v, rest), values, d_values, eps=1e-5)
    fd_rest = central_difference(lambda r: loss(values, r), rest, d_rest, eps=1e-5)
    # Finite differences: O(eps^2) truncation at eps = 1e-5, measured 2.7e-9 (rest) and 8.7e-11 (handles).
    np.testing.assert_allclose(float(jnp.sum(grad_values * d_values)), float(fd_values), rtol=1e-7)
    np.testing.assert_allclose(float(jnp.sum(grad_rest * d_rest)), float(fd_rest), rtol=1e-7)  # measured 2.7e-9
    _, tangent = jax.jvp(lambda v: loss(v, rest), (jnp.asarray(values),), (jnp.asarray(d_values),))
    np.testing.assert_allclose(float(tangent), float(fd_values), rtol=1e-7)  # the handles' FD: measured 8.7e-11


def test_bad_input_raises(without_type_checker):
    mesh, handles, values = _twisted(n_around=6, n_along=3)
    ok = dict(fixed_vertices=handles, fixed_values=values)
    cases = [
        (dict(fixed_vertices=[], fixed_values=np.zeros((0, 3))), "fixed_vertices"),
        (dict(fixed_vertices=handles, fixed_values=None), "fixed_values"),
        (dict(fixed_vertices=[0, 0], fixed_values=np.zeros((2, 3))), "distinct"),
        (dict(fixed_vertices=[0, 10_000], fixed_values=np.zeros((2, 3))), "fixed_vertices"),
        (dict(fixed_vertices=handles, fixed_values=values[:, :2]), "fixed_values"),
        (dict(ok, initial=np.zeros((3, 3))), "initial"),
        (dict(ok, max_steps=0), "max_steps"),
        (dict(ok, rtol=-1.0), "rtol"),
        (dict(ok, solver="magic"), "solver"),
    ]
    for kwargs, name in cases:
        with pytest.raises(DDGInputError, match=name):
            arap(mesh, **kwargs)
    with pytest.raises(DDGInputError, match="mesh"):
        arap((mesh.vertices, mesh.faces), **ok)
    # A second component without a handle: its position is undetermined.
    two = disjoint_union([(np.asarray(mesh.vertices), np.asarray(mesh.faces))] * 2).mesh
    with pytest.raises(DDGInputError, match="component"):
        arap(two, **ok)
