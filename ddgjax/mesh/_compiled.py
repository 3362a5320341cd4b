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

import jax

from ._mesh import Mesh
from ._topology import MeshTopology


class ElementCounts(MeshTopology):
    """Stand-in topology inside a compiled kernel: element counts only, equal when the counts are equal."""

    def __init__(self, n_vertices: int, n_faces: int, n_edges: int):  # noqa: D107 (no dataclass init: no arrays)
        object.__setattr__(self, "_counts", (n_vertices, n_faces, n_edges))

    @property
    def n_vertices(self) -> int:
        return self._counts[0]

    @property
    def n_faces(self) -> int:
        return self._counts[1]

    @property
    def n_edges(self) -> int:
        return self._counts[2]

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
        return f"ElementCounts(n_vertices={self.n_vertices}, n_faces={self.n_faces}, n_edges={self.n_edges})"


def counts_only(mesh: Mesh) -> Mesh:
    """The same mesh arrays with the topology replaced by its `ElementCounts`."""
    topology = mesh.topology
    if type(topology) is ElementCounts:
        return mesh
    return dataclasses.replace(mesh, topology=ElementCounts(topology.n_vertices, topology.n_faces, topology.n_edges))


def compiled_kernel(function=None, *, static_argnames: tuple[str, ...] = ()):
    """`jax.jit` of `function(mesh, *args, **kwargs)`, cached by the mesh's array shapes and element counts.

    For private kernels whose body reads only the mesh's arrays and counts (module docstring); the
    public function validates its inputs and does any topology work first.
    """
    if function is None:
        return functools.partial(compiled_kernel, static_argnames=static_argnames)
    compiled = jax.jit(function, static_argnames=static_argnames)

    @functools.wraps(function)
    def kernel(mesh: Mesh, *args, **kwargs):
        return compiled(counts_only(mesh), *args, **kwargs)

    return kernel
