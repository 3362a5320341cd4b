"""Dirichlet bookkeeping of a problem on a triangle or tet mesh: fixed vertices, one pin per free component, the block plan.

Host work from the connectivity and the indices only (outside every kernel, cached per connectivity), as
`ddgjax.pde`'s module docstring describes: a component without a fixed vertex determines a solution only up
to a constant, so its lowest vertex is pinned to 0 and the constant fixed afterwards; unreferenced vertices
are held at 0.
"""

from __future__ import annotations

import weakref

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._compile import device_array
from .._errors import DDGInputError, check_vertex_indices
from ..mesh import Mesh, MeshTopology
from ..sparse import SparsityPattern, dirichlet_plan
from ..volume import TetMesh, TetTopology


class DirichletData:
    """Host bookkeeping of a Poisson problem (module docstring): components, pinned vertices, the block plan.

    Built from the mesh's topology (outside every kernel) and checked: `vertices` and `values` are a
    caller's `fixed_vertices` / `fixed_values` (`None`, `None` for none), `trailing` the trailing shape
    of the right-hand side, `pattern` the sparsity pattern the plan is of (`Discretization.pattern`, or
    an operator's own). A `TetMesh` works the same, its tets in place of faces. Shared by every solver
    that pins one vertex per free component (`ddgjax.discretization.internal.DirichletData`).

    Attributes:
        vertices, values: the checked fixed vertices (host int64) and their values.
        fixed: `(n_fixed + n_pinned,)` host indices held fixed in the solve: `vertices`, then one pinned
            vertex per component without a fixed vertex, then the unreferenced vertices.
        plan: the `DirichletPlan` of `fixed` on `pattern`, or `None` when every vertex is fixed.
        n_pinned: how many indices `fixed` adds to `vertices` (all held at 0).
        labels: `(nv,)` the component of each vertex (unreferenced vertices: `n_components - 1`).
        n_components: the number of labels (the face (tet) components, plus one for unreferenced vertices).
        floating: `(nv,)` whether each vertex's component has no fixed vertex (re-centred to zero mean).
    """

    def __init__(self, mesh: Mesh | TetMesh, vertices, values, trailing: tuple[int, ...], pattern: SparsityPattern):
        topology = mesh.topology
        n = mesh.n_vertices
        if vertices is None:
            if values is not None:
                raise DDGInputError("fixed_values: given without fixed_vertices; pass both or neither")
            vertices = np.zeros(0, dtype=np.int64)
        vertices = check_vertex_indices("fixed_vertices", vertices, n)
        if values is None:
            values = np.zeros((vertices.size,) + trailing)
        values = device_array(values)  # host data moved without an eager program (`ddgjax._compile.device_array`)
        if values.shape != (vertices.size,) + trailing:
            raise DDGInputError(
                f"fixed_values: expected shape {(vertices.size,) + trailing} (one value per fixed vertex, "
                f"as many columns as rho), got {values.shape}"
            )
        self.vertices = vertices
        self.values = values
        self.fixed, self.plan, self.n_pinned, self.labels, self.n_components, self.floating = _pins(topology, vertices, pattern)

    def fixed_values(self, dtype) -> Float[Array, " n_fixed *k"]:
        """The values of `fixed` in `dtype`: `values`, then zeros for the pinned and unreferenced vertices."""
        zeros = jnp.zeros((self.n_pinned,) + self.values.shape[1:], dtype)
        return jnp.concatenate([self.values.astype(dtype), zeros])


# The host bookkeeping of the last few problems per connectivity: solving again with the same fixed
# vertices (new values, a new right-hand side, moved vertices) skips it.
_PINS: "weakref.WeakKeyDictionary[MeshTopology | TetTopology, dict]" = weakref.WeakKeyDictionary()
_PINS_KEPT = 8


def _pins(topology: MeshTopology | TetTopology, vertices: np.ndarray, pattern: SparsityPattern) -> tuple:
    """`DirichletData`'s `(fixed, plan, n_pinned, labels, n_components, floating)` for these fixed vertices (cached)."""
    kept = _PINS.setdefault(topology, {})
    key = (vertices.tobytes(), id(pattern))
    entry = kept.get(key)
    if entry is not None and entry[0] is pattern:
        return entry[1]
    n = topology.n_vertices
    # Component of each vertex (unreferenced vertices: their own label, past the components of the cells).
    cells, cell_components = topology.cells, topology.cell_components
    labels = np.full(n, topology.n_components, dtype=np.int32)
    labels[cells.ravel()] = np.repeat(cell_components, cells.shape[1])
    constrained = np.zeros(topology.n_components + 1, dtype=bool)
    constrained[labels[vertices]] = True
    floating = ~constrained
    floating[-1] = False  # unreferenced vertices are fixed to 0, not re-centred
    # Pin the lowest vertex of each floating component (components are numbered by first cell).
    first_vertex = np.full(topology.n_components, n, dtype=np.int64)
    np.minimum.at(first_vertex, labels[labels < topology.n_components], np.flatnonzero(labels < topology.n_components))
    pins = first_vertex[floating[:-1]]
    extra = np.setdiff1d(topology.unreferenced_vertices, vertices)
    fixed = np.concatenate([vertices, pins, extra])
    fixed.setflags(write=False)
    # Host work even inside a caller's trace: it depends on the connectivity and the indices only.
    with jax.ensure_compile_time_eval():
        plan = dirichlet_plan(pattern, fixed) if fixed.size < n else None
        pinned = (
            fixed,
            plan,
            pins.size + extra.size,
            device_array(labels),
            topology.n_components + 1,
            device_array(floating[labels]),
        )
    if len(kept) >= _PINS_KEPT:
        kept.pop(next(iter(kept)))
    kept[key] = (pattern, pinned)
    return pinned
