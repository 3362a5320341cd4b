"""Mesh construction checks, `check_mesh` reports and the `ddgjax info` command."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ddgjax import DDGInputError, MeshDataError
from ddgjax.cli import main
from ddgjax.mesh import Mesh, check_mesh, face_areas
from ddgjax.mesh.internal import default_area_tol

from conftest import data_path

TET_V = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
TET_F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])


# ---------------------------------------------------------------- construction refuses bad input


@pytest.mark.parametrize(
    "vertices, faces, message",
    [
        (TET_V[:, :2], TET_F, r"vertices: expected shape \(n, 3\), got \(4, 2\)"),
        (TET_V.astype(complex), TET_F, "vertices: expected a real floating-point array, got dtype complex128"),
        (np.where(np.arange(12).reshape(4, 3) == 7, np.nan, TET_V), TET_F, r"NaN/inf at rows \[2\]"),
        (np.where(np.arange(12).reshape(4, 3) == 0, np.inf, TET_V), TET_F, r"NaN/inf at rows \[0\]"),
        (np.zeros((0, 3)), TET_F, "vertices: expected at least 1 rows, got 0"),
        (TET_V, np.zeros((0, 3), dtype=int), "faces: expected at least one face"),
        (TET_V, TET_F[:, :2], r"faces: expected shape \(nf, 3\)"),
        (TET_V, TET_F + 0.5, "faces: expected an integer array"),
        # Whole-number floats too: a float face array is a mix-up, not a valid index list.
        (TET_V, TET_F.astype(np.float64), r"faces: expected an integer array of vertex indices .*got dtype float64"),
        (TET_V, TET_F.astype(np.float32), "got dtype float32"),
        (TET_V, TET_F.astype(bool), "got dtype bool"),
        (TET_V, np.where(TET_F == 3, 4, TET_F), r"must lie in \[0, 4\), got out-of-range entries in faces \[1, 2, 3\]"),
        (TET_V, np.where(TET_F == 3, -1, TET_F), r"out-of-range entries in faces \[1, 2, 3\]"),
        (TET_V, np.array([[0, 1, 2], [1, 1, 3]]), r"three distinct vertices; faces \[1\] \(1 in all\) repeat one"),
    ],
)
def test_construction_refuses_bad_input(vertices, faces, message):
    with pytest.raises(DDGInputError, match=message):
        Mesh.from_arrays(vertices, faces)


@settings(max_examples=60, deadline=None)
@given(
    n_vertices=st.integers(3, 12),
    faces=st.lists(st.tuples(st.integers(-3, 15), st.integers(-3, 15), st.integers(-3, 15)), min_size=1, max_size=12),
)
def test_construction_accepts_exactly_the_valid_face_lists(n_vertices, faces):
    """Property: a face list is accepted iff every index is in range and no face repeats a vertex;
    otherwise the error names the first offending face."""
    F = np.array(faces)
    in_range = (F >= 0) & (n_vertices > F)
    distinct = (F[:, 0] != F[:, 1]) & (F[:, 1] != F[:, 2]) & (F[:, 0] != F[:, 2])
    vertices = np.random.default_rng(n_vertices).normal(size=(n_vertices, 3))
    if in_range.all() and distinct.all():
        topology = Mesh.from_arrays(vertices, F).topology
        # Structural invariants of any triangle soup: 3F = sum of edge face counts; edges low < high.
        assert 3 * F.shape[0] == int(topology.edge_face_counts.sum())
        assert np.all(topology.edges[:, 0] < topology.edges[:, 1])
        assert topology.unreferenced_vertices.size == n_vertices - np.unique(F).size
    else:
        first_bad = int(np.flatnonzero(~in_range.all(axis=1) if not in_range.all() else ~distinct)[0])
        with pytest.raises(DDGInputError, match=rf"faces \[{first_bad}[,\]]"):
            Mesh.from_arrays(vertices, F)


@pytest.mark.parametrize(
    "vertices, message",
    [
        (np.zeros((5, 3)), r"vertices: expected shape \(4, 3\), got \(5, 3\)"),
        (np.zeros((4, 2)), r"vertices: expected shape \(4, 3\), got \(4, 2\)"),
        (np.zeros(12), r"vertices: expected shape \(4, 3\), got \(12,\)"),
        (
            np.where(np.arange(12).reshape(4, 3) == 4, np.nan, TET_V),
            r"vertices: expected finite coordinates, got NaN/inf at rows \[1\]",
        ),
        (jnp.asarray(TET_V).at[3, 2].set(-jnp.inf), r"NaN/inf at rows \[3\]"),
        (TET_V.astype(complex), "vertices: expected a real floating-point array, got dtype complex128"),
    ],
)
def test_with_vertices_refuses_bad_concrete_vertices(vertices, message):
    mesh = Mesh.from_arrays(TET_V, TET_F)
    with pytest.raises(DDGInputError, match=message):
        mesh.with_vertices(vertices)


def test_with_vertices_passes_traced_vertices_through():
    """Inside jit / grad the values cannot be checked on the host (shapes are); they pass through
    unchanged (a NaN included), and the mesh works as usual."""
    mesh = Mesh.from_arrays(TET_V, TET_F)
    moved = jax.jit(lambda V: mesh.with_vertices(V).vertices)(jnp.asarray(TET_V).at[0, 0].set(jnp.nan))
    assert np.isnan(np.asarray(moved)[0, 0])
    gradient = jax.grad(lambda V: jnp.sum(face_areas(mesh.with_vertices(V))))(jnp.asarray(TET_V))
    assert gradient.shape == (4, 3) and np.all(np.isfinite(np.asarray(gradient)))
    # Integer positions become floats, as in Mesh.from_arrays.
    assert jnp.issubdtype(mesh.with_vertices(TET_V.astype(int)).vertices.dtype, jnp.floating)


def test_operators_needing_a_manifold_refuse_clearly(data_mesh):
    topology = data_mesh("triple_vierbein.obj").topology
    with pytest.raises(MeshDataError, match=r"my operator needs an edge-manifold mesh; edges \["):
        topology.require_manifold("my operator")
    moebius = data_mesh("moebius.obj").topology
    with pytest.raises(MeshDataError, match="consistently oriented"):
        moebius.require_oriented("d1")


# ---------------------------------------------------------------- check_mesh


def test_check_mesh_on_clean_and_problem_meshes(data_mesh):
    clean = check_mesh(Mesh.from_arrays(TET_V, TET_F))
    assert clean.is_clean and clean.is_closed and clean.genus == 0 and clean.euler_characteristic == 2
    assert "Euler characteristic 2  genus 0" in str(clean)

    hourglass = check_mesh(data_mesh("hourglass_ico.obj"))
    assert hourglass.nonmanifold_vertices.tolist() == [22] and not hourglass.is_manifold and hourglass.genus is None
    assert "non-manifold vertices (2+ fans): [22] (1 in all)" in str(hourglass)
    assert "non-manifold edges (3+ faces): none" in str(hourglass)

    vierbein = check_mesh(data_mesh("triple_vierbein.obj"))
    assert vierbein.nonmanifold_edges.size == 20 and not vierbein.is_oriented

    moebius = check_mesh(data_mesh("moebius.obj"))
    assert moebius.is_manifold and not moebius.is_oriented and moebius.boundary_loop_lengths == (112,)

    bunny = check_mesh(data_mesh("stanford-bunny.obj"))
    assert bunny.unreferenced_vertices.size == 1113 and bunny.n_boundary_loops == 5
    assert bunny.duplicate_faces.size == 0
    assert "unreferenced vertices: [8, 16, 18, 72, 86, 99, 104, 117, 157, 177], ... (1113 in all)" in str(bunny)
    assert "boundary loops: 5 (vertices per loop: [22, 42, 39, 40, 80])" in str(bunny)


def test_check_mesh_names_duplicate_faces(data_mesh):
    """A face whose three vertices repeat an earlier face's, in any order or orientation, is named as a
    duplicate (the later copies), not only through the non-manifold edges it creates."""
    assert check_mesh(Mesh.from_arrays(TET_V, TET_F)).duplicate_faces.size == 0
    # Face 1 again as it is, reversed, and rotated (same orientation, other starting corner).
    copies = np.vstack([TET_F, TET_F[1], TET_F[1, ::-1], TET_F[1, [1, 2, 0]]])
    report = check_mesh(Mesh.from_arrays(TET_V, copies))
    assert report.duplicate_faces.tolist() == [4, 5, 6] and not report.is_clean
    assert "duplicate faces (same three vertices as an earlier face): [4, 5, 6] (3 in all)" in str(report)
    # A copy placed first: the later face (here the original, index 1) is the one listed.
    first = np.vstack([TET_F[1, ::-1], TET_F])
    assert check_mesh(Mesh.from_arrays(TET_V, first)).duplicate_faces.tolist() == [2]
    # A triangle and its reversed copy: a closed, oriented, manifold "pillow" that no edge check
    # flags; only the duplicate test makes it unclean.
    pillow = check_mesh(Mesh.from_arrays(TET_V[:3], np.array([[0, 1, 2], [0, 2, 1]])))
    assert pillow.duplicate_faces.tolist() == [1] and not pillow.is_clean

    # Real meshes: none of tests/data/meshes has duplicate faces (checked for all 20); triple_vierbein's
    # 20 non-manifold edges come from distinct faces. bob with one face appended reversed names it.
    vierbein = check_mesh(data_mesh("triple_vierbein.obj"))
    assert vierbein.nonmanifold_edges.size == 20 and vierbein.duplicate_faces.size == 0
    assert "duplicate faces (same three vertices as an earlier face): none" in str(vierbein)
    bob = data_mesh("bob_small.ply")
    faces = np.asarray(bob.faces)
    doubled = check_mesh(Mesh.from_arrays(np.asarray(bob.vertices), np.vstack([faces, faces[7, ::-1]])))
    assert doubled.duplicate_faces.tolist() == [faces.shape[0]] and check_mesh(bob).is_clean


def test_check_mesh_finds_zero_area_faces_at_current_positions(icosphere0):
    sphere = icosphere0
    assert check_mesh(sphere).zero_area_faces.size == 0
    V = np.asarray(sphere.vertices).copy()
    V[11] = V[0]  # faces 0 and 4 collapse
    V[4] = 0.5 * (V[3] + V[9])  # face 10 becomes collinear
    report = check_mesh(sphere.with_vertices(V))
    assert report.zero_area_faces.tolist() == [0, 4, 10]
    assert "zero-area faces (area <= 1e-12 * longest edge^2): [0, 4, 10] (3 in all)" in str(report)
    edge = np.flatnonzero(np.all(np.sort(np.asarray(sphere.edges), axis=1) == [0, 11], axis=1))
    assert report.zero_length_edges.tolist() == edge.tolist() and edge.size == 1 and not report.is_clean
    assert f"zero-length edges (coincident vertices): [{edge[0]}] (1 in all)" in str(report)
    assert "zero-length edges (coincident vertices): none" in str(check_mesh(sphere))
    # The tolerance scales with the precision the operators compute in: 16 eps in float32, where a
    # collinear face's area rounds to ~eps l^2 (scale-invariant: the same faces at 1e-30 and 1e30).
    assert default_area_tol(np.float64) == 1e-12 and default_area_tol(np.float32) == 16 * np.finfo(np.float32).eps
    single = check_mesh(sphere.with_vertices(V.astype(np.float32)))
    assert single.zero_area_faces.tolist() == [0, 4, 10] and single.area_tol == default_area_tol(np.float32)
    for scale in (1e-30, 1e30):
        assert check_mesh(sphere.with_vertices(scale * V)).zero_area_faces.tolist() == [0, 4, 10]
    # A needle of aspect 1e-4 is not zero-area at the default tolerance, but is at area_tol=1e-3.
    V[4] += 1e-4 * np.cross(V[9] - V[3], [0.0, 0.0, 1.0])
    assert 10 not in check_mesh(sphere.with_vertices(V)).zero_area_faces
    assert 10 in check_mesh(sphere.with_vertices(V), area_tol=1e-3).zero_area_faces  # area / l^2 ~ 1e-4 / 2
    with pytest.raises(DDGInputError, match="area_tol"):
        check_mesh(sphere, area_tol=-1.0)


# ---------------------------------------------------------------- ddgjax info


def test_info_default_shape(capsys):
    assert main(["info"]) == 0
    out = capsys.readouterr().out
    assert "built-in torus" in out and "genus 1" in out
    assert "Gauss-Bonnet" in out and "Gaussian curvature K" in out and "enclosed volume:" in out
    difference = float(out.split("difference")[1].split()[0])
    assert abs(difference) < 1e-10


def test_info_on_a_file(capsys):
    path = data_path("meshes", "hourglass_ico.obj")
    assert main(["info", str(path)]) == 0
    out = capsys.readouterr().out
    assert "non-manifold vertices (2+ fans): [22] (1 in all)" in out
    assert "2 pi chi 18.849555921538" in out  # chi = 3


@pytest.mark.parametrize(
    "name, problem", [("moebius.obj", "inconsistently oriented edges"), ("triple_vierbein.obj", "non-manifold edges")]
)
def test_info_says_signed_curvatures_are_undefined_without_an_orientation(capsys, name, problem, data_mesh):
    """No statistics of H, k1, k2 where their sign means nothing; K and Gauss-Bonnet still reported."""
    topology = data_mesh(name).topology
    assert main(["info", str(data_path("meshes", name))]) == 0
    out = capsys.readouterr().out
    count = (topology.inconsistent_edges if problem.startswith("inconsistently") else topology.nonmanifold_edges).size
    assert count > 0
    assert (
        "mean curvature H, principal curvatures k1, k2: undefined (their sign needs consistently oriented "
        f"faces; this mesh has {count} {problem})"
    ) in out
    assert "mean curvature H (dihedral angles)" not in out and "principal curvature k1 " not in out
    assert "Gaussian curvature K" in out and "Gauss-Bonnet" in out


def test_info_reports_signed_curvatures_on_oriented_meshes(capsys):
    assert main(["info", str(data_path("meshes", "tet.obj"))]) == 0
    out = capsys.readouterr().out
    assert "mean curvature H (dihedral angles)" in out and "principal curvature k2" in out
    assert "undefined" not in out


@pytest.mark.slow
@pytest.mark.parametrize("name, panels", [(None, 2), ("moebius.obj", 1)])
def test_info_draws_the_curvatures_when_asked(capsys, tmp_path, name, panels):
    """`--output`: K and H side by side (K alone without an orientation, where H's sign means nothing)."""
    import matplotlib.image

    output = tmp_path / "curvature.png"
    argv = ["info", "--output", str(output)] + ([] if name is None else [str(data_path("meshes", name))])
    assert main(argv) == 0
    assert f"figure written to {output}" in capsys.readouterr().out
    height, width = matplotlib.image.imread(output).shape[:2]
    assert (width > 1.8 * height) == (panels == 2)
    assert main(["info", "--output", str(tmp_path / "missing" / "c.png")]) == 2
    assert "could not write" in capsys.readouterr().err


@pytest.mark.parametrize("name", ["missing.obj", "points.xyz"])
def test_info_bad_file_exits_2_without_traceback(capsys, tmp_path, name):
    assert main(["info", str(tmp_path / name)]) == 2
    captured = capsys.readouterr()
    assert captured.err.startswith("ddgjax info: error: ") and "Traceback" not in captured.err
    assert captured.out == ""
