"""ddgjax.pointcloud.point_cloud_laplacian against robust_laplacian 1.1's, entry by entry (`L` and `M`).

robust_laplacian wraps geometry-central; `ddgjax.pointcloud._triangulation` follows its construction
step by step (neighbour ties, normals and their signs, the local walk, the tufted cover's ties, the
flip tolerance), so the two agree to round-off on sampled surfaces, mesh vertices, coplanar points and
grids. The one measured remainder: at duplicated points the flips (rounds here, a queue there) may end
in different Delaunay triangulations of equal `L`, which move mass between the coincident copies.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from ddgjax.pointcloud import point_cloud_laplacian

from conftest import load_data_mesh, unit_icosphere

robust_laplacian = pytest.importorskip("robust_laplacian")


def _surface_samples(name: str, n: int, seed: int) -> np.ndarray:
    """`n` points uniform by area on a stored mesh."""
    mesh = load_data_mesh(name)
    V, F = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    rng = np.random.default_rng(seed)
    areas = np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)
    faces = F[rng.choice(len(F), n, p=areas / areas.sum())]
    u, v = rng.random(n), rng.random(n)
    outside = u + v > 1
    u[outside], v[outside] = 1 - u[outside], 1 - v[outside]
    return V[faces[:, 0]] + u[:, None] * (V[faces[:, 1]] - V[faces[:, 0]]) + v[:, None] * (V[faces[:, 2]] - V[faces[:, 0]])


def _both(points: np.ndarray):
    L, M = point_cloud_laplacian(points)
    L_ref, M_ref = robust_laplacian.point_cloud_laplacian(points, mollify_factor=1e-5, n_neighbors=30)
    return L.to_scipy().tocsr(), M.to_scipy().diagonal(), L_ref.tocsr(), M_ref.diagonal()


def _assert_laplacian_equal(L, L_ref):
    # Entry by entry (a pattern comparison would count co-circular weights, 0 here and 1e-17 there).
    assert abs(L - L_ref).max() <= 1e-10 * abs(L_ref).max()


def _assert_mass_equal(M, M_ref):
    np.testing.assert_allclose(M, M_ref, rtol=1e-10, atol=1e-10 * M_ref.max())


def _jittered_icosphere(level: int, scale: float = 1e-3) -> np.ndarray:
    points = np.asarray(unit_icosphere(level).vertices)
    points = points + scale * np.random.default_rng(0).normal(size=points.shape)
    return points / np.linalg.norm(points, axis=1, keepdims=True)


def test_sampled_surface():
    L, M, L_ref, M_ref = _both(_surface_samples("stanford-bunny.obj", 3000, seed=0))
    _assert_laplacian_equal(L, L_ref)
    _assert_mass_equal(M, M_ref)


def test_jittered_icosphere():
    L, M, L_ref, M_ref = _both(_jittered_icosphere(3))
    _assert_laplacian_equal(L, L_ref)
    _assert_mass_equal(M, M_ref)


def test_mesh_vertices_as_the_cloud(data_mesh):
    # Mesh vertices tie in distance and angle where the mesh is regular: nanoflann's and std::sort's orders.
    points = np.asarray(data_mesh("spot.obj").vertices)
    L, M, L_ref, M_ref = _both(points)
    _assert_laplacian_equal(L, L_ref)
    _assert_mass_equal(M, M_ref)


@pytest.mark.parametrize("tilted", [False, True])
def test_coplanar_points(tilted):
    rng = np.random.default_rng(2)
    flat = rng.random((2000, 2))
    points = flat @ np.array([[1.0, 0.2, -0.5], [0.3, 1.0, 0.7]]) + 2.0 if tilted else np.c_[flat, np.zeros(2000)]
    L, M, L_ref, M_ref = _both(points)
    _assert_laplacian_equal(L, L_ref)
    _assert_mass_equal(M, M_ref)


def test_integer_grid():
    # Every tie at once: equal distances, equal angles, co-circular neighbourhoods, coplanar normals.
    grid = np.stack(np.meshgrid(np.arange(30.0), np.arange(30.0)), axis=-1).reshape(-1, 2)
    L, M, L_ref, M_ref = _both(np.c_[grid, np.zeros(len(grid))])
    _assert_laplacian_equal(L, L_ref)
    _assert_mass_equal(M, M_ref)


def test_duplicated_points():
    samples = _surface_samples("spot.obj", 2000, seed=1)
    points = np.concatenate([samples, samples[:500]])
    L, M, L_ref, M_ref = _both(points)
    _assert_laplacian_equal(L, L_ref)
    # Where the two flip orders end in different Delaunay triangulations (equal L), mass moves between the
    # coincident copies of a point: measured in 30 of 2,500 rows (1.2%, all duplicated points), up to 16%
    # of an entry; the mass of each pair of copies, and every other row, agree to round-off.
    differs = np.abs(M - M_ref) > 1e-10 * M_ref.max()
    assert differs.mean() <= 0.015
    assert np.all(differs[500:2000] == 0)
    pairs = np.r_[np.arange(500), np.arange(2000, 2500)]
    merged = sp.csr_matrix((np.ones(1000), (pairs, np.r_[np.arange(500), np.arange(500)])), shape=(2500, 500))
    np.testing.assert_allclose(merged.T @ M, merged.T @ M_ref, rtol=1e-10)
