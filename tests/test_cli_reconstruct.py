"""The `ddgjax reconstruct` subcommand (ddgjax/_cli/reconstruct.py), through `ddgjax.cli.main`.

Small grids (`--depth 4` / `5`) and few samples keep each run short; the default run (the built-in torus) and
the mesh file compile a reconstruction and draw or sample: marked slow. Bad input is refused before any solve.
"""

from __future__ import annotations

import re

import matplotlib.image
import numpy as np
import pytest

from conftest import data_path, run_cli


def _numbers(out: str, row: str) -> list[float]:
    """The numbers of the printed row `row` (the first word of its line)."""
    line = next(line for line in out.splitlines() if line.split()[:1] == [row])
    return [float(x) for x in re.findall(r"-?\d+\.?\d*(?:e-?\d+)?", line[len(row) :])]


@pytest.mark.slow
def test_default_torus_writes_a_figure_and_prints_its_topology(tmp_path):
    output = tmp_path / "reconstruct.png"
    status, out, err = run_cli(["reconstruct", "--depth", "5", "--samples", "4000", "--output", str(output)])
    assert status == 0, err
    assert "built-in torus" in out and "4000 points" in out and "32^3 nodes" in out
    assert "closed True, manifold True, components 1, genus 1" in out
    # The vertices lie within a grid spacing (2.2 * 2.8 / 32 = 0.19) of the sampled torus.
    mean, largest = _numbers(out, "distance")[-2:]
    assert mean < 0.05 and largest < 0.2
    assert matplotlib.image.imread(output).shape[0] > 100


@pytest.mark.slow
def test_a_mesh_file_is_sampled_and_reconstructed():
    path = str(data_path("meshes", "torus.obj"))
    status, out, err = run_cli(["reconstruct", path, "--depth", "5", "--samples", "4000", "--no-plot"])
    assert status == 0, err
    assert "torus.obj, sampled: 4000 points" in out
    assert "closed True, manifold True, components 1, genus 1" in out


def test_a_missing_file_exits_with_status_2(tmp_path):
    status, out, err = run_cli(["reconstruct", str(tmp_path / "absent.xyz"), "--no-plot"])
    assert status == 2 and out == ""
    assert "ddgjax reconstruct: error: POINTS_OR_MESH: expected an existing file" in err


def test_a_point_file_with_nan_exits_with_status_2(tmp_path):
    points = np.random.default_rng(0).standard_normal((200, 3))
    points /= np.linalg.norm(points, axis=1, keepdims=True)
    points[5, 1] = np.nan
    path = tmp_path / "points.xyz"
    np.savetxt(path, np.concatenate([points, points], axis=1))  # positions and normals
    status, out, err = run_cli(["reconstruct", str(path), "--depth", "4", "--no-plot"])
    assert status == 2 and out == ""
    assert "ddgjax reconstruct: error:" in err and "NaN/inf at rows [5]" in err


def test_a_point_file_with_the_wrong_columns_exits_with_status_2(tmp_path):
    path = tmp_path / "points.xyz"
    np.savetxt(path, np.ones((20, 4)))
    status, _, err = run_cli(["reconstruct", str(path), "--no-plot"])
    assert status == 2 and "expected 3 columns (positions) or 6 (positions and normals), got 4" in err
