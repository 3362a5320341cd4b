"""`match_shapes` and `geodesic_error` on pairs with known ground truth, against pyFM's pipeline and exact geodesics."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.spatial

import ddgjax
from ddgjax import DDGInputError
from ddgjax.deform import arap
from ddgjax.matching import MatchResult, geodesic_error, match_shapes
from ddgjax.mesh import Mesh, icosphere

from conftest import data_path, unit_icosphere

pp3d = pytest.importorskip("potpourri3d")
igl = pytest.importorskip("igl")


@pytest.fixture(scope="module")
def spot_full() -> tuple[np.ndarray, np.ndarray]:
    """spot.obj as read (2,930 vertices; the cow is left-right symmetric about x = 0)."""
    return igl.read_triangle_mesh(str(data_path("meshes", "spot.obj")))


@pytest.fixture(scope="module")
def spot(spot_full) -> Mesh:
    """spot.obj decimated to ~1,500 vertices."""
    V, F, *_ = igl.decimate(*spot_full, 3000)
    return Mesh.from_arrays(V, F)


def _bent_and_shuffled(mesh: Mesh) -> tuple[Mesh, np.ndarray]:
    """ARAP with the feet held and the top moved sideways, vertices permuted: (target, perm), target vertex i = mesh vertex perm[i]."""
    V, F = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    low, high = np.flatnonzero(V[:, 2] < np.quantile(V[:, 2], 0.05)), np.flatnonzero(V[:, 2] > np.quantile(V[:, 2], 0.95))
    fixed = np.concatenate([low, high])
    values = V[fixed] + np.where(np.isin(fixed, high), 0.3, 0.0)[:, None] * np.array([1.0, 0.0, 0.0])
    W = np.asarray(arap(mesh, fixed_vertices=fixed, fixed_values=values, rtol=1e-5))  # a bent target, not ARAP's minimum
    perm = np.random.default_rng(0).permutation(len(V))
    return Mesh.from_arrays(W[perm], np.argsort(perm)[F]), perm


def _mirror_map(mesh: Mesh) -> np.ndarray:
    V = np.asarray(mesh.vertices)
    return scipy.spatial.cKDTree(V).query(V * np.array([-1.0, 1.0, 1.0]))[1]


def _pyfm_point_map(source: Mesh, target: Mesh, *, orientation_weight: float = 0.0, tight: bool = False) -> np.ndarray:
    """pyFM's pipeline with match_shapes' defaults (orientation term off, pyFM's default, unless given);
    `tight`: its L-BFGS run to the minimiser (`factr=10, pgtol=1e-14`), which ddgjax's one solve reaches."""
    import threadpoolctl
    from pyFM.functional import FunctionalMapping
    from pyFM.mesh import TriMesh

    # One thread: scikit-learn's OpenMP threads in pyFM's nearest neighbours contend with JAX's on a small
    # machine (3x slower); the map is the same.
    with threadpoolctl.threadpool_limits(1):
        model = FunctionalMapping(*(TriMesh(np.asarray(m.vertices), np.asarray(m.faces)) for m in (source, target)))
        model.preprocess(n_descr=100, descr_type="WKS", k_process=100)
        model.fit(K=(50, 50), w_orient=orientation_weight, **(dict(factr=1e1, pgtol=1e-14) if tight else {}))
        return model.get_p2p(model.zoomout_refine(nit=50, step=1))


def _assert_good_match(source: Mesh, target: Mesh, truth: np.ndarray, pyfm_orientation_weight: float) -> None:
    """Under 0.03, no worse than pyFM's (up to 1e-3, a thirtieth of an edge length here: the two pipelines'
    eigensolvers differ, so a few vertices may land on a neighbour of pyFM's choice), and far from the mirror map."""
    result = match_shapes(source, target)
    assert result.point_map.shape == (target.n_vertices,)
    assert result.functional_map.shape == (100, 100)
    assert np.all(np.isfinite(np.asarray(result.functional_map)))
    error = geodesic_error(source, result.point_map, truth)
    assert error < 0.03  # a good match: within about one edge length (~0.03 of sqrt(area) here) on average
    pyfm = _pyfm_point_map(source, target, orientation_weight=pyfm_orientation_weight)
    # The pipelines' eigensolvers differ: a few vertices may land on a neighbour of pyFM's choice.
    assert error <= geodesic_error(source, pyfm, truth) + 1e-3
    # The left-right flip is avoided: far below the mirror map's error (300 vertices estimate it well).
    assert error < 0.2 * geodesic_error(source, _mirror_map(source)[truth], truth, n_samples=300)


@pytest.mark.slow
def test_bent_shuffled_pair(spot):
    target, truth = _bent_and_shuffled(spot)
    _assert_good_match(spot, target, truth, pyfm_orientation_weight=0.0)


@pytest.mark.slow
def test_without_the_orientation_term_the_map_is_pyfms(spot):
    """`orientation_weight=0` on the bent, shuffled cow: both pipelines map it left to right flipped (WKS
    descriptors cannot tell the sides apart), and ddgjax's map is pyFM's run to its minimiser (up to
    1e-3, a thirtieth of an edge: the eigensolvers differ). Measured: 0.169 and 0.169 here; on a
    remeshed cow 0.226 against 0.226, where pyFM's default tolerance stops at 0.219."""
    target, truth = _bent_and_shuffled(spot)
    error = geodesic_error(spot, match_shapes(spot, target, orientation_weight=0.0).point_map, truth)
    pyfm = geodesic_error(spot, _pyfm_point_map(spot, target, orientation_weight=0.0, tight=True), truth)
    assert abs(error - pyfm) <= 1e-3, (error, pyfm)


@pytest.mark.slow
def test_remeshed_pair(spot, spot_full):
    """The full-resolution cow remeshed (Botsch & Kobbelt) to ~1,700 vertices, none shared with the decimated source.

    Truth: each target vertex's source vertex nearest to its closest point on the source surface. pyFM's
    default (no orientation term) flips this pair left to right, so it is compared with pyFM given the same
    orientation term as `match_shapes` (Ren et al. 2018, weight 1).
    """
    gpytoolbox = pytest.importorskip("gpytoolbox")
    V, F = np.asarray(spot.vertices), np.asarray(spot.faces)
    W, G = gpytoolbox.remesh_botsch(spot_full[0], spot_full[1].astype(np.int32), i=10, h=0.9 * igl.avg_edge_length(V, F))
    assert 1500 <= len(W) <= 3000 and scipy.spatial.cKDTree(V).query(W)[0].min() > 1e-6
    _, _, closest = igl.point_mesh_squared_distance(W, V, F)
    truth = scipy.spatial.cKDTree(V).query(closest)[1]
    _assert_good_match(spot, Mesh.from_arrays(W, G.astype(np.int64)), truth, pyfm_orientation_weight=1.0)


@pytest.mark.slow  # the fast tier's time limit (its checks run in the full suite)
def test_geodesic_error_against_potpourri3d(spot):
    """The same heat method as potpourri3d's, on pairs mostly far apart (where the chord bound rarely acts)."""
    V, F = np.asarray(spot.vertices), np.asarray(spot.faces)
    rng = np.random.default_rng(3)
    true = rng.integers(0, len(V), 40)
    predicted = rng.integers(0, len(V), 40)
    predicted[:5] = true[:5]
    solver = pp3d.MeshHeatMethodDistanceSolver(V, F)
    expected = np.mean([solver.compute_distance(t)[p] for t, p in zip(true, predicted)])
    expected /= np.sqrt(np.sum(igl.doublearea(V, F)) / 2)
    # Both heat methods (t = h^2) but ours raises a distance below the chord to the chord (a few short pairs
    # here), and potpourri3d builds its own (intrinsic Delaunay) Laplacian: first-order errors of each differ.
    np.testing.assert_allclose(geodesic_error(spot, predicted, true), expected, rtol=2e-2)
    assert geodesic_error(spot, true, true) == 0.0


def test_geodesic_error_against_exact_geodesics(spot):
    """Against exact (MMP, libigl's `exact_geodesic`) distances, at short range (a neighbour, a few edges: where
    matching errors lie and the bare heat method underestimates by ~8-15%) and at long range."""
    V, F = np.asarray(spot.vertices), np.asarray(spot.faces)
    rng = np.random.default_rng(1)
    true = rng.choice(len(V), 20, replace=False)
    ring = igl.adjacency_list(F)

    def walk(vertex: int, steps: int) -> int:
        for _ in range(steps):
            vertex = ring[vertex][rng.integers(len(ring[vertex]))]
        return vertex

    neighbours = np.array([ring[t][0] for t in true])
    few_edges = np.array([walk(t, 4) for t in true])
    far = rng.integers(0, len(V), 20)
    sqrt_area = np.sqrt(np.sum(igl.doublearea(V, F)) / 2)
    predicted = np.stack([neighbours, few_edges, far], axis=1)
    exact = np.array([igl.exact_geodesic(V, F, VS=np.array([t]), VT=p) for t, p in zip(true, predicted)])
    # The heat method's first-order error in the edge length (after the chord bound): within 1% of the
    # exact mean over near pairs, 2% over distant ones (geodesic_error's documented accuracy).
    for column, rtol in ((0, 1e-2), (1, 1e-2), (2, 2e-2)):
        np.testing.assert_allclose(
            geodesic_error(spot, predicted[:, column], true), np.mean(exact[:, column]) / sqrt_area, rtol=rtol
        )
    # throw=False: the same error in a `ddgjax.Solution`, with one heat-method query per distinct true vertex.
    solution = geodesic_error(spot, predicted[:, 2], true, throw=False)
    assert isinstance(solution, ddgjax.Solution) and solution.result == ddgjax.RESULTS.successful
    assert solution.value == geodesic_error(spot, predicted[:, 2], true)
    assert solution.stats["n_queries"] == np.unique(true[predicted[:, 2] != true]).size


@pytest.mark.slow
def test_geodesic_error_on_a_sphere_is_the_great_circle_distance_over_sqrt_4_pi_r2():
    """Within 1% of the analytic value on a 2,562-vertex sphere (measured 0.8% low: the inscribed polyhedron)."""
    radius = 2.0
    mesh = icosphere(4, radius=radius, dtype=np.float64)
    V = np.asarray(mesh.vertices)
    rng = np.random.default_rng(0)
    true, predicted = rng.integers(0, len(V), 30), rng.integers(0, len(V), 30)
    cosines = np.clip(np.sum(V[true] * V[predicted], axis=1) / radius**2, -1.0, 1.0)
    expected = np.mean(radius * np.arccos(cosines)) / np.sqrt(4 * np.pi * radius**2)
    # The inscribed polyhedron is shorter than the sphere (and the heat method first order): measured 0.8% low.
    np.testing.assert_allclose(geodesic_error(mesh, predicted, true), expected, rtol=1e-2)


def test_geodesic_error_subsamples_target_vertices_uniformly_without_replacement(spot):
    rng = np.random.default_rng(2)
    true, predicted = rng.integers(0, spot.n_vertices, 60), rng.integers(0, spot.n_vertices, 60)
    chosen = np.random.default_rng(7).choice(60, 25, replace=False)
    assert geodesic_error(spot, predicted, true, n_samples=25, key=7) == pytest.approx(
        geodesic_error(spot, predicted[chosen], true[chosen]), rel=1e-12
    )
    assert geodesic_error(spot, predicted, true, n_samples=60) == geodesic_error(spot, predicted, true)


def _with_slivers(mesh: Mesh, n: int) -> tuple[Mesh, np.ndarray]:
    """`n` vertices moved: the first onto a neighbour (two faces of exactly zero area), the others onto the
    midpoint of the opposite edge of one of their faces (a zero-area face, to round-off, with slivers around
    the vertex). Returns the mesh and the moved vertices."""
    V, F = np.array(mesh.vertices), np.asarray(mesh.faces)
    faces = np.random.default_rng(4).choice(len(F), 4 * n, replace=False)
    moved: list[int] = []
    for a, b, c in F[faces]:
        if len(moved) == n:
            break
        if not {a, b, c} & set(moved):
            V[a] = V[b] if not moved else (V[b] + V[c]) / 2
            moved.append(int(a))
    return Mesh.from_arrays(V, F), np.array(moved)


@pytest.fixture(scope="module")
def bumpy_sphere() -> Mesh:
    """A 162-vertex sphere with random radii (no symmetry)."""
    mesh = unit_icosphere(2)
    radii = 1.0 + 0.1 * np.random.default_rng(0).standard_normal(mesh.n_vertices)
    return mesh.with_vertices(np.asarray(mesh.vertices) * radii[:, None])


@pytest.mark.slow
@pytest.mark.parametrize("orientation_weight", [0.0, 1.0])
def test_match_shapes_on_slivers_with_robust_laplacian_is_finite_and_reports_its_outcome(bumpy_sphere, orientation_weight):
    """Zero-area faces and slivers: `robust=True` (intrinsic Delaunay) keeps every step finite; `throw=False`
    reports the steps' outcome in the record's `result`. Without `robust`, the mesh is refused up front."""
    degenerate, moved = _with_slivers(bumpy_sphere, 4)
    areas = igl.doublearea(np.asarray(degenerate.vertices), np.asarray(degenerate.faces)) / 2
    assert len(moved) == 4 and np.sum(areas == 0) >= 2 and np.sum(areas < 1e-12) >= 5
    with pytest.raises(ddgjax.MeshDataError, match="robust=True"):
        match_shapes(bumpy_sphere, degenerate, k=10, k_final=20)
    result = match_shapes(
        bumpy_sphere, degenerate, k=10, k_final=20, orientation_weight=orientation_weight, robust=True, throw=False
    )
    assert isinstance(result, MatchResult) and result.result == ddgjax.RESULTS.successful
    assert np.all(np.isfinite(np.asarray(result.functional_map))) and result.functional_map.shape == (20, 20)
    assert result.initial_functional_map.shape == (10, 10) and np.all(np.isfinite(np.asarray(result.initial_functional_map)))
    for shape in (result.source, result.target):
        assert np.all(np.isfinite(np.asarray(shape.values))) and np.all(np.isfinite(np.asarray(shape.vectors)))
    point_map = np.asarray(result.point_map)
    assert point_map.shape == (degenerate.n_vertices,)
    # The same vertices, only four moved: the map stays within about an edge of the identity.
    assert geodesic_error(bumpy_sphere, point_map, np.arange(bumpy_sphere.n_vertices)) < 0.05


def test_bad_input(spot, without_type_checker, icosphere1):
    with pytest.raises(DDGInputError, match="true_point_map"):
        geodesic_error(spot, np.arange(5), np.arange(6))
    with pytest.raises(DDGInputError, match="point_map"):
        geodesic_error(spot, np.full(5, spot.n_vertices), np.arange(5))
    with pytest.raises(DDGInputError, match="point_map"):
        geodesic_error(spot, np.arange(5.0), np.arange(5))
    with pytest.raises(DDGInputError, match="true_point_map"):
        geodesic_error(spot, np.arange(6), np.arange(6).reshape(2, 3))
    with pytest.raises(DDGInputError, match="source_mesh"):
        geodesic_error(np.zeros((3, 3)), np.arange(3), np.arange(3))
    with pytest.raises(DDGInputError, match="n_samples"):
        geodesic_error(spot, np.arange(5), np.arange(5), n_samples=0)
    with pytest.raises(DDGInputError, match="refine"):
        match_shapes(spot, spot, refine="nope")
    with pytest.raises(DDGInputError, match="k_final"):
        match_shapes(spot, spot, k=50, k_final=20)
    with pytest.raises(DDGInputError, match="target_mesh"):
        match_shapes(spot, np.zeros((3, 3)))
    with pytest.raises(DDGInputError, match="source_mesh"):
        match_shapes((np.zeros((3, 3)), np.zeros((1, 3), int)), spot)
    with pytest.raises(DDGInputError, match="source_mesh"):
        match_shapes(icosphere1, spot, k=50)


@pytest.mark.slow
def test_match_shapes_with_throw_false_reports_its_steps_outcome_in_its_record(bumpy_sphere):
    """`throw=False`: the pipeline's record, its `result` the first failed step's (here none: a shape with
    no symmetry matched to itself maps every vertex to itself), `value` the point map, `stats` each step's."""
    record = match_shapes(bumpy_sphere, bumpy_sphere, k=10, k_final=20, throw=False)
    assert isinstance(record, MatchResult) and isinstance(record, ddgjax.Record)
    assert record.result == ddgjax.RESULTS.successful
    assert record.functional_map.shape == (20, 20)
    np.testing.assert_array_equal(record.value, np.arange(bumpy_sphere.n_vertices))
    assert set(record.stats) == {"source", "target", "functional_map", "refine"}
