"""Compiled mesh kernels: one program per mesh size, shared by every connectivity of that size.

A `Mesh`'s static `topology` compares equal only for equal connectivity, so a plain `jax.jit` of a
function of the mesh compiles once per connectivity. Most operators read nothing of the topology
inside the computation: every array they need is a leaf of the mesh (or of an operator's storage
plan) and the element counts are array shapes. `compiled_kernel` jits such a function on
`mesh.without_topology()`, so its program is keyed by array shapes alone; eager calls then run one
compiled program instead of hundreds of op-by-op dispatches. Inside a caller's trace (`jit`, `grad`,
`vmap`) the kernel is a nested call that XLA inlines.

Host work that needs the topology (orientation checks, storage plans) and the validation of user
arrays run in the wrapper, before the kernel: inside it `mesh.topology` is `None`.
"""

from __future__ import annotations

import functools

from .._compile import tuned_jit
from ._mesh import Mesh, require_mesh


def compiled_kernel(function=None, *, static_argnames: tuple[str, ...] = (), requires_orientation: str | None = None):
    """`ddgjax._compile.tuned_jit` of `function(mesh, *args, **kwargs)`, cached by the mesh's array shapes.

    The wrapper refuses a first argument that is not a `Mesh` (`DDGInputError`). `requires_orientation`
    (the operation's name for the error) checks the topology's orientation before the call
    (`MeshTopology.require_oriented`); a kernel that calls an orientation-requiring kernel in its
    body must declare it too, since inside a kernel the topology is no longer there to check.
    Other array arguments are validated by the caller.
    """
    if function is None:
        return functools.partial(compiled_kernel, static_argnames=static_argnames, requires_orientation=requires_orientation)
    compiled = tuned_jit(function, static_argnames=static_argnames)

    @functools.wraps(function)
    def kernel(mesh: Mesh, *args, **kwargs):
        mesh = require_mesh("mesh", mesh)
        if requires_orientation is not None and mesh.topology is not None:
            mesh.topology.require_oriented(requires_orientation)
        return compiled(mesh.without_topology(), *args, **kwargs)

    kernel.compiled = compiled  # the jitted function (its cache: `kernel.compiled._cache_size()`)
    return kernel
