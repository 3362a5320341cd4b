"""Test configuration: float64 everywhere, quick XLA compilation, and the test data in `tests/data`."""

from __future__ import annotations

import functools
import lzma
import os
import pathlib
import shutil
import tempfile

# The suite checks values, not speed, and compiles hundreds of small programs: XLA's LLVM optimisation
# passes are most of each compilation (the suite runs ~25% faster without them; results agree to
# round-off). Set before the backend starts; inherited by the CLI and notebook subprocesses.
os.environ.setdefault("XLA_FLAGS", "--xla_backend_optimization_level=0 --xla_llvm_disable_expensive_passes=true")

import jax
import numpy as np
import pytest

jax.config.update("jax_enable_x64", True)

REPO = pathlib.Path(__file__).resolve().parents[1]
DATA = REPO / "tests" / "data"  # meshes and DDG exercise solutions, xz-compressed; provenance in SOURCES.md

# The one test mesh that is made, not stored (SOURCES.md): a mesh of 400 k faces for the tests that run on
# every mesh, whose round-off bounds grow with the mesh.
LARGE_MESH, LARGE_MESH_SEED = "nefertiti_loop1.ply", "nefertiti.obj"


def data_path(*parts: str) -> pathlib.Path:
    """Readable path of a file or folder of `tests/data` (`data_path("meshes", "spot.obj")`).

    Files are stored xz-compressed (`spot.obj.xz`); each is unpacked on first use into a temporary folder
    that this process removes when pytest ends, so readers that need a path (libigl, the command line) get one.
    A folder comes with every file in it unpacked, and `meshes` with the made mesh `LARGE_MESH` too.
    """
    target = _unpacked_root().joinpath(*parts)
    source = DATA.joinpath(*parts)
    if source.is_dir():
        for packed in source.glob("*.xz"):
            data_path(*parts, packed.stem)
        if parts == ("meshes",):
            data_path("meshes", LARGE_MESH)
    elif not target.exists():
        target.parent.mkdir(parents=True, exist_ok=True)
        if parts == ("meshes", LARGE_MESH):
            _write_large_mesh(data_path("meshes", LARGE_MESH_SEED), target)
        else:
            packed = source.with_name(source.name + ".xz")
            if not packed.exists():
                raise FileNotFoundError(f"no test data {packed} (tests/data/SOURCES.md lists the files)")
            with lzma.open(packed) as compressed, open(target, "wb") as unpacked:
                shutil.copyfileobj(compressed, unpacked)
    return target


def read_ddg_reference(name: str) -> dict:
    """`{tag: (rows, numbers) array}` of a DDG exercises reference file (`tests/data/ddg-exercises`,
    FORMAT.md: one record a line, a tag then numbers)."""
    records: dict[str, list] = {}
    for line in data_path("ddg-exercises", name).read_text().splitlines():
        tag, *numbers = line.split()
        records.setdefault(tag, []).append([float(x) for x in numbers])
    return {tag: np.array(rows) for tag, rows in records.items()}


@functools.cache
def _unpacked_root() -> pathlib.Path:
    return pathlib.Path(tempfile.mkdtemp(prefix="ddgjax-test-data-"))


def pytest_unconfigure(config):
    """Remove the folder `data_path` unpacked into (in each xdist worker: each unpacks its own), and the run's
    cache of compiled programs (`pytest_configure`, in the process that made it)."""
    if _unpacked_root.cache_info().currsize:
        shutil.rmtree(_unpacked_root(), ignore_errors=True)
    if getattr(config, "_ddgjax_cache", None):
        shutil.rmtree(config._ddgjax_cache, ignore_errors=True)


def _write_large_mesh(seed: pathlib.Path, target: pathlib.Path) -> None:
    """One level of Loop subdivision of `seed` (libigl), written as binary PLY (float32 coordinates) the
    way `../shared/meshes/armadillo_loop1.ply` was made from `armadillo.obj`."""
    import igl
    import trimesh

    vertices, faces = igl.loop(*igl.read_triangle_mesh(str(seed)))
    target.write_bytes(trimesh.exchange.ply.export_ply(trimesh.Trimesh(vertices, faces, process=False), encoding="binary"))


@pytest.fixture(scope="session")
def sphere_obj(tmp_path_factory) -> str:
    """The unit icosphere of 162 vertices (`icosphere(2)`) as an OBJ file, as a user's mesh file (the CLI tests)."""
    from ddgjax.io import save_mesh

    path = tmp_path_factory.mktemp("meshes") / "sphere.obj"
    save_mesh(path, unit_icosphere(2))
    return str(path)


@functools.cache
def unit_icosphere(subdivisions: int):
    """`ddgjax.mesh.icosphere(subdivisions)`, built once per process: the object the `icosphere<n>` fixtures share
    (for a module's helper that builds on one; a test takes the fixture)."""
    from ddgjax.mesh import icosphere

    return icosphere(subdivisions)


@functools.cache
def load_data_mesh(name: str):
    """`load_mesh(data_path("meshes", name))`, read once per process: the object the `data_mesh` fixture gives."""
    from ddgjax.io import load_mesh

    return load_mesh(data_path("meshes", name))


# The suite's common meshes, built once per session: a `Mesh` is immutable, so tests share one. Each unit
# icosphere is the subdivided icosahedron of `ddgjax.mesh.icosphere`; the real meshes are the files of
# `tests/data/meshes` as `load_mesh` reads them.
@pytest.fixture(scope="session")
def icospheres():
    """`icospheres(n)`: the unit icosphere of `n` subdivisions, one object per level for the session (the
    fixtures `icosphere0` ... `icosphere4` are the same ones), for the tests that loop over levels."""
    return unit_icosphere


@pytest.fixture(scope="session")
def data_mesh():
    """`data_mesh(name)`: `load_mesh(data_path("meshes", name))` (`"spot.obj"`, `"camelhead.off"`, ...), each file
    read once per session. A test of reading itself calls `load_mesh`."""
    return load_data_mesh


@pytest.fixture(scope="session")
def icosphere0():
    """The icosahedron inscribed in the unit sphere: 12 vertices, 20 faces."""
    return unit_icosphere(0)


@pytest.fixture(scope="session")
def icosphere1():
    """The unit icosphere of 42 vertices and 80 faces."""
    return unit_icosphere(1)


@pytest.fixture(scope="session")
def icosphere2():
    """The unit icosphere of 162 vertices and 320 faces."""
    return unit_icosphere(2)


@pytest.fixture(scope="session")
def icosphere3():
    """The unit icosphere of 642 vertices and 1280 faces."""
    return unit_icosphere(3)


@pytest.fixture(scope="session")
def icosphere4():
    """The unit icosphere of 2562 vertices and 5120 faces."""
    return unit_icosphere(4)


@pytest.fixture
def without_type_checker():
    """Turn off the suite's run-time type checker (jaxtyping + beartype) for one test: what a user sees,
    for tests of the library's own `DDGInputError` messages on arguments of the wrong type."""
    import jaxtyping

    jaxtyping.config.update("jaxtyping_disable", True)
    yield
    jaxtyping.config.update("jaxtyping_disable", False)


def pytest_configure(config):
    """One cache of compiled programs for the whole run, shared by its xdist workers (they start after this
    hook and inherit the variable): a kernel compiled by one worker at a size is read by the others
    (`ddgjax._program_store`). A fresh temporary folder, removed at the end, never the user's; a
    `DDGJAX_CACHE_DIR` already set (a CI image that keeps its cache) is used as it is."""
    if hasattr(config, "workerinput") or os.environ.get("DDGJAX_CACHE_DIR"):
        return
    config._ddgjax_cache = tempfile.mkdtemp(prefix="ddgjax-test-cache-")
    os.environ["DDGJAX_CACHE_DIR"] = config._ddgjax_cache
    os.environ.pop("DDGJAX_COMPILATION_CACHE", None)


def run_cli(argv: list[str]) -> tuple[int, str, str]:
    """`ddgjax.cli.main(argv)` with its exit status (also from SystemExit), stdout and stderr.

    With the run's cache directory (`pytest_configure`): a test writes nothing to the user's cache directory
    (tests/test_cli.py tests the cache).
    """
    import contextlib
    import io

    from ddgjax.cli import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            status = main(argv)
        except SystemExit as exit_:
            status = exit_.code
    return status, out.getvalue(), err.getvalue()
