"""Tests for ddgjax.sharding: a batch sharded over devices and one mesh partitioned across them, each
equal to its unsharded computation, on 8 host CPU devices in a subprocess (tests/sharding_checks.py).

The device count of JAX's CPU backend is fixed when the backend starts (`XLA_FLAGS=
--xla_force_host_platform_device_count=8`), so the checks run in a fresh interpreter, with the flag
appended to the suite's own `XLA_FLAGS` (tests/conftest.py), and report what they measured as JSON.
"""

from __future__ import annotations

import functools
import json
import os
import subprocess
import sys

import numpy as np
import pytest

from ddgjax import DDGInputError
from ddgjax.sharding import batch_sharding, partition_vertices, shard_batch, sharded_cg, sharded_laplacian_apply

from conftest import REPO

# The slow tier (pyproject.toml): the checks run in a subprocess with 8 host devices.
pytestmark = pytest.mark.slow

SHARDED = "P('batch',)"
VERTICES = "P('vertices',)"


@functools.cache
def _report() -> dict:
    env = dict(os.environ)
    env["XLA_FLAGS"] = (env.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=8").strip()
    completed = subprocess.run(
        [sys.executable, str(REPO / "tests" / "sharding_checks.py")],
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
        cwd=REPO,
    )
    assert completed.returncode == 0, completed.stderr[-4000:]
    return json.loads(completed.stdout.strip().splitlines()[-1])


def test_the_checks_run_on_eight_devices():
    assert _report()["n_devices"] == 8


@pytest.mark.parametrize("name", ["energy", "gradient", "flow", "solve"])
def test_a_sharded_batch_equals_the_single_device_batch_and_stays_sharded(name):
    report = _report()["batch"]
    assert report["input"] == {"spec": SHARDED, "shards": 8}
    # Same program, partitioned along the batch: each member is computed as on one device, but XLA
    # may fuse differently per partition, so agreement is to round-off, not bitwise; the flow and
    # the solve add CG's stopping point (rtol 1e-10) on a system of condition ~1e2.
    tolerance = {"energy": 1e-12, "gradient": 1e-12, "flow": 1e-12, "solve": 1e-11}[name]
    assert report[name]["difference"] <= tolerance
    assert report[name]["spec"] == SHARDED
    assert report[name]["shards"] == 8


def test_an_uneven_batch_is_refused_with_advice():
    message = _report()["batch"]["uneven_batch_error"]
    assert message is not None and "6" in message and "8 devices" in message


@pytest.mark.parametrize("case", ["sphere_8", "torus_3"])
def test_the_partitioned_laplacian_equals_laplacian_apply(case):
    report = _report()[case]
    # The partitioned cotangents come from squared lengths (Kahan's area), laplacian_apply's from a
    # cross product: the two agree to round-off of O(1) weights times O(1) values.
    assert report["apply"]["difference"] < 1e-12
    assert report["apply_block"] < 1e-12
    assert report["apply_padding"] == 0.0
    assert report["apply"]["spec"] == VERTICES
    assert report["apply"]["shards"] == int(case.split("_")[1])
    assert report["vertex_gradient"] < 1e-12


@pytest.mark.parametrize("case", ["sphere_8", "torus_3"])
def test_the_partitioned_cg_converges_to_scipy_spsolve(case):
    report = _report()[case]["cg"]
    # CG stops at a relative residual of 1e-10; L + 2M has condition number ~1e2 on these meshes.
    assert report["residual"] < 1e-10
    assert report["relative_difference"] < 1e-8
    assert report["spec"] == VERTICES
    assert report["shards"] == int(case.split("_")[1])
    assert _report()[case]["cg_b_gradient"] < 1e-8


def test_the_amg_preconditioned_partitioned_cg_converges_in_far_fewer_steps():
    report = _report()["amg"]
    assert len(report["levels"]) >= 2
    for name in ("jacobi", "amg", "hierarchy"):
        # CG stops at a relative residual of 1e-10 whatever the preconditioner; the solution's error is that
        # times the condition number (~1e2), as in test_the_partitioned_cg_converges_to_scipy_spsolve.
        assert report[name]["residual"] < 1e-10
        assert report[name]["relative_difference"] < 1e-8
        assert report[name]["spec"] == VERTICES
        assert report[name]["shards"] == 8
    for name in ("amg", "hierarchy"):
        assert report[name]["num_steps"] <= report["jacobi"]["num_steps"] / 3
    assert report["b_gradient"] < 1e-8  # the adjoint CG solve: the same 1e-10 times the condition number
    assert report["jit_argument_steps"] == report["amg"]["num_steps"]


def test_on_one_device_the_sharded_amg_is_linear_solves_amg():
    steps = _report()["amg"]["one_device"]
    # The same V-cycle up to a permutation of the vertices: equal up to round-off in the stopping step.
    assert abs(steps["sharded_steps"] - steps["unsharded_steps"]) <= 2


def test_a_bad_amg_preconditioner_is_refused():
    errors = _report()["amg"]["errors"]
    assert "shape (2562, 2562)" in errors["wrong_size"] and "(162, 162)" in errors["wrong_size"]
    assert errors["traced_shift"] is not None and errors["traced_shift"].startswith("shift:")
    assert errors["other_partition"] is not None and "partition_amg" in errors["other_partition"]
    assert errors["unknown"] is not None and "'ilu'" in errors["unknown"]


def test_on_one_device_the_partition_is_the_whole_mesh(icosphere1):
    mesh = icosphere1
    partition = partition_vertices(mesh)
    assert partition.n_devices == 1 and partition.n_padded == mesh.n_vertices
    u = np.linspace(0.0, 1.0, mesh.n_vertices)
    np.testing.assert_array_equal(partition.unshard(partition.shard(u)), u)
    assert sharded_laplacian_apply(partition, partition.shard(u)).shape == (mesh.n_vertices,)
    assert sharded_cg(partition, partition.shard(u), shift=1.0).residual < 1e-10
    # icosphere(1) is below amg_hierarchy's max_coarse: a single level, P_0 = I, B = A^{-1}: one step.
    assert sharded_cg(partition, partition.shard(u), shift=1.0, preconditioner="amg").num_steps <= 2


def test_bad_input_is_refused(without_type_checker, icosphere1):
    partition = partition_vertices(icosphere1)
    with pytest.raises(DDGInputError, match="partition_vertices"):
        sharded_laplacian_apply(np.zeros(42), np.zeros(42))
    with pytest.raises(DDGInputError, match=r"\(42,\)"):
        sharded_laplacian_apply(partition, np.zeros(41))
    with pytest.raises(DDGInputError, match="lumped mass matrices 'voronoi', 'barycentric', got 'galerkin'"):
        sharded_cg(partition, np.zeros(42), mass="galerkin")
    with pytest.raises(DDGInputError, match="mass: expected one of 'voronoi', 'barycentric', 'galerkin'"):
        sharded_cg(partition, np.zeros(42), mass="lumped")
    with pytest.raises(DDGInputError, match="shift: expected a number >= 0"):
        sharded_cg(partition, np.zeros(42), shift=-1.0, preconditioner="amg")
    with pytest.raises(DDGInputError, match="n_devices"):
        batch_sharding(n_devices=2)
    with pytest.raises(DDGInputError, match="leading"):
        shard_batch({"a": np.zeros((2, 3)), "b": np.zeros((3, 3))}, batch_sharding(n_devices=1))
