"""The top-level package: lazy loading (PEP 562), the shared vocabulary's constants, the outcome helpers."""

import subprocess
import sys

import jax.numpy as jnp
import pytest

import ddgjax
from ddgjax._results import RESULTS, Solution, first_failure, outcome


def test_import_loads_no_subpackage_until_used():
    code = (
        "import sys, ddgjax; loaded = sorted(m for m in sys.modules if m.startswith('ddgjax.')); print(loaded); "
        "ddgjax.pde; print('ddgjax.pde' in sys.modules, 'ddgjax.plot' in sys.modules); "
        "ddgjax.plot; print('plotly' in sys.modules)"
    )
    lines = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True).stdout.splitlines()
    assert lines[0] == "['ddgjax._errors']"  # the exceptions only
    assert lines[1] == "True False"
    assert lines[2] == "False"  # ddgjax.plot imports plotly only when show() draws (the viewer extra)


def test_top_level_names_and_unknown_attributes():
    assert ddgjax.MASS_MATRICES == ("voronoi", "barycentric", "galerkin")
    assert set(ddgjax.LUMPED_MASS_MATRICES) < set(ddgjax.MASS_MATRICES)
    assert ddgjax.Mesh is ddgjax.mesh.Mesh and ddgjax.Curve is ddgjax.curves.Curve
    assert {"pde", "solve", "Solution", "RESULTS"} <= set(dir(ddgjax))
    with pytest.raises(AttributeError, match="no attribute 'not_a_name'"):
        ddgjax.not_a_name  # noqa: B018


def test_outcome_and_first_failure():
    value = jnp.arange(3.0)
    assert outcome(value, RESULTS.successful, throw=True) is value
    solution = outcome(value, RESULTS.singular, throw=False, stats={"residual": 1.0})
    assert isinstance(solution, Solution) and solution.result == RESULTS.singular and solution.stats == {"residual": 1.0}
    with pytest.raises(Exception, match="singular"):
        outcome(value, RESULTS.singular, throw=True)
    assert first_failure(RESULTS.successful, RESULTS.max_steps_reached, RESULTS.singular) == RESULTS.max_steps_reached
    assert first_failure(RESULTS.successful, RESULTS.successful) == RESULTS.successful
