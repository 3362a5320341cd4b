"""The `ddgjax geodesic` and `ddgjax spectrum` subcommands (ddgjax/_cli/spectral.py), through `ddgjax.cli.main`."""

from __future__ import annotations

import matplotlib.image
import numpy as np
import pytest

from ddgjax.io import save_mesh
from ddgjax.mesh import icosphere

from conftest import run_cli


@pytest.mark.slow
def test_geodesic_on_the_built_in_torus_writes_a_figure(tmp_path):
    output = tmp_path / "geodesic.png"
    status, out, err = run_cli(["geodesic", "--output", str(output)])
    assert status == 0, err
    assert "1536 vertices" in out and "vertex 0" in out
    # On the torus (R = 1, r = 0.4) the farthest distance lies between the longest chord, 2 (R + r), and
    # the path half round the outer equator then half round a meridian, pi (R + r) + pi r.
    largest = float(out.split("distance")[1].split("max")[1].split(",")[0])
    assert 2 * 1.4 < largest < np.pi * 1.4 + np.pi * 0.4
    assert matplotlib.image.imread(output).shape[0] > 100


def test_spectrum_of_a_mesh_file_prints_the_sphere_eigenvalues(tmp_path):
    path = tmp_path / "sphere.obj"
    save_mesh(path, icosphere(3))
    status, out, err = run_cli(["spectrum", str(path), "-k", "4", "--no-plot"])
    assert status == 0, err
    values = [float(x) for x in out.split("eigenvalues")[1].split()]
    np.testing.assert_allclose(values, [0.0, 2.0, 2.0, 2.0], atol=0.02)  # l (l + 1) on the unit sphere


def test_bad_input_exits_2_with_a_message(tmp_path):
    status, _, err = run_cli(["geodesic", "--source", "99999", "--no-plot"])
    assert status == 2 and "--source: expected a vertex index in [0, 1536)" in err
    status, _, err = run_cli(["spectrum", str(tmp_path / "missing.obj")])
    assert status == 2 and "MESH: expected an existing mesh file" in err
    status, _, err = run_cli(["spectrum", "-k", "0", "--no-plot"])
    assert status == 2 and "k: expected an integer >= 1" in err
