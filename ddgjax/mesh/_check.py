"""Mesh checks: one report of the topology and the data problems of a mesh (DESIGN.md, Errors).

Degenerate geometry (the policy, as geometry-central's): a face whose area is zero or within
rounding of zero (`A <= area_tol * l_max^2`, `default_area_tol`) has infinite or undefined
cotangents, so no cotan operator is meaningful on it. Building a mesh never refuses positions
(they change under optimisation, inside `jit`); instead

- `check_mesh` reports such faces and the zero-length edges (coincident vertices) among them;
- `require_nondegenerate` (used where a problem chooses between the mesh's own cotan Laplacian and
  the intrinsic one: `ddgjax.laplacian.laplacian_and_mass`, `eigenpairs`, `solve_poisson`,
  `heat_distance`, ...) refuses them with `MeshDataError` when the positions are concrete, naming
  the faces and the remedies: `robust=True` (intrinsic Delaunay on the mollified metric, positive
  semidefinite on every mesh) or a repair. The faces are found once per `Mesh` object, on the host
  (`degenerate_faces`), and remembered with it;
- under `jit` / `grad` / `vmap` positions cannot be inspected: the operators run, and what the
  rounding of infinite cotangents breaks is reported by the solvers' outcomes (`ddgjax.RESULTS`:
  a factorisation's `not_positive_definite`, `eigenpairs`' negative eigenvalues).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .._errors import DDGInputError, MeshDataError, first_indices, is_traced
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
        zero_area_faces: faces with `area <= area_tol * (longest edge)^2` at the current positions
            (collinear or coincident corners, or within rounding of that; module docstring).
        zero_length_edges: edges whose two ends coincide at the current positions (their faces are
            among `zero_area_faces`).
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
    zero_length_edges: np.ndarray
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
        """True when no data problem was found (manifold, oriented; no unreferenced vertices, duplicate or zero-area faces, zero-length edges)."""
        return (
            self.is_manifold
            and self.is_oriented
            and self.unreferenced_vertices.size == 0
            and self.duplicate_faces.size == 0
            and self.zero_area_faces.size == 0
            and self.zero_length_edges.size == 0
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
            ("zero-length edges (coincident vertices)", self.zero_length_edges, self.n_edges),
        ]
        for label, indices, size in problems:
            lines.append(f"{label}: " + (first_indices(index_mask(indices, size)) if indices.size else "none"))
        return "\n".join(lines)


def check_mesh(mesh: Mesh, *, area_tol: float | None = None) -> MeshReport:
    """Topology and data checks of a mesh, with counts and the offending indices.

    Topology comes from `mesh.topology` (built once). Duplicate faces are found on the host in NumPy by
    sorting each face's vertex indices and looking for repeated rows, so a copy with reversed orientation
    counts too (a face and its reversed copy form a closed, oriented two-face "pillow" that no edge check
    flags). Zero-area faces are measured at the current vertex positions: a face is flagged when
    `A_f <= area_tol * l_max^2` (`l_max` its longest edge), a scale-invariant test that also catches collinear
    corners; the default tolerance (`1e-12` in float64) is the one below which the operators refuse a face
    (module docstring). Zero-length edges join two coincident vertices. This is a host-side function (not for
    use under jit).

    Args:
        mesh: any triangle mesh, with concrete (not traced) vertices.
        area_tol: a face is flagged zero-area when `A_f <= area_tol * l_max^2` (keyword-only, a
            nonnegative number); `None` (default) is `default_area_tol` of the vertices' dtype.

    Returns:
        `MeshReport` with the counts, flags (manifold, oriented, closed) and offending indices.

    Raises:
        DDGInputError: `area_tol` is not a nonnegative finite number, or the vertices are traced.

    Equivalents: libigl `is_edge_manifold`, `is_vertex_manifold`, `euler_characteristic`,
    `boundary_loop`, `unique_simplices`; trimesh `Trimesh.is_watertight` / `is_winding_consistent`;
    geometry-central's `EdgeLengthGeometry` has no check (its cotangents are inf / NaN there).
    """
    topology = require_mesh("mesh", mesh).topology
    default = default_area_tol(mesh.vertices.dtype)
    if area_tol is None:
        area_tol = default
    if not (np.isscalar(area_tol) and np.isfinite(area_tol) and area_tol >= 0):
        raise DDGInputError(f"area_tol: expected a nonnegative finite number, got {area_tol!r}")
    if is_traced(mesh.vertices):
        raise DDGInputError("mesh: check_mesh measures the positions on the host and needs concrete vertices, got traced ones")
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    zero_area = degenerate_faces(mesh) if area_tol == default else _zero_area_faces(vertices, topology.faces, area_tol)
    edges = topology.edges
    zero_length = np.flatnonzero(np.all(vertices[edges[:, 0]] == vertices[edges[:, 1]], axis=1))
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
        zero_length_edges=zero_length,
        area_tol=float(area_tol),
    )


def default_area_tol(dtype) -> float:
    """The relative area `A / l_max^2` at or below which a face counts as degenerate: `max(1e-12, 16 eps)`.

    The cotangents of a face of relative area `r` carry a rounding error of about `eps / r` (their
    law-of-cosines numerators cancel to `~eps l_max^2`, then are divided by `4 A`), and so does the
    Laplacian built from them. In float64, `1e-12` keeps that below ~1e-4 of an entry: measured on an
    icosphere, one face of relative area 1e-12 moves the zero eigenvalue of `L phi = lambda M phi` by
    5e-9, one of 1e-14 by 8e-4, and a collinear one (computed area ~1e-17) to -170. In float32 a
    collinear face's computed area is ~eps l^2 itself, which `16 eps` (1.9e-6) catches.
    """
    return max(1e-12, 16.0 * float(np.finfo(np.dtype(dtype)).eps))


def degenerate_faces(mesh: Mesh) -> np.ndarray | None:
    """Faces of zero or near-zero area at the mesh's positions (`check_mesh`'s `zero_area_faces`), or `None` if traced.

    `A_f <= default_area_tol(dtype) * l_max^2`, measured on the host in float64 once per `Mesh` object
    and remembered with it (a mesh's arrays never change; `with_vertices` makes a new object). Under
    `jit` / `grad` / `vmap` the positions are tracers and cannot be measured: `None`.
    """
    mesh = require_mesh("mesh", mesh)
    if is_traced(mesh.vertices):
        return None
    faces = mesh.topology.faces if mesh.topology is not None else np.asarray(mesh.faces)
    return mesh.host_fact(
        "degenerate_faces",
        lambda: _zero_area_faces(np.asarray(mesh.vertices, dtype=np.float64), faces, default_area_tol(mesh.vertices.dtype)),
    )


def require_nondegenerate(mesh: Mesh) -> None:
    """`MeshDataError` naming the degenerate faces (`degenerate_faces`) and the remedies, if there are any.

    For the plain cotan route of a problem that also offers `robust=` (module docstring); nothing
    is checked under `jit` (traced positions).
    """
    faces = degenerate_faces(mesh)
    if faces is not None and faces.size:
        tol = default_area_tol(mesh.vertices.dtype)
        raise MeshDataError(
            f"mesh: faces {first_indices(index_mask(faces, mesh.n_faces))} have zero or near-zero area "
            f"(area <= {tol:g} * longest edge^2: collinear or coincident corners), where the cotan Laplacian's "
            "cotangents are infinite or undefined and its rounding makes it indefinite. Pass robust=True (the "
            "intrinsic Delaunay Laplacian of the mollified metric, positive semidefinite on every mesh; Sharp & "
            "Crane 2020), or repair the mesh (merge coincident vertices, drop or flip those faces; "
            "ddgjax.mesh.check_mesh(mesh) reports them)"
        )


def _zero_area_faces(vertices: np.ndarray, faces: np.ndarray, area_tol: float) -> np.ndarray:
    """Indices of the faces with `A <= area_tol * l_max^2` (float64 host arrays), compared squared.

    `4 A^2 = |e_1 x e_2|^2`, so the test is `|e_1 x e_2|^2 <= (2 area_tol l_max^2)^2`: no square root,
    and one gather per corner rather than an `(nf, 3, 3)` copy (this runs once per new mesh).
    """
    scale = np.max(np.abs(vertices), initial=0.0)
    # Scaled to unit size first: `|e_1 x e_2|^2` and `l^4` are fourth powers of the coordinates.
    unit = vertices / scale if scale > 0 else vertices
    a, b, c = unit[faces[:, 0]], unit[faces[:, 1]], unit[faces[:, 2]]
    across_a, across_b, across_c = c - b, a - c, b - a
    longest_sq = np.einsum("ij,ij->i", across_a, across_a)
    np.maximum(longest_sq, np.einsum("ij,ij->i", across_b, across_b), out=longest_sq)
    np.maximum(longest_sq, np.einsum("ij,ij->i", across_c, across_c), out=longest_sq)
    normal = np.cross(across_b, across_c)
    return np.flatnonzero(np.einsum("ij,ij->i", normal, normal) <= (2.0 * area_tol * longest_sq) ** 2)


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


def nondegenerate_face_mask(mesh: Mesh):
    """`(nf,)` bool, in JAX (traced positions too): faces whose area exceeds `default_area_tol * l_max^2`.

    What a computation that needs a face's normal or its plane uses to leave out the faces that have
    none (a flat cap's normal is any direction across its line, and turns arbitrarily fast as it moves).
    The test is a threshold, held out of differentiation (`stop_gradient`): the derivative is the one
    of the configuration with those faces left out.
    """
    import jax
    import jax.numpy as jnp

    from ._geometry import face_area_vectors, face_edge_lengths_sq

    areas = jnp.linalg.norm(face_area_vectors(mesh), axis=-1)
    longest_sq = jnp.max(face_edge_lengths_sq(mesh), axis=1)
    return jax.lax.stop_gradient(areas > default_area_tol(areas.dtype) * longest_sq)
