"""Compiled mesh kernels cached by array shapes, not by the mesh's topology object.

A `Mesh` carries its `MeshTopology` as a static field hashed by identity, so a function jitted with
the mesh as an argument compiles again for every new mesh (new topology object), even one of the
same size. Most operators need nothing from the topology inside the computation but the element
counts: everything else they read is an integer array leaf of the mesh. `compiled_kernel` jits
such a function with the topology replaced by an `ElementCounts` stand-in (equal when the counts
are equal), so the compiled program is shared by every mesh with the same array shapes and dtypes,
and eager calls run one compiled program instead of hundreds of op-by-op dispatches (the cotan
Laplacian of a 5k-face mesh: 12 ms eager, 0.3 ms compiled; measured, benchmarks/README.md).

Host work that needs the real topology (orientation checks, host-built plans) and the validation
of user arrays must run before the kernel is called: inside it every array is traced. A kernel
that reads anything of the topology but the counts fails loudly (`AttributeError`) instead of
baking one mesh's connectivity into a program other meshes would reuse.

Inside a trace (the caller's `jit`, `grad`, `vmap`) the kernel is a nested call that XLA inlines.
"""

from __future__ import annotations

import dataclasses
import functools

from .._compile import tuned_jit

from ._mesh import Mesh
from ._topology import MeshTopology


class ElementCounts(MeshTopology):
    """Stand-in topology inside a compiled kernel: element counts only, equal when the counts are equal.

    `oriented` records that the kernel's caller checked the real topology's orientation
    (`compiled_kernel(requires_orientation=...)`): `require_oriented` then passes, and otherwise
    refuses, since the stand-in cannot tell.
    """

    def __init__(self, n_vertices: int, n_faces: int, n_edges: int, oriented: bool = False):  # noqa: D107
        object.__setattr__(self, "_counts", (n_vertices, n_faces, n_edges, oriented))

    @property
    def n_vertices(self) -> int:
        return self._counts[0]

    @property
    def n_faces(self) -> int:
        return self._counts[1]

    @property
    def n_edges(self) -> int:
        return self._counts[2]

    @property
    def oriented(self) -> bool:
        return self._counts[3]

    def require_oriented(self, operation: str) -> None:
        if not self.oriented:
            raise AttributeError(
                f"{operation}: a compiled mesh kernel cannot check the orientation; check it before the "
                "kernel (compiled_kernel(requires_orientation=...))"
            )

    def __eq__(self, other: object) -> bool:
        return type(other) is ElementCounts and self._counts == other._counts

    def __hash__(self) -> int:
        return hash(self._counts)

    def __getattr__(self, name: str):
        raise AttributeError(
            f"MeshTopology.{name}: a compiled mesh kernel sees only the element counts; read the topology "
            "before calling the kernel (ddgjax.mesh._compiled)"
        )

    def __repr__(self) -> str:
        return (
            f"ElementCounts(n_vertices={self.n_vertices}, n_faces={self.n_faces}, n_edges={self.n_edges}, "
            f"oriented={self.oriented})"
        )


def counts_only(mesh: Mesh, *, oriented: bool = False) -> Mesh:
    """The same mesh arrays with the topology replaced by its `ElementCounts` (a stand-in is kept as it is)."""
    topology = mesh.topology
    if type(topology) is ElementCounts:
        return mesh
    # Field by field without `__init__`, as equinox rebuilds a module when it unflattens one: the
    # arrays are the mesh's own and were checked when it was made. (`dataclasses.replace` runs the
    # whole constructor again: 90 us per call, a third of a compiled `face_areas` at 5k faces.)
    stand_in = object.__new__(Mesh)
    for field in dataclasses.fields(mesh):
        object.__setattr__(stand_in, field.name, getattr(mesh, field.name))
    object.__setattr__(stand_in, "topology", ElementCounts(topology.n_vertices, topology.n_faces, topology.n_edges, oriented))
    return stand_in


def compiled_kernel(function=None, *, static_argnames: tuple[str, ...] = (), requires_orientation: str | None = None):
    """`jax.jit` of `function(mesh, *args, **kwargs)` (`ddgjax._compile.tuned_jit`), cached by the mesh's array
    shapes and element counts.

    For functions whose body reads only the mesh's arrays and counts (module docstring); array
    arguments other than the mesh are validated by the caller. `requires_orientation` (the
    operation's name for the error) checks the real topology's orientation before the call
    (`MeshTopology.require_oriented`), so the body may call `require_oriented` itself.
    """
    if function is None:
        return functools.partial(compiled_kernel, static_argnames=static_argnames, requires_orientation=requires_orientation)
    compiled = tuned_jit(function, static_argnames=static_argnames)

    @functools.wraps(function)
    def kernel(mesh: Mesh, *args, **kwargs):
        if requires_orientation is not None:
            mesh.topology.require_oriented(requires_orientation)
        return compiled(counts_only(mesh, oriented=requires_orientation is not None), *args, **kwargs)

    kernel.compiled = compiled  # the jitted function (its cache: `kernel.compiled._cache_size()`; `ddgjax._compile`)
    return kernel
