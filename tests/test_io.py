"""Mesh files (ddgjax.io): round trips, vertex order, the SOURCES.md table, clear errors."""

from __future__ import annotations

import io
import pathlib

import igl
import numpy as np
import pytest

from ddgjax import DDGInputError
from ddgjax.io import load_mesh, save_mesh
from ddgjax.mesh import Mesh

from conftest import data_path

# From tests/data/SOURCES.md: V, F, E, chi, genus (None: not defined), boundary loops
# (None: not listed, non-manifold). Small and special meshes plus the large ones with UV seams,
# unreferenced vertices and slivers.
SOURCES_TABLE = {
    "tet.obj": (4, 4, 6, 2, 0, 0),
    "small_disk.obj": (19, 27, 45, 1, 0, 1),
    "sphere_small.ply": (162, 320, 480, 2, 0, 0),
    "bob_small.ply": (250, 500, 750, 0, 1, 0),
    "hourglass_ico.obj": (23, 40, 60, 3, None, 0),
    "triple_vierbein.obj": (75, 108, 182, 1, None, None),
    "moebius.obj": (280, 448, 728, 0, None, 1),
    "torus.obj": (3840, 7680, 11520, 0, 1, 0),
    "double-torus.obj": (3070, 6144, 9216, -2, 2, 0),
    "fertility.off": (4494, 9000, 13500, -6, 4, 0),
    "spot.obj": (2930, 5856, 8784, 2, 0, 0),
    "camelhead.off": (11381, 22704, 34084, 1, 0, 1),
    "beetle.off": (19887, 38656, 58552, -9, 0, 11),
    "stanford-bunny.obj": (35947, 69451, 104288, -3, 0, 5),
}


@pytest.mark.parametrize("name", sorted(SOURCES_TABLE))
def test_meshes_match_sources_table(name):
    mesh = load_mesh(data_path("meshes", name))
    topology = mesh.topology
    n_vertices, n_faces, n_edges, chi, genus, loops = SOURCES_TABLE[name]
    assert (mesh.n_vertices, mesh.n_faces, mesh.n_edges) == (n_vertices, n_faces, n_edges)
    assert topology.euler_characteristic == chi
    assert topology.genus == genus
    if loops is not None:
        assert len(topology.boundary_loops) == loops
    # Every boundary edge lies in exactly one loop.
    assert sum(loop.size for loop in topology.boundary_loops) == topology.boundary_edges.size or loops is None
    special = {
        "hourglass_ico.obj": lambda t: t.nonmanifold_vertices.tolist() == [22] and t.is_edge_manifold and t.is_oriented,
        "triple_vierbein.obj": lambda t: t.nonmanifold_edges.size == 20 and not t.is_oriented,
        "moebius.obj": lambda t: t.is_manifold and not t.is_oriented and t.inconsistent_edges.size > 0,
        "stanford-bunny.obj": lambda t: t.unreferenced_vertices.size == 1113 and t.is_manifold and t.is_oriented,
        "spot.obj": lambda t: t.is_closed and t.n_components == 1,
    }
    assert special.get(name, lambda t: t.is_manifold and t.is_oriented)(topology)


@pytest.mark.parametrize("name", ["spot.obj", "stanford-bunny.obj", "camelhead.off", "bob_small.ply", "moebius.obj"])
def test_vertex_order_and_faces_match_libigl_reader(name):
    path = data_path("meshes", name)
    mesh = load_mesh(path)
    V, F = igl.read_triangle_mesh(str(path))
    np.testing.assert_array_equal(np.asarray(mesh.vertices), V)
    np.testing.assert_array_equal(np.asarray(mesh.faces), F)


def test_obj_with_texture_coordinates_is_read_by_position_index(tmp_path):
    # Corners `v/vt/vn`, `v//vn`, negative (relative) indices and a quad, fan-triangulated.
    path = tmp_path / "quad.obj"
    path.write_text(
        "# comment\nv 0 0 0\nv 1 0 0\nv 1 1 0 1.0\nv 0 1 0 0.5 0.5 0.5\nvt 0 0\nvt 1 0\nvn 0 0 1\n"
        "g group\nusemtl none\nf 1/1/1 2/2/1 3//1 4\nv 0 0 1\nf -1 -4 -5\n"
    )
    mesh = load_mesh(path)
    np.testing.assert_array_equal(np.asarray(mesh.faces), [[0, 1, 2], [0, 2, 3], [4, 1, 0]])
    np.testing.assert_array_equal(np.asarray(mesh.vertices)[2], [1.0, 1.0, 0.0])


@pytest.mark.parametrize("suffix", [".obj", ".off", ".ply"])
def test_round_trip_is_exact(tmp_path, suffix):
    rng = np.random.default_rng(0)
    # Unreferenced vertex 5 and full-precision coordinates must survive.
    V = rng.normal(size=(6, 3)) * 1e3
    F = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 4], [1, 4, 2]])
    mesh = Mesh.from_arrays(V, F)
    path = tmp_path / f"mesh{suffix}"
    save_mesh(path, mesh)
    loaded = load_mesh(path)
    np.testing.assert_array_equal(np.asarray(loaded.vertices), V)
    np.testing.assert_array_equal(np.asarray(loaded.faces), F)


def test_stl_round_trip_merges_corners_in_float32(tmp_path):
    mesh = load_mesh(data_path("meshes", "bob_small.ply"))
    path = tmp_path / "bob.stl"
    save_mesh(path, mesh)
    loaded = load_mesh(path)
    # STL keeps triangles only (float32): same counts after merging, same corner positions face by face.
    assert (loaded.n_vertices, loaded.n_faces, loaded.n_edges) == (mesh.n_vertices, mesh.n_faces, mesh.n_edges)
    corners = np.asarray(mesh.vertices)[np.asarray(mesh.faces)]
    loaded_corners = np.asarray(loaded.vertices)[np.asarray(loaded.faces)]
    np.testing.assert_allclose(loaded_corners, corners.astype(np.float32), rtol=0, atol=0)
    assert loaded.topology.euler_characteristic == mesh.topology.euler_characteristic


def test_dtype_option(tmp_path):
    import jax.numpy as jnp

    mesh = load_mesh(data_path("meshes", "tet.obj"), dtype=jnp.float32)
    assert mesh.vertices.dtype == jnp.float32
    assert load_mesh(data_path("meshes", "tet.obj")).vertices.dtype == jnp.float64


def test_clear_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="no such mesh file"):
        load_mesh(tmp_path / "missing.obj")
    with pytest.raises(DDGInputError, match=r"unknown mesh format '\.xyz'"):
        load_mesh(tmp_path / "points.xyz")
    with pytest.raises(DDGInputError, match="unknown mesh format"):
        save_mesh(tmp_path / "mesh.vtk", load_mesh(data_path("meshes", "tet.obj")))
    points = tmp_path / "points.obj"
    points.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\n")
    with pytest.raises(DDGInputError, match="contains no faces"):
        load_mesh(points)
    bad_index = tmp_path / "bad_index.obj"
    bad_index.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 7\n")
    with pytest.raises(DDGInputError, match=r"out-of-range entries in faces \[0\]"):
        load_mesh(bad_index)
    segment = tmp_path / "segment.obj"
    segment.write_text("v 0 0 0\nv 1 0 0\nf 1 2\n")
    with pytest.raises(DDGInputError, match="line 3: a face needs at least three corners"):
        load_mesh(segment)
    garbage = tmp_path / "garbage.off"
    garbage.write_text("this is not an OFF file\n")
    with pytest.raises(DDGInputError, match="garbage.off"):
        load_mesh(garbage)


def test_public_api_is_explicit():
    """`ddgjax.io` exports its two functions, not its imports (`np`, `os`, `pathlib`, `Mesh`, ...)."""
    import ddgjax.io

    assert ddgjax.io.__all__ == ["load_mesh", "save_mesh"]
    namespace: dict = {}
    exec("from ddgjax.io import *", namespace)
    assert sorted(name for name in namespace if name != "__builtins__") == ["load_mesh", "save_mesh"]


FORMATS = [".obj", ".off", ".ply", ".stl"]


def _written(tmp_path, suffix: str) -> tuple:
    """A file of `suffix` holding the tetrahedron, its bytes, and the folder's listing."""
    path = tmp_path / f"mesh{suffix}"
    save_mesh(path, load_mesh(data_path("meshes", "tet.obj")))
    return path, path.read_bytes(), sorted(tmp_path.iterdir())


@pytest.mark.parametrize("suffix", FORMATS)
@pytest.mark.parametrize("failure", ["midway", "formatting", "interrupt"])
def test_failed_write_leaves_the_old_file_intact(tmp_path, monkeypatch, suffix, failure):
    """A write that fails after half the bytes (a full disk), before any (an error while formatting) or by an
    interrupt leaves the old file byte for byte and no temporary file; the next write succeeds."""
    import errno

    import ddgjax.io

    path, old, listing = _written(tmp_path, suffix)
    mesh = load_mesh(data_path("meshes", "sphere_small.ply"))
    real = ddgjax.io._WRITERS[suffix[1:]]

    def failing(handle, vertices, faces):
        if failure == "formatting":
            raise RuntimeError("formatting failed")
        buffer = io.BytesIO()
        real(buffer, vertices, faces)
        handle.write(buffer.getvalue()[: buffer.tell() // 2])
        handle.flush()  # the half really reaches the temporary file
        if failure == "interrupt":
            raise KeyboardInterrupt
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setitem(ddgjax.io._WRITERS, suffix[1:], failing)
    expected = {"midway": OSError, "formatting": RuntimeError, "interrupt": KeyboardInterrupt}[failure]
    with pytest.raises(expected):
        save_mesh(path, mesh)
    assert path.read_bytes() == old
    assert sorted(tmp_path.iterdir()) == listing
    monkeypatch.setitem(ddgjax.io._WRITERS, suffix[1:], real)
    save_mesh(path, mesh)
    assert load_mesh(path).n_faces == mesh.n_faces and sorted(tmp_path.iterdir()) == listing


_SIZE_LIMITED_SAVES = """
import resource, signal, sys
from ddgjax.io import save_mesh
from ddgjax.mesh import icosphere
mesh = icosphere(3)
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit then fails with EFBIG, not a signal
resource.setrlimit(resource.RLIMIT_FSIZE, (4096, 4096))
for path in sys.argv[1:]:
    try:
        save_mesh(path, mesh)
    except OSError as error:
        print(path, error.errno)
    else:
        print(path, "written")
"""


@pytest.mark.slow
def test_file_size_limit_leaves_the_old_files_intact(tmp_path):
    """A real failure midway: a process limited to 4 KiB files (RLIMIT_FSIZE) cannot write a 642-vertex mesh
    over the tetrahedron's files (each under 4 KiB); every format keeps the old bytes and no temporary file."""
    import errno
    import subprocess
    import sys

    resource = pytest.importorskip("resource")
    assert resource.RLIMIT_FSIZE
    paths, olds = [], []
    for suffix in FORMATS:
        path, old, _ = _written(tmp_path, suffix)
        assert len(old) < 4096
        paths.append(str(path))
        olds.append(old)
    listing = sorted(tmp_path.iterdir())
    run = subprocess.run([sys.executable, "-c", _SIZE_LIMITED_SAVES, *paths], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    assert run.stdout.split() == [str(x) for path in paths for x in (path, errno.EFBIG)]
    assert [pathlib.Path(path).read_bytes() for path in paths] == olds
    assert sorted(tmp_path.iterdir()) == listing


def test_permissions_of_replaced_and_new_files(tmp_path):
    """A replaced file keeps its mode (not mkstemp's 0o600), a new file gets 0o666 less the umask, and a
    symbolic link keeps pointing at its (replaced) target."""
    import os
    import stat

    mesh = load_mesh(data_path("meshes", "tet.obj"))
    path, _, _ = _written(tmp_path, ".obj")
    os.chmod(path, 0o640)
    save_mesh(path, mesh)
    assert stat.S_IMODE(path.stat().st_mode) == 0o640
    umask = os.umask(0o022)
    os.umask(umask)
    fresh = tmp_path / "fresh.ply"
    save_mesh(fresh, mesh)
    assert stat.S_IMODE(fresh.stat().st_mode) == 0o666 & ~umask
    link = tmp_path / "link.obj"
    link.symlink_to(path)
    save_mesh(link, mesh.with_vertices(mesh.vertices * 2))
    assert link.is_symlink() and stat.S_IMODE(path.stat().st_mode) == 0o640
    np.testing.assert_array_equal(np.asarray(load_mesh(path).vertices), np.asarray(mesh.vertices) * 2)


def test_non_finite_vertices_are_refused_before_anything_is_written(tmp_path):
    """Whatever made them (`eqx.tree_at`, `with_vertices` under `jit`, positions computed under `jit`), NaN or inf vertices are
    refused with the argument, the count, the first vertices and the remedy; the old file stays as it was.
    `Mesh.from_arrays` and an eager `with_vertices` refuse them already."""
    import equinox as eqx
    import jax
    import jax.numpy as jnp

    mesh = load_mesh(data_path("meshes", "tet.obj"))
    broken = mesh.vertices.at[1, 0].set(jnp.nan).at[3, 2].set(jnp.inf)
    routes = {
        "tree_at": eqx.tree_at(lambda m: m.vertices, mesh, broken),
        "jit": jax.jit(lambda m, V: m.with_vertices(V))(mesh, broken),
        "computed": jax.jit(lambda m: m.with_vertices(m.vertices / jnp.where(jnp.arange(4)[:, None] % 2 == 1, 0.0, 1.0)))(mesh),
    }
    for suffix in FORMATS:
        path, old, listing = _written(tmp_path, suffix)
        for route, bad in routes.items():
            with pytest.raises(
                DDGInputError, match=r"mesh: 2 of its 4 vertices have NaN or inf coordinates \(vertices \[1, 3\]"
            ) as raised:
                save_mesh(path, bad)
            assert "nothing was written" in str(raised.value) and "finite positions" in str(raised.value), route
            assert path.read_bytes() == old and sorted(tmp_path.iterdir()) == listing
    with pytest.raises(DDGInputError, match="vertices"):
        Mesh.from_arrays(np.asarray(broken), np.asarray(mesh.faces))
    with pytest.raises(DDGInputError, match="vertices"):
        mesh.with_vertices(broken)


@pytest.mark.parametrize("compression", ["xz", "gz", "bz2"])
def test_a_compressed_mesh_file_reads_as_the_file_it_holds(tmp_path, compression):
    import bz2
    import gzip
    import lzma

    compress = {"xz": lzma.compress, "gz": gzip.compress, "bz2": bz2.compress}[compression]
    plain = data_path("meshes", "spot.obj")
    packed = tmp_path / f"spot.obj.{compression}"
    packed.write_bytes(compress(plain.read_bytes()))
    read, expected = load_mesh(packed), load_mesh(plain)
    np.testing.assert_array_equal(np.asarray(read.vertices), np.asarray(expected.vertices))
    np.testing.assert_array_equal(np.asarray(read.faces), np.asarray(expected.faces))
    assert not list(tmp_path.glob("spot.obj")) and len(list(tmp_path.iterdir())) == 1  # unpacked elsewhere, removed


def test_a_compressed_file_that_is_not_a_mesh_or_not_compressed_is_refused(tmp_path):
    not_xz = tmp_path / "spot.obj.xz"
    not_xz.write_bytes(b"v 0 0 0\n")
    with pytest.raises(DDGInputError, match="could not be decompressed"):
        load_mesh(not_xz)
    with pytest.raises(DDGInputError, match="unknown mesh format '.txt'"):
        load_mesh(tmp_path / "notes.txt.gz")
    with pytest.raises(FileNotFoundError, match="no such mesh file"):
        load_mesh(tmp_path / "missing.ply.gz")
