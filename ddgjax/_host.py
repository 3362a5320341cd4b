"""Moving host-built (NumPy) arrays to the device: one `jax.device_put` for many arrays.

Topology and sparsity patterns are built in NumPy (DESIGN.md, two phases) and then become JAX
arrays. `jnp.asarray` per array costs ~50 us of dispatch each and copies: 14 conversions were
0.9 ms of a 5k-face `Mesh.from_arrays` and ~19 ms for arrays of a million entries, where one
`jax.device_put` of the whole list took 0.6 ms and 2.2 ms (measured, benchmarks/README.md).
On CPU `device_put` may share the NumPy buffer instead of copying it, so only arrays that no code
mutates afterwards (freshly built, owned by the topology or pattern) go through here.
"""

from __future__ import annotations

import jax
import numpy as np


def to_device(**arrays: np.ndarray) -> dict[str, jax.Array]:
    """`{name: jax.Array}` for freshly built host arrays that are never mutated afterwards, in one transfer."""
    return jax.device_put(arrays)
