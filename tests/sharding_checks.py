"""Sharded computations against their unsharded twins, run by tests/test_sharding.py in a subprocess.

JAX fixes the number of host devices when its backend starts, so the pytest process (one CPU
device) cannot test sharding itself; this script runs with
`XLA_FLAGS=--xla_force_host_platform_device_count=8` and prints one JSON object of measured
differences and shardings for the test to check.
"""

from __future__ import annotations

import json

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import scipy.sparse.linalg as spla  # noqa: E402

from ddgjax import DDGInputError  # noqa: E402
from ddgjax.laplacian import cotan_laplacian, dirichlet_energy, laplacian_apply, mass_matrix  # noqa: E402
from ddgjax.mesh import icosphere, torus  # noqa: E402
from ddgjax.pde import mean_curvature_flow  # noqa: E402
from ddgjax.sharding import (  # noqa: E402
    batch_sharding,
    partition_amg,
    partition_vertices,
    shard_batch,
    sharded_amg_hierarchy,
    sharded_cg,
    sharded_laplacian_apply,
)
from ddgjax.solve import amg_hierarchy, linear_solve  # noqa: E402

SPHERE = icosphere(2)


def difference(a, b) -> float:
    return float(np.max(np.abs(np.asarray(a) - np.asarray(b))))


def describe(array) -> dict:
    return {"spec": str(array.sharding.spec), "shards": len(array.addressable_shards)}


def batch_checks() -> dict:
    """`jit(vmap(f))` on a batch sharded over 8 devices against the same program on one device."""
    rng = np.random.default_rng(0)
    V = SPHERE.vertices[None] * (1.0 + 0.1 * rng.random((8, 1, 1))) + 0.01 * rng.standard_normal((8, SPHERE.n_vertices, 3))
    u = jnp.sin(3.0 * SPHERE.vertices[:, 0])

    def energy(V):
        return dirichlet_energy(SPHERE.with_vertices(V), u)

    def flow(V):
        return mean_curvature_flow(SPHERE.with_vertices(V), tau=1e-3, steps=3, solver="cg").value

    def solve(V):
        mesh = SPHERE.with_vertices(V)
        return linear_solve(mass_matrix(mesh) + 1e-2 * cotan_laplacian(mesh), V[:, 0], solver="cg").value

    sharded = shard_batch(V, batch_sharding())
    single = jax.device_put(V, jax.devices()[0])
    results = {"input": describe(sharded)}
    for name, function in {"energy": energy, "gradient": jax.grad(energy), "flow": flow, "solve": solve}.items():
        program = jax.jit(jax.vmap(function))
        value = program(sharded)
        results[name] = {"difference": difference(value, program(single)), **describe(value)}
    try:
        shard_batch(V[:6])
        results["uneven_batch_error"] = None
    except DDGInputError as error:
        results["uneven_batch_error"] = str(error)
    return results


def big_mesh_checks(mesh, n_devices) -> dict:
    """The vertex-partitioned apply and CG against `laplacian_apply`, `dirichlet_energy` and SciPy's `spsolve`."""
    partition = partition_vertices(mesh, n_devices=n_devices)
    rng = np.random.default_rng(1)
    u = rng.standard_normal(mesh.n_vertices)
    U = rng.standard_normal((mesh.n_vertices, 2))
    applied = sharded_laplacian_apply(partition, partition.shard(u))
    block = sharded_laplacian_apply(partition, partition.shard(U))
    # Derivative in the positions through the halo exchange: the gradient of 1/2 u^T L u.
    sharded_u = partition.shard(u)

    def energy(vertices):
        return 0.5 * jnp.sum(sharded_u * sharded_laplacian_apply(partition, sharded_u, vertices=vertices))

    gradient = jax.jit(jax.grad(energy))(partition.vertices)
    expected_gradient = jax.grad(lambda V: dirichlet_energy(mesh.with_vertices(V), u))(mesh.vertices)
    shift = 2.0
    system = (cotan_laplacian(mesh) + shift * mass_matrix(mesh)).to_scipy().tocsc()
    solution = sharded_cg(partition, partition.shard(u), shift=shift)
    expected = spla.spsolve(system, u)
    # d/db of <c, x(b)> = A^{-1} c (implicit differentiation through the CG).
    c = rng.standard_normal(mesh.n_vertices)
    sharded_c = partition.shard(c)
    b_gradient = jax.grad(lambda b: jnp.sum(sharded_c * sharded_cg(partition, b, shift=shift).value))(partition.shard(u))
    expected_b_gradient = spla.spsolve(system, c)
    scale = float(np.abs(expected).max())
    return {
        "partition": repr(partition),
        "apply": {"difference": difference(partition.unshard(applied), laplacian_apply(mesh, u)), **describe(applied)},
        "apply_block": difference(partition.unshard(block), laplacian_apply(mesh, jnp.asarray(U))),
        "apply_padding": float(np.abs(np.asarray(applied)[mesh.n_vertices :]).max(initial=0.0)),
        "vertex_gradient": difference(partition.unshard(gradient), expected_gradient),
        "cg": {
            "relative_difference": difference(partition.unshard(solution.value), expected) / scale,
            "residual": float(solution.residual),
            "num_steps": int(solution.num_steps),
            **describe(solution.value),
        },
        "cg_b_gradient": difference(partition.unshard(b_gradient), expected_b_gradient) / np.abs(expected_b_gradient).max(),
    }


def amg_checks(mesh) -> dict:
    """The AMG-preconditioned partitioned CG against SciPy's `spsolve`, Jacobi, and the unsharded AMG-preconditioned CG."""
    shift = 2.0
    matrix = cotan_laplacian(mesh) + shift * mass_matrix(mesh)
    system = matrix.to_scipy().tocsc()
    hierarchy = amg_hierarchy(matrix)
    rng = np.random.default_rng(2)
    u, c = rng.standard_normal(mesh.n_vertices), rng.standard_normal(mesh.n_vertices)
    expected = spla.spsolve(system, u)
    scale = float(np.abs(expected).max())
    partition = partition_vertices(mesh, n_devices=8)
    b = partition.shard(u)
    results = {"levels": list(hierarchy.sizes)}
    for name, preconditioner in {"jacobi": "jacobi", "amg": "amg", "hierarchy": hierarchy}.items():
        solution = sharded_cg(partition, b, shift=shift, preconditioner=preconditioner)
        results[name] = {
            "relative_difference": difference(partition.unshard(solution.value), expected) / scale,
            "residual": float(solution.residual),
            "num_steps": int(solution.num_steps),
            **describe(solution.value),
        }
    # d/db of <c, x(b)> = A^{-1} c, through the AMG-preconditioned CG (the hierarchy a constant).
    prepared = sharded_amg_hierarchy(partition, shift=shift)
    sharded_c = partition.shard(c)
    gradient = jax.jit(
        jax.grad(lambda b: jnp.sum(sharded_c * sharded_cg(partition, b, shift=shift, preconditioner=prepared).value))
    )(b)
    expected_gradient = spla.spsolve(system, c)
    results["b_gradient"] = difference(partition.unshard(gradient), expected_gradient) / np.abs(expected_gradient).max()
    # A ShardedAMG is a pytree: an argument of a jitted solve, as any array.
    solve = jax.jit(lambda b, preconditioner: sharded_cg(partition, b, shift=shift, preconditioner=preconditioner).num_steps)
    results["jit_argument_steps"] = int(solve(b, prepared))
    # One device: the same hierarchy, permuted to the locality order, is the preconditioner of linear_solve's CG.
    single = partition_vertices(mesh, n_devices=1)
    one = sharded_cg(single, single.shard(u), shift=shift, preconditioner=partition_amg(single, hierarchy))
    unsharded = linear_solve(matrix, jnp.asarray(u), solver="cg", preconditioner=hierarchy)
    results["one_device"] = {"sharded_steps": int(one.num_steps), "unsharded_steps": int(unsharded.num_steps)}
    errors = {}
    small = amg_hierarchy(cotan_laplacian(icosphere(2)) + shift * mass_matrix(icosphere(2)))
    for name, call in {
        "wrong_size": lambda: sharded_cg(partition, b, shift=shift, preconditioner=small),
        "traced_shift": lambda: jax.jit(lambda s: sharded_cg(partition, b, shift=s, preconditioner="amg").value)(shift),
        "other_partition": lambda: sharded_cg(partition, b, shift=shift, preconditioner=partition_amg(single, hierarchy)),
        "unknown": lambda: sharded_cg(partition, b, shift=shift, preconditioner="ilu"),
    }.items():
        try:
            call()
            errors[name] = None
        except DDGInputError as error:
            errors[name] = str(error)
    results["errors"] = errors
    return results


if __name__ == "__main__":
    print(
        json.dumps(
            {
                "n_devices": jax.device_count(),
                "batch": batch_checks(),
                "sphere_8": big_mesh_checks(icosphere(3), 8),
                "torus_3": big_mesh_checks(torus(n_major=40, n_minor=13), 3),
                "amg": amg_checks(icosphere(4)),
            }
        )
    )
