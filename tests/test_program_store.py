"""ddgjax's store of compiled kernels (ddgjax/_program_store.py): a fresh process reads what an earlier one
compiled, and a store that is off, corrupted, unwritable or written by two processes at once costs a
compilation, never a wrong result or an exception."""

from __future__ import annotations

import json
import os
import pathlib
import subprocess
import sys
import threading

import jax
import numpy as np
import pytest

from ddgjax import _program_store

# One kernel call in a fresh process: the cotan Laplacian of a mesh whose size no other test uses, in a
# store of the test's own. Prints the XLA compilations the call made, its values'
# checksum and the warnings it raised.
CALL = """
import json, warnings, jax
jax.config.update("jax_enable_x64", True)
compiles = []
jax.monitoring.register_event_duration_secs_listener(
    lambda event, duration, **_: compiles.append(event) if event == "/jax/core/compile/backend_compile_duration" else None)
import ddgjax
mesh = ddgjax.mesh.torus(n_major=13, n_minor=7)
ddgjax.cpu_compiler_options()  # its one-off probe of the compiler compiles a program of its own
before = len(compiles)
with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter("always")
    values = ddgjax.laplacian.cotan_laplacian(mesh).values
print(json.dumps({"compiles": len(compiles) - before, "sum": float(abs(values).sum()),
                  "warnings": [str(w.message) for w in caught]}))
"""


# A kernel that calls LAPACK (`eigh`), alone in its process: JAX binds LAPACK only when it lowers a
# linear-algebra operation, which a program read from disk never is.
CALL_LAPACK = """
import json, jax, numpy as np
jax.config.update("jax_enable_x64", True)
import ddgjax
points = np.random.default_rng(0).normal(size=(211, 3))
normals = np.asarray(ddgjax.pointcloud.point_cloud_normals(points))
print(json.dumps({"sum": float(np.abs(normals).sum())}))
"""


def _fresh_process(cache: pathlib.Path, script: str = CALL, **environment) -> dict:
    env = {**os.environ, "DDGJAX_CACHE_DIR": str(cache), **environment}
    env.pop(_program_store.SWITCH_VARIABLE, None) if _program_store.SWITCH_VARIABLE not in environment else None
    done = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout.strip().splitlines()[-1])


def _entries(cache: pathlib.Path) -> list[pathlib.Path]:
    return sorted((cache / "programs").glob("*.bin")) if (cache / "programs").exists() else []


def test_a_fresh_process_reads_the_program_an_earlier_one_compiled(tmp_path):
    first = _fresh_process(tmp_path)
    assert first["compiles"] >= 1 and len(_entries(tmp_path)) >= 1 and not first["warnings"]
    second = _fresh_process(tmp_path)
    assert second["compiles"] == 0  # no tracing, lowering or compiling: the executable came from disk
    assert second["sum"] == first["sum"] and not second["warnings"]


def test_a_program_jaxs_own_cache_served_is_not_stored(tmp_path):
    # With JAX's persistent cache on (as the command line has it), a process that finds the program there
    # must not store it: such an executable serializes incomplete on XLA:CPU (a later load fails on its
    # first call). The next process that compiles it stores it, and a process after that reads it.
    jax_cache = {
        "JAX_COMPILATION_CACHE_DIR": str(tmp_path / "jax"),
        "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": "0",
        "JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES": "-1",
    }
    first = _fresh_process(tmp_path, **jax_cache)
    assert len(_entries(tmp_path)) >= 1 and any((tmp_path / "jax").iterdir())
    for entry in _entries(tmp_path):
        entry.unlink()
    served = _fresh_process(tmp_path, **jax_cache)  # JAX's cache answers every compilation
    assert not _entries(tmp_path) and served["sum"] == first["sum"]
    _fresh_process(tmp_path)  # compiles (JAX's cache off), so it stores
    assert len(_entries(tmp_path)) >= 1
    assert _fresh_process(tmp_path, **jax_cache)["sum"] == first["sum"]


def test_a_stored_program_that_calls_lapack_runs_in_a_fresh_process(tmp_path):
    first = _fresh_process(tmp_path, CALL_LAPACK)
    assert _fresh_process(tmp_path, CALL_LAPACK)["sum"] == first["sum"]  # read from disk: no crash, same values


def test_a_corrupted_entry_is_compiled_again_and_replaced(tmp_path):
    reference = _fresh_process(tmp_path)
    for entry in _entries(tmp_path):
        entry.write_bytes(entry.read_bytes()[: len(entry.read_bytes()) // 3])  # a truncated write
    damaged = _fresh_process(tmp_path)
    assert damaged["sum"] == reference["sum"] and damaged["compiles"] >= 1
    assert len(damaged["warnings"]) == 1 and "compiled again" in damaged["warnings"][0]  # said once
    assert _fresh_process(tmp_path)["compiles"] == 0  # the bad entry was replaced by a good one


@pytest.mark.slow  # two more fresh processes; the same path as the tests above
def test_an_unwritable_directory_or_the_switch_keeps_programs_in_memory(tmp_path):
    blocked = tmp_path / "a-file"
    blocked.write_text("not a folder")  # even root cannot make a folder under a file
    unwritable = _fresh_process(blocked)
    assert unwritable["compiles"] >= 1 and len(unwritable["warnings"]) == 1 and "in memory only" in unwritable["warnings"][0]
    off = _fresh_process(tmp_path / "off", **{_program_store.SWITCH_VARIABLE: "0"})
    assert off["sum"] == unwritable["sum"] and not off["warnings"] and not (tmp_path / "off").exists()


def test_two_writers_of_one_entry_leave_a_valid_entry(tmp_path, monkeypatch):
    monkeypatch.setenv("DDGJAX_CACHE_DIR", str(tmp_path))
    function = jax.jit(lambda x: jax.numpy.cumsum(x * 2.0))
    x = np.arange(5.0)
    lowered = function.lower(x)
    compiled = lowered.compile()
    writers = [threading.Thread(target=_program_store.save, args=("entry", lowered, compiled)) for _ in range(8)]
    for writer in writers:
        writer.start()
    for writer in writers:
        writer.join()
    assert [path.name for path in (tmp_path / "programs").iterdir()] == ["entry.bin"]  # no temporary file left
    loaded = _program_store.load("entry", jax.tree_util.tree_structure(((x,), {})))
    np.testing.assert_array_equal(loaded(x), compiled(x))


def test_what_is_not_stored(monkeypatch):
    # Host callbacks point into this process; kernels outside ddgjax or inside a function are not in the key.
    callback = jax.jit(lambda x: jax.pure_callback(np.sin, jax.ShapeDtypeStruct((3,), np.float64), x)).lower(np.zeros(3))
    assert _program_store._host_callbacks(callback)
    assert not _program_store._host_callbacks(jax.jit(jax.numpy.sin).lower(np.zeros(3)))
    signature = ((), (), ())
    assert _program_store.entry_key("ddgjax.mesh._geometry.face_areas", signature, {}) is not None
    assert _program_store.entry_key("mypackage.f", signature, {}) is None
    assert _program_store.entry_key("ddgjax.x.f.<locals>.g", signature, {}) is None
    assert _program_store.entry_key("ddgjax.x.f", ((), (("option", object()),), ()), {}) is None  # no stable key
    # The key changes with what changes a program: the static values, the options, the tracing configuration.
    keys = {
        _program_store.entry_key("ddgjax.x.f", ((), (("k", 1),), ()), {}),
        _program_store.entry_key("ddgjax.x.f", ((), (("k", 2),), ()), {}),
        _program_store.entry_key("ddgjax.x.f", ((), (("k", 1),), ()), {"xla_option": "1"}),
    }
    with jax.numpy_rank_promotion("raise"):
        keys.add(_program_store.entry_key("ddgjax.x.f", ((), (("k", 1),), ()), {}))
    assert len(keys) == 4


def test_more_sizes_than_a_kernel_keeps_in_memory_compile_nothing_on_a_second_pass(tmp_path, monkeypatch):
    """A dataset's second pass: programs dropped from a kernel's in-memory cache (`PROGRAMS_PER_KERNEL`)
    come back from the store, so a dataset of more sizes than the cache holds compiles nothing again."""
    from ddgjax import _compile
    from ddgjax.laplacian import cotan_laplacian
    from ddgjax.mesh import torus

    monkeypatch.setenv("DDGJAX_CACHE_DIR", str(tmp_path))
    monkeypatch.delenv(_program_store.SWITCH_VARIABLE, raising=False)
    monkeypatch.setattr(_compile, "PROGRAMS_PER_KERNEL", 2)
    meshes = [torus(n_major=n, n_minor=5) for n in (17, 19, 23, 29, 31)]  # sizes no other test uses
    compiles = []

    def listen(event, duration, **_):
        if event == "/jax/core/compile/backend_compile_duration":
            compiles.append(event)

    first = [np.asarray(cotan_laplacian(mesh).values) for mesh in meshes]
    jax.monitoring.register_event_duration_secs_listener(listen)
    try:
        second = [np.asarray(cotan_laplacian(mesh).values) for mesh in meshes]
    finally:
        jax.monitoring.unregister_event_duration_listener(listen)
    assert not compiles
    for a, b in zip(first, second):
        np.testing.assert_array_equal(a, b)
