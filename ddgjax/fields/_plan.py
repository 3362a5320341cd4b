"""Host plan of the discrete connection: the corners around each vertex in counterclockwise order.

Built once per connectivity on first use and cached (DESIGN.md, two phases). Everything the angle
form of the connection needs beyond the vertex positions is here:

- the fans: the corners of each vertex in counterclockwise order (seen from the side the faces'
  orientation points to), starting at the vertex's *reference corner*: the first corner after the
  boundary for a boundary vertex, the lowest corner index `3 f + k` for an interior one. The
  reference outgoing edge of a vertex (polar angle 0) is the first edge of its reference corner;
- for each edge, where its two polar angles (at its low and at its high end) are read;
- the pattern of the real form `[[Re A, -Im A], [Im A, Re A]]` of a complex matrix on the vertex
  pattern, and where each of its slots reads the complex values (for the eigenproblem).

Corner `(f, k)` at vertex `i = F[f, k]` has the *first edge* `i -> F[f, k+1]` and the *second edge*
`i -> F[f, k+2]`; on a counterclockwise face the second lies a corner angle counterclockwise of the
first. The next corner counterclockwise around `i` is the corner at `i` of the face across the
second edge, whose first edge is that same edge.
"""

from __future__ import annotations

import weakref

import equinox as eqx
import jax
import numpy as np
from jaxtyping import Array, Bool, Int

from .._errors import DDGInputError, MeshDataError, first_indices
from ..laplacian.internal import vertex_plan
from ..mesh import Mesh, MeshTopology, require_mesh
from ..sparse import SparsityPattern


class FieldPlan(eqx.Module):
    """Fans, edge lookups and the real-form pattern of one connectivity (module docstring).

    Attributes:
        fan_order: `(3 nf,)` the flat corners `3 f + k` sorted by vertex, then counterclockwise from
            each vertex's reference corner.
        fan_start: `(3 nf,)` true where `fan_order` starts a new vertex.
        corner_position: `(3 nf,)` the inverse permutation: where each corner sits in `fan_order`.
        edge_angle_source: `(ne, 2)` for the low and the high end of each edge, the index into
            `[first-edge angles (3 nf) | second-edge angles (3 nf)]` of the corner whose first or second
            edge it is (the edge's first face provides both).
        reference_neighbor: `(nv,)` the head of each vertex's reference outgoing edge (the vertex
            itself when unreferenced).
        boundary: `(nv,)` true on boundary vertices.
        real_pattern: the `(2 nv, 2 nv)` pattern of the real form of a matrix on the vertex pattern.
        real_source: `(real_pattern.nnz,)` the index into `[Re values | Im values | -Im values]` each
            real-form slot reads (`3 nnz` for padding: reads 0).
    """

    fan_order: Int[Array, " n_corners"]
    fan_start: Bool[Array, " n_corners"]
    corner_position: Int[Array, " n_corners"]
    edge_angle_source: Int[Array, "ne 2"]
    reference_neighbor: Int[Array, " nv"]
    boundary: Bool[Array, " nv"]
    real_pattern: SparsityPattern
    real_source: Int[Array, " nnz_real"]


_FIELD_PLANS: "weakref.WeakKeyDictionary[MeshTopology, FieldPlan]" = weakref.WeakKeyDictionary()


def field_plan(mesh: Mesh, operation: str) -> FieldPlan:
    """The `FieldPlan` of `mesh`'s connectivity, after refusing meshes the connection is undefined on.

    `operation` names the caller in the `MeshDataError` raised for a non-manifold or inconsistently
    oriented mesh (a tangent-space rotation needs a consistent sense of counterclockwise).
    """
    topology = require_mesh("mesh", mesh).topology
    if topology is None:
        raise DDGInputError("mesh: the connection's plan needs the mesh's topology; build it before any compiled kernel")
    plan = _FIELD_PLANS.get(topology)
    if plan is None:
        topology.require_manifold(operation)
        topology.require_oriented(operation)
        with jax.ensure_compile_time_eval():
            plan = _FIELD_PLANS[topology] = _build(topology, vertex_plan(mesh).pattern)
    return plan


def require_referenced(mesh: Mesh, operation: str) -> None:
    """`MeshDataError` when some vertex belongs to no face (its tangent space and mass are empty)."""
    unreferenced = mesh.topology.unreferenced_vertices
    if unreferenced.size:
        mask = np.zeros(mesh.n_vertices, dtype=bool)
        mask[unreferenced] = True
        raise MeshDataError(
            f"{operation} needs every vertex in a face (its mass would be 0); vertices {first_indices(mask)} are "
            "unreferenced: remove them first"
        )


def _build(topology: MeshTopology, pattern: SparsityPattern) -> FieldPlan:
    faces, nv = topology.faces, topology.n_vertices
    n_corners = faces.size
    vertex_of = faces.reshape(-1).astype(np.int64)
    successor = _successors(topology)
    fan_order, fan_start, start_of_vertex = _fans(successor, vertex_of, nv)
    corner_position = np.empty(n_corners, dtype=np.int32)
    corner_position[fan_order] = np.arange(n_corners, dtype=np.int32)

    # Edge e's first face f traverses it a -> b, a = F[f, o+1], b = F[f, o+2] (o the opposite corner):
    # a -> b is the first edge of corner (f, o+1), b -> a the second edge of corner (f, o+2).
    f0 = topology.edge_faces[:, 0].astype(np.int64)
    o = topology.edge_face_corners[:, 0].astype(np.int64)
    corner_a, corner_b = 3 * f0 + (o + 1) % 3, 3 * f0 + (o + 2) % 3
    a_is_low = faces[f0, (o + 1) % 3] == topology.edges[:, 0]
    source_a, source_b = corner_a, n_corners + corner_b
    edge_angle_source = np.stack([np.where(a_is_low, source_a, source_b), np.where(a_is_low, source_b, source_a)], axis=1)

    reference_neighbor = np.arange(nv, dtype=np.int64)
    referenced = start_of_vertex >= 0
    start = start_of_vertex[referenced]
    reference_neighbor[referenced] = faces.reshape(-1)[3 * (start // 3) + (start % 3 + 1) % 3]
    boundary = np.zeros(nv, dtype=bool)
    boundary[topology.boundary_vertices] = True

    real_pattern, real_source = _real_form_plan(pattern)
    arrays = jax.device_put(
        {
            "fan_order": fan_order.astype(np.int32),
            "fan_start": fan_start,
            "corner_position": corner_position,
            "edge_angle_source": edge_angle_source.astype(np.int32),
            "reference_neighbor": reference_neighbor.astype(np.int32),
            "boundary": boundary,
            "real_source": real_source,
        }
    )
    return FieldPlan(real_pattern=real_pattern, **arrays)


def _successors(topology: MeshTopology) -> np.ndarray:
    """`(3 nf,)` the next corner counterclockwise around the same vertex, `-1` across a boundary edge."""
    faces = topology.faces
    nf = faces.shape[0]
    corners = np.arange(3 * nf, dtype=np.int64)
    f, k = corners // 3, corners % 3
    # The second edge of corner (f, k) is the edge opposite corner k+1.
    edge = topology.face_edges[f, (k + 1) % 3]
    pair_faces = topology.edge_faces[edge, :2].astype(np.int64)
    pair_corners = topology.edge_face_corners[edge, :2].astype(np.int64)
    other = np.where(pair_faces[:, 0] == f, 1, 0)
    g = pair_faces[corners, other]
    opposite = pair_corners[corners, other]
    # The other face traverses the edge the other way, so the shared vertex follows its opposite corner.
    return np.where(g >= 0, 3 * g + (opposite + 1) % 3, -1)


def _fans(successor: np.ndarray, vertex_of: np.ndarray, nv: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Corners sorted by vertex and counterclockwise position, the fan-start flags, each vertex's start corner."""
    n = successor.size
    has_predecessor = np.zeros(n, dtype=bool)
    has_predecessor[successor[successor >= 0]] = True
    # Boundary fans start at their corner without predecessor; a closed fan at its lowest corner index.
    start_of_vertex = np.full(nv, n, dtype=np.int64)
    open_starts = np.flatnonzero(~has_predecessor)
    np.minimum.at(start_of_vertex, vertex_of[open_starts], open_starts)
    closed = start_of_vertex == n
    lowest = np.full(nv, n, dtype=np.int64)
    np.minimum.at(lowest, vertex_of, np.arange(n))
    start_of_vertex = np.where(closed, lowest, start_of_vertex)
    start_of_vertex[start_of_vertex == n] = -1  # unreferenced
    is_start = np.zeros(n, dtype=bool)
    is_start[start_of_vertex[start_of_vertex >= 0]] = True
    # Cut every closed fan before its start, then rank the corners along the open chains by pointer
    # jumping (log2 of the largest valence passes): distance to the end of the chain.
    links = np.where((successor >= 0) & ~is_start[np.maximum(successor, 0)], successor, -1)
    to_end = (links >= 0).astype(np.int64)
    jump = links.copy()
    while np.any(jump >= 0):
        going = jump >= 0
        target = jump[going]
        to_end[going] += to_end[target]
        jump[going] = jump[target]
    fan_size = np.bincount(vertex_of, minlength=nv)
    position = fan_size[vertex_of] - 1 - to_end
    order = np.lexsort((position, vertex_of))
    return order, position[order] == 0, start_of_vertex


def _real_form_plan(pattern: SparsityPattern) -> tuple[SparsityPattern, np.ndarray]:
    """Pattern of `[[Re A, -Im A], [Im A, Re A]]` for `A` on `pattern`, and the source of each of its slots."""
    rows, cols, slot = pattern.entries()
    n, nnz = pattern.shape[0], pattern.nnz
    real_rows = np.concatenate([rows, rows, rows + n, rows + n])
    real_cols = np.concatenate([cols, cols + n, cols, cols + n])
    # Sources in [Re (nnz) | Im (nnz) | -Im (nnz)]: Re, -Im / Im, Re.
    sources = np.concatenate([slot, 2 * nnz + slot, nnz + slot, slot])
    real_pattern, landing = SparsityPattern.from_coo(real_rows, real_cols, (2 * n, 2 * n))
    real_source = np.full(real_pattern.nnz, 3 * nnz, dtype=np.int32)
    real_source[landing] = sources
    return real_pattern, real_source
