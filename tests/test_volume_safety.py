"""Nothing lost and nothing silent with tet meshes: TetGen pairs saved all or nothing, killed saves cleaned up,
inverted tets kept by a round trip and refused by the problem layer (issue 41)."""

from __future__ import annotations

import os
import pathlib
import signal
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ddgjax import DDGInputError, MeshDataError
from ddgjax.geodesics import heat_distance
from ddgjax.io import load_mesh, save_mesh
from ddgjax.pde import solve_poisson
from ddgjax.spectral import eigenpairs
from ddgjax.volume import TetMesh, check_tet_mesh, load_tet_mesh, save_tet_mesh, tet_ball, tet_box


def _listing(folder: pathlib.Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


def test_tetgen_pair_is_replaced_together_or_not_at_all(tmp_path, monkeypatch):
    """The `.ele` rename fails after the `.node` one succeeded: the `.node` gets its old bytes back, so the
    old pair is whole, no temporary file is left, and the next save writes the new pair."""
    old_mesh, new_mesh = tet_ball(1), tet_ball(2)
    path = tmp_path / "solid.node"
    save_tet_mesh(path, old_mesh)
    old = {name: (tmp_path / name).read_bytes() for name in _listing(tmp_path)}
    real_replace = os.replace

    def failing_replace(source, target):
        if str(target).endswith(".ele"):
            raise OSError(28, "No space left on device")
        return real_replace(source, target)

    monkeypatch.setattr(os, "replace", failing_replace)
    with pytest.raises(OSError, match="No space"):
        save_tet_mesh(path, new_mesh)
    monkeypatch.setattr(os, "replace", real_replace)
    assert {name: (tmp_path / name).read_bytes() for name in _listing(tmp_path)} == old
    assert load_tet_mesh(path).n_vertices == old_mesh.n_vertices
    save_tet_mesh(path, new_mesh)
    assert _listing(tmp_path) == ["solid.ele", "solid.node"]
    np.testing.assert_array_equal(np.asarray(load_tet_mesh(path).tets), np.asarray(new_mesh.tets))


def test_a_new_pair_that_fails_halfway_leaves_no_file(tmp_path, monkeypatch):
    """With no old pair, a failed second rename removes the first new file too: never a lone `.node`."""
    real_replace = os.replace
    monkeypatch.setattr(
        os,
        "replace",
        lambda s, t: (_ for _ in ()).throw(OSError(5, "I/O error")) if str(t).endswith(".ele") else real_replace(s, t),
    )
    with pytest.raises(OSError):
        save_tet_mesh(tmp_path / "solid.ele", tet_ball(1))
    assert _listing(tmp_path) == []


def test_a_pair_not_written_together_is_refused_by_name(tmp_path):
    """A `.node` from one save beside an `.ele` from another (the pair a half-failed save used to leave) is refused,
    naming both files; a pair written by another tool (no tags) is read as before."""
    save_tet_mesh(tmp_path / "a.node", tet_ball(1))
    save_tet_mesh(tmp_path / "b.node", tet_ball(2))
    (tmp_path / "a.node").write_bytes((tmp_path / "b.node").read_bytes())
    with pytest.raises(DDGInputError, match=r"a\.node.*a\.ele.*not written together"):
        load_tet_mesh(tmp_path / "a.ele")
    for suffix in (".node", ".ele"):  # the same pair without ddgjax's first line: a foreign pair
        lines = (tmp_path / f"b{suffix}").read_text().splitlines(keepends=True)
        (tmp_path / f"c{suffix}").write_text("".join(lines[1:]))
    assert load_tet_mesh(tmp_path / "c.node").n_tets == tet_ball(2).n_tets


_KILLED_SAVE = """
import sys, time
import ddgjax.io
from ddgjax.mesh import icosphere

def stalled(handle, vertices, faces):
    handle.write(b"v 0 0 0")
    handle.flush()
    print("writing", flush=True)
    time.sleep(600)

ddgjax.io._WRITERS["obj"] = stalled
ddgjax.io.save_mesh(sys.argv[1], icosphere(1))
"""


@pytest.mark.slow
def test_a_killed_save_leaves_files_the_next_save_removes(tmp_path, icosphere1):
    """A save killed mid-write (SIGKILL: no clean-up runs) leaves its hidden temporary file; the next save of the
    same target removes it, and keeps the temporary file of a save still running in another process."""
    path = tmp_path / "mesh.obj"
    save_mesh(path, icosphere1)
    run = subprocess.Popen([sys.executable, "-c", _KILLED_SAVE, str(path)], stdout=subprocess.PIPE, text=True)
    assert run.stdout.readline().strip() == "writing"
    running = subprocess.Popen([sys.executable, "-c", _KILLED_SAVE, str(path)], stdout=subprocess.PIPE, text=True)
    try:
        assert running.stdout.readline().strip() == "writing"
        os.kill(run.pid, signal.SIGKILL)
        run.wait()
        leftovers = [name for name in _listing(tmp_path) if name.startswith(".mesh.obj.ddgjax-")]
        assert len(leftovers) == 2  # the killed save's and the running one's
        save_mesh(path, icosphere1)
        assert [name for name in _listing(tmp_path) if name.startswith(".")] == [f for f in leftovers if f"-{running.pid}-" in f]
        assert load_mesh(path).n_vertices == icosphere1.n_vertices
    finally:
        running.kill()
        running.wait()


def test_save_tet_mesh_writes_no_scratch_folder_beside_the_target(tmp_path, monkeypatch):
    """meshio's scratch files go to the system's temporary folder, so a crash there leaves nothing in the user's."""
    import meshio

    seen = []
    real_write = meshio.write
    monkeypatch.setattr(meshio, "write", lambda p, *a, **k: (seen.append(pathlib.Path(p).parent), real_write(p, *a, **k))[1])
    save_tet_mesh(tmp_path / "solid.vtu", tet_ball(1))
    assert seen and all(tmp_path not in folder.parents and folder != tmp_path for folder in seen)


def _inverted(tet_mesh: TetMesh, vertex: int = 0) -> TetMesh:
    """`tet_mesh` with `vertex` pushed through the face opposite it in its first tet (some tets turned inside out)."""
    vertices = np.array(tet_mesh.vertices)
    tet = np.asarray(tet_mesh.tets)[np.flatnonzero((np.asarray(tet_mesh.tets) == vertex).any(axis=1))[0]]
    opposite = vertices[tet[tet != vertex]].mean(axis=0)
    vertices[vertex] = opposite + 1.5 * (opposite - vertices[vertex])
    return tet_mesh.with_vertices(vertices)


def test_problem_layer_refuses_inverted_tets():
    """heat_distance, solve_poisson and eigenpairs on a solid with inverted tets raise MeshDataError naming them
    (the mass used to sum to more than the signed volume: a folded solid), as they refuse flat tets."""
    moved = _inverted(tet_ball(2))
    inverted = check_tet_mesh(moved).inverted_tets
    assert inverted.size
    for run in (
        lambda: heat_distance(moved, [5]),
        lambda: solve_poisson(moved, np.ones(moved.n_vertices)),
        lambda: eigenpairs(moved, k=4),
    ):
        with pytest.raises(MeshDataError, match=rf"tet_mesh: {inverted.size} of its .* inverted .*tets \[{inverted[0]}"):
            run()
    mirrored = tet_ball(2).with_vertices(-tet_ball(2).vertices)
    with pytest.raises(MeshDataError, match="from_arrays"):
        heat_distance(mirrored, [5])
    rebuilt = TetMesh.from_arrays(mirrored.vertices, mirrored.tets)  # the remedy the message names
    assert np.isfinite(np.asarray(heat_distance(rebuilt, [5]))).all()


@pytest.mark.parametrize("suffix", [".msh", ".vtu", ".mesh", ".node"])
def test_a_round_trip_keeps_inverted_tets_inverted(tmp_path, suffix):
    """save + load gives back the tets as they were, inverted ones too, so the inversion can still be seen; a file
    whose tets are all negative (another convention) is turned right side out."""
    moved = _inverted(tet_ball(2))
    save_tet_mesh(tmp_path / f"moved{suffix}", moved)
    loaded = load_tet_mesh(tmp_path / f"moved{suffix}")
    np.testing.assert_array_equal(np.asarray(loaded.tets), np.asarray(moved.tets))
    np.testing.assert_array_equal(check_tet_mesh(loaded).inverted_tets, check_tet_mesh(moved).inverted_tets)
    with pytest.raises(MeshDataError, match="inverted"):
        solve_poisson(loaded, np.ones(loaded.n_vertices))
    ball = tet_ball(1)
    flipped = TetMesh.from_arrays(ball.vertices, ball.tets)  # positive, then written with every tet reversed:
    save_tet_mesh(tmp_path / f"reversed{suffix}", flipped.with_vertices(-ball.vertices))
    assert check_tet_mesh(load_tet_mesh(tmp_path / f"reversed{suffix}")).inverted_tets.size == 0


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.data())
def test_random_moves_are_refused_exactly_when_a_tet_inverts(data):
    """Random moves of random vertices of a box: the problem layer refuses the solid iff `check_tet_mesh`
    finds an inverted (or flat) tet, and otherwise solves with finite values."""
    box = tet_box(3)
    rng = np.random.default_rng(data.draw(st.integers(0, 2**31 - 1)))
    vertices = np.array(box.vertices)
    chosen = rng.choice(box.n_vertices, size=data.draw(st.integers(1, 4)), replace=False)
    vertices[chosen] += rng.normal(scale=data.draw(st.sampled_from([0.05, 0.3, 0.8])), size=(chosen.size, 3))
    moved = box.with_vertices(vertices)
    report = check_tet_mesh(moved)
    if report.inverted_tets.size or report.degenerate_tets.size:
        with pytest.raises(MeshDataError, match="inverted|near-zero volume"):
            solve_poisson(moved, np.ones(moved.n_vertices))
    else:
        assert np.isfinite(np.asarray(solve_poisson(moved, np.ones(moved.n_vertices)))).all()
