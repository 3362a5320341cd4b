"""`match_shapes` and `geodesic_error` on pairs with known ground truth, against pyFM's pipeline."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.spatial

from ddgjax import DDGInputError
from ddgjax.deform import arap
from ddgjax.matching import geodesic_error, match_shapes
from ddgjax.mesh import Mesh

from conftest import data_path

pp3d = pytest.importorskip("potpourri3d")
igl = pytest.importorskip("igl")


@pytest.fixture(scope="module")
def spot() -> Mesh:
    """spot.obj decimated to ~1,500 vertices (the cow is left-right symmetric)."""
    V, F = igl.read_triangle_mesh(str(data_path("meshes", "spot.obj")))
    V, F, *_ = igl.decimate(V, F, 3000)
    return Mesh.from_arrays(V, F)


def _bent_and_shuffled(mesh: Mesh) -> tuple[Mesh, np.ndarray]:
    """ARAP with the feet held and the top moved sideways, vertices permuted: (target, truth)."""
    V, F = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    low, high = np.flatnonzero(V[:, 2] < np.quantile(V[:, 2], 0.05)), np.flatnonzero(V[:, 2] > np.quantile(V[:, 2], 0.95))
    fixed = np.concatenate([low, high])
    values = V[fixed] + np.where(np.isin(fixed, high), 0.3, 0.0)[:, None] * np.array([1.0, 0.0, 0.0])
    W = np.asarray(arap(mesh, fixed_vertices=fixed, fixed_values=values, rtol=1e-5))
    perm = np.random.default_rng(0).permutation(len(V))
    return Mesh.from_arrays(W[perm], np.argsort(perm)[F]), perm


def _mirror_map(mesh: Mesh) -> np.ndarray:
    V = np.asarray(mesh.vertices)
    return scipy.spatial.cKDTree(V).query(V * np.array([-1.0, 1.0, 1.0]))[1]


def _pyfm_point_map(source: Mesh, target: Mesh) -> np.ndarray:
    from pyFM.functional import FunctionalMapping
    from pyFM.mesh import TriMesh

    model = FunctionalMapping(*(TriMesh(np.asarray(m.vertices), np.asarray(m.faces)) for m in (source, target)))
    model.preprocess(n_descr=100, descr_type="WKS", k_process=100)
    model.fit(K=(50, 50))
    return model.get_p2p(model.zoomout_refine(nit=50, step=1))


@pytest.mark.slow
def test_bent_shuffled_pair(spot):
    target, truth = _bent_and_shuffled(spot)
    result = match_shapes(spot, target)
    error = geodesic_error(spot, result.point_map, truth)
    assert result.point_map.shape == (target.n_vertices,)
    assert result.functional_map.shape == (100, 100)
    assert error < 0.03
    assert error <= geodesic_error(spot, _pyfm_point_map(spot, target), truth) + 1e-3
    # The left-right flip is avoided: far below the mirror map's error.
    assert error < 0.2 * geodesic_error(spot, _mirror_map(spot)[truth], truth)


def test_geodesic_error_against_potpourri3d(spot):
    V, F = np.asarray(spot.vertices), np.asarray(spot.faces)
    rng = np.random.default_rng(3)
    true = rng.integers(0, len(V), 40)
    predicted = rng.integers(0, len(V), 40)
    predicted[:5] = true[:5]
    solver = pp3d.MeshHeatMethodDistanceSolver(V, F)
    expected = np.mean([solver.compute_distance(t)[p] for t, p in zip(true, predicted)])
    expected /= np.sqrt(np.sum(igl.doublearea(V, F)) / 2)
    np.testing.assert_allclose(geodesic_error(spot, predicted, true), expected, rtol=2e-2)
    assert geodesic_error(spot, true, true) == 0.0


def test_bad_input(spot, without_type_checker):
    with pytest.raises(DDGInputError, match="true_point_map"):
        geodesic_error(spot, np.arange(5), np.arange(6))
    with pytest.raises(DDGInputError, match="point_map"):
        geodesic_error(spot, np.full(5, spot.n_vertices), np.arange(5))
    with pytest.raises(DDGInputError, match="refine"):
        match_shapes(spot, spot, refine="nope")
    with pytest.raises(DDGInputError, match="k_final"):
        match_shapes(spot, spot, k=50, k_final=20)
    with pytest.raises(DDGInputError, match="target_mesh"):
        match_shapes(spot, np.zeros((3, 3)))


def test_match_shapes_with_throw_false_reports_its_steps_outcome_in_a_solution():
    """`throw=False`: the pipeline's result in a `ddgjax.Solution`, its `result` the first failed step's
    (here none: a shape with no symmetry matched to itself maps every vertex to itself)."""
    import ddgjax
    from ddgjax.matching import MatchResult, match_shapes
    from ddgjax.mesh import icosphere

    mesh = icosphere(2, dtype=np.float64)
    radii = 1.0 + 0.1 * np.random.default_rng(0).standard_normal(mesh.n_vertices)
    mesh = mesh.with_vertices(np.asarray(mesh.vertices) * radii[:, None])
    solution = match_shapes(mesh, mesh, k=10, k_final=20, throw=False)
    assert isinstance(solution, ddgjax.Solution) and isinstance(solution.value, MatchResult)
    assert solution.result == ddgjax.RESULTS.successful
    assert solution.value.functional_map.shape == (20, 20)
    np.testing.assert_array_equal(solution.value.point_map, np.arange(mesh.n_vertices))
