"""The `ddgjax fields` subcommand (ddgjax/_cli/fields.py), through `ddgjax.cli.main`."""

from __future__ import annotations

import matplotlib.image
import pytest

from ddgjax.io import save_mesh
from ddgjax.mesh import torus

from conftest import run_cli


def _row(out: str, key: str) -> str:
    return next(line for line in out.splitlines() if line.startswith(key))[10:].strip()


@pytest.mark.slow
def test_fields_on_the_built_in_sphere_writes_a_figure(tmp_path):
    output = tmp_path / "fields.png"
    status, out, err = run_cli(["fields", "--output", str(output)])
    assert status == 0, err
    assert _row(out, "mesh").startswith("built-in icosphere(3): 642 vertices") and "Euler characteristic 2" in out
    # The smoothest cross field on a sphere: eight +1/4 singularities (Poincare-Hopf: they sum to 2).
    assert _row(out, "singular") == "8 x +1/4" and _row(out, "sum").startswith("+2 ")
    assert matplotlib.image.imread(output).shape[0] > 100


@pytest.mark.slow
def test_fields_of_a_torus_file_aligned_and_bad_input(tmp_path):
    path = tmp_path / "torus.obj"
    save_mesh(path, torus(major_radius=1.0, minor_radius=0.4, n_major=32, n_minor=12))
    status, out, err = run_cli(["fields", str(path), "-n", "2", "--align", "1.0", "--no-plot"])
    assert status == 0, err
    # Curvature-aligned line field on a torus: no singularities (chi = 0).
    assert "aligned to principal curvature" in _row(out, "field") and _row(out, "singular") == "none"
    assert _row(out, "sum").startswith("0 ")
    status, _, err = run_cli(["fields", "-n", "0", "--no-plot"])
    assert status == 2 and "n:" in err
    status, _, err = run_cli(["fields", str(tmp_path / "missing.obj")])
    assert status == 2 and "MESH: expected an existing mesh file" in err
