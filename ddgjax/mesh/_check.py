"""Mesh checks: one report of the topology and the data problems of a mesh (DESIGN.md, Errors)."""

from __future__ import annotations

import dataclasses

import numpy as np

from .._errors import DDGInputError, first_indices
from ._mesh import Mesh, require_mesh
from ._topology import index_mask


@dataclasses.dataclass(frozen=True)
class MeshReport:
    """What `check_mesh` found. Index arrays are NumPy `int` arrays (empty when there is no problem).

    Attributes:
        n_vertices, n_faces, n_edges: element counts (`n_vertices` includes unreferenced vertices).
        euler_characteristic: `V - E + F` over referenced vertices.
        genus: `(2 - chi - b) / 2` for a connected, oriented manifold; `None` otherwise.
        n_components: edge-connected components of faces (two faces touching only at a vertex are
            separate components, as in libigl's `facet_components`).
        boundary_loop_lengths: number of vertices of each boundary loop.
        nonmanifold_edges: edges with three or more faces.
        nonmanifold_vertices: vertices whose faces form more than one fan.
        inconsistent_edges: two-face edges traversed in the same direction by both faces.
        unreferenced_vertices: vertices used by no face.
        duplicate_faces: faces with the same three vertices as an earlier face, in any order or
            orientation (each later copy; the first stays unlisted).
        zero_area_faces: faces with `area <= area_tol * (longest edge)^2` at the current positions.
        area_tol: the relative tolerance used.
    """

    n_vertices: int
    n_faces: int
    n_edges: int
    euler_characteristic: int
    genus: int | None
    n_components: int
    boundary_loop_lengths: tuple[int, ...]
    nonmanifold_edges: np.ndarray
    nonmanifold_vertices: np.ndarray
    inconsistent_edges: np.ndarray
    unreferenced_vertices: np.ndarray
    duplicate_faces: np.ndarray
    zero_area_faces: np.ndarray
    area_tol: float

    @property
    def n_boundary_loops(self) -> int:
        return len(self.boundary_loop_lengths)

    @property
    def is_closed(self) -> bool:
        return self.n_boundary_loops == 0

    @property
    def is_manifold(self) -> bool:
        return self.nonmanifold_edges.size == 0 and self.nonmanifold_vertices.size == 0

    @property
    def is_oriented(self) -> bool:
        return self.nonmanifold_edges.size == 0 and self.inconsistent_edges.size == 0

    @property
    def is_clean(self) -> bool:
        """True when no data problem was found (manifold, oriented; no unreferenced vertices, duplicate or zero-area faces)."""
        return (
            self.is_manifold
            and self.is_oriented
            and self.unreferenced_vertices.size == 0
            and self.duplicate_faces.size == 0
            and self.zero_area_faces.size == 0
        )

    def __str__(self) -> str:
        loops = self.boundary_loop_lengths
        # NumPy's own summarisation ("[a, b, ..., y, z]") keeps a mesh with many holes to one line.
        sizes = np.array2string(
            np.asarray(loops), separator=", ", threshold=10, edgeitems=5, max_line_width=10**6, formatter={"int": str}
        )
        loop_text = "none (closed)" if not loops else f"{len(loops)} (vertices per loop: {sizes})"
        lines = [
            f"vertices {self.n_vertices:,}  faces {self.n_faces:,}  edges {self.n_edges:,}",
            f"Euler characteristic {self.euler_characteristic}  genus {'-' if self.genus is None else self.genus}  "
            f"components {self.n_components}",
            f"boundary loops: {loop_text}",
            f"manifold: {_yes_no(self.is_manifold)}  oriented: {_yes_no(self.is_oriented)}  closed: {_yes_no(self.is_closed)}",
        ]
        problems = [
            ("non-manifold edges (3+ faces)", self.nonmanifold_edges, self.n_edges),
            ("non-manifold vertices (2+ fans)", self.nonmanifold_vertices, self.n_vertices),
            ("inconsistently oriented edges", self.inconsistent_edges, self.n_edges),
            ("unreferenced vertices", self.unreferenced_vertices, self.n_vertices),
            ("duplicate faces (same three vertices as an earlier face)", self.duplicate_faces, self.n_faces),
            (f"zero-area faces (area <= {self.area_tol:g} * longest edge^2)", self.zero_area_faces, self.n_faces),
        ]
        for label, indices, size in problems:
            lines.append(f"{label}: " + (first_indices(index_mask(indices, size)) if indices.size else "none"))
        return "\n".join(lines)


def check_mesh(mesh: Mesh, *, area_tol: float = 1e-12) -> MeshReport:
    """Topology and data checks of a mesh, with counts and the offending indices.

    Topology comes from `mesh.topology` (built once). Duplicate faces are found on the host in NumPy
    by sorting each face's vertex indices and looking for repeated rows, so a copy with reversed
    orientation counts too (a face and its reversed copy form a closed, oriented two-face "pillow"
    that no edge check flags). Zero-area faces are measured at the current vertex positions: a face
    is flagged when `A_f <= area_tol * l_max^2` (`l_max` its longest edge), a scale-invariant test
    that also catches collinear corners. This is a host-side function (not for use under jit).

    Equivalents: libigl `is_edge_manifold`, `is_vertex_manifold`, `euler_characteristic`,
    `boundary_loop`, `unique_simplices`; trimesh `Trimesh.is_watertight` / `is_winding_consistent`.
    """
    if not (np.isscalar(area_tol) and np.isfinite(area_tol) and area_tol >= 0):
        raise DDGInputError(f"area_tol: expected a nonnegative finite number, got {area_tol!r}")
    topology = require_mesh("mesh", mesh).topology
    corners = np.asarray(mesh.vertices, dtype=np.float64)[topology.faces]
    doubled_areas = np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)
    longest_sq = np.max(np.sum((np.roll(corners, -1, axis=1) - corners) ** 2, axis=-1), axis=1)
    zero_area = np.flatnonzero(0.5 * doubled_areas <= area_tol * longest_sq)
    return MeshReport(
        n_vertices=topology.n_vertices,
        n_faces=topology.n_faces,
        n_edges=topology.n_edges,
        euler_characteristic=topology.euler_characteristic,
        genus=topology.genus,
        n_components=topology.n_components,
        boundary_loop_lengths=tuple(int(loop.size) for loop in topology.boundary_loops),
        nonmanifold_edges=topology.nonmanifold_edges,
        nonmanifold_vertices=topology.nonmanifold_vertices,
        inconsistent_edges=topology.inconsistent_edges,
        unreferenced_vertices=topology.unreferenced_vertices,
        duplicate_faces=_duplicate_faces(topology.faces),
        zero_area_faces=zero_area,
        area_tol=float(area_tol),
    )


def _duplicate_faces(faces: np.ndarray) -> np.ndarray:
    """Indices of the faces whose vertex set repeats an earlier face's, in increasing order."""
    ordered = np.sort(faces, axis=1)
    # lexsort is stable, so the first face of each group of equal rows is its lowest index.
    order = np.lexsort(ordered.T[::-1])
    rows = ordered[order]
    repeats = np.all(rows[1:] == rows[:-1], axis=1)
    return np.sort(order[1:][repeats])


def _yes_no(flag: bool) -> str:
    return "yes" if flag else "no"
