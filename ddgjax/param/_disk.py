"""Disk topology for parametrisation: the check, the boundary loop, and boundary placement on a convex curve.

Every map of `ddgjax.param` takes a topological disk: one connected component, manifold, consistently
oriented, exactly one boundary loop and Euler characteristic `chi = V - E + F = 1` (over referenced
vertices). `require_disk` refuses anything else with a `DDGInputError` naming `mesh` and what to do.

The boundary loop is `mesh.topology.boundary_loops[0]`, in the direction its faces traverse it, so a
loop placed counterclockwise in the plane gives an orientation-preserving map (faces counterclockwise
seen from their normal side keep positive signed area). Every per-boundary-vertex argument and result
of `ddgjax.param` is in that loop order. Unreferenced vertices belong to no face: every map puts them
at the origin `(0, 0)` and they take part in nothing else.

Index sets and block plans depend on the connectivity only (DESIGN.md, two phases); they are built on
the host once per connectivity and cached, like the Laplacian's vertex plan.
"""

from __future__ import annotations

import dataclasses
import weakref

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from .._compile import device_array
from .._errors import DDGInputError, check_float_shape, is_traced
from .._indexing import take_rows
from .._numerics import safe_div, safe_norm
from ..mesh import Mesh, MeshTopology, require_mesh

BOUNDARY_SHAPES = ("circle", "square")
"""`shape=` of the fixed-boundary maps: the convex curves the boundary loop can be placed on."""


@dataclasses.dataclass(frozen=True, eq=False)
class DiskTopology:
    """Host index sets of a disk-topology mesh (NumPy, built once per connectivity).

    Attributes:
        loop: `(nb,)` boundary vertices in loop order (`mesh.topology.boundary_loops[0]`).
        unreferenced: `(nu,)` vertices used by no face (placed at the origin by every map).
        n_vertices: `nv`.
        plans: cache of block plans of this connectivity, keyed by what they fix (see `cached_plan`).
    """

    loop: np.ndarray
    unreferenced: np.ndarray
    n_vertices: int
    plans: dict = dataclasses.field(default_factory=dict)

    @property
    def n_boundary(self) -> int:
        return int(self.loop.size)


_DISKS: "weakref.WeakKeyDictionary[MeshTopology, DiskTopology]" = weakref.WeakKeyDictionary()


def require_disk(mesh: Mesh, operation: str) -> DiskTopology:
    """The `DiskTopology` of `mesh`, or `DDGInputError` naming `mesh`, what makes it no disk and what to do.

    `operation` names the caller in the message (e.g. `"tutte_embedding"`). Cached per connectivity.
    """
    mesh = require_mesh("mesh", mesh)
    topology = mesh.topology
    if topology is None:
        raise DDGInputError(f"mesh: {operation} needs the mesh's topology; call it on a mesh made by Mesh.from_arrays")
    disk = _DISKS.get(topology)
    if disk is not None:
        return disk
    problems = _disk_problems(topology)
    if problems:
        raise DDGInputError(
            f"mesh: {operation} needs a topological disk (one connected component, manifold and consistently "
            f"oriented, one boundary loop, Euler characteristic 1); this mesh has {'; '.join(problems)}. "
            "Cut a closed surface or a surface with handles open to a disk (e.g. igl.cut_mesh along a cut graph), "
            "fill extra holes or keep a single component first (ddgjax.mesh.check_mesh reports what it has)"
        )
    disk = DiskTopology(
        loop=np.asarray(topology.boundary_loops[0], dtype=np.int32),
        unreferenced=np.asarray(topology.unreferenced_vertices, dtype=np.int32),
        n_vertices=topology.n_vertices,
    )
    _DISKS[topology] = disk
    return disk


def _disk_problems(topology: MeshTopology) -> list[str]:
    """What keeps the mesh from being a topological disk, as phrases for the error message (empty: a disk)."""
    if not topology.is_manifold:
        return ["non-manifold edges or vertices"]
    problems = []
    if not topology.is_oriented:
        problems.append("inconsistently oriented faces")
    if topology.n_components != 1:
        problems.append(f"{topology.n_components} connected components")
    loops = len(topology.boundary_loops)
    if loops == 0:
        problems.append("no boundary (it is closed)")
    elif loops > 1:
        problems.append(f"{loops} boundary loops")
    if topology.euler_characteristic != 1:
        problems.append(f"Euler characteristic {topology.euler_characteristic}")
    return problems


def cached_plan(disk: DiskTopology, key, build):
    """`build()` once per connectivity and `key` (a hashable description of the fixed indices), then cached."""
    plan = disk.plans.get(key)
    if plan is None:
        with jax.ensure_compile_time_eval():  # host work even when called inside a caller's trace
            plan = disk.plans[key] = build()
    return plan


def on_device(disk: DiskTopology, name: str) -> Int[Array, " m"]:
    """The index set `disk.<name>` (`"loop"`, `"unreferenced"`) as a device array, transferred once per connectivity."""
    return cached_plan(disk, ("device", name), lambda: device_array(getattr(disk, name)))


def boundary_edge_lengths(vertices: Float[Array, "nv 3"], loop: Int[Array, " nb"]) -> Float[Array, " nb"]:
    """Length of each boundary edge, entry `p` the edge from `loop[p]` to `loop[p + 1]` (cyclically), `(nb,)`."""
    points = take_rows(vertices, loop)
    return safe_norm(jnp.roll(points, -1, axis=0) - points)


def boundary_dual_lengths(edge_lengths: Float[Array, " nb"]) -> Float[Array, " nb"]:
    """Half the two boundary edges at each boundary vertex, `(l_{p-1} + l_p) / 2` (sums to the perimeter)."""
    return 0.5 * (edge_lengths + jnp.roll(edge_lengths, 1))


def arc_length_parameters(edge_lengths: Float[Array, " nb"]) -> Float[Array, " nb"]:
    """Fraction of the perimeter before each boundary vertex, `t_p = sum_{q < p} l_q / sum_q l_q` in `[0, 1)`."""
    before = jnp.cumsum(edge_lengths) - edge_lengths
    return safe_div(before, jnp.sum(edge_lengths))


def place_boundary(kind: str, edge_lengths: Float[Array, " nb"]) -> Float[Array, "nb 2"]:
    """Boundary vertices on a convex curve, counterclockwise, spaced by arc length (Floater 1997).

    `"circle"`: `(cos 2 pi t, sin 2 pi t)` on the unit circle (libigl `map_vertices_to_circle`).
    `"square"`: the square `[-1, 1]^2`, starting at its corner `(-1, -1)`, each side a quarter of the
    perimeter. `t` from `arc_length_parameters`. Differentiable in the lengths.
    """
    t = arc_length_parameters(edge_lengths)
    if kind == "circle":
        angle = 2.0 * jnp.pi * t
        return jnp.stack([jnp.cos(angle), jnp.sin(angle)], axis=-1)
    corners = jnp.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0], [-1.0, -1.0]], dtype=edge_lengths.dtype)
    s = 4.0 * t
    side = jnp.clip(jnp.floor(jax.lax.stop_gradient(s)), 0, 3).astype(jnp.int32)
    fraction = (s - side)[:, None]
    return corners[side] + fraction * (corners[side + 1] - corners[side])


def shape_argument(shape, disk: DiskTopology) -> tuple[str | None, Float[Array, "nb 2"] | None]:
    """`(kind, positions)`: a shape name from `BOUNDARY_SHAPES` or `(nb, 2)` positions, checked (`DDGInputError`)."""
    if isinstance(shape, str):
        if shape not in BOUNDARY_SHAPES:
            raise DDGInputError(
                f"shape: expected one of {', '.join(map(repr, BOUNDARY_SHAPES))} or an (n_boundary, 2) array of "
                f"positions, got {shape!r}"
            )
        return shape, None
    return None, boundary_values("shape", shape, disk, (2,))


def boundary_values(name: str, values, disk: DiskTopology, trailing: tuple[int, ...]) -> Float[Array, "nb ..."]:
    """A float array of shape `(nb, *trailing)` (one row per boundary vertex, in loop order), or `DDGInputError`."""
    expected = (disk.n_boundary,) + trailing
    if isinstance(values, str) or np.shape(values) != expected:
        raise DDGInputError(
            f"{name}: expected shape {expected} (one entry per boundary vertex, in the order of "
            f"mesh.topology.boundary_loops[0]), got {np.shape(values) if not isinstance(values, str) else repr(values)}"
        )
    check_float_shape(name, np.empty(expected) if is_traced(values) else np.asarray(values), trailing)
    if not is_traced(values) and not np.all(np.isfinite(np.asarray(values))):
        raise DDGInputError(f"{name}: expected finite values, got NaN/inf")
    if isinstance(values, (jax.Array, jax.core.Tracer)):
        return values if jnp.issubdtype(values.dtype, jnp.floating) else values.astype(float)
    host = np.asarray(values)  # host data moved without an eager program
    return device_array(host if np.issubdtype(host.dtype, np.floating) else host.astype(float))
