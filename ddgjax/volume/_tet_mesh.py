"""The `TetMesh` pytree: vertex positions plus tetrahedral connectivity built once in NumPy (DESIGN.md, two phases)."""

from __future__ import annotations

import equinox as eqx
import jax
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int

from .._domain import Domain
from .._errors import DDGInputError, check_float_array, is_traced
from ..mesh import Mesh, MeshTopology
from ..mesh.internal import as_float_vertices, build_topology, checked_vertices, validate_simplices
from ._topology import TetTopology, build_tet_topology


class TetMesh(Domain):
    """A tetrahedral mesh: vertex positions (differentiable) and connectivity (fixed), the volume analogue of `Mesh`.

    Make one with `TetMesh.from_arrays(vertices, tets)` or `ddgjax.volume.load_tet_mesh(path)`. Every
    quantity in `ddgjax.volume` is a pure JAX function of `tet_mesh.vertices`; differentiate with

        jax.grad(lambda V: energy(tet_mesh.with_vertices(V)))(tet_mesh.vertices)

    As for `Mesh`, integer arrays are pytree leaves and `topology` (static, compared by content) holds
    the connectivity, so a function jitted with a `TetMesh` argument compiles once per connectivity.
    Conventions (local edge and triangle order, orientation, signs): `ddgjax.volume._topology` and
    docs/conventions.md.

    Attributes:
        vertices: `(nv, 3)` positions, in the caller's float dtype.
        tets: `(nt, 4)` int32 vertex indices, positively oriented (`det(b - a, c - a, d - a) > 0`)
            where the positions given to `from_arrays` allowed it.
        edges: `(ne, 2)` int32, low -> high, sorted.
        tet_edges, tet_edge_signs: `(nt, 6)` the global edge of each local edge (libigl's
            `edge_lengths` order `(3,0), (3,1), (3,2), (1,2), (2,0), (0,1)`) and +1 where it runs low -> high.
        triangles: `(ntri, 3)` int32 sorted vertex triples.
        tet_triangles, tet_triangle_signs: `(nt, 4)` the triangle opposite each vertex and +1 where its
            outward orientation agrees with the sorted order.
        triangle_edges: `(ntri, 3)` the edge opposite each corner of a triangle.
        topology: `TetTopology` (static; `None` only inside ddgjax's compiled kernels).
    """

    vertices: Float[Array, "nv 3"]
    tets: Int[Array, "nt 4"]
    edges: Int[Array, "ne 2"]
    tet_edges: Int[Array, "nt 6"]
    tet_edge_signs: Int[Array, "nt 6"]
    triangles: Int[Array, "ntri 3"]
    tet_triangles: Int[Array, "nt 4"]
    tet_triangle_signs: Int[Array, "nt 4"]
    triangle_edges: Int[Array, "ntri 3"]
    topology: TetTopology | None = eqx.field(static=True)

    parameter_name = "tet_mesh"

    def __init__(self, *args, **kwargs):
        raise DDGInputError(
            "TetMesh(...): build one with ddgjax.volume.TetMesh.from_arrays(vertices, tets) (it checks the arrays, "
            "orients the tets and builds the connectivity) or ddgjax.volume.load_tet_mesh(path)"
        )

    @classmethod
    def from_arrays(cls, vertices, tets) -> "TetMesh":
        """Build a tet mesh from `(nv, 3)` vertex positions and `(nt, 4)` integer tets.

        Raises `DDGInputError` on bad shapes or dtypes, NaN/inf coordinates, an empty mesh, indices
        out of range and tets repeating a vertex. Tets of negative signed volume are re-oriented
        (their last two vertices swapped), so every non-degenerate tet is positive and the mesh is
        consistently oriented (libigl and TetGen leave this to the caller); degenerate tets (zero or
        near-zero volume) keep their order and are reported by `check_tet_mesh`. Non-manifold
        triangles (three or more tets) are accepted and reported.
        """
        host_vertices, host_tets = _validated(vertices, tets, "TetMesh.from_arrays")
        volumes = host_signed_volumes(host_vertices, host_tets)
        host_tets[volumes < 0] = host_tets[volumes < 0][:, [0, 1, 3, 2]]
        return cls.from_topology(as_float_vertices(vertices), build_tet_topology(host_tets, host_vertices.shape[0]))

    @classmethod
    def from_topology(cls, vertices: Float[Array, "nv 3"], topology: TetTopology) -> "TetMesh":
        """A tet mesh with the given (already built) topology and vertex positions."""
        arrays = jax.device_put(
            {
                "tets": topology.tets,
                "edges": topology.edges,
                "tet_edges": topology.tet_edges,
                "tet_edge_signs": topology.tet_edge_signs.astype(np.int32),
                "triangles": topology.triangles,
                "tet_triangles": topology.tet_triangles,
                "tet_triangle_signs": topology.tet_triangle_signs.astype(np.int32),
                "triangle_edges": topology.triangle_edges,
            }
        )
        return _assemble(vertices=vertices, **arrays, topology=topology)

    def with_vertices(self, vertices: ArrayLike) -> "TetMesh":
        """The same connectivity with new vertex positions `(nv, 3)` (works under jit, grad and vmap).

        Checked as `Mesh.with_vertices` checks: shape `(nv, 3)`, a real dtype, finite values when
        concrete (`DDGInputError` naming `vertices`). The tets keep their orientation: a move that
        inverts a tet gives it a negative signed volume (`tet_signed_volumes`), it is not re-oriented.
        """
        return eqx.tree_at(lambda tet_mesh: tet_mesh.vertices, self, checked_vertices(vertices, self.n_vertices))

    @property
    def n_vertices(self) -> int:
        """Number of vertices `nv`, unreferenced ones included."""
        return self.vertices.shape[0]

    @property
    def n_tets(self) -> int:
        """Number of tetrahedra `nt` (libigl `T.shape[0]`)."""
        return self.tets.shape[0]

    @property
    def n_edges(self) -> int:
        """Number of distinct edges `ne`."""
        return self.edges.shape[0]

    @property
    def n_triangles(self) -> int:
        """Number of distinct triangles `ntri` (interior and boundary)."""
        return self.triangles.shape[0]

    def boundary_mesh(self) -> Mesh:
        """The boundary surface as a `ddgjax.Mesh` on the same `(nv, 3)` vertices (so values carry over unchanged).

        Its faces are the triangles of exactly one tet, oriented so that their normals point out of the
        solid; interior vertices are unreferenced in it. Differentiable in the vertex positions like any
        `Mesh` (`boundary_mesh().with_vertices(V)` or `tet_mesh.with_vertices(V).boundary_mesh()`).
        libigl: `igl.boundary_facets(T)` (its orientation convention differs).
        """
        topology = _require_topology(self)
        if topology.boundary_faces.shape[0] == 0:
            raise DDGInputError("tet_mesh: this tet mesh has no boundary triangles (every triangle has two or more tets)")
        return Mesh.from_topology(self.vertices, _boundary_topology(topology))

    @classmethod
    def how_to_build(cls, value: object) -> str:
        """How to make a `TetMesh` from what was given (`Domain.require`'s hint)."""
        if isinstance(value, Mesh):
            return "this is a triangle Mesh; the volume operators need tetrahedra (ddgjax.volume.tetrahedralize(mesh) fills a closed surface)"
        if isinstance(value, tuple) and len(value) == 2:
            return "for a (vertices, tets) pair use ddgjax.volume.TetMesh.from_arrays(vertices, tets)"
        return "build one with ddgjax.volume.TetMesh.from_arrays(vertices, tets) or ddgjax.volume.load_tet_mesh(path)"

    def for_kernel(self, operation: str | None) -> "TetMesh":
        """The tet mesh a compiled kernel traces (`without_topology`); its tets are oriented on construction."""
        return self.without_topology()

    def without_topology(self) -> "TetMesh":
        """The same arrays with `topology=None`: what ddgjax's compiled kernels trace (`ddgjax._compile.kernel`)."""
        if self.topology is None:
            return self
        return _assemble(**{name: getattr(self, name) for name in _ARRAY_FIELDS}, topology=None)


_ARRAY_FIELDS = (
    "vertices",
    "tets",
    "edges",
    "tet_edges",
    "tet_edge_signs",
    "triangles",
    "tet_triangles",
    "tet_triangle_signs",
    "triangle_edges",
)


def tet_mesh_as_given(vertices, tets) -> TetMesh:
    """A `TetMesh` checked as `TetMesh.from_arrays` checks it, with the tets in the order given (not re-oriented).

    For `load_tet_mesh`: a file whose tets are mostly positive and some inverted keeps them inverted, so
    `check_tet_mesh` and the problem layer see what was saved (`from_arrays` would silently turn them
    right side out).
    """
    host_vertices, host_tets = _validated(vertices, tets, "load_tet_mesh")
    return TetMesh.from_topology(as_float_vertices(vertices), build_tet_topology(host_tets, host_vertices.shape[0]))


def host_signed_volumes(vertices: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """`(nt,)` float64 signed volumes times 6, `det(b - a, c - a, d - a)`, on the host."""
    corners = vertices[tets].astype(np.float64)
    return np.einsum(
        "ij,ij->i", corners[:, 1] - corners[:, 0], np.cross(corners[:, 2] - corners[:, 0], corners[:, 3] - corners[:, 0])
    )


def _validated(vertices, tets, caller: str) -> tuple[np.ndarray, np.ndarray]:
    if is_traced(vertices):
        raise DDGInputError(
            f"vertices: {caller} builds topology on the host and needs concrete arrays; inside jit use "
            "tet_mesh.with_vertices(V) on a tet mesh made outside"
        )
    host_vertices = check_float_array("vertices", vertices, (3,))
    return host_vertices, validate_simplices("tets", tets, host_vertices.shape[0], width=4)


def _assemble(**fields) -> TetMesh:
    """A `TetMesh` from its fields, as equinox rebuilds a module when it unflattens one (`__init__` is for users)."""
    tet_mesh = object.__new__(TetMesh)
    for name, value in fields.items():
        object.__setattr__(tet_mesh, name, value)
    return tet_mesh


_BOUNDARY_TOPOLOGIES: dict = {}


def _boundary_topology(topology: TetTopology) -> MeshTopology:
    """The `MeshTopology` of the boundary surface, built once per tet connectivity (a few kept)."""
    cached = _BOUNDARY_TOPOLOGIES.get(topology)
    if cached is None:
        if len(_BOUNDARY_TOPOLOGIES) >= 8:
            _BOUNDARY_TOPOLOGIES.pop(next(iter(_BOUNDARY_TOPOLOGIES)))
        cached = _BOUNDARY_TOPOLOGIES[topology] = build_topology(np.array(topology.boundary_faces), topology.n_vertices)
    return cached


def _require_topology(tet_mesh: TetMesh) -> TetTopology:
    topology = require_tet_mesh("tet_mesh", tet_mesh).topology
    if topology is None:
        raise DDGInputError("tet_mesh: this needs the tet mesh's topology, which a compiled kernel does not see")
    return topology


def require_tet_mesh(name: str, value) -> TetMesh:
    """`value` if it is a `TetMesh`, else `DDGInputError` naming the argument and saying how to make one.

    Args:
        name: the argument's name, for the error message.
        value: the object to check.

    Returns:
        `value` itself, when it is a `TetMesh`.
    """
    return TetMesh.require(name, value)
