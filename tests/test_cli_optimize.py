"""The `ddgjax optimize` subcommand (ddgjax/_cli/optimize.py), through `ddgjax.cli.main`."""

from __future__ import annotations

import matplotlib.image
import numpy as np
import pytest

from conftest import run_cli


def _row(out: str, key: str) -> str:
    return next(line for line in out.splitlines() if line.startswith(key))[10:].strip()


@pytest.mark.slow
def test_willmore_example_rounds_the_bumpy_sphere_and_writes_a_figure(tmp_path):
    output = tmp_path / "optimize.png"
    status, out, err = run_cli(["optimize", "--no-progress", "--output", str(output)])  # 300 steps: 0.2 s after compiling
    assert status == 0, err
    start, end = (float(x) for x in _row(out, "loss").split(" -> "))
    # The discrete Willmore energy of the rounded icosphere(3): 4 pi minus its O(h^2) error (~0.06).
    assert start > 14 and abs(end - 4 * np.pi) < 0.1
    # The discrete minimiser after 300 steps is nearly, not exactly, round: measured spread 0.56 %.
    assert float(_row(out, "round").split("spread ")[1].split("%")[0]) < 1.5
    before, after = (float(x) for x in _row(out, "volume").split(" (held)")[0].split(" -> "))
    assert after == before
    assert matplotlib.image.imread(output).shape[0] > 100


@pytest.mark.slow
def test_catenoid_example_and_bad_input():
    status, out, err = run_cli(["optimize", "--example", "catenoid", "--steps", "400", "--no-progress", "--no-plot"])
    assert status == 0, err
    assert float(_row(out, "profile").split("= ")[1]) < 5e-4  # as tests/test_optim.py measures at this size
    status, _, err = run_cli(["optimize", "--steps", "0", "--no-plot"])
    assert status == 2 and "--steps: expected at least 1" in err
