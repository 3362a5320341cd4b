"""A batch of shapes of one connectivity, sharded across devices along its leading (batch) axis.

Every ddgjax function of a mesh is a pure JAX function of `mesh.vertices`, so a batch of shapes
that share one connectivity is `jax.vmap` over a `(batch, nv, 3)` array, and spreading that batch
over several devices takes nothing but JAX's own sharding: put the batch on the devices with a
`NamedSharding` whose spec splits axis 0 (`shard_batch`), and `jax.jit` of the vmapped function
partitions the whole program along the batch (each device computes its own shapes; the
connectivity and other closed-over arrays are replicated). Results come back sharded the same way.

    sharding = ddgjax.sharding.batch_sharding()                  # all devices, axis "batch"
    V = ddgjax.sharding.shard_batch(vertices_batch, sharding)    # (B, nv, 3), B divisible by the device count
    energy = lambda V: ddgjax.laplacian.dirichlet_energy(mesh.with_vertices(V), u)
    grads = jax.jit(jax.vmap(jax.grad(energy)))(V)               # (B, nv, 3), sharded like V

What shards: everything written in JAX, i.e. energies and their derivatives, geometry, operators
(`cotan_laplacian`, `mass_matrix`, `laplacian_apply`), and the solves with the conjugate gradient:
`linear_solve(..., solver="cg")` and the problems with `solver="cg"` (`solve_poisson`,
`mean_curvature_flow`, ...), with the Jacobi preconditioner (an `"amg"` hierarchy is built on the
host from concrete values, so it cannot be made per shape inside `vmap`). A vmapped CG runs until
every member of the batch has converged: the stopping test is one all-reduce per iteration. What does
not: the host backends (`"cholesky"`, `"superlu"`, `"pyamg"`, and `"auto"` on CPU, which picks one
of them) call the host through XLA's FFI or `jax.pure_callback`; they run, but on the host of each
process, not on the devices the batch lives on. Pass `solver="cg"` for sharded solves.

Reference: JAX documentation, "Distributed arrays and automatic parallelization"
(`jax.sharding.NamedSharding`, `jax.device_put`, computation follows data).
"""

from __future__ import annotations

from collections.abc import Sequence

import jax
import numpy as np
from jax.sharding import NamedSharding
from jax.sharding import PartitionSpec as P
from jaxtyping import PyTree

from .._errors import DDGInputError
from ._devices import device_mesh

BATCH = "batch"
"""The name of the device-mesh axis a batch is sharded along."""


def batch_sharding(*, n_devices: int | None = None, devices: Sequence[jax.Device] | None = None) -> NamedSharding:
    """`NamedSharding(device_mesh, P("batch"))`: arrays split along their leading axis over `n_devices` devices.

    Args:
        n_devices: how many devices (default: all of `jax.devices()`, every host's after
            `jax.distributed.initialize()`).
        devices: the devices to use instead of `jax.devices()`.

    Returns:
        A sharding for `(B, ...)` arrays with `B` divisible by the device count; its
        `.mesh` is the one-axis device mesh (`ddgjax.sharding.device_mesh`).
    """
    return NamedSharding(device_mesh(BATCH, n_devices=n_devices, devices=devices), P(BATCH))


def replicated(sharding: NamedSharding) -> NamedSharding:
    """A copy of every array on every device of `sharding`'s device mesh (`P()`), e.g. for per-batch constants.

    Args:
        sharding: a sharding whose device mesh to use (e.g. `batch_sharding()`).

    Returns:
        A `NamedSharding` on `sharding.mesh` with the empty partition spec `P()`.
    """
    return NamedSharding(sharding.mesh, P())


def shard_batch(batch: PyTree, sharding: NamedSharding | None = None) -> PyTree:
    """Every array of `batch` (a pytree of `(B, ...)` arrays) placed on the devices, split along its leading axis.

    `jax.device_put(batch, sharding)` after checking that the leaves have one leading size `B`
    divisible by the number of devices (JAX requires even shards of an input; pad the batch, e.g.
    by repeating its last shape, or use fewer devices).

    Args:
        batch: `(B, ...)` arrays (e.g. `(B, nv, 3)` vertex positions), NumPy or JAX.
        sharding: default `batch_sharding()` (all devices).

    Returns:
        The same pytree of `jax.Array`s, each with `sharding` (`.addressable_shards` holds this
        process's `B / n_devices`-row pieces).
    """
    if sharding is None:
        sharding = batch_sharding()
    leaves = jax.tree_util.tree_leaves(batch)
    sizes = {np.shape(leaf)[0] if np.ndim(leaf) else None for leaf in leaves}
    n_devices = sharding.mesh.size
    if len(sizes) != 1 or None in sizes:
        raise DDGInputError(
            f"batch: expected arrays with one common leading (batch) size, got leading sizes {sorted(map(str, sizes))}"
        )
    (size,) = sizes
    if size % n_devices:
        raise DDGInputError(
            f"batch: a batch of {size} does not split evenly over {n_devices} devices; pad it to a multiple of "
            f"{n_devices} or use batch_sharding(n_devices=...) with a divisor of {size}"
        )
    return jax.device_put(batch, sharding)
