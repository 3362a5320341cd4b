"""The `ddgjax deform` subcommand (ddgjax/_cli/deform.py), through `ddgjax.cli.main`."""

from __future__ import annotations

import matplotlib.image
import numpy as np
import pytest

from ddgjax._cli.deform import fixed_and_moved_vertices, standing_cylinder
from ddgjax.deform import arap
from ddgjax.io import save_mesh

from conftest import run_cli


def _rows(out: str, key: str) -> list[str]:
    return [line for line in out.splitlines() if line.startswith(key)]


def test_handles_are_the_lowest_and_highest_bands_turned_about_the_up_axis():
    for up in ("x", "y", "z"):
        rest = np.asarray(standing_cylinder(up).vertices)
        axis = "xyz".index(up)
        fixed, moved, targets = fixed_and_moved_vertices(rest, up, 0.1, 0.3, 90.0, 0.2)
        # 17 rings 0.125 apart: a band of 0.2 of the height 2 holds the two end rings of 32 vertices.
        assert fixed.size == moved.size == 64
        assert np.all(rest[fixed, axis] < -0.8) and np.all(rest[moved, axis] > 0.8)
        # A quarter turn about the up axis through the ring's centre (the axis itself), then lift and shift.
        a, b = (axis + 1) % 3, (axis + 2) % 3
        np.testing.assert_allclose(targets[:, a], -rest[moved, b] + 0.2, atol=1e-12)
        np.testing.assert_allclose(targets[:, b], rest[moved, a], atol=1e-12)
        np.testing.assert_allclose(targets[:, axis], rest[moved, axis] + 0.3, atol=1e-12)


@pytest.mark.slow
def test_deform_default_writes_a_figure_and_moves_the_handles_exactly(tmp_path):
    output = tmp_path / "deform.png"
    status, out, err = run_cli(["deform", "--output", str(output)])
    assert status == 0, err
    assert _rows(out, "mesh")[0].endswith("built-in cylinder: 544 vertices, 1024 faces")
    (row,) = _rows(out, "arap")
    assert row.endswith("successful")
    assert matplotlib.image.imread(output).shape[0] > 100
    # The printed largest displacement is the quarter turn of the top ring: |d| = sqrt(2) r = 0.7071.
    assert "0.7071" in row.split()
    # The same handles through the library: exact at the fixed_and_moved_vertices, the largest move at the top ring.
    mesh = standing_cylinder()
    rest = np.asarray(mesh.vertices)
    fixed, moved, targets = fixed_and_moved_vertices(rest, "z", 0.1, 0.0, 90.0, 0.0)
    deformed = np.asarray(
        arap(mesh, fixed_vertices=np.concatenate([fixed, moved]), fixed_values=np.concatenate([rest[fixed], targets]))
    )
    np.testing.assert_array_equal(deformed[fixed], rest[fixed])
    np.testing.assert_array_equal(deformed[moved], targets)
    # The top ring is placed exactly: the quarter turn's round-off (measured 1e-16).
    assert np.linalg.norm(deformed - rest, axis=1).max() == pytest.approx(np.sqrt(2) * 0.5, abs=1e-14)


@pytest.mark.slow
def test_deform_both_prints_two_rows_and_no_plot_writes_nothing(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    status, out, err = run_cli(["deform", "--method", "both", "-k", "3", "--no-plot"])
    assert status == 0, err
    assert len(_rows(out, "arap")) == 1 and len(_rows(out, "triharmonic k=3")) == 1
    assert "figure" not in out and list(tmp_path.iterdir()) == []


@pytest.mark.slow
def test_deform_of_a_mesh_file_along_y(tmp_path):
    path = tmp_path / "tube.obj"
    save_mesh(path, standing_cylinder("y"))
    status, out, err = run_cli(
        ["deform", str(path), "--up", "y", "--method", "biharmonic", "-k", "1", "--lift", "0.5", "--no-plot"]
    )
    assert status == 0, err
    assert "tube.obj: 544 vertices" in _rows(out, "mesh")[0]
    (row,) = _rows(out, "harmonic k=1")
    assert row.endswith("successful")


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--band", "0.5"], "--band: expected a fraction in (0, 0.5)"),
        (["--band", "0"], "--band: expected a fraction in (0, 0.5)"),
        (["--steps", "0"], "--steps: expected at least 1"),
        (["--turn", "nan"], "--turn: expected a finite number"),
        (["missing.obj"], "MESH: expected an existing mesh file"),
        (["--method", "lbs"], "--method: invalid choice"),
        (["-k", "4"], "-k: invalid choice"),
    ],
)
def test_deform_bad_input_exits_2_naming_the_option(argv, message):
    status, _, err = run_cli(["deform", "--no-plot", *argv])
    assert status == 2 and message in err
