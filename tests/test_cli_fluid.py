"""The `ddgjax fluid` subcommand (ddgjax/_cli/fluid.py), through `ddgjax.cli.main`.

Checked against conservation laws (the implicit midpoint steps keep kinetic energy and enstrophy of the
inviscid flow, and the dye's L2 norm, to round-off), Haurwitz's closed form for the turning rate of a
Rossby-Haurwitz wave, and the great-circle geometry of a user's sphere (the vortex pair's vertices
antipodal). Runs on the built-in icosphere(4) or on icosphere(2) files compile a basis and a flow each
(5-10 s on a loaded machine): marked slow; refused input returns before anything compiles.
"""

from __future__ import annotations

import re

import matplotlib.image
import numpy as np
import pytest
from PIL import Image

from ddgjax.io import save_mesh
from ddgjax.mesh import disk, icosphere

from conftest import run_cli


def _numbers(out: str, row: str) -> list[float]:
    """The numbers of the printed row `row` (the first word of its line)."""
    line = next(line for line in out.splitlines() if line.split()[:1] == [row])
    return [float(x) for x in re.findall(r"-?\d+\.?\d*(?:e[-+]?\d+)?", line[len(row) :])]


def _drift(out: str, row: str) -> float:
    """The relative drift printed in row `row`, checked against its own first and last values."""
    first, last, drift = _numbers(out, row)[-3:]
    # first and last are printed to 10 significant digits (5e-11 relative each), the drift to 3.
    assert drift == pytest.approx(abs(last - first) / first, abs=1e-9)
    return drift


@pytest.mark.slow
def test_default_vortex_pair_conserves_energy_and_enstrophy():
    status, out, err = run_cli(["fluid", "--steps", "40", "--no-plot"])
    assert status == 0, err
    assert "2562 vertices, 5120 faces" in out and "k = 64" in out
    assert "40 steps of tau 0.05, t = 0 to 2, 21 saved states" in out
    # Implicit midpoint steps keep both quadratic invariants to round-off (measured 5e-16 and 1e-16).
    assert _drift(out, "energy") < 1e-12
    assert _drift(out, "enstrophy") < 1e-12
    assert _drift(out, "dye") < 1e-12  # the dye's Cayley-transform step is orthogonal (measured 1.6e-15)
    assert out.splitlines()[-1].split() == ["result", "successful"]


@pytest.mark.slow
def test_rossby_haurwitz_rate_against_haurwitz(tmp_path):
    output = tmp_path / "rossby.png"
    status, out, err = run_cli(["fluid", "--initial", "rossby-haurwitz", "--dye", "none", "--output", str(output)])
    assert status == 0, err
    image = matplotlib.image.imread(output)
    assert image.shape[1] > 3 * image.shape[0]  # without dye: one row of four states
    assert "l = 4, m = 3" in out and "rotation 1" in out
    rate, closed = _numbers(out, "haurwitz")[0], _numbers(out, "haurwitz")[-2]
    # Haurwitz (1940): the pattern turns westward at -2 Omega / (l (l + 1)) = -0.1 in the rotating frame;
    # the discrete eigenvalues lie below l (l + 1) (second order in h): measured 0.73 % on icosphere(4).
    assert closed == -0.1  # -2 / 20, printed to 6 significant digits
    assert rate == pytest.approx(-2 * 1.0 / (4 * 5), rel=0.02)
    assert _drift(out, "energy") < 1e-12  # the Coriolis term does no work: round-off (measured 7e-15)


@pytest.mark.slow
def test_mesh_file_vortex_pair_and_figures(sphere_obj, icosphere2, tmp_path):
    output, frames, animation = tmp_path / "fluid.png", tmp_path / "frames", tmp_path / "fluid.gif"
    argv = ["fluid", sphere_obj, "-k", "16", "--steps", "20", "--save-every", "5", "--dye", "checker"]
    status, out, err = run_cli([*argv, "--output", str(output), "--frames", str(frames), "--animation", str(animation)])
    assert status == 0, err
    assert "sphere.obj: 162 vertices, 320 faces" in out and "5 saved states" in out
    # The two farthest vertices of a unit sphere are antipodal (icosphere(2) has antipodal vertex pairs).
    first, second = (int(x) for x in _numbers(out, "initial")[-3:-1])
    points = np.asarray(icosphere2.vertices)
    assert points[first] @ points[second] == pytest.approx(-1.0, abs=1e-12)
    assert _drift(out, "energy") < 1e-12 and _drift(out, "enstrophy") < 1e-12  # round-off (measured 0)
    image = matplotlib.image.imread(output)
    assert image.shape[0] > 300 and image.shape[1] > 3 * image.shape[0] / 2  # a 2 x 4 grid of panels
    assert sorted(p.name for p in frames.iterdir()) == [f"frame_{i:04d}.png" for i in range(5)]
    assert matplotlib.image.imread(frames / "frame_0004.png").shape[0] > 100
    with Image.open(animation) as gif:
        assert gif.n_frames == 5
    assert "5 frames written" in out and "animation of 5 frames" in out


def test_mesh_with_boundary_refused(tmp_path):
    path = tmp_path / "disk.obj"
    save_mesh(path, disk(8))  # 217 vertices: more than k = 64
    status, out, err = run_cli(["fluid", str(path), "--no-plot"])
    assert status == 2 and out == ""
    assert err.startswith("ddgjax fluid: error: mesh: expected a closed surface") and "boundary vertices" in err


def test_bad_options_refused(sphere_obj, tmp_path):
    status, _, err = run_cli(["fluid", "--initial", "bogus"])
    assert status == 2 and "invalid choice: 'bogus'" in err
    status, _, err = run_cli(["fluid", "--tau", "0"])
    assert status == 2 and "--tau: expected a number > 0" in err
    status, _, err = run_cli(["fluid", "--steps", "20", "--save-every", "7", "--no-plot"])
    assert status == 2 and "--save-every: expected a divisor of --steps (20), got 7" in err
    status, _, err = run_cli(["fluid", "--viscosity", "-1", "--no-plot"])
    assert status == 2 and "--viscosity: expected a finite number >= 0" in err
    status, _, err = run_cli(["fluid", "--degree", "3", "--no-plot"])
    assert status == 2 and "--degree: only with --initial rossby-haurwitz" in err
    status, _, err = run_cli(["fluid", "--initial", "rossby-haurwitz", "--order", "5", "--no-plot"])
    assert status == 2 and "expected 1 <= m <= l, got l = 4, m = 5" in err
    status, _, err = run_cli(["fluid", "--animation", "movie.mp4", "--no-plot"])
    assert status == 2 and "--animation: expected a .gif file name" in err
    status, _, err = run_cli(["fluid", sphere_obj, "-k", "500", "--no-plot"])
    assert status == 2 and err.startswith("ddgjax fluid: error: k: expected fewer eigenfunctions than the 162 vertices")
    big = tmp_path / "big.obj"
    save_mesh(big, icosphere(1, radius=2.0))
    status, _, err = run_cli(["fluid", str(big), "--initial", "rossby-haurwitz", "--no-plot"])
    assert status == 2 and "expected a unit sphere centred at the origin" in err
    status, _, err = run_cli(["fluid", str(tmp_path / "missing.obj"), "--no-plot"])
    assert status == 2 and "MESH: expected an existing mesh file" in err
