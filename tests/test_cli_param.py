"""The `ddgjax param` subcommand (ddgjax/_cli/param.py), through `ddgjax.cli.main`."""

from __future__ import annotations

import matplotlib.image
import pytest

from ddgjax._cli.param import hemisphere
from ddgjax.io import save_mesh
from ddgjax.param import boundary_first_flattening, map_distortion

from conftest import run_cli


def _row(out: str, key: str) -> str:
    return next(line for line in out.splitlines() if line.startswith(key))[10:].strip()


@pytest.mark.slow
def test_param_on_the_built_in_hemisphere_writes_a_figure(tmp_path):
    output = tmp_path / "param.png"
    status, out, err = run_cli(["param", "--output", str(output)])
    assert status == 0, err
    assert _row(out, "mesh") == "built-in hemisphere: 1801 vertices, 3456 faces"
    assert _row(out, "flipped") == "0 faces"
    # The printed mean quasi-conformal ratio is the library's (BFF with u = 0: near-conformal, ~1.02).
    mesh = hemisphere()
    expected = float(map_distortion(mesh, boundary_first_flattening(mesh)).mean_conformal_distortion)
    assert f"area-weighted mean {expected:.4g}" in _row(out, "conformal") and 1.0 < expected < 1.05
    assert matplotlib.image.imread(output).shape[0] > 100


@pytest.mark.slow
def test_param_of_a_mesh_file_by_lscm_and_bad_input(tmp_path, icosphere1):
    path = tmp_path / "patch.obj"
    save_mesh(path, hemisphere(6))
    status, out, err = run_cli(["param", str(path), "--method", "lscm", "--no-plot"])
    assert status == 0, err
    assert "least squares conformal map" in _row(out, "method") and _row(out, "flipped") == "0 faces"
    closed = tmp_path / "sphere.obj"
    save_mesh(closed, icosphere1)
    status, _, err = run_cli(["param", str(closed), "--no-plot"])
    assert status == 2 and "needs a topological disk" in err and "no boundary" in err
    status, _, err = run_cli(["param", "--checks", "0", "--no-plot"])
    assert status == 2 and "--checks: expected at least 1" in err
    status, _, err = run_cli(["param", str(tmp_path / "missing.obj")])
    assert status == 2 and "MESH: expected an existing mesh file" in err
