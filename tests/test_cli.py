"""The `ddgjax` command line as a whole (ddgjax/_cli/__init__.py): the persistent compilation cache,
the options shared by the subcommands, and the command line kept apart from the mathematics."""

from __future__ import annotations

import ast
import contextlib
import pathlib

import jax
import pytest
from jax.experimental.compilation_cache import compilation_cache

import ddgjax
from ddgjax import _program_store
from ddgjax._cli import CACHE_VARIABLE, cache_directory
from ddgjax._compile import clear_programs
from ddgjax.cli import main
from ddgjax.geodesics import heat_distance
from ddgjax.io import load_mesh, save_mesh
from ddgjax.mesh import disk

PACKAGE = pathlib.Path(ddgjax.__file__).parent
#: Modules that serve the command line, files and figures; every other module is mathematics.
OUTSIDE_MATHEMATICS = {"__init__.py", "cli.py", "io.py", "plot", "_cli"}
FORBIDDEN = ("ddgjax.io", "ddgjax._cli", "ddgjax.cli", "ddgjax.plot", "matplotlib", "argparse")


@contextlib.contextmanager
def jax_cache_directory(directory: str | None):
    """JAX's persistent-cache directory set to `directory` for the block (a `JAX_COMPILATION_CACHE_DIR` of the
    environment included), then put back as it was."""
    configured = jax.config.jax_compilation_cache_dir
    jax.config.update("jax_compilation_cache_dir", directory)
    compilation_cache.reset_cache()
    try:
        yield
    finally:
        jax.config.update("jax_compilation_cache_dir", configured)
        compilation_cache.reset_cache()


@pytest.fixture
def user_cache(tmp_path, monkeypatch):
    """An empty `XDG_CACHE_HOME`, the cache switched on, and no cache directory configured in JAX."""
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    monkeypatch.delenv("DDGJAX_CACHE_DIR", raising=False)
    monkeypatch.delenv(CACHE_VARIABLE, raising=False)
    with jax_cache_directory(None):
        yield tmp_path / "ddgjax" / "jax"


def _compile_requests(argv) -> tuple[int, int]:
    """`main(argv)`, from empty in-memory caches; (compilations that asked the persistent cache, its hits)."""
    events = []

    def listen(event, **kwargs):
        events.append(event)

    # Only the caches on disk may serve the run: drop every program compiled in this process.
    jax.clear_caches()
    clear_programs()
    jax.monitoring.register_event_listener(listen)
    try:
        assert main(argv) == 0
    finally:
        jax.monitoring.unregister_event_listener(listen)
    return events.count("/jax/compilation_cache/compile_requests_use_cache"), events.count("/jax/compilation_cache/cache_hits")


@pytest.mark.slow  # the fast tier's time limit (its checks run in the full suite)
def test_a_second_run_compiles_nothing(user_cache, capsys):
    requests, _ = _compile_requests(["info"])
    first = capsys.readouterr().out
    assert requests > 0 and any(user_cache.iterdir())
    # A new process would start here: same command, every program read from the cache.
    requests, hits = _compile_requests(["info"])
    # ddgjax's kernels come from its program store (no compile request); JAX's own programs from its cache.
    assert hits == requests and any((user_cache.parent / "programs").iterdir())
    assert capsys.readouterr().out == first
    # JAX's settings are back as they were: nothing else in this process writes to the cache.
    assert jax.config.jax_compilation_cache_dir is None


@pytest.mark.slow  # compiles the heat method's programs (its figures run in the full suite)
def test_warmup_keeps_the_programs_a_later_process_reads(user_cache, tmp_path, capsys, monkeypatch, icosphere2):
    """`ddgjax warmup FOLDER`: once per distinct size; a later process's first call reads every kernel from the store."""
    folder = tmp_path / "meshes"
    folder.mkdir()
    save_mesh(folder / "a.obj", icosphere2)
    save_mesh(folder / "b.off", icosphere2)  # the same size: warmed once
    save_mesh(folder / "c.ply", disk(5))
    (folder / "notes.txt").write_text("not a mesh")
    assert main(["warmup", str(folder), "--only", "laplacian,heat"]) == 0
    captured = capsys.readouterr()
    assert "warmed 2 entry points for 2 mesh sizes" in captured.out
    assert "skipped" not in captured.err
    # A new process would start here: only the store on disk may serve it.
    jax.clear_caches()
    clear_programs()
    loaded = []
    load = _program_store.load
    monkeypatch.setattr(_program_store, "load", lambda *args: loaded.append(load(*args)) or loaded[-1])
    jax.block_until_ready(heat_distance(load_mesh(folder / "c.ply"), [0]))
    assert loaded and all(program is not None for program in loaded)


def test_warmup_refuses_what_is_not_a_mesh(capsys, tmp_path):
    assert main(["warmup", str(tmp_path)]) == 2
    assert "no mesh files" in capsys.readouterr().err
    assert main(["warmup", str(tmp_path / "missing.obj")]) == 2
    assert "expected a mesh file or a folder" in capsys.readouterr().err
    assert main(["warmup", str(tmp_path), "--only", "laplacian,teleport"]) == 2
    assert "unknown entry points ['teleport']" in capsys.readouterr().err


@pytest.mark.parametrize("switch", [None, "option", "environment"])
def test_the_cache_can_be_switched_off(user_cache, monkeypatch, capsys, tmp_path, switch):
    # A missing file: the command stops before any compilation, after choosing where to cache.
    argv = ["info", str(tmp_path / "missing.obj")]
    if switch == "option":
        argv.append("--no-compilation-cache")
    elif switch == "environment":
        monkeypatch.setenv(CACHE_VARIABLE, "0")
    assert main(argv) == 2
    assert "missing.obj" in capsys.readouterr().err
    assert user_cache.exists() == (switch is None)


def test_a_cache_directory_configured_in_jax_is_kept(user_cache, capsys, tmp_path):
    """With a directory already configured (e.g. by JAX_COMPILATION_CACHE_DIR), the command uses JAX's and makes none."""
    theirs = str(tmp_path / "theirs")
    with jax_cache_directory(theirs):
        assert main(["info", str(tmp_path / "missing.obj")]) == 2
        assert jax.config.jax_compilation_cache_dir == theirs
    assert "missing.obj" in capsys.readouterr().err
    assert not user_cache.exists()


def test_cache_directory(monkeypatch, tmp_path):
    monkeypatch.delenv("DDGJAX_CACHE_DIR", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert cache_directory() == str(tmp_path / "ddgjax" / "jax")
    # XDG: a relative (or empty) XDG_CACHE_HOME is ignored.
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    for value in ("relative/cache", ""):
        monkeypatch.setenv("XDG_CACHE_HOME", value)
        assert cache_directory() == str(tmp_path / "home" / ".cache" / "ddgjax" / "jax")


def test_help_lists_the_commands_and_the_cache_switch(capsys):
    assert main([]) == 0
    out = capsys.readouterr().out
    assert "flow" in out and "info" in out
    with pytest.raises(SystemExit) as exit_:
        main(["info", "--help"])
    assert exit_.value.code == 0
    assert "--no-compilation-cache" in capsys.readouterr().out


def _imported_modules(path: pathlib.Path) -> set[str]:
    """Absolute names of the modules `path` imports (relative imports resolved within ddgjax)."""
    package = ".".join(("ddgjax", *path.relative_to(PACKAGE).parent.parts)).split(".")
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = ".".join(package[: len(package) - node.level + 1]) if node.level else ""
            module = ".".join(part for part in (base, node.module) if part)
            names.add(module)
            names.update(f"{module}.{alias.name}" for alias in node.names)
    return names


def test_the_mathematics_imports_no_command_line_files_or_figures():
    """DESIGN.md's layout: the math packages import neither `ddgjax.io`, the CLI, matplotlib nor argparse."""
    modules = [path for path in PACKAGE.rglob("*.py") if path.relative_to(PACKAGE).parts[0] not in OUTSIDE_MATHEMATICS]
    assert any("mesh" in path.parts for path in modules) and any("curves" in path.parts for path in modules)
    for path in modules:
        bad = {name for name in _imported_modules(path) if name.startswith(FORBIDDEN)}
        assert not bad, f"{path.relative_to(PACKAGE)} imports {sorted(bad)}"


# ---------------------------------------------------------------- ddgjax info on a tet mesh


def test_info_reads_a_tet_mesh(tmp_path, capsys):
    from ddgjax.volume import save_tet_mesh, tet_ball

    path = tmp_path / "ball.msh"
    save_tet_mesh(path, tet_ball(2))
    assert main(["info", str(path)]) == 0
    out = capsys.readouterr().out
    assert f"tet mesh: {path}" in out and "tets 160" in out and "Euler characteristic 1  components 1" in out
    assert "boundary: 80 triangles, 42 vertices, 1 components" in out and "degenerate tets" in out
    # The boundary surface encloses what the tets fill (outward normals), up to rounding.
    assert abs(float(out.split("sum of tet volumes minus it:")[1].split(")")[0])) < 1e-12
    assert "dihedral angle (degrees)" in out


def test_info_on_a_tet_mesh_refuses_what_it_cannot_do(tmp_path, capsys):
    from ddgjax.volume import save_tet_mesh, tet_box

    path = tmp_path / "box.vtu"
    save_tet_mesh(path, tet_box(1))
    assert main(["info", str(path), "--output", str(tmp_path / "figure.png")]) == 2
    assert "--output: figures are drawn for triangle meshes only" in capsys.readouterr().err
    (tmp_path / "points.xyz").write_text("0 0 0\n")
    assert main(["info", str(tmp_path / "points.xyz")]) == 2
    err = capsys.readouterr().err
    assert "unknown tet mesh format '.xyz'" in err and ".msh" in err and ".obj" in err
