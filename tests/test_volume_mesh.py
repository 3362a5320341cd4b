"""Tet meshes as objects: built-in solids (ddgjax.volume._shapes), `TetMesh.from_arrays` / `with_vertices`
checks, `check_tet_mesh`, IO through meshio, and `tetrahedralize` (fTetWild, the optional extra)."""

from __future__ import annotations

import itertools
import sys

import equinox as eqx
import igl
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.sparse.linalg as sla

from ddgjax import DDGInputError
from ddgjax.mesh import grid
from ddgjax.volume import (
    TetMesh,
    check_tet_mesh,
    load_tet_mesh,
    save_tet_mesh,
    tet_ball,
    tet_box,
    tet_shell,
    tet_solid_torus,
    tetrahedralize,
)


def host_signed_volumes(vertices, tets) -> np.ndarray:
    corners = np.asarray(vertices, dtype=np.float64)[np.asarray(tets)]
    return (
        np.einsum(
            "ij,ij->i", corners[:, 1] - corners[:, 0], np.cross(corners[:, 2] - corners[:, 0], corners[:, 3] - corners[:, 0])
        )
        / 6
    )


def host_dihedral_degrees(tet_mesh) -> np.ndarray:
    """Dihedral angles from the outward face normals (independent of ddgjax's edge-length formula)."""
    corners = np.asarray(tet_mesh.vertices)[np.asarray(tet_mesh.tets)]
    normals = []
    for a, b, c in ((1, 2, 3), (0, 3, 2), (0, 1, 3), (0, 2, 1)):
        n = np.cross(corners[:, b] - corners[:, a], corners[:, c] - corners[:, a])
        normals.append(n / np.linalg.norm(n, axis=1, keepdims=True))
    cosines = [np.einsum("ij,ij->i", normals[i], normals[j]) for i, j in itertools.combinations(range(4), 2)]
    return 180.0 - np.degrees(np.arccos(np.clip(cosines, -1, 1)))


def fitted_rate(h, errors) -> float:
    return float(np.polyfit(np.log(h), np.log(errors), 1)[0])


def assert_solid(tet_mesh, *, chi: int, boundary_components: int) -> None:
    """Manifold, connected, every tet positive, boundary closed and outward, counts against NumPy's own."""
    report = check_tet_mesh(tet_mesh)
    assert report.is_clean and report.n_components == 1
    assert (report.euler_characteristic, report.n_boundary_components) == (chi, boundary_components)
    tets = np.asarray(tet_mesh.tets)
    assert (host_signed_volumes(tet_mesh.vertices, tets) > 0).all()
    # Independent counts: distinct sorted vertex pairs and triples of the tets.
    pairs = np.unique(np.sort(tets[:, list(itertools.combinations(range(4), 2))].reshape(-1, 2), axis=1), axis=0)
    triples = np.unique(np.sort(tets[:, list(itertools.combinations(range(4), 3))].reshape(-1, 3), axis=1), axis=0)
    assert (tet_mesh.n_edges, tet_mesh.n_triangles) == (pairs.shape[0], triples.shape[0])
    np.testing.assert_array_equal(np.asarray(tet_mesh.edges), pairs)
    # libigl's boundary facets: the same triangles (its orientation differs, so compare as sets).
    boundary = tet_mesh.boundary_mesh()
    expected = np.unique(np.sort(igl.boundary_facets(tets.astype(np.int64))[0], axis=1), axis=0)
    np.testing.assert_array_equal(np.unique(np.sort(np.asarray(boundary.faces), axis=1), axis=0), expected)
    topology = boundary.topology
    assert topology.is_manifold and topology.is_oriented and not topology.boundary_loops
    corners = np.asarray(boundary.vertices)[np.asarray(boundary.faces)]
    enclosed = np.einsum("ij,ij->", corners[:, 0], np.cross(corners[:, 1], corners[:, 2])) / 6
    np.testing.assert_allclose(enclosed, report.volume, rtol=1e-12)  # outward normals: the same volume


@pytest.mark.parametrize("n", [1, 2, 5])
def test_tet_ball_counts_topology_and_sphere(n):
    ball = tet_ball(n, radius=2.0)
    assert ball.n_tets == 20 * n**3
    assert_solid(ball, chi=1, boundary_components=1)
    boundary = np.asarray(ball.vertices)[check_boundary_vertices(ball)]
    np.testing.assert_allclose(np.linalg.norm(boundary, axis=1), 2.0, rtol=1e-15)
    np.testing.assert_array_equal(np.asarray(ball.vertices)[0], 0.0)  # the centre
    radii = np.linalg.norm(np.asarray(ball.vertices), axis=1)
    np.testing.assert_allclose(np.unique(radii.round(12)), 2.0 * np.arange(n + 1) / n, atol=1e-12)  # n shells
    angles = host_dihedral_degrees(ball)
    assert angles.min() > 37.0 and angles.max() < 130.5  # bounded shapes at every size (no slivers)


def check_boundary_vertices(tet_mesh) -> np.ndarray:
    return np.unique(np.asarray(tet_mesh.boundary_mesh().faces))


def test_tet_ball_is_deterministic_and_takes_dtype():
    a, b = tet_ball(3), tet_ball(3, dtype=jnp.float32)
    np.testing.assert_array_equal(np.asarray(a.tets), np.asarray(tet_ball(3).tets))
    assert b.vertices.dtype == jnp.float32 and a.vertices.dtype == jnp.float64
    np.testing.assert_array_equal(np.asarray(a.tets), np.asarray(b.tets))


def test_tet_ball_volume_and_area_converge_at_second_order():
    ns = np.array([4, 8, 16])
    volume_errors, area_errors = [], []
    for n in ns:
        ball = tet_ball(int(n))
        volume_errors.append(abs(host_signed_volumes(ball.vertices, ball.tets).sum() - 4 / 3 * np.pi))
        corners = np.asarray(ball.vertices)[np.asarray(ball.boundary_mesh().faces)]
        area = 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1).sum()
        area_errors.append(abs(area - 4 * np.pi))
    assert fitted_rate(1 / ns, volume_errors) > 1.9 and fitted_rate(1 / ns, area_errors) > 1.9
    # Inscribed polyhedra: O(h^2) errors at n = 16, measured 0.0091 (volume) and 0.015 (area).
    assert volume_errors[-1] < 0.01 and area_errors[-1] < 0.03


def ball_poisson_and_eigenvalues(n: int) -> tuple[float, float, np.ndarray]:
    """libigl's FEM on tet_ball(n): max and mass-weighted L2 errors of -Delta u = 1 (u = 0 on the sphere)
    against (1 - r^2) / 6, and the first four Dirichlet eigenvalues."""
    ball = tet_ball(n)
    V, T = np.asarray(ball.vertices), np.asarray(ball.tets).astype(np.int64)
    L = -igl.cotmatrix(V, T)
    M = igl.massmatrix(V, T, igl.MASSMATRIX_TYPE_BARYCENTRIC)
    r = np.linalg.norm(V, axis=1)
    inside = np.ones(len(V), dtype=bool)
    inside[check_boundary_vertices(ball)] = False
    L_ii, M_ii = L[inside][:, inside].tocsc(), M[inside][:, inside].tocsc()
    u = np.zeros(len(V))
    u[inside] = sla.spsolve(L_ii, M_ii @ np.ones(inside.sum()))
    error = u - (1 - r**2) / 6
    eigenvalues = np.sort(sla.eigsh(L_ii, k=4, M=M_ii, sigma=0, which="LM")[0])
    return np.abs(error).max(), np.sqrt(error**2 @ M.diagonal()), eigenvalues


def test_tet_ball_poisson_and_spectrum_at_one_size():
    max_error, l2_error, eigenvalues = ball_poisson_and_eigenvalues(8)
    assert max_error < 2.6e-3 and l2_error < 7e-4  # measured 2.50e-3 and 6.67e-4
    # pi^2 and the threefold (j_{3/2,1})^2 = 20.19: O(h^2) discretisation errors 0.13 and 0.4.
    np.testing.assert_allclose(eigenvalues, [np.pi**2, 20.19073, 20.19073, 20.19073], rtol=0.025)


@pytest.mark.slow
def test_tet_ball_poisson_and_spectrum_converge_at_second_order():
    ns = np.array([6, 12, 18])
    results = [ball_poisson_and_eigenvalues(int(n)) for n in ns]
    max_errors, l2_errors = [r[0] for r in results], [r[1] for r in results]
    first = [abs(r[2][0] - np.pi**2) for r in results]
    second = [abs(r[2][1] - 20.190728556) for r in results]
    # Rates measured 2.00 (L2), 1.5 -> 1.7 (max: pre-asymptotic, as the log factor and the radial map's kinks allow).
    assert fitted_rate(1 / ns, l2_errors) > 1.9
    assert fitted_rate(1 / ns, max_errors) > 1.4
    assert fitted_rate(1 / ns, first) > 1.9 and fitted_rate(1 / ns, second) > 1.9


def test_tet_box_is_the_kuhn_subdivision():
    box = tet_box(3, size=2.0)
    assert (box.n_vertices, box.n_tets) == (64, 162)
    assert_solid(box, chi=1, boundary_components=1)
    np.testing.assert_allclose(host_signed_volumes(box.vertices, box.tets), 8.0 / 162, rtol=1e-14)  # all congruent
    np.testing.assert_allclose(np.unique(host_dihedral_degrees(box).round(9)), [45.0, 60.0, 90.0])
    assert np.abs(np.asarray(box.vertices)).max() == 1.0
    uneven = tet_box(2, 3, 4)
    assert (uneven.n_vertices, uneven.n_tets) == (3 * 4 * 5, 6 * 24)
    np.testing.assert_allclose(host_signed_volumes(uneven.vertices, uneven.tets).sum(), 1.0, rtol=1e-14)
    # Vertex (i, j, k) is number (k (ny + 1) + j) (nx + 1) + i.
    np.testing.assert_allclose(np.asarray(uneven.vertices)[(1 * 4 + 2) * 3 + 1], [0.0, 2 / 3 - 0.5, -0.25])


def test_tet_solid_torus_topology_and_surface():
    R, r = 1.0, 0.4
    torus = tet_solid_torus(major_radius=R, minor_radius=r, n_major=24, n_rings=3)
    assert torus.n_tets == 18 * 24 * 9
    assert_solid(torus, chi=0, boundary_components=1)
    assert torus.boundary_mesh().topology.genus == 1
    surface = np.asarray(torus.vertices)[check_boundary_vertices(torus)]
    tube = np.hypot(np.hypot(surface[:, 0], surface[:, 1]) - R, surface[:, 2])
    np.testing.assert_allclose(tube, r, rtol=1e-14)
    # Inscribed polygons in both directions: the volume falls short of 2 pi^2 R r^2 by O(h^2).
    volume = host_signed_volumes(torus.vertices, torus.tets).sum()
    assert 0.95 < volume / (2 * np.pi**2 * R * r**2) < 1.0
    assert host_dihedral_degrees(tet_solid_torus()).min() > 17.0


def test_tet_shell_two_spheres():
    shell = tet_shell(6, inner_radius=0.45, radius=1.5)
    assert_solid(shell, chi=2, boundary_components=2)
    radii = np.linalg.norm(np.asarray(shell.vertices)[check_boundary_vertices(shell)], axis=1)
    inner = radii < 1.0
    np.testing.assert_allclose(radii[inner], 0.45, rtol=1e-14)
    np.testing.assert_allclose(radii[~inner], 1.5, rtol=1e-14)
    assert host_dihedral_degrees(shell).min() > 20.0


@pytest.mark.parametrize(
    ("call", "name"),
    [
        (lambda: tet_ball(0), "n_layers"),
        (lambda: tet_ball(2, radius=-1.0), "radius"),
        (lambda: tet_box(2, 0), "ny"),
        (lambda: tet_box(2.5), "nx"),
        (lambda: tet_shell(1), "n_layers"),
        (lambda: tet_shell(4, inner_radius=1.0), "inner_radius"),
        (lambda: tet_solid_torus(minor_radius=1.5), "minor_radius"),
        (lambda: tet_solid_torus(n_rings=0), "n_rings"),
    ],
)
def test_shapes_refuse_bad_arguments(call, name):
    with pytest.raises(DDGInputError, match=name):
        call()


UNIT_TET = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 1.0, 1.0]])


@pytest.mark.parametrize(
    ("vertices", "tets", "name", "words"),
    [
        (UNIT_TET, np.array([[0, 1, 2]]), "tets", "shape"),
        (UNIT_TET, np.array([[0.0, 1.0, 2.0, 3.0]]), "tets", "integer"),
        (UNIT_TET, np.array([[0, 1, 2, 5]]), "tets", "out-of-range"),
        (UNIT_TET, np.array([[0, 1, 2, -1]]), "tets", "out-of-range"),
        (UNIT_TET, np.array([[0, 1, 2, 3], [0, 1, 1, 4]]), "tets", r"repeat one"),
        (UNIT_TET, np.zeros((0, 4), dtype=np.int32), "tets", "at least one"),
        (np.where(np.arange(15).reshape(5, 3) == 4, np.nan, UNIT_TET), np.array([[0, 1, 2, 3]]), "vertices", "NaN"),
        (UNIT_TET[:, :2], np.array([[0, 1, 2, 3]]), "vertices", ""),
    ],
)
def test_from_arrays_refuses_bad_input(vertices, tets, name, words):
    with pytest.raises(DDGInputError, match=name) as caught:
        TetMesh.from_arrays(vertices, tets)
    assert words in str(caught.value)


def test_from_arrays_orients_negative_tets_and_keeps_degenerate_ones():
    # Tet 0 negative, tet 1 positive, tet 2 flat (four coplanar corners).
    vertices = np.concatenate([UNIT_TET, [[0.5, 0.5, 0.0]]])
    tets = np.array([[0, 2, 1, 3], [1, 2, 3, 4], [0, 1, 2, 5]])
    tet_mesh = TetMesh.from_arrays(vertices, tets)
    np.testing.assert_array_equal(np.asarray(tet_mesh.tets), [[0, 2, 3, 1], [1, 2, 3, 4], [0, 1, 2, 5]])
    volumes = host_signed_volumes(vertices, tet_mesh.tets)
    assert volumes[0] > 0 and volumes[1] > 0 and volumes[2] == 0
    report = check_tet_mesh(tet_mesh)
    np.testing.assert_array_equal(report.degenerate_tets, [2])
    assert report.inverted_tets.size == 0


def test_with_vertices_checks_and_keeps_orientation():
    ball = tet_ball(2)
    with pytest.raises(DDGInputError, match="vertices"):
        ball.with_vertices(np.zeros((ball.n_vertices + 1, 3)))
    with pytest.raises(DDGInputError, match="vertices"):
        ball.with_vertices(np.full((ball.n_vertices, 3), np.nan))
    mirrored = ball.with_vertices(-ball.vertices)  # a point reflection inverts every tet
    report = check_tet_mesh(mirrored)
    assert report.inverted_tets.size == ball.n_tets and not report.is_clean
    np.testing.assert_allclose(report.volume, -check_tet_mesh(ball).volume, rtol=1e-14)
    # Under jit: the same connectivity, no host checks of the values.
    moved = jax.jit(lambda V: ball.with_vertices(2 * V).vertices)(ball.vertices)
    np.testing.assert_allclose(moved, 2 * np.asarray(ball.vertices))


def test_check_report_finds_every_problem():
    vertices = np.concatenate([UNIT_TET, [[0.5, 0.5, 0.0], [0.0, 0.0, -1.0], [5.0, 5.0, 5.0]]])
    tets = np.array(
        [
            [0, 1, 2, 3],  # triangle (0, 1, 2) is shared by three tets, (1, 2, 3) too (with tets 3 and 4)
            [0, 1, 2, 6],
            [0, 1, 2, 5],  # flat
            [1, 2, 3, 4],
            [1, 3, 2, 4],  # the same vertices as tet 3
        ]
    )
    report = check_tet_mesh(TetMesh.from_arrays(vertices, tets))
    assert (report.n_vertices, report.n_tets) == (8, 5)
    triangles = np.asarray(TetMesh.from_arrays(vertices, tets).triangles)
    np.testing.assert_array_equal(triangles[report.nonmanifold_triangles], [[0, 1, 2], [1, 2, 3]])
    np.testing.assert_array_equal(report.degenerate_tets, [2])
    np.testing.assert_array_equal(report.duplicate_tets, [4])
    np.testing.assert_array_equal(report.unreferenced_vertices, [7])
    assert not report.is_manifold and not report.is_clean
    text = str(report)
    assert "non-manifold triangles (3+ tets): [" in text and "degenerate tets" in text and "[2] (1 in all)" in text
    assert "unreferenced vertices: [7] (1 in all)" in text and "inverted tets (negative volume): none" in text
    # Two tets meeting at one vertex: each triangle has at most two tets, but the boundary is pinched there.
    pinched = TetMesh.from_arrays(np.concatenate([UNIT_TET[:4], -UNIT_TET[1:4]]), np.array([[0, 1, 2, 3], [0, 4, 5, 6]]))
    pinched_report = check_tet_mesh(pinched)
    assert pinched_report.nonmanifold_triangles.size == 0 and not pinched_report.is_manifold
    np.testing.assert_array_equal(pinched_report.nonmanifold_boundary_vertices, [0])
    assert pinched_report.n_components == 2
    clean = check_tet_mesh(tet_ball(2))
    assert clean.is_clean and "manifold: yes" in str(clean)


def test_check_volume_tol():
    nearly_flat = TetMesh.from_arrays(np.concatenate([UNIT_TET[:3], [[0.3, 0.3, 1e-9]]]), np.array([[0, 1, 2, 3]]))
    assert check_tet_mesh(nearly_flat).degenerate_tets.size == 0  # relative volume 1.7e-10 > 1e-12
    assert check_tet_mesh(nearly_flat, volume_tol=1e-8).degenerate_tets.size == 1
    for bad in (-1.0, np.nan, np.inf):
        with pytest.raises(DDGInputError, match="volume_tol"):
            check_tet_mesh(nearly_flat, volume_tol=bad)


FORMATS = [".msh", ".vtk", ".vtu", ".mesh", ".meshb", ".ele", ".node"]


@pytest.mark.parametrize("suffix", FORMATS)
def test_io_round_trip_is_exact(tmp_path, suffix):
    # Unreferenced vertex 5 and unsorted tets: both must come back as they were.
    vertices = np.concatenate([np.asarray(tet_ball(1).vertices) * np.pi, [[7.0, 7.0, 7.0]]])
    tet_mesh = TetMesh.from_arrays(vertices, np.asarray(tet_ball(1).tets)[::-1])
    path = tmp_path / f"solid{suffix}"
    save_tet_mesh(path, tet_mesh)
    loaded = load_tet_mesh(path)
    np.testing.assert_array_equal(np.asarray(loaded.vertices), np.asarray(tet_mesh.vertices))
    np.testing.assert_array_equal(np.asarray(loaded.tets), np.asarray(tet_mesh.tets))
    if suffix in (".ele", ".node"):  # TetGen: both files, whichever was named
        assert sorted(p.name for p in tmp_path.iterdir()) == ["solid.ele", "solid.node"]
    else:
        assert [p.name for p in tmp_path.iterdir()] == [path.name]  # no scratch files left behind
    assert load_tet_mesh(path, dtype=jnp.float32).vertices.dtype == jnp.float32


GMSH_22 = """$MeshFormat
2.2 0 8
$EndMeshFormat
$Nodes
6
1 0 0 0
2 1 0 0
3 0 1 0
4 0 0 1
5 1 1 1
6 9 9 9
$EndNodes
$Elements
5
1 15 2 0 1 6
2 2 2 0 1 1 2 3
3 4 2 0 1 1 3 2 4
4 4 2 0 1 2 3 4 5
5 1 2 0 1 1 2
$EndElements
"""


def test_load_gmsh_file_with_other_cells(tmp_path):
    """A gmsh 2.2 file as gmsh writes it: a point, a line and a boundary triangle beside the tets (ignored)."""
    path = tmp_path / "two.msh"
    path.write_text(GMSH_22)
    tet_mesh = load_tet_mesh(path)
    assert (tet_mesh.n_vertices, tet_mesh.n_tets) == (6, 2)
    # Tet 0 is negative in the file, tet 1 positive: kept as written (a mixed file is an inverted solid, not
    # another convention), for check_tet_mesh and the problem layer to report.
    np.testing.assert_array_equal(np.sign(host_signed_volumes(tet_mesh.vertices, tet_mesh.tets)), [-1, 1])
    np.testing.assert_array_equal(check_tet_mesh(tet_mesh).inverted_tets, [0])
    np.testing.assert_array_equal(check_tet_mesh(tet_mesh).unreferenced_vertices, [5])


def test_load_refuses_files_without_tets(tmp_path, icosphere0):
    import meshio

    path = tmp_path / "surface.vtk"
    meshio.write(path, meshio.Mesh(np.asarray(icosphere0.vertices), [("triangle", np.asarray(icosphere0.faces))]))
    with pytest.raises(DDGInputError, match=r"path: .*surface\.vtk.* no tetrahedra .*triangle x 20"):
        load_tet_mesh(path)
    broken = tmp_path / "broken.msh"
    broken.write_text("$MeshFormat\nnonsense\n")
    with pytest.raises(DDGInputError, match=r"path: .*broken\.msh"):
        load_tet_mesh(broken)
    with pytest.raises(DDGInputError, match=r"path: unknown tet mesh format '\.obj'"):
        load_tet_mesh(tmp_path / "x.obj")
    with pytest.raises(FileNotFoundError, match="path"):
        load_tet_mesh(tmp_path / "missing.vtu")


def test_save_refuses_bad_input_and_keeps_the_old_file(tmp_path):
    path = tmp_path / "solid.vtu"
    ball = tet_ball(1)
    save_tet_mesh(path, ball)
    before = path.read_bytes()
    with pytest.raises(DDGInputError, match="tet_mesh: 1 of its"):
        # with_vertices refuses inf; a blown-up flow under jit or eqx.tree_at can carry it.
        save_tet_mesh(path, eqx.tree_at(lambda m: m.vertices, ball, ball.vertices.at[3, 0].set(jnp.inf)))
    with pytest.raises(DDGInputError, match=r"path: unknown tet mesh format '\.stl'"):
        save_tet_mesh(tmp_path / "solid.stl", ball)
    assert path.read_bytes() == before and [p.name for p in tmp_path.iterdir()] == ["solid.vtu"]


def test_tetrahedralize_refuses_open_meshes_and_says_which_extra(monkeypatch, icosphere1):
    with pytest.raises(DDGInputError, match="mesh: expected a closed surface"):
        tetrahedralize(grid(2, 2))
    with pytest.raises(DDGInputError, match="edge_length"):
        tetrahedralize(icosphere1, edge_length=0.0)
    monkeypatch.setitem(sys.modules, "pytetwild", None)  # as if it were not installed
    with pytest.raises(DDGInputError, match=r"ddgjax\[tetmesh\]"):
        tetrahedralize(icosphere1)


def test_tetrahedralize_fills_a_sphere_and_a_torus(icosphere2):
    pytest.importorskip("pytetwild")
    sphere = icosphere2
    ball = tetrahedralize(sphere, edge_length=0.25)
    assert_solid(ball, chi=1, boundary_components=1)
    # The boundary lies within the envelope (1e-3 of the bounding-box diagonal, 2 sqrt(3)) of the sphere.
    radii = np.linalg.norm(np.asarray(ball.vertices)[check_boundary_vertices(ball)], axis=1)
    assert np.abs(radii - 1).max() < 0.08  # the icosphere's faces lie up to 0.05 inside the unit sphere
    corners = np.asarray(sphere.vertices)[np.asarray(sphere.faces)]
    enclosed = np.einsum("ij,ij->", corners[:, 0], np.cross(corners[:, 1], corners[:, 2])) / 6
    # The envelope: radii within 3.5e-3 of the sphere's, three times that in volume.
    np.testing.assert_allclose(check_tet_mesh(ball).volume, enclosed, rtol=1e-2)
    solid_torus = tetrahedralize(tet_solid_torus(n_major=24, n_rings=2).boundary_mesh())
    assert check_tet_mesh(solid_torus).euler_characteristic == 0
