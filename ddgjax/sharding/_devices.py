"""One-axis device meshes: the `jax.sharding.Mesh` that every sharding of ddgjax is laid out on.

A device mesh (JAX's word) is an array of devices with named axes; it is unrelated to a triangle
`ddgjax.Mesh`, so ddgjax calls it a *device mesh* throughout. ddgjax shards along one axis at a
time: `"batch"` for a batch of shapes of one connectivity (`ddgjax.sharding.batch_sharding`) and
`"vertices"` for the vertices of one large mesh (`ddgjax.sharding.partition_vertices`).

With several hosts, call `jax.distributed.initialize()` first on every process: `jax.devices()`
then lists the devices of every host and the same code shards across all of them.
Reference: JAX documentation, "Distributed arrays and automatic parallelization" and
"Multi-process environments" (`jax.sharding.Mesh`, `jax.distributed`).
"""

from __future__ import annotations

from collections.abc import Sequence

import jax
import numpy as np
from jax.sharding import Mesh as DeviceMesh

from .._errors import DDGInputError


def device_mesh(axis_name: str, *, n_devices: int | None = None, devices: Sequence[jax.Device] | None = None) -> DeviceMesh:
    """A one-axis `jax.sharding.Mesh` named `axis_name` over `devices` (default `jax.devices()`), or their first `n_devices`.

    Args:
        axis_name: the name of the mesh axis (`"batch"`, `"vertices"`).
        n_devices: how many of the devices to use (default: all of them).
        devices: the devices (default `jax.devices()`: every device of every process).

    Returns:
        `jax.sharding.Mesh(np.array(devices[:n_devices]), (axis_name,))`.
    """
    devices = list(jax.devices() if devices is None else devices)
    if n_devices is None:
        n_devices = len(devices)
    if isinstance(n_devices, bool) or not isinstance(n_devices, (int, np.integer)) or not 1 <= n_devices <= len(devices):
        raise DDGInputError(f"n_devices: expected an integer from 1 to {len(devices)} (the devices available), got {n_devices!r}")
    return DeviceMesh(np.array(devices[:n_devices]), (axis_name,))
