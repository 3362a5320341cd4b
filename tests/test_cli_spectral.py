"""The `ddgjax spectrum` subcommand (ddgjax/_cli/spectral.py), through `ddgjax.cli.main`; `ddgjax geodesic`: test_cli_geodesic.py."""

from __future__ import annotations

import numpy as np

from ddgjax.io import save_mesh

from conftest import run_cli


def test_spectrum_of_a_mesh_file_prints_the_sphere_eigenvalues(tmp_path, icosphere3):
    path = tmp_path / "sphere.obj"
    save_mesh(path, icosphere3)
    status, out, err = run_cli(["spectrum", str(path), "-k", "4", "--no-plot"])
    assert status == 0, err
    values = [float(x) for x in out.split("eigenvalues")[1].split()]
    # l (l + 1) on the unit sphere, printed to 6 significant digits (rounding <= 5e-6); the l = 1 values of
    # icosphere(3) are 8.2e-7 below 2.
    np.testing.assert_allclose(values, [0.0, 2.0, 2.0, 2.0], atol=1e-5)


def test_bad_input_exits_2_with_a_message(tmp_path):
    status, _, err = run_cli(["spectrum", str(tmp_path / "missing.obj")])
    assert status == 2 and "MESH: expected an existing mesh file" in err
    status, _, err = run_cli(["spectrum", "-k", "0", "--no-plot"])
    assert status == 2 and "k: expected an integer >= 1" in err
