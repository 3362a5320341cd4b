"""`diffusion_operators(cache_dir=)`: a file of the wrong content is recomputed, an unwritable folder only warns."""

from __future__ import annotations

import os
import re
import shutil
import warnings
import zipfile

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import ddgjax.learn._operators as operators_module
from ddgjax.learn import diffusion_operators, diffusion_operators_of_meshes
from ddgjax.learn._operators import cache_key

from conftest import unit_icosphere

K = 8


def _bumpy(seed: int):
    """icosphere(1) moved radially at random: 42 vertices, no repeated eigenvalues (deterministic eigenvectors)."""
    mesh = unit_icosphere(1)
    V = np.asarray(mesh.vertices)
    return mesh.with_vertices(jnp.asarray(V * (1 + 0.05 * np.random.default_rng(seed).standard_normal((len(V), 1)))))


@pytest.fixture(scope="module")
def mesh():
    return _bumpy(0)


@pytest.fixture(scope="module")
def fresh(mesh):
    """The operators computed without a cache: what every call below must return."""
    return diffusion_operators(mesh, K)


def _assert_equal(ops, expected):
    for a, b in zip(jax.tree.leaves(ops), jax.tree.leaves(expected), strict=True):
        assert a.shape == b.shape and a.dtype == b.dtype
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)


def _target(folder, mesh, k=K):
    return folder / f"{cache_key(mesh, k, mass='voronoi', robust=True)}.npz"


def _cached_file(folder, mesh, k):
    """Compute `mesh`'s operators for `k` into `folder` and return that file."""
    diffusion_operators(mesh, k, cache_dir=folder)
    return _target(folder, mesh, k)


def _no_warnings_call(mesh, folder):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        return diffusion_operators(mesh, K, cache_dir=folder)


def _stored_key(path):
    with np.load(path, allow_pickle=False) as stored:
        return str(stored["key"])


@pytest.mark.parametrize(
    "planted",
    ["fewer_eigenpairs", "another_mesh", pytest.param("a_larger_mesh", marks=pytest.mark.slow)],  # compiles for 162 vertices
)
def test_a_planted_file_of_wrong_content_is_recomputed_and_rewritten(mesh, fresh, tmp_path, planted, icosphere2):
    elsewhere, folder = tmp_path / "elsewhere", tmp_path / "cache"
    folder.mkdir()
    if planted == "fewer_eigenpairs":  # (42, 3) eigenvectors under the name of k = 8
        source = _cached_file(elsewhere, mesh, 3)
        with np.load(source) as stored:
            assert stored["vectors"].shape == (42, 3)
    elif planted == "another_mesh":  # the same shapes and dtypes, another mesh's values
        source = _cached_file(elsewhere, _bumpy(1), K)
    else:
        source = _cached_file(elsewhere, icosphere2, K)
    path = _target(folder, mesh)
    shutil.copyfile(source, path)
    ops = _no_warnings_call(mesh, folder)
    _assert_equal(ops, fresh)
    assert _stored_key(path) == path.stem  # rewritten with this mesh's content
    assert sorted(p.name for p in folder.iterdir()) == [path.name]

    def refuse(*args, **kwargs):
        raise AssertionError("computed although the rewritten file is valid")

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(operators_module, "_compute", refuse)
        _assert_equal(_no_warnings_call(mesh, folder), fresh)


@pytest.mark.parametrize(
    "tamper",
    [
        "float32_values",
        "nan_vectors",
        "fewer_eigenvalues",
        "shuffled_neighbors",
        "missing_field",
        "extra_field",
        "no_key",
        "pickled_key",
    ],
)
def test_a_file_with_the_right_key_and_wrong_arrays_is_recomputed(mesh, fresh, tmp_path, tamper):
    path = _cached_file(tmp_path, mesh, K)
    with np.load(path) as stored:
        arrays = dict(stored)
    if tamper == "float32_values":
        arrays = {name: a.astype(np.float32) if a.dtype == np.float64 else a for name, a in arrays.items()}
    elif tamper == "nan_vectors":
        arrays["vectors"] = np.full_like(arrays["vectors"], np.nan)
    elif tamper == "fewer_eigenvalues":
        arrays["values"] = arrays["values"][:-1]
    elif tamper == "shuffled_neighbors":
        arrays["gradient_neighbors"] = np.roll(arrays["gradient_neighbors"], 1, axis=0)
    elif tamper == "missing_field":
        del arrays["gradient_weights"]
    elif tamper == "extra_field":
        arrays["something"] = np.zeros(3)
    elif tamper == "no_key":
        del arrays["key"]
    else:
        arrays["key"] = np.asarray([path.stem], dtype=object)
    np.savez(path, **arrays)
    _assert_equal(_no_warnings_call(mesh, tmp_path), fresh)
    assert _stored_key(path) == path.stem


@pytest.mark.parametrize("damage", ["garbage", "empty", "truncated", "flipped_bytes", "a_folder"])
def test_an_unreadable_file_is_recomputed_without_an_error(mesh, fresh, tmp_path, damage):
    path = _cached_file(tmp_path, mesh, K)
    data = path.read_bytes()
    if damage == "garbage":
        path.write_bytes(os.urandom(len(data)))
    elif damage == "empty":
        path.write_bytes(b"")
    elif damage == "truncated":
        path.write_bytes(data[: len(data) // 2])
    elif damage == "flipped_bytes":
        with zipfile.ZipFile(path) as archive:  # a byte inside the stored eigenvectors: the CRC catches it
            info = archive.getinfo("vectors.npy")
        offset = info.header_offset + 30 + len(info.filename) + len(info.extra) + info.compress_size // 2
        damaged = bytearray(data)
        damaged[offset] ^= 0xFF
        path.write_bytes(bytes(damaged))
    if damage == "a_folder":  # a folder where the file should be: read as a miss, then it cannot be replaced
        path.unlink()
        path.mkdir()
        with pytest.warns(UserWarning, match="cache_dir: cannot write"):
            ops = diffusion_operators(mesh, K, cache_dir=tmp_path)
        _assert_equal(ops, fresh)
        return
    _assert_equal(_no_warnings_call(mesh, tmp_path), fresh)
    assert _stored_key(path) == path.stem


def _make_read_only(folder, monkeypatch) -> None:
    """Take write permission from `folder`. Root writes into read-only folders anyway, so for root the kernel's
    refusal is played by `mkstemp`, the cache's one way of creating a file there."""
    folder.chmod(0o555)
    if os.geteuid() == 0:
        create = operators_module.tempfile.mkstemp

        def refuse_inside(*args, dir=None, **kwargs):
            if dir is not None and os.path.realpath(dir).startswith(os.path.realpath(folder)):
                raise PermissionError(13, "Permission denied", os.fspath(dir))
            return create(*args, dir=dir, **kwargs)

        monkeypatch.setattr(operators_module.tempfile, "mkstemp", refuse_inside)


def _unwritable(tmp_path, kind, monkeypatch):
    """A `cache_dir` that takes no file, and the reason the warning gives."""
    if kind == "read_only_folder":
        folder = tmp_path / "read_only"
        folder.mkdir()
        _make_read_only(folder, monkeypatch)
        return folder, "Permission denied"
    regular = tmp_path / "a_file"
    regular.write_text("not a folder")
    if kind == "regular_file":
        return regular, "a regular file, not a folder"
    if kind == "below_a_regular_file":
        return regular / "cache", "Not a directory"
    return str(tmp_path / "nul\0byte"), "null byte"  # no operating system takes this name


@pytest.mark.parametrize("kind", ["read_only_folder", "regular_file", "below_a_regular_file", "nul_byte"])
def test_an_unwritable_cache_dir_warns_once_and_returns_the_operators(mesh, fresh, tmp_path, monkeypatch, kind):
    folder, reason = _unwritable(tmp_path, kind, monkeypatch)
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            ops = diffusion_operators(mesh, K, cache_dir=folder)
        assert len(caught) == 1 and caught[0].category is UserWarning
        message = str(caught[0].message)
        assert "cache_dir" in message and repr(os.fsdecode(folder)) in message and reason in message, message
        _assert_equal(ops, fresh)
        # A dataset warns once, not once a mesh, and every mesh's operators come back.
        meshes = [mesh, _bumpy(2), _bumpy(3)]
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            many = diffusion_operators_of_meshes(meshes, K, cache_dir=folder)
        assert len(caught) == 1 and reason in str(caught[0].message)
        _assert_equal(many[0], fresh)
        _assert_equal(many[2], diffusion_operators(meshes[2], K))
    finally:
        if kind == "read_only_folder":
            folder.chmod(0o755)


@pytest.mark.parametrize(
    ("where", "error"),
    [
        ("mkstemp", PermissionError(13, "Permission denied")),  # a read-only folder, as root sees none
        ("savez", OSError(28, "No space left on device")),  # a full disk, half-way through the file
    ],
)
def test_an_os_error_while_writing_warns_and_leaves_no_temporary_file(mesh, fresh, tmp_path, monkeypatch, where, error):
    def fail(*args, **kwargs):
        raise error

    monkeypatch.setattr(operators_module.tempfile if where == "mkstemp" else operators_module.np, where, fail)
    with pytest.warns(UserWarning, match=f"cannot write .*{re.escape(str(tmp_path))}.*{error.strerror}") as caught:
        ops = diffusion_operators(mesh, K, cache_dir=tmp_path)
    monkeypatch.undo()
    assert len(caught) == 1
    _assert_equal(ops, fresh)
    assert list(tmp_path.iterdir()) == []


def test_a_read_only_folder_with_the_files_already_there_is_used_without_a_warning(mesh, fresh, tmp_path, monkeypatch):
    _cached_file(tmp_path, mesh, K)
    _make_read_only(tmp_path, monkeypatch)
    try:

        def refuse(*args, **kwargs):
            raise AssertionError("computed although cached")

        with pytest.MonkeyPatch.context() as patch:
            patch.setattr(operators_module, "_compute", refuse)
            _assert_equal(_no_warnings_call(mesh, tmp_path), fresh)
    finally:
        tmp_path.chmod(0o755)
