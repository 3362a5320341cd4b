"""Tet mesh checks: one report of the topology and the data problems of a tet mesh (DESIGN.md, Errors).

The volume counterpart of `ddgjax.mesh.check_mesh`, with the same degenerate-geometry policy: a tet
whose volume is zero or within rounding of zero (`|vol| <= volume_tol * l_max^3`,
`default_volume_tol`) has infinite or undefined dihedral cotangents, so no cotan operator is
meaningful on it. Building a tet mesh never refuses positions; `check_tet_mesh` reports such tets,
and the tets a move through `with_vertices` turned inside out (negative signed volume), on the host.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .._errors import DDGInputError, MeshDataError, first_indices, is_traced
from ._tet_mesh import TetMesh, require_tet_mesh


@dataclasses.dataclass(frozen=True)
class TetMeshReport:
    """What `check_tet_mesh` found. Index arrays are NumPy `int` arrays (empty when there is no problem).

    Attributes:
        n_vertices, n_tets, n_triangles, n_edges: element counts (`n_vertices` includes unreferenced ones).
        euler_characteristic: `V - E + T - C` over referenced vertices (1 for a ball, 0 for a solid
            torus, 2 for a spherical shell).
        n_components: components of tets (two tets sharing a triangle are connected).
        volume: the sum of the signed tet volumes (the enclosed volume when no tet is inverted).
        n_boundary_triangles, n_boundary_vertices: triangles of exactly one tet and their vertices.
        n_boundary_components: edge-connected components of the boundary surface (2 for a shell).
        nonmanifold_triangles: triangles of three or more tets.
        nonmanifold_boundary_edges, nonmanifold_boundary_vertices: edges of three or more boundary
            triangles and vertices whose boundary triangles form more than one fan (tets touching only
            along an edge or at a vertex), as `check_mesh` finds them on `tet_mesh.boundary_mesh()`.
        unreferenced_vertices: vertices used by no tet.
        duplicate_tets: tets with the same four vertices as an earlier tet, in any order (each later copy).
        degenerate_tets: tets with `|signed volume| <= volume_tol * (longest edge)^3` at the current
            positions (coplanar or coincident corners, or within rounding of that).
        inverted_tets: tets of negative signed volume beyond that tolerance (inside out: made positive
            by `TetMesh.from_arrays`, so only a later move, `with_vertices`, inverts one).
        volume_tol: the relative tolerance used.
    """

    n_vertices: int
    n_tets: int
    n_triangles: int
    n_edges: int
    euler_characteristic: int
    n_components: int
    volume: float
    n_boundary_triangles: int
    n_boundary_vertices: int
    n_boundary_components: int
    nonmanifold_triangles: np.ndarray
    nonmanifold_boundary_edges: np.ndarray
    nonmanifold_boundary_vertices: np.ndarray
    unreferenced_vertices: np.ndarray
    duplicate_tets: np.ndarray
    degenerate_tets: np.ndarray
    inverted_tets: np.ndarray
    volume_tol: float

    @property
    def is_manifold(self) -> bool:
        """True when every triangle has at most two tets and the boundary surface is a manifold."""
        return not (
            self.nonmanifold_triangles.size or self.nonmanifold_boundary_edges.size or self.nonmanifold_boundary_vertices.size
        )

    @property
    def is_clean(self) -> bool:
        """True when no data problem was found (manifold; no unreferenced vertices, duplicate, degenerate or inverted tets)."""
        return self.is_manifold and not (
            self.unreferenced_vertices.size or self.duplicate_tets.size or self.degenerate_tets.size or self.inverted_tets.size
        )

    def __str__(self) -> str:
        lines = [
            f"vertices {self.n_vertices:,}  tets {self.n_tets:,}  triangles {self.n_triangles:,}  edges {self.n_edges:,}",
            f"Euler characteristic {self.euler_characteristic}  components {self.n_components}  volume {self.volume:.6g}",
            f"boundary: {self.n_boundary_triangles:,} triangles, {self.n_boundary_vertices:,} vertices, "
            f"{self.n_boundary_components} components",
            f"manifold: {'yes' if self.is_manifold else 'no'}",
        ]
        problems = [
            ("non-manifold triangles (3+ tets)", self.nonmanifold_triangles),
            ("non-manifold boundary edges (3+ boundary triangles)", self.nonmanifold_boundary_edges),
            ("non-manifold boundary vertices (2+ fans)", self.nonmanifold_boundary_vertices),
            ("unreferenced vertices", self.unreferenced_vertices),
            ("duplicate tets (same four vertices as an earlier tet)", self.duplicate_tets),
            (f"degenerate tets (|volume| <= {self.volume_tol:g} * longest edge^3)", self.degenerate_tets),
            ("inverted tets (negative volume)", self.inverted_tets),
        ]
        for label, indices in problems:
            lines.append(f"{label}: " + (_first(indices) if indices.size else "none"))
        return "\n".join(lines)


def check_tet_mesh(tet_mesh: TetMesh, *, volume_tol: float | None = None) -> TetMeshReport:
    """Topology and data checks of a tet mesh, with counts and the offending indices.

    Topology comes from `tet_mesh.topology` (built once); the boundary surface's manifold check is
    `check_mesh`'s, on `tet_mesh.boundary_mesh()`. Degenerate and inverted tets are measured on the
    host in float64 at the current positions with the scale-invariant test `|vol| <= volume_tol *
    l_max^3` (`l_max` the tet's longest edge; a regular tet has `vol / l^3 = 0.118`). Duplicate tets
    are found by sorting each tet's vertex indices. A host-side function (not for use under jit).

    Equivalents: libigl `boundary_facets`, `volume` (signed volumes) and TetGen's `-d` (no report
    object); gpytoolbox has none.

    Args:
        tet_mesh: the tet mesh, with its topology (not under `jit`) and concrete vertices.
        volume_tol: the relative tolerance of the degenerate-tet test, `>= 0` (keyword-only); `None`
            (default): `default_volume_tol` of the vertices' dtype (`1e-12` in float64).

    Returns:
        A `TetMeshReport` of counts and NumPy index arrays.
    """
    topology = require_tet_mesh("tet_mesh", tet_mesh).topology
    if topology is None:
        raise DDGInputError("tet_mesh: check_tet_mesh needs the tet mesh's topology, which a compiled kernel does not see")
    if volume_tol is None:
        volume_tol = default_volume_tol(tet_mesh.vertices.dtype)
    if not (np.isscalar(volume_tol) and np.isfinite(volume_tol) and volume_tol >= 0):
        raise DDGInputError(f"volume_tol: expected a nonnegative finite number, got {volume_tol!r}")
    if is_traced(tet_mesh.vertices):
        raise DDGInputError(
            "tet_mesh: check_tet_mesh measures the positions on the host and needs concrete vertices, got traced ones"
        )
    signed, longest, scale = _unit_signed_volumes_and_longest_edges(
        np.asarray(tet_mesh.vertices, dtype=np.float64), topology.tets
    )
    flat = np.abs(signed) <= volume_tol * longest**3
    if topology.is_closed:  # no boundary surface (a periodic complex)
        boundary_edges = boundary_vertices = np.zeros(0, dtype=np.int64)
        boundary_components = 0
    else:
        surface = tet_mesh.boundary_mesh().topology
        boundary_edges, boundary_vertices = surface.nonmanifold_edges, surface.nonmanifold_vertices
        boundary_components = surface.n_components
    return TetMeshReport(
        n_vertices=topology.n_vertices,
        n_tets=topology.n_tets,
        n_triangles=topology.n_triangles,
        n_edges=topology.n_edges,
        euler_characteristic=topology.euler_characteristic,
        n_components=topology.n_components,
        volume=float(signed.sum() * scale**3),
        n_boundary_triangles=int(topology.boundary_triangles.size),
        n_boundary_vertices=int(topology.boundary_vertices.size),
        n_boundary_components=boundary_components,
        nonmanifold_triangles=topology.nonmanifold_triangles,
        nonmanifold_boundary_edges=boundary_edges,
        nonmanifold_boundary_vertices=boundary_vertices,
        unreferenced_vertices=topology.unreferenced_vertices,
        duplicate_tets=_duplicate_tets(topology.tets),
        degenerate_tets=np.flatnonzero(flat),
        inverted_tets=np.flatnonzero(~flat & (signed < 0)),
        volume_tol=float(volume_tol),
    )


def default_volume_tol(dtype) -> float:
    """The relative volume `|vol| / l_max^3` at or below which a tet counts as degenerate: `max(1e-12, 16 eps)`.

    The same bound as `ddgjax.mesh`'s zero-area faces, for the same reason: the cotangent of a
    dihedral angle is a product of face areas over `l vol`, whose rounding error (`~eps l^3` in `vol`)
    grows like `eps / r` for a tet of relative volume `r`; `1e-12` keeps it near 1e-4 of a weight
    in float64, and `16 eps` catches a coplanar tet's computed volume in float32.
    """
    return max(1e-12, 16.0 * float(np.finfo(np.dtype(dtype)).eps))


def _unit_signed_volumes_and_longest_edges(vertices: np.ndarray, tets: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Signed volumes `det(b - a, c - a, d - a) / 6` and longest edges of the tets scaled to unit size, and the scale."""
    scale = float(np.max(np.abs(vertices), initial=0.0)) or 1.0
    # Scaled to unit size first, as check_mesh does: volumes and l^3 are third powers of the coordinates.
    corners = (vertices / scale)[tets]
    a, b, c, d = (corners[:, k] for k in range(4))
    signed = np.einsum("ij,ij->i", b - a, np.cross(c - a, d - a)) / 6.0
    pairs = [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)]
    longest = np.sqrt(np.max([np.sum((corners[:, i] - corners[:, j]) ** 2, axis=1) for i, j in pairs], axis=0))
    return signed, longest, scale


def _duplicate_tets(tets: np.ndarray) -> np.ndarray:
    """Indices of the tets whose vertex set repeats an earlier tet's, in increasing order."""
    _, first = np.unique(np.sort(tets, axis=1), axis=0, return_index=True)
    later = np.ones(tets.shape[0], dtype=bool)
    later[first] = False  # np.unique's return_index is the first occurrence of each distinct row
    return np.flatnonzero(later)


def _first(indices: np.ndarray) -> str:
    mask = np.zeros(int(indices.max()) + 1, dtype=bool)
    mask[indices] = True
    return first_indices(mask)


def require_tet_problem(tet_mesh: TetMesh, robust: object) -> None:
    """What the problem layer (`solve_poisson`, `eigenpairs`, `heat_distance` on a `TetMesh`) checks first,
    as `ddgjax.laplacian`'s `resolve_robust` does for a triangle mesh.

    - `robust=` must be `False` (`DDGInputError` naming it): the robust operators are the intrinsic
      Delaunay retriangulation of a surface (Sharp & Crane 2020), which has no tetrahedral counterpart.
    - No degenerate tets at concrete positions (`MeshDataError` naming them): a tet of near-zero volume
      has near-infinite cotan weights, so its Laplacian's rounding makes the solve fail or lie, and tets
      have no `robust=` remedy.
    - No inverted tets (`MeshDataError` naming them): a tet turned inside out by a move (`with_vertices`)
      overlaps its neighbours, so the solid is no longer an embedding; its signed volume would enter the
      mass with the wrong sign and its cotan weights would describe a folded solid, an answer with no
      meaning rather than an error.

    Both are measured once per `TetMesh` object, on the host, with `check_tet_mesh`'s test; nothing is
    checked under `jit` (traced positions), where values and gradients stay finite.
    """
    if robust is not False:
        raise DDGInputError(
            f"robust: the intrinsic Delaunay operators are a triangle-mesh construction with no tetrahedral "
            f"counterpart (no intrinsic Delaunay retriangulation in 3-D), so a TetMesh takes only robust=False, "
            f"got {robust!r}"
        )
    if is_traced(tet_mesh.vertices) or tet_mesh.topology is None:
        return

    def measure():
        signed, longest, _ = _unit_signed_volumes_and_longest_edges(
            np.asarray(tet_mesh.vertices, dtype=np.float64), tet_mesh.topology.tets
        )
        flat = np.abs(signed) <= default_volume_tol(tet_mesh.vertices.dtype) * longest**3
        return np.flatnonzero(flat), np.flatnonzero(~flat & (signed < 0))

    degenerate, inverted = tet_mesh.host_fact("unusable_tets", measure)
    if degenerate.size:
        raise MeshDataError(
            f"tet_mesh: tets {_first(degenerate)} have zero or near-zero volume (|volume| <= "
            f"{default_volume_tol(tet_mesh.vertices.dtype):g} * longest edge^3: coplanar or coincident corners), where "
            "the cotan weights are infinite or undefined; remove or repair them (ddgjax.volume.check_tet_mesh lists them; "
            "re-mesh with ddgjax.volume.tetrahedralize)"
        )
    if inverted.size:
        raise MeshDataError(
            f"tet_mesh: {inverted.size} of its {tet_mesh.n_tets} tets are inverted (negative signed volume: tets "
            f"{_first(inverted)}), so the solid folds over itself and its Laplacian and mass have no meaning; untangle "
            "the positions (a move through with_vertices turned them inside out), or, for a mirrored mesh whose tets "
            "are all inverted, rebuild it with ddgjax.volume.TetMesh.from_arrays(vertices, tets), which orients each tet"
        )
