"""Tests for ddgjax.volume's DEC: d0, d1, d2, the Hodge stars on the three duals, vertex dual volumes against
libigl's Voronoi mass, Betti numbers from the Hodge Laplacians, gradient / divergence, derivatives, flat tets."""

from __future__ import annotations

import functools
import itertools

import igl
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.sparse
import scipy.spatial
from jax.test_util import check_grads

from ddgjax import DDGInputError, volume

from tet_meshes import jittered_grid_tets

jax.config.update("jax_enable_x64", True)


def kuhn_tets(cells: np.ndarray) -> volume.TetMesh:
    """The six Kuhn tets (paths along the main diagonal) of each selected unit cell of a grid, conforming, no unused vertices."""
    shape = np.array(cells.shape) + 1
    tets = []
    for corner in np.argwhere(cells):
        for order in itertools.permutations(range(3)):
            path = [corner.copy()]
            for axis in order:
                path.append(path[-1] + np.eye(3, dtype=int)[axis])
            tets.append([np.ravel_multi_index(p, shape) for p in path])
    tets = np.array(tets)
    used, tets = np.unique(tets, return_inverse=True)
    points = np.stack(np.unravel_index(used, shape), axis=1).astype(float)
    return volume.TetMesh.from_arrays(points, tets.reshape(-1, 4))


def cell_centres(n: tuple[int, int, int]) -> np.ndarray:
    """`(*n, 3)` centres of the unit cells of an `n` grid, centred on the origin."""
    axes = [np.arange(k) + 0.5 - k / 2 for k in n]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)


@functools.cache
def solids() -> dict[str, tuple[volume.TetMesh, tuple[int, int, int, int]]]:
    """Small Kuhn solids and their Betti numbers: a ball, a solid torus (cells whose centre lies in the torus), a hollow cube."""
    ball = np.linalg.norm(cell_centres((4, 4, 4)), axis=-1) < 1.8
    c = cell_centres((8, 8, 2))
    torus = (np.hypot(c[..., 0], c[..., 1]) - 2.5) ** 2 + c[..., 2] ** 2 < 1.0
    shell = np.abs(cell_centres((4, 4, 4))).max(axis=-1) > 1.0
    return {
        "ball": (kuhn_tets(ball), (1, 0, 0, 0)),
        "solid torus": (kuhn_tets(torus), (1, 1, 0, 0)),
        "hollow cube": (kuhn_tets(shell), (1, 0, 1, 0)),
    }


@pytest.fixture(scope="module")
def tet_mesh() -> volume.TetMesh:
    return jittered_grid_tets()


def host(tet_mesh):
    return np.asarray(tet_mesh.vertices), np.asarray(tet_mesh.tets).astype(np.int64)


def five_tet_cube(seed: int = 2) -> volume.TetMesh:
    """The five-tet split of a unit cube, moved a little: well-shaped tets, so central differences are accurate."""
    cube = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], dtype=float)
    cube = cube + 0.05 * np.random.default_rng(seed).uniform(-1, 1, size=cube.shape)
    return volume.TetMesh.from_arrays(cube, np.array([[0, 1, 2, 4], [3, 1, 2, 7], [5, 1, 4, 7], [6, 2, 4, 7], [1, 2, 4, 7]]))


def test_exterior_derivatives_compose_to_zero(tet_mesh):
    torus, _ = solids()["solid torus"]
    for mesh in (tet_mesh, torus):
        D0, D1, D2 = (d(mesh).to_scipy() for d in (volume.d0, volume.d1, volume.d2))
        assert D0.shape == (mesh.n_edges, mesh.n_vertices)
        assert D1.shape == (mesh.n_triangles, mesh.n_edges)
        assert D2.shape == (mesh.n_tets, mesh.n_triangles)
        assert abs(D1 @ D0).max() == 0.0 and abs(D2 @ D1).max() == 0.0
        assert (abs(D1).sum(axis=1) == 3).all() and (abs(D2).sum(axis=1) == 4).all()
    # One positive tet: d2 is its outward boundary; d1 of triangle (0, 1, 2) runs 0 -> 1 -> 2.
    single = volume.TetMesh.from_arrays(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]]), np.array([[0, 1, 2, 3]]))
    np.testing.assert_array_equal(np.asarray(volume.d1(single).todense())[0], [1, -1, 0, 1, 0, 0])  # edges 01, 02, 03, 12, ...
    flux = np.asarray(volume.d2(single).todense())[0]  # triangles 012, 013, 023, 123
    # Outward normals: 012 runs clockwise seen from outside (-z), 013 counterclockwise from -y, 023 clockwise from -x.
    np.testing.assert_array_equal(flux, [-1, 1, -1, 1])


def test_d0_star1_d0_is_the_cotan_laplacian(tet_mesh):
    V, T = host(tet_mesh)
    D0 = volume.d0(tet_mesh).to_scipy()
    L = volume.cotan_laplacian(tet_mesh).to_scipy()
    for dual in ("voronoi", "circumcentric"):
        star = scipy.sparse.diags(np.asarray(volume.hodge_star_entries(tet_mesh, degree=1, dual=dual)))
        # The same sums of the same weights: equal on CPU; a GPU may add them in another order.
        assert abs(D0.T @ star @ D0 - L).max() <= 1e-14 * abs(L).max()
    reference = -igl.cotmatrix(V, T)
    star = volume.hodge1(tet_mesh).to_scipy()
    # libigl's cotangents go through face areas and arccos: ~1e-9 of the largest entry on this mesh's slivers.
    assert abs(D0.T @ star @ D0 - reference).max() < 1e-9 * abs(reference).max()


def test_voronoi_volumes_equal_libigl_voronoi_mass(tet_mesh):
    V, T = host(tet_mesh)
    reference = igl.massmatrix(V, T, igl.MASSMATRIX_TYPE_VORONOI).diagonal()
    assert np.count_nonzero(np.asarray(volume.tet_volumes(tet_mesh))) == tet_mesh.n_tets
    dual = np.asarray(volume.vertex_dual_volumes(tet_mesh))
    mass = volume.mass_matrix(tet_mesh, mass="voronoi")
    assert np.abs(dual - reference).max() < 1e-13 * reference.max()
    assert abs(mass.to_scipy() - scipy.sparse.diags(reference)).max() < 1e-13 * reference.max()
    # Most tet circumcentres (526 of 685) and many triangle circumcentres (1056 of 2740) of this mesh snap.


@pytest.mark.parametrize("dual", volume.TET_DUALS)
def test_dual_volumes_sum_to_the_volume(tet_mesh, dual):
    volumes = volume.tet_volumes(tet_mesh)
    dual_volumes = np.asarray(volume.vertex_dual_volumes(tet_mesh, dual=dual))
    # The circumcentric cells of slivers are large and of both signs: their sum cancels to ~1e-13 of their sizes.
    assert abs(dual_volumes.sum() - float(jnp.sum(volumes))) < 1e-13 * np.abs(dual_volumes).sum()
    # The intrinsic core: each tet's four shares sum to its volume, with the lengths' own volumes too.
    lengths_sq = volume.tet_edge_lengths_sq(tet_mesh)
    shares = jax.jit(functools.partial(volume.tet_vertex_dual_volumes_from_lengths_sq, dual=dual))(lengths_sq)
    # The circumcentric shares of slivers are large and cancel: relative to the largest share.
    scale = float(jnp.abs(shares).max())
    np.testing.assert_allclose(
        jnp.sum(shares, axis=1), volume.tet_volumes_from_lengths_sq(lengths_sq), rtol=0, atol=1e-12 * scale
    )
    if dual != "circumcentric":
        assert dual_volumes.min() > 0


def test_circumcentric_equals_voronoi_where_circumcentres_lie_in_the_tets():
    # Kuhn tets have their circumcentre at the cube's centre, the midpoint of their long edge: no snapping changes it.
    cube, _ = solids()["hollow cube"]
    voronoi = np.asarray(volume.vertex_dual_volumes(cube))
    np.testing.assert_allclose(volume.vertex_dual_volumes(cube, dual="circumcentric"), voronoi, rtol=0, atol=1e-14)
    V, T = host(cube)
    np.testing.assert_allclose(voronoi, igl.massmatrix(V, T, igl.MASSMATRIX_TYPE_VORONOI).diagonal(), rtol=0, atol=1e-14)
    # One Kuhn tet (volume 1/6): the circumcentric cells by hand are 1/48, 1/16, 1/16, 1/48 (the cotan split
    # sum_j l_ij^2 w_ij / 6 = V (1 - beta_i) / 3 would give 1/36, 1/18, 1/18, 1/36: not the circumcentric dual in 3-D).
    kuhn = volume.TetMesh.from_arrays(np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [1, 1, 1.0]]), np.array([[0, 1, 2, 3]]))
    expected = np.array([1, 3, 3, 1]) / 48.0
    for dual in ("voronoi", "circumcentric"):
        np.testing.assert_allclose(volume.vertex_dual_volumes(kuhn, dual=dual), expected, rtol=1e-14)
    # A regular tet: every dual gives a quarter of it to each vertex.
    regular = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1.0]])
    single = volume.TetMesh.from_arrays(regular, np.array([[0, 1, 2, 3]]))
    for dual in volume.TET_DUALS:
        np.testing.assert_allclose(volume.vertex_dual_volumes(single, dual=dual), np.full(4, 8.0 / 12.0), rtol=1e-14)


def test_circumcentric_cells_and_star2_against_explicit_circumcentres():
    mesh = jittered_grid_tets(n=3, jitter=0.2, seed=4)
    V, T = host(mesh)
    triangles = np.asarray(mesh.triangles)

    def circumcentre(points):
        # |c - p_0|^2 = |c - p_k|^2 in the simplex's affine hull: c = p_0 + E x with 2 E^T E x = diag(E^T E).
        edges = (points[1:] - points[0]).T
        gram = edges.T @ edges
        return points[0] + edges @ np.linalg.solve(2 * gram, np.diag(gram))

    def signed_volume(a, b, c, d):
        return np.linalg.det(np.stack([b - a, c - a, d - a])) / 6.0

    dual_lengths = np.zeros(len(triangles))
    barycentric_lengths = np.zeros(len(triangles))
    cells = np.zeros(len(V))
    for tet in T:
        centre = circumcentre(V[tet])
        # Vertex j's cell: the pieces (p_j, m_ja, c_face, c_tet) over the two triangles at edge ja, oriented as the
        # same piece with centroids (always positive), so that a centre outside the tet gives a negative piece.
        for j, a in itertools.permutations(range(4), 2):
            p, m = V[tet[j]], 0.5 * (V[tet[j]] + V[tet[a]])
            for b in set(range(4)) - {j, a}:
                face = np.delete(tet, b)
                orientation = np.sign(signed_volume(p, m, V[face].mean(axis=0), V[tet].mean(axis=0)))
                cells[tet[j]] += orientation * signed_volume(p, m, circumcentre(V[face]), centre)
        for k in range(4):
            face = np.delete(tet, k)
            index = np.flatnonzero((triangles == np.sort(face)).all(axis=1))[0]
            face_centre = circumcentre(V[face])
            normal = np.cross(V[face[1]] - V[face[0]], V[face[2]] - V[face[0]])
            towards_tet = np.sign(normal @ (V[tet[k]] - V[face[0]]))
            dual_lengths[index] += towards_tet * normal @ (centre - face_centre) / np.linalg.norm(normal)
            barycentric_lengths[index] += np.linalg.norm(V[tet].mean(axis=0) - V[face].mean(axis=0))
    np.testing.assert_allclose(volume.vertex_dual_volumes(mesh, dual="circumcentric"), cells, rtol=1e-10)
    areas = np.asarray(volume.triangle_areas(mesh))
    for dual in ("voronoi", "circumcentric"):
        np.testing.assert_allclose(volume.hodge_star_entries(mesh, degree=2, dual=dual), dual_lengths / areas, rtol=1e-10)
    np.testing.assert_allclose(
        volume.hodge_star_entries(mesh, degree=2, dual="barycentric"), barycentric_lengths / areas, rtol=1e-12
    )


def test_star1_barycentric_against_a_loop():
    mesh = five_tet_cube()
    V, T = host(mesh)
    edges = np.asarray(mesh.edges)
    areas = np.zeros(len(edges))
    for tet in T:
        centroid = V[tet].mean(axis=0)
        for a, b in itertools.combinations(range(4), 2):
            index = np.flatnonzero((edges == np.sort([tet[a], tet[b]])).all(axis=1))[0]
            midpoint = 0.5 * (V[tet[a]] + V[tet[b]])
            for c in set(range(4)) - {a, b}:
                face_centroid = V[np.delete(tet, c)].mean(axis=0)
                areas[index] += 0.5 * np.linalg.norm(np.cross(face_centroid - midpoint, centroid - midpoint))
    lengths = np.linalg.norm(V[edges[:, 1]] - V[edges[:, 0]], axis=1)
    np.testing.assert_allclose(volume.hodge1(mesh, dual="barycentric").diagonal(), areas / lengths, rtol=1e-13)
    np.testing.assert_allclose(volume.hodge3(mesh).diagonal(), 1.0 / np.abs(igl.volume(V, T)), rtol=1e-13)


def test_inverse_stars_invert_nonzero_entries_and_keep_zeros():
    cube, _ = solids()["ball"]
    star = np.asarray(volume.hodge_star_entries(cube, degree=1, dual="circumcentric"))
    inverse = np.asarray(volume.hodge_star_entries(cube, degree=1, dual="circumcentric", inverse=True))
    zero = star == 0
    assert zero.any()  # the face diagonals of a Kuhn grid: opposite right dihedral angles
    np.testing.assert_array_equal(inverse[zero], 0.0)
    np.testing.assert_allclose(inverse[~zero] * star[~zero], 1.0, rtol=1e-14)
    np.testing.assert_allclose(volume.hodge3(cube, inverse=True).diagonal(), volume.tet_volumes(cube), rtol=1e-15)


@pytest.mark.parametrize(
    "name", [pytest.param("ball", marks=pytest.mark.slow), "solid torus", pytest.param("hollow cube", marks=pytest.mark.slow)]
)
def test_betti_numbers_from_the_hodge_laplacians(name):
    mesh, betti = solids()[name]
    assert mesh.topology.euler_characteristic == betti[0] - betti[1] + betti[2] - betti[3]
    sizes = (mesh.n_vertices, mesh.n_edges, mesh.n_triangles, mesh.n_tets)

    @jax.jit
    def laplacians(vertices):
        moved = mesh.with_vertices(vertices)
        return [volume.hodge_laplacian(moved, jnp.eye(n), degree=k, dual="barycentric", weak=True) for k, n in enumerate(sizes)]

    kernels = []
    for matrix in laplacians(mesh.vertices):
        matrix = np.asarray(matrix)
        assert np.abs(matrix - matrix.T).max() < 1e-12 * np.abs(matrix).max()
        eigenvalues = np.linalg.eigvalsh(matrix)
        assert eigenvalues.min() > -1e-12 * eigenvalues.max()  # positive stars: PSD
        kernels.append(int(np.sum(eigenvalues < 1e-9 * eigenvalues.max())))
    assert tuple(kernels) == betti


@pytest.mark.slow
def test_hodge_laplacian_and_codifferential_conventions(tet_mesh):
    u = jnp.asarray(np.random.default_rng(5).normal(size=tet_mesh.n_vertices))
    Lu = volume.cotan_laplacian(tet_mesh) @ u
    star0 = volume.vertex_dual_volumes(tet_mesh)
    np.testing.assert_allclose(
        volume.hodge_laplacian(tet_mesh, u, degree=0, weak=True), Lu, rtol=0, atol=1e-12 * jnp.abs(Lu).max()
    )
    np.testing.assert_allclose(volume.hodge_laplacian(tet_mesh, u, degree=0), Lu / star0, rtol=1e-10)
    np.testing.assert_allclose(volume.codifferential(tet_mesh, volume.d0(tet_mesh) @ u, degree=1), Lu / star0, rtol=1e-10)
    # Top degree: Delta_3 = d2 delta_3 only; the weak form is symmetric.
    mesh = five_tet_cube()
    M = np.asarray(volume.hodge_laplacian(mesh, jnp.eye(mesh.n_tets), degree=3, weak=True))
    np.testing.assert_allclose(M, M.T, rtol=0, atol=1e-12 * np.abs(M).max())


def test_gradient_and_divergence(tet_mesh):
    V, T = host(tet_mesh)
    linear = V @ np.array([1.0, -2.0, 0.5]) + 3.0
    np.testing.assert_allclose(
        volume.gradient(tet_mesh, linear), np.broadcast_to([1.0, -2.0, 0.5], (tet_mesh.n_tets, 3)), atol=1e-12
    )
    u = np.random.default_rng(6).normal(size=tet_mesh.n_vertices)
    grad = volume.gradient(tet_mesh, u)
    G = igl.grad(V, T)
    np.testing.assert_allclose(grad, (G @ u).reshape(3, -1).T, rtol=0, atol=1e-11 * np.abs(grad).max())
    Lu = np.asarray(volume.cotan_laplacian(tet_mesh) @ jnp.asarray(u))
    div = np.asarray(volume.divergence(tet_mesh, grad))
    np.testing.assert_allclose(div, -Lu, rtol=0, atol=1e-12 * np.abs(Lu).max())
    field = np.random.default_rng(7).normal(size=(tet_mesh.n_tets, 3))
    weighted = (np.abs(igl.volume(V, T))[:, None] * field).T.reshape(-1)
    np.testing.assert_allclose(volume.divergence(tet_mesh, field), -G.T @ weighted, rtol=0, atol=1e-11)
    # An outward field x has positive divergence inside: 3 times the dual volume at interior vertices.
    outward = volume.divergence(tet_mesh, np.asarray(jnp.mean(volume.tet_corner_positions(tet_mesh), axis=1)))
    interior = np.setdiff1d(np.arange(tet_mesh.n_vertices), tet_mesh.topology.boundary_vertices)
    np.testing.assert_allclose(
        np.asarray(outward)[interior],
        3.0 * np.asarray(volume.vertex_dual_volumes(tet_mesh, dual="barycentric"))[interior],
        rtol=1e-10,
    )


FLAT_POINTS = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0.3, 0.3, 0.0], [0.2, 0.2, 1.0]])
FLAT_TETS = np.array([[0, 1, 2, 3], [0, 1, 2, 4]])  # tet 0 is flat


def _all_stars(mesh: volume.TetMesh, field: jax.Array):
    """Every star of every dual (and two inverses) and the divergence of `field`, as one jitted function of the positions."""

    @jax.jit  # one compilation for both tests on this connectivity (and one of its derivative)
    def stars(V):
        moved = mesh.with_vertices(V)
        entries = [volume.hodge_star_entries(moved, degree=k, dual=dual) for dual in volume.TET_DUALS for k in range(3)]
        inverses = [volume.hodge_star_entries(moved, degree=k, inverse=True) for k in (1, 3)]
        return jnp.concatenate([*entries, *inverses, volume.hodge_star_entries(moved, degree=3), volume.divergence(moved, field)])

    return stars


@functools.cache
def two_tet_stars():
    mesh = volume.TetMesh.from_arrays(FLAT_POINTS, FLAT_TETS)
    return mesh, _all_stars(mesh, jnp.asarray(np.random.default_rng(8).normal(size=(2, 3))))


@pytest.mark.slow
def test_flat_tets_keep_values_and_gradients_finite():
    mesh, stars = two_tet_stars()
    values, pullback = jax.vjp(stars, mesh.vertices)
    assert np.isfinite(np.asarray(values)).all()
    per_dual = mesh.n_vertices + mesh.n_edges + mesh.n_triangles
    for i in range(len(volume.TET_DUALS)):  # each *0 still sums to the volume
        star0 = values[i * per_dual : i * per_dual + mesh.n_vertices]
        np.testing.assert_allclose(jnp.sum(star0), jnp.sum(volume.tet_volumes(mesh)), rtol=1e-14)
    assert np.isfinite(np.asarray(pullback(jnp.ones_like(values))[0])).all()


@pytest.mark.slow
def test_derivatives_in_the_vertex_positions_match_finite_differences():
    mesh, stars = two_tet_stars()
    lifted = FLAT_POINTS + np.array([[0, 0, 0], [0, 0, 0.1], [0, 0, -0.1], [0, 0, -0.8], [0, 0, 0]])  # tet 0 below face 012
    check_grads(stars, (jnp.asarray(lifted),), order=1, modes=("rev",), eps=1e-6)


@pytest.mark.slow
def test_derivatives_on_a_cube_match_finite_differences_in_both_modes():
    mesh = five_tet_cube()
    stars = _all_stars(mesh, jnp.asarray(np.random.default_rng(9).normal(size=(mesh.n_tets, 3))))
    check_grads(stars, (mesh.vertices,), order=1, modes=("fwd", "rev"), eps=1e-6)


def test_bad_arguments_name_themselves(tet_mesh, without_type_checker):
    with pytest.raises(DDGInputError, match="dual"):
        volume.vertex_dual_volumes(tet_mesh, dual="mixed")
    with pytest.raises(DDGInputError, match="degree"):
        volume.hodge_star_entries(tet_mesh, degree=4)
    with pytest.raises(DDGInputError, match="form"):
        volume.hodge_laplacian(tet_mesh, jnp.ones(3), degree=1)
    with pytest.raises(DDGInputError, match="degree"):
        volume.codifferential(tet_mesh, jnp.ones(tet_mesh.n_vertices), degree=0)
    with pytest.raises(DDGInputError, match="field"):
        volume.divergence(tet_mesh, jnp.ones((tet_mesh.n_tets, 2)))
    with pytest.raises(DDGInputError, match="u"):
        volume.gradient(tet_mesh, jnp.ones(3))
    with pytest.raises(DDGInputError, match="tet_mesh"):
        volume.d2((tet_mesh.vertices, tet_mesh.tets))
