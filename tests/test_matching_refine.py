"""Point maps and their refinements (`ddgjax.matching`) against pyFM on the same eigenvectors."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ddgjax import RESULTS, DDGInputError, Solution
from ddgjax.matching import SpectralShape, functional_map_from_point_map, icp_refine, point_map, spectral_shape, zoomout_refine

from conftest import load_data_mesh

pyFM_spectral = pytest.importorskip("pyFM.spectral")
pyFM_refine = pytest.importorskip("pyFM.refine")


@pytest.fixture(scope="module")
def shape() -> SpectralShape:
    """A 162-vertex sphere with 40 eigenpairs."""
    return spectral_shape(load_data_mesh("sphere_small.ply"), 40)


@pytest.fixture(scope="module")
def shuffled(shape):
    """The same shape with its vertices permuted, and `perm` (target vertex i is source vertex perm[i])."""
    perm = np.random.default_rng(1).permutation(shape.mesh.n_vertices)
    return SpectralShape(shape.mesh, shape.mass[perm], shape.values, shape.vectors[perm]), perm


def _noisy_map(k_t: int, k_s: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.eye(k_t, k_s) + 0.1 * rng.normal(size=(k_t, k_s))


def _arrays(shape):
    return np.asarray(shape.vectors), np.asarray(shape.mass)


def test_point_map_matches_pyfm(shape):
    C = _noisy_map(15, 20)
    Phi, _ = _arrays(shape)
    np.testing.assert_array_equal(np.asarray(point_map(C, shape, shape)), pyFM_spectral.FM_to_p2p(C, Phi, Phi))


def test_functional_map_from_point_map_matches_pyfm(shape):
    Phi, M = _arrays(shape)
    p = np.random.default_rng(2).integers(0, shape.mesh.n_vertices, shape.mesh.n_vertices)
    C = functional_map_from_point_map(p, shape, shape, k_source=20, k_target=12)
    assert C.shape == (12, 20)
    np.testing.assert_allclose(C, pyFM_spectral.p2p_to_FM(p, Phi[:, :20], Phi[:, :12], A2=M), atol=1e-12)


def test_identity_recovered(shape):
    """On one shape the identity functional map gives the identity point map, and back."""
    n = shape.mesh.n_vertices
    np.testing.assert_array_equal(point_map(jnp.eye(30), shape, shape), np.arange(n))
    np.testing.assert_allclose(functional_map_from_point_map(np.arange(n), shape, shape), np.eye(shape.k), atol=1e-10)


def test_round_trip_on_shuffled_copy(shape, shuffled):
    """Point map -> C -> point map recovers a permutation of the vertices."""
    target, perm = shuffled
    C = functional_map_from_point_map(perm, shape, target)
    np.testing.assert_allclose(C, np.eye(shape.k), atol=1e-10)
    np.testing.assert_array_equal(point_map(C, shape, target), perm)


def test_icp_matches_pyfm(shape):
    C = _noisy_map(20, 20, seed=3)
    Phi, M = _arrays(shape)
    expected = pyFM_refine.icp_refine(C, Phi[:, :20], Phi[:, :20], A2=M, nit=10)
    np.testing.assert_allclose(icp_refine(C, shape, shape), expected, atol=1e-10)


def test_icp_stops_at_a_fixed_point(shape, shuffled):
    target, perm = shuffled
    C = icp_refine(np.eye(20) + 0.02 * np.random.default_rng(4).normal(size=(20, 20)), shape, target, max_steps=50)
    np.testing.assert_allclose(C, np.eye(20), atol=1e-10)
    np.testing.assert_array_equal(point_map(C, shape, target), perm)


@pytest.mark.parametrize(("k_t", "k_s", "step"), [(10, 10, 1), (10, 10, 3)])
def test_zoomout_matches_pyfm(shape, k_t, k_s, step):
    C = _noisy_map(k_t, k_s, seed=5)
    Phi, M = _arrays(shape)
    nit = 9 if step == 3 else 26
    expected = pyFM_refine.zoomout_refine(C, Phi, Phi, nit=nit, step=step, A2=M)
    refined = zoomout_refine(C, shape, shape, k_final=k_t + nit * step, step=step)
    assert refined.shape == expected.shape
    np.testing.assert_allclose(refined, expected, atol=1e-10)


def test_zoomout_rectangular_and_identity(shape, shuffled):
    """A (k_t, k_s) map grows to (k_final, k_final); near the identity on a shuffled copy it finds the permutation."""
    target, perm = shuffled
    refined = zoomout_refine(np.eye(8, 10), shape, target, k_final=30)
    assert refined.shape == (30, 30)
    np.testing.assert_array_equal(point_map(refined, shape, target), perm)


def test_bad_input(shape, without_type_checker):
    with pytest.raises(DDGInputError, match="source"):
        point_map(np.eye(5), shape.vectors, shape)
    with pytest.raises(DDGInputError, match="C"):
        point_map(np.eye(50), shape, shape)
    with pytest.raises(DDGInputError, match="point_map"):
        functional_map_from_point_map(np.arange(5), shape, shape)
    with pytest.raises(DDGInputError, match="point_map"):
        functional_map_from_point_map(np.full(shape.mesh.n_vertices, -1), shape, shape)
    with pytest.raises(DDGInputError, match="k_source"):
        functional_map_from_point_map(np.arange(shape.mesh.n_vertices), shape, shape, k_source=100)
    with pytest.raises(DDGInputError, match="k_final"):
        zoomout_refine(np.eye(10), shape, shape, k_final=5)
    with pytest.raises(DDGInputError, match="k_final"):
        zoomout_refine(np.eye(10), shape, shape, k_final=41)
    with pytest.raises(DDGInputError, match="max_steps"):
        icp_refine(np.eye(10), shape, shape, max_steps=-1)


def test_icp_reports_its_steps_and_a_nonfinite_map(shape):
    """`throw=False`: pyFM's map in a `ddgjax.Solution`, with the steps taken (at most `max_steps`) and the last
    change; a map that turns NaN inside `jit` (where its values cannot be checked first) is `nonfinite`."""
    C = _noisy_map(20, 20, seed=3)
    solution = icp_refine(C, shape, shape, throw=False)
    assert isinstance(solution, Solution) and solution.result == RESULTS.successful
    np.testing.assert_allclose(solution.value, icp_refine(C, shape, shape), atol=0)
    assert 1 <= int(solution.stats["num_steps"]) <= 10 and float(solution.stats["change"]) >= 0
    poisoned = jax.jit(lambda C: icp_refine(C, shape, shape, throw=False).result)(jnp.asarray(C).at[0, 0].set(jnp.nan))
    assert poisoned == RESULTS.nonfinite
    with pytest.raises(Exception, match="non-finite|nonfinite|NaN"):
        jax.block_until_ready(jax.jit(lambda C: icp_refine(C, shape, shape))(jnp.asarray(C).at[0, 0].set(jnp.nan)))
