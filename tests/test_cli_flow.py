"""The `ddgjax flow` subcommand (ddgjax/_cli/flow.py), driven through `ddgjax.cli.main`."""

from __future__ import annotations

import re

import matplotlib.image
import numpy as np
import pytest

from ddgjax.curves import figure3_polygon

from conftest import run_cli

SHORT = ["--steps", "40", "--save-every", "10"]
INVARIANTS = ("total curvature", "centroid", "cyclic residual", "length", "area", "isoperimetric ratio", "simple")


_run = run_cli


def _table(text):
    """`{(kind, quantity): change}` from the printed table (rows of a flow follow its first row)."""
    changes, kind = {}, None
    for line in text.splitlines():
        match = re.match(r"^([ABCD])\s+\S+\s+(.*)$", line) or re.match(r"^\s{10,}(.*)$", line)
        if not match or line.startswith("-"):
            continue
        if len(match.groups()) == 2:
            kind, rest = match.groups()
        else:
            (rest,) = match.groups()
        quantity = next((name for name in INVARIANTS if rest.startswith(name)), None)
        if kind and quantity:
            last = rest.split()[-1]
            changes[kind, quantity] = float(last) if re.match(r"^[+-]\d", last) else last
    return changes


@pytest.fixture(scope="module")
def default_run(tmp_path_factory):
    """One short run of the default flows A, B, D on the default polygon, with the figure."""
    output = tmp_path_factory.mktemp("flow") / "flow.png"
    status, out, err = _run(["flow", *SHORT, "--output", str(output)])
    return status, out, err, output


@pytest.mark.slow  # the main job end to end, with its figure (> 2 s)
def test_flow_writes_a_figure(default_run):
    status, out, err, output = default_run
    assert status == 0, err
    assert output.exists() and output.stat().st_size > 50_000
    image = matplotlib.image.imread(output)
    assert image.shape[0] > 500 and image.shape[1] > 1000
    # Not blank: many distinct colours (curves in four colours, anti-aliased, plus text).
    rgb = np.round(image[..., :3] * 255).astype(np.uint32)
    assert np.unique((rgb[..., 0] << 16) | (rgb[..., 1] << 8) | rgb[..., 2]).size > 100
    assert f"figure written to {output}" in out


@pytest.mark.slow
def test_flow_table_lists_every_flow_and_invariant(default_run):
    _, out, _, _ = default_run
    changes = _table(out)
    for kind in "ABD":
        for quantity in INVARIANTS:
            assert (kind, quantity) in changes, (kind, quantity, out)
    # The report's claims, read off the table: A keeps its total curvature, B its vertex centroid
    # (explicit steps, rounding only), D does not keep either, and its cyclic residual falls.
    assert abs(changes["A", "total curvature"]) < 1e-12
    assert abs(changes["B", "centroid"]) < 1e-12
    assert abs(changes["D", "total curvature"]) > 1e-6 and changes["D", "centroid"] > 1e-6
    assert changes["D", "cyclic residual"] < 0
    assert changes["A", "simple"] == "yes"
    assert "compilation included" in out


def test_flow_help():
    status, out, _ = _run(["flow", "--help"])
    assert status == 0
    for option in ("--shape", "--kinds", "--tau", "--steps", "--save-every", "--method", "--rescale", "--output"):
        assert option in out


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--shape", "no/such/polygon.csv"], "--shape: expected one of figure3"),
        (["--shape", "{bad_file}"], "two numbers"),
        (["--steps", "40", "--save-every", "7"], "save_every: expected a divisor"),
    ],
)
def test_flow_bad_input_is_a_clean_error(tmp_path, argv, message):
    bad_file = tmp_path / "bad.csv"
    bad_file.write_text("x,y\n0,0\n1\n")
    status, out, err = _run(["flow", "--output", str(tmp_path / "x.png"), *(a.format(bad_file=bad_file) for a in argv)])
    assert status == 2
    assert message in err and "Traceback" not in err + out
    assert not (tmp_path / "x.png").exists()


@pytest.mark.parametrize("argv", [["--kinds", "A,E"], ["--kinds", "A,A"], ["--steps", "0"], ["--tau", "-1"], ["--method", "rk4"]])
def test_flow_bad_options_are_usage_errors(argv):
    status, _, err = _run(["flow", *argv])
    assert status == 2 and "usage:" in err


@pytest.mark.slow  # the fast tier's time limit (its checks run in the full suite)
def test_flow_reads_and_reorients_a_clockwise_file(tmp_path):
    points = np.asarray(figure3_polygon().points)[::-1]
    path = tmp_path / "clockwise.csv"
    np.savetxt(path, points, delimiter=",")
    # Same size, kind, steps and saves as `default_run`: the compiled flow is reused.
    status, out, err = _run(["flow", "--shape", str(path), "--kinds", "b", *SHORT, "--no-plot"])
    assert status == 0, err
    assert "clockwise.csv is clockwise; reversing" in out
    changes = _table(out)
    assert abs(changes["B", "centroid"]) < 1e-12 and changes["B", "simple"] == "yes"


def test_a_self_intersecting_flow_is_reported_not_raised():
    # Far above the explicit stability limit: the first step already crosses the polygon over itself.
    status, out, err = _run(["flow", "--kinds", "B", "--tau", "10", *SHORT, "--no-plot"])
    assert status == 0, err
    assert re.search(r"simple \(at every step\)\s+yes\s+no \(step 1\)", out), out
    assert "warning: flow B: the curve self-intersected at step 1" in out
