"""The `ddgjax geodesic` subcommand (ddgjax/_cli/geodesic.py) and its modes, through `ddgjax.cli.main`.

The modes run on the unit icosphere of 162 vertices (a file, as a user's mesh), whose distances have a
closed form (the great-circle distance, largest pi at the antipode). Each mode compiles its own solver
(10-20 s on a loaded machine): marked slow.
"""

from __future__ import annotations

import re

import matplotlib.image
import numpy as np
import pytest

from conftest import run_cli


def _numbers(out: str, row: str) -> list[float]:
    """The numbers of the printed row `row` (the first word of its line)."""
    line = next(line for line in out.splitlines() if line.split()[:1] == [row])
    return [float(x) for x in re.findall(r"-?\d+\.?\d*(?:e-?\d+)?", line[len(row) :])]


@pytest.mark.slow
def test_geodesic_on_the_built_in_torus_writes_a_figure(tmp_path):
    output = tmp_path / "geodesic.png"
    status, out, err = run_cli(["geodesic", "--output", str(output)])
    assert status == 0, err
    assert "1536 vertices" in out and "vertex 0" in out
    # On the torus (R = 1, r = 0.4) the farthest distance lies between the longest chord, 2 (R + r), and
    # the path half round the outer equator then half round a meridian, pi (R + r) + pi r.
    largest = _numbers(out, "distance")[0]
    assert 2 * 1.4 < largest < np.pi * 1.4 + np.pi * 0.4
    assert matplotlib.image.imread(output).shape[0] > 100


@pytest.mark.slow
def test_log_map_reaches_the_antipode(sphere_obj):
    status, out, err = run_cli(["geodesic", sphere_obj, "--log-map", "--cells", "4", "--no-plot"])
    assert status == 0, err
    radius, mean = _numbers(out, "log")[0], _numbers(out, "log")[1]
    # The radial field integrated at 162 vertices: measured 2.959 at the antipode (5.8 % short: the cut locus,
    # where the radial field turns) and 1.548 on average (1.5 % short).
    assert radius == pytest.approx(np.pi, rel=0.08)  # the antipode of the unit sphere
    assert mean == pytest.approx(np.pi / 2, rel=0.03)  # the mean great-circle distance on the sphere


@pytest.mark.slow
def test_transport_keeps_lengths(sphere_obj):
    status, out, err = run_cli(["geodesic", sphere_obj, "--transport", "--angle", "30", "--no-plot"])
    assert status == 0, err
    assert "30 degrees from e1" in out
    shortest, longest, normal = _numbers(out, "transport")[:2] + _numbers(out, "transport")[-1:]
    assert abs(shortest - 1) < 1e-10 and abs(longest - 1) < 1e-10  # printed to 12 decimals: 1.000000000000
    assert normal < 1e-10  # tangent to the vertex frames


@pytest.mark.slow
def test_signed_distance_changes_sign_across_the_ball_boundary(sphere_obj, tmp_path):
    output = tmp_path / "signed.png"
    status, out, err = run_cli(["geodesic", sphere_obj, "--signed", "--radius", "1.2", "--output", str(output)])
    assert status == 0, err
    assert "1 curve(s), 1 closed" in out
    low, high = _numbers(out, "signed")
    assert low < 0 < high
    negative, _, positive, _ = _numbers(out, "sign")
    assert negative == 100.0 and positive == 100.0
    # Against the distance to the ball's boundary (|d - r| on a geodesic ball), up to the faces' jagged edge
    # (the curve runs along the mesh's edges, not the circle): measured 0.19.
    assert _numbers(out, "vs")[0] < 0.25
    assert output.stat().st_size > 0 and matplotlib.image.imread(output).shape[0] > 100
    # A gap of 3 edges: the sign survives (the signed heat method's robustness to holes).
    status, out, err = run_cli(["geodesic", sphere_obj, "--signed", "--radius", "1.2", "--gap", "3", "--no-plot"])
    assert status == 0, err
    assert "3 removed" in out
    negative, _, positive, _ = _numbers(out, "sign")
    assert negative > 90 and positive > 90
    # A ball too small to hold a face, and a gap as long as the loop: exit 2.
    status, _, err = run_cli(["geodesic", sphere_obj, "--signed", "--radius", "0.01", "--no-plot"])
    assert status == 2 and "holds no whole face" in err
    status, _, err = run_cli(["geodesic", sphere_obj, "--signed", "--radius", "1.2", "--gap", "1000", "--no-plot"])
    assert status == 2 and "--gap: expected at most" in err


@pytest.mark.slow
def test_point_cloud_distance_agrees_with_the_mesh(sphere_obj):
    status, out, err = run_cli(["geodesic", sphere_obj, "--point-cloud", "--no-plot"])
    assert status == 0, err
    assert "162 (the mesh's vertices)" in out
    assert _numbers(out, "relative")[0] < 0.005  # the point cloud's Laplacian against the mesh's: measured 0.0011
    # The heat method's error at 162 points, as the mesh's: measured 3.044 (3.1 % short of pi).
    assert _numbers(out, "cloud")[0] == pytest.approx(np.pi, rel=0.05)


def test_bad_input_exits_2_with_a_message(sphere_obj):
    status, _, err = run_cli(["geodesic", "--source", "99999", "--no-plot"])
    assert status == 2 and "--source: expected a vertex index in [0, 1536)" in err
    status, _, err = run_cli(["geodesic", "--log-map", "--transport", "--no-plot"])
    assert status == 2 and "not allowed with argument" in err
    status, _, err = run_cli(["geodesic", sphere_obj, "--gap", "2", "--no-plot"])
    assert status == 2 and "--gap: only with --signed" in err
    status, _, err = run_cli(["geodesic", sphere_obj, "--signed", "--angle", "10", "--no-plot"])
    assert status == 2 and "--angle: only with --transport" in err
    status, _, err = run_cli(["geodesic", sphere_obj, "--signed", "--radius", "-1", "--no-plot"])
    assert status == 2 and "--radius: expected a positive number" in err
    status, _, err = run_cli(["geodesic", sphere_obj, "--log-map", "--cells", "0", "--no-plot"])
    assert status == 2 and "--cells: expected at least 1" in err
