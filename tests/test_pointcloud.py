"""ddgjax.pointcloud: the point-cloud Laplacian, normals and heat distance, against robust_laplacian,
potpourri3d and the unit sphere's closed forms."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import jax.test_util
import numpy as np
import pytest
import scipy.sparse.linalg as sla

import ddgjax
from ddgjax import DDGInputError
from ddgjax.pointcloud import (
    point_cloud_heat_distance,
    point_cloud_heat_solver,
    point_cloud_laplacian,
    point_cloud_log_map,
    point_cloud_normals,
    point_cloud_parallel_transport,
    point_cloud_triangulation,
)
from ddgjax.pointcloud._triangulation import local_triangles, nearest_neighbor_graph

from conftest import unit_icosphere

robust_laplacian = pytest.importorskip("robust_laplacian")
pp3d = pytest.importorskip("potpourri3d")


def _sphere_samples(n: int, seed: int = 0) -> np.ndarray:
    points = np.random.default_rng(seed).normal(size=(n, 3))
    return points / np.linalg.norm(points, axis=1, keepdims=True)


def _jittered_icosphere(level: int, scale: float = 1e-3) -> np.ndarray:
    """Icosphere vertices moved a little (off the co-circular neighbourhoods of the exact icosphere), on the sphere."""
    points = np.asarray(unit_icosphere(level).vertices)
    points = points + scale * np.random.default_rng(0).normal(size=points.shape)
    return points / np.linalg.norm(points, axis=1, keepdims=True)


def _sphere_spectrum_error(L, M, l_max: int = 4) -> float:
    """Largest relative error of the eigenvalues 1..(l_max+1)^2-1 of `L x = lambda M x` against `l (l + 1)`."""
    expected = np.repeat([deg * (deg + 1) for deg in range(l_max + 1)], [2 * deg + 1 for deg in range(l_max + 1)])
    values = sla.eigsh(L.tocsc(), k=expected.size, M=M.tocsc(), sigma=-1e-3, which="LM")[0]
    return float(np.max(np.abs(np.sort(values)[1:] - expected[1:]) / expected[1:]))


def test_local_triangles_match_potpourri3d():
    points = _sphere_samples(1000)
    faces = local_triangles(points, nearest_neighbor_graph(points, 30))
    theirs = pp3d.PointCloudLocalTriangulation(points).get_local_triangulation()
    ours = {tuple(sorted(face)) for face in faces.tolist()}
    reference = {tuple(sorted(face)) for face in theirs.reshape(-1, 3).tolist() if face[0] >= 0}
    # Both walk to Delaunay fans by different rules (robust_laplacian's, ours, accepts circumcircles empty
    # to 1e-4 of the radius; potpourri3d flips by an exact in-circle test): measured 1.4% apart here.
    assert len(ours ^ reference) <= 0.02 * len(reference)


@pytest.mark.slow
def test_identities():
    points = _sphere_samples(600, seed=1)
    L, M = point_cloud_laplacian(points, n_neighbors=20)
    dense = np.asarray(L.todense())
    np.testing.assert_allclose(dense, dense.T, atol=1e-12)
    np.testing.assert_allclose(dense @ np.ones(600), 0.0, atol=1e-10)
    off = dense - np.diag(np.diag(dense))
    assert off.max() <= 1e-12  # intrinsic Delaunay: non-negative weights, the maximum principle
    assert np.linalg.eigvalsh(dense).min() > -1e-10
    mass = np.asarray(M.diagonal())
    assert mass.min() > 0
    # The tufted cover of the local triangles covers the sphere about once (3% here).
    assert abs(mass.sum() - 4 * np.pi) < 0.03 * 4 * np.pi


@pytest.mark.slow
def test_sphere_spectrum_no_worse_than_robust_laplacian(icosphere4):
    for points in (_jittered_icosphere(4), _sphere_samples(2000)):
        L, M = point_cloud_laplacian(points)
        ours = _sphere_spectrum_error(L.to_scipy(), M.to_scipy())
        theirs = _sphere_spectrum_error(*robust_laplacian.point_cloud_laplacian(points, n_neighbors=30))
        # Equal on the jittered icosphere (0.0067 both); random samples have near-coincident pairs where
        # the two tufted covers may differ (both intrinsic Delaunay): 0.0757 vs 0.0756, so 1% of theirs.
        assert ours <= 1.01 * theirs
        assert ours < 0.1  # the discretisation error of 2000 random samples (uneven spacing): measured 0.0757
    # The exact icosphere's neighbourhoods are co-circular, where any Delaunay 1-ring is valid and the two
    # choose differently: measured 0.0079 here, 0.0067 robust_laplacian.
    L, M = point_cloud_laplacian(np.asarray(icosphere4.vertices))
    assert _sphere_spectrum_error(L.to_scipy(), M.to_scipy()) < 0.01


@pytest.mark.slow
def test_normals_on_sphere_and_gradient():
    points = _jittered_icosphere(2)
    normals = np.asarray(point_cloud_normals(points, n_neighbors=10))
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-12)
    # PCA normals of 162 jittered points, 10 neighbours: 1 - |cos| to the radial direction measured 2.4e-3.
    assert np.abs(np.abs(np.sum(normals * points, axis=1)) - 1).max() < 5e-3
    neighbors = nearest_neighbor_graph(points, 10)
    weights = jnp.asarray(np.random.default_rng(2).normal(size=points.shape))
    loss = lambda p: jnp.sum(weights * point_cloud_normals(p, neighbors=neighbors) ** 2)  # sign-free
    # check_grads' finite differences at its default step 1e-4: O(eps^2) truncation of the PCA eigenvectors.
    jax.test_util.check_grads(loss, (jnp.asarray(points),), order=1, modes=("rev",), atol=1e-5, rtol=1e-5)


@pytest.mark.slow
def test_laplacian_gradient_matches_finite_differences():
    points = jnp.asarray(_jittered_icosphere(2))
    triangulation = point_cloud_triangulation(points, n_neighbors=12)
    u = jnp.asarray(np.random.default_rng(3).normal(size=points.shape[0]))

    def energy(p):
        L, M = point_cloud_laplacian(p, triangulation=triangulation)
        return u @ (L @ u) + jnp.sum(M.diagonal())

    # eps=1e-6: the default 1e-4 steps leave a 1e-5 truncation error on the thin triangles' cotangents; at
    # 1e-6 the truncation is ~1e-9 there and round-off / eps ~1e-10 relative, within 1e-6.
    jax.test_util.check_grads(energy, (points,), order=1, modes=("rev",), atol=1e-6, rtol=1e-6, eps=1e-6)
    eager = energy(points)
    assert jnp.allclose(jax.jit(energy)(points), eager, rtol=1e-12, atol=0.0)


@pytest.mark.slow
def test_heat_distance_on_sphere_and_against_potpourri3d():
    points = _sphere_samples(3000)
    solver = point_cloud_heat_solver(points)
    great_circle = np.arccos(np.clip(points @ points[0], -1, 1))
    distance = np.asarray(solver.distance(0))
    reference = pp3d.PointCloudHeatSolver(points).compute_distance(0)
    assert distance[0] == 0 and distance.min() >= 0
    # First-order accurate in the spacing (~0.065): measured max 0.080 (potpourri3d 0.069), mean 0.033 (0.032).
    assert np.abs(distance - great_circle).max() < 0.1
    assert np.abs(distance - great_circle).mean() < 0.04
    # The same method on the same tufted triangulation up to the covers' gluing at near-coincident pairs
    # and potpourri3d's own choices (its heat method's Laplacian): measured max 0.029, 0.9% of pi.
    assert np.abs(distance - reference).max() < 0.04
    one_shot = np.asarray(point_cloud_heat_distance(points, [0]))
    np.testing.assert_allclose(one_shot, distance, atol=1e-10)


@pytest.mark.slow
def test_heat_distance_small_cloud_and_outcome():
    points = _jittered_icosphere(3)
    solution = point_cloud_heat_distance(points, np.array([0, 5]), n_neighbors=15, throw=False)
    assert solution.result == ddgjax.RESULTS.successful
    great_circle = np.min(np.arccos(np.clip(points @ points[[0, 5]].T, -1, 1)), axis=1)
    # 642 points (spacing ~0.15): first-order error, measured 0.13.
    assert np.abs(np.asarray(solution.value) - great_circle).max() < 0.2


def test_bad_input():
    points = _sphere_samples(50)
    with pytest.raises(DDGInputError, match="points"):
        point_cloud_laplacian(points[:, :2])
    bad = points.copy()
    bad[3, 1] = np.nan
    with pytest.raises(DDGInputError, match="NaN"):
        point_cloud_laplacian(bad)
    with pytest.raises(DDGInputError, match="n_neighbors"):
        point_cloud_laplacian(points, n_neighbors=50)
    with pytest.raises(DDGInputError, match="n_neighbors"):
        point_cloud_normals(points, n_neighbors=1)
    with pytest.raises(DDGInputError, match="sources"):
        point_cloud_heat_distance(points, [60])
    with pytest.raises(DDGInputError, match="t_coef"):
        point_cloud_heat_solver(points, n_neighbors=10, t_coef=-1.0)
    triangulation = point_cloud_triangulation(points, n_neighbors=10)
    with pytest.raises(DDGInputError, match="built for 50 points"):
        point_cloud_laplacian(points[:40], triangulation=triangulation)


def _great_circle_transport(source: np.ndarray, points: np.ndarray, vector: np.ndarray) -> np.ndarray:
    """Unit closed-form transport of `vector` (tangent at `source`) along the great circles to `points` (unit sphere)."""
    axis = np.cross(source, points)
    sine, cosine = np.linalg.norm(axis, axis=1), points @ source
    k = axis / np.where(sine > 0, sine, 1.0)[:, None]
    moved = vector * cosine[:, None] + np.cross(k, vector) * sine[:, None] + k * (k @ vector)[:, None] * (1 - cosine)[:, None]
    return moved / np.linalg.norm(moved, axis=1, keepdims=True)


def _angles(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    cosine = np.sum(a * b, axis=-1) / (np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1))
    return np.arccos(np.clip(cosine, -1, 1))


@pytest.mark.slow
def test_transport_and_log_map_on_sphere_and_against_potpourri3d():
    points = _jittered_icosphere(4)  # 2562 points, spacing ~0.075
    solver = point_cloud_heat_solver(points)
    e1, e2, normal = (np.asarray(frame) for frame in solver.tangent_frames)
    np.testing.assert_allclose(np.sum(e1 * normal, axis=1), 0, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(e2, axis=1), 1, atol=1e-12)
    assert np.min(np.sum(normal * points, axis=1)) > 0.999  # oriented outward; PCA normals tilt O(h) off the radius
    great_circle = np.arccos(np.clip(points @ points[0], -1, 1))
    away = great_circle < 2.8  # off the cut locus (the antipode)
    transported = np.asarray(solver.transport(0, 2.0 * e1[0]))
    np.testing.assert_allclose(np.sum(transported * normal, axis=1), 0, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(transported, axis=1), 2.0, rtol=1e-10)
    exact = _great_circle_transport(points[0], points, e1[0])
    # Measured max 0.017 rad, mean 0.0043 (potpourri3d's: max 0.093).
    assert _angles(transported, exact)[away].max() < 0.03
    assert _angles(transported, exact).mean() < 0.008

    log = np.asarray(solver.log_map(0))
    radius = np.linalg.norm(log, axis=1)
    inside = great_circle < 2.5
    # The heat distance's first-order error: measured max 0.017, mean 0.013.
    assert np.abs(radius - great_circle)[inside].max() < 0.025
    chord = points - points[0]
    tangent = chord - np.outer(chord @ points[0], points[0])
    log_world = log[:, :1] * e1[0] + log[:, 1:] * e2[0]
    direction = (great_circle > 0.05) & inside
    # Measured max 0.037 rad, mean 0.012.
    error = _angles(log_world[direction], tangent[direction])
    assert error.max() < 0.06
    assert error.mean() < 0.02

    reference = pp3d.PointCloudHeatSolver(points)
    basis_x, basis_y, _ = reference.get_tangent_frames()
    theirs = reference.transport_tangent_vector(0, [1.0, 0.0])
    theirs = theirs[:, :1] * basis_x + theirs[:, 1:] * basis_y
    ours = np.asarray(solver.transport(0, basis_x[0]))
    # Their own error against the closed form is max 0.093 rad; measured between the two: max 0.093, mean 0.0074.
    assert _angles(ours, theirs)[away].max() < 0.12
    assert _angles(ours, theirs).mean() < 0.015
    their_log = reference.compute_log_map(0)
    # The same heat distance up to the covers' gluing: measured 3.7e-5.
    assert np.abs(np.linalg.norm(their_log, axis=1) - radius)[inside].max() < 1e-3
    their_world = their_log[:, :1] * basis_x[0] + their_log[:, 1:] * basis_y[0]
    # Measured max 0.071 rad, mean 0.015 (theirs against the tangent projection: max 0.054, mean 0.012).
    assert _angles(log_world[direction], their_world[direction]).max() < 0.1
    np.testing.assert_allclose(np.asarray(point_cloud_log_map(points, 0)), log, atol=1e-10)
    one_shot = np.asarray(point_cloud_parallel_transport(points, 0, 2.0 * e1[0]))
    np.testing.assert_allclose(one_shot, transported, atol=1e-10)


@pytest.mark.slow
def test_transport_several_sources_gradient_and_outcome():
    points = _jittered_icosphere(2)  # 162 points
    triangulation = point_cloud_triangulation(points, n_neighbors=12)
    solver = point_cloud_heat_solver(points, triangulation=triangulation)
    e1 = np.asarray(solver.tangent_frames.e1)
    far = int(np.argmin(points @ points[0]))
    solution = solver.transport(np.array([0, far]), np.stack([e1[0], 3.0 * e1[far]]), throw=False)
    assert solution.result == ddgjax.RESULTS.successful
    to_sources = np.arccos(np.clip(points @ points[[0, far]].T, -1, 1))
    # Each point takes its nearest source's magnitude, the diffused ratio blending them near the bisector.
    error = np.abs(np.linalg.norm(np.asarray(solution.value), axis=1) - np.where(to_sources[:, 0] < to_sources[:, 1], 1.0, 3.0))
    clear = np.abs(to_sources[:, 0] - to_sources[:, 1]) > 2.0
    assert error[[0, far]].max() < 1e-3  # measured 1.4e-4
    assert error[clear].max() < 0.01  # measured 3.5e-3 (0.07 within 1 of the bisector: the heat kernels' overlap)

    great_circle = np.arccos(np.clip(points @ points[5], -1, 1))
    weights = jnp.asarray(np.where((great_circle > 0.3) & (great_circle < 2.0), 1.0, 0.0))
    vector = jnp.asarray(e1[5])
    target = jnp.asarray(np.random.default_rng(1).normal(size=points.shape))

    def loss(p):
        kept = point_cloud_heat_solver(p, triangulation=triangulation)
        log = kept.log_map(5)
        return jnp.sum(weights[:, None] * target * kept.transport(5, vector)) + jnp.sum(weights * log[:, 0] ** 2)

    # Finite differences at step 1e-6 through two heat solves and PCA frames: O(eps^2) truncation on the
    # thin local triangles' cotangents + round-off / eps.
    jax.test_util.check_grads(loss, (jnp.asarray(points),), order=1, modes=("rev",), atol=1e-5, rtol=1e-5, eps=1e-6)


def test_transport_bad_input():
    points = _sphere_samples(50)
    solver = point_cloud_heat_solver(points, n_neighbors=10)
    with pytest.raises(DDGInputError, match="source"):
        solver.transport(50, [1.0, 0.0, 0.0])
    with pytest.raises(DDGInputError, match="vector"):
        solver.transport(0, [1.0, 0.0])
    with pytest.raises(DDGInputError, match="vector"):
        solver.transport([0, 1], [1.0, 0.0, 0.0])
    with pytest.raises(DDGInputError, match="source"):
        solver.log_map([0, 1])
    with pytest.raises(DDGInputError, match="source"):
        solver.log_map(-1)
    with pytest.raises(DDGInputError, match="source"):
        point_cloud_parallel_transport(points, [70], [1.0, 0.0, 0.0])
    with pytest.raises(DDGInputError, match="source"):
        point_cloud_log_map(points, 2.5)


def test_a_solver_for_distances_alone_has_the_same_distances_and_refuses_vector_queries(without_type_checker):
    points = _sphere_samples(200)
    full = point_cloud_heat_solver(points, n_neighbors=10)
    distances_only = point_cloud_heat_solver(points, n_neighbors=10, vector_heat=False)
    assert distances_only.vector_heat is None
    np.testing.assert_allclose(distances_only.distance(3), full.distance(3), rtol=0, atol=1e-14)
    np.testing.assert_allclose(point_cloud_heat_distance(points, 3, n_neighbors=10), full.distance(3), rtol=0, atol=1e-14)
    with pytest.raises(DDGInputError, match="transport needs the vector heat factorisation.*vector_heat=True"):
        distances_only.transport(0, [1.0, 0.0, 0.0])
    with pytest.raises(DDGInputError, match="log_map needs the vector heat factorisation"):
        distances_only.log_map(0)
    with pytest.raises(DDGInputError, match="vector_heat: expected True or False"):
        point_cloud_heat_solver(points, n_neighbors=10, vector_heat="no")


@pytest.mark.slow
def test_transport_and_log_map_two_components():
    sphere = _jittered_icosphere(2)
    points = np.concatenate([sphere, 0.5 * sphere + 5.0])  # two spheres, radii 1 and 0.5
    solver = point_cloud_heat_solver(points, n_neighbors=12)
    normal = np.asarray(solver.tangent_frames.normal)
    # Each part turned outward; PCA normals of 12 neighbours tilt O(h) off the radius.
    assert np.min(np.sum(normal[:162] * sphere, axis=1)) > 0.99
    assert np.min(np.sum(normal[162:] * sphere, axis=1)) > 0.99
    transported = np.asarray(solver.transport(0, solver.tangent_frames.e1[0]))
    assert np.all(transported[162:] == 0)  # no source there
    np.testing.assert_allclose(np.linalg.norm(transported[:162], axis=1), 1, rtol=1e-10)
    log = np.asarray(solver.log_map(170))
    assert np.all(np.isinf(log[:162])) and np.all(np.isfinite(log[162:]))
    # Half the small sphere's circumference plus the heat distance's first-order error: measured 1.52.
    assert np.linalg.norm(log[162:], axis=1).max() < 0.5 * np.pi + 0.1


@pytest.mark.slow
def test_transport_and_log_map_with_points_in_no_triangle():
    grid = np.stack(np.meshgrid(np.linspace(0, 1, 12), np.linspace(0, 1, 12)), axis=-1).reshape(-1, 2)
    plane = np.c_[grid, 0.01 * np.random.default_rng(0).normal(size=len(grid))]
    line = np.c_[np.linspace(5, 8, 20), np.zeros((20, 2))]  # collinear neighbourhoods: in no triangle
    solver = point_cloud_heat_solver(np.concatenate([plane, line]), n_neighbors=8)
    assert solver.heat_plan is not None and solver.heat_plan.fixed.shape == (20,)
    transported = np.asarray(solver.transport(np.array([0, 5]), np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])))
    assert np.all(transported[144:] == 0)
    # Both sources' magnitude 1 less their projection on the tangent planes of the noisy plane's PCA normals
    # (|z| = cos(tilt), tilts ~0.03 rad): measured 4.1e-4.
    np.testing.assert_allclose(np.linalg.norm(transported[:144], axis=1), 1, atol=1e-3)
    log = np.asarray(solver.log_map(0))
    assert np.all(np.isinf(log[144:])) and np.all(np.isfinite(log[:144]))


@pytest.mark.slow
def test_duplicated_points_keep_finite_operators_and_distances():
    """Coincident points (a cloud with five points repeated): the mollified intrinsic Delaunay metric keeps
    L and M finite, and the heat distance reaches every point."""
    points = _jittered_icosphere(3)
    points = np.vstack([points, points[:5]])
    L, M = point_cloud_laplacian(points, n_neighbors=12)
    assert np.all(np.isfinite(np.asarray(L.values))) and np.all(np.isfinite(np.asarray(M.values)))
    distance = point_cloud_heat_distance(points, [0], n_neighbors=12)
    assert np.all(np.isfinite(np.asarray(distance)))
    # The copies are kept apart only by the mollification, 1e-5 of the mean edge length (~1.5e-6): measured 1.4e-6.
    assert np.max(np.abs(np.asarray(distance)[-5:] - np.asarray(distance)[:5])) < 1e-5
