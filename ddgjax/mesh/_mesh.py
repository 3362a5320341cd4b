"""The `Mesh` pytree: vertex positions plus integer connectivity built once in NumPy (DESIGN.md, two phases)."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int

from .._compile import device_array
from .._domain import Domain
from .._errors import DDGInputError, check_float_array, check_float_shape, is_traced
from ._topology import MeshTopology, build_topology, validate_simplices


class Mesh(Domain):
    r"""A triangle mesh: vertex positions (differentiable) and connectivity (fixed).

    Make one with `Mesh.from_arrays(vertices, faces)` or `ddgjax.io.load_mesh(path)`. Every geometric
    quantity in ddgjax is a pure JAX function of `mesh.vertices`; differentiate with

        jax.grad(lambda V: energy(mesh.with_vertices(V)))(mesh.vertices)

    Integer arrays are pytree leaves (so large meshes are jit arguments, not baked-in constants);
    `topology` (NumPy, static) holds the connectivity and its checks and compares equal for equal
    face arrays, so a function you jit with the mesh as an argument compiles once per connectivity
    (the same mesh loaded twice reuses the program) and moving vertices never recompiles. The storage
    plans of operators (sparsity patterns, slot maps) are not part of a mesh: the package that uses
    one builds it on first use and caches it per connectivity (e.g. `ddgjax.laplacian`).

    A mesh is the pair $(V, F)$: positions $V \in \mathbb{R}^{n_v \times 3}$ (`vertices`) and triangles
    $F \in \mathbb{N}^{n_f \times 3}$ (`faces`, three vertex indices per row).

    Attributes:
        vertices: `(nv, 3)` positions, in the caller's float dtype.
        faces: `(nf, 3)` int32 vertex indices (counterclockwise seen from outside, for oriented meshes).
        edges: `(ne, 2)` int32, oriented low -> high, sorted.
        face_edges: `(nf, 3)` edge opposite each corner (libigl / gpytoolbox order).
        face_edge_signs: `(nf, 3)` int32 +1 / -1: does the face traverse that edge low -> high.
        edge_faces, edge_face_corners: `(ne, m)` faces of each edge and the corner opposite it, -1 padded.
        topology: `MeshTopology` (static; `None` only inside ddgjax's compiled kernels, see
            `ddgjax._compile.kernel`).

    Examples:
        >>> import numpy as np
        >>> import ddgjax
        >>> vertices = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
        >>> faces = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
        >>> tetrahedron = ddgjax.Mesh.from_arrays(vertices, faces)
        >>> tetrahedron.n_vertices, tetrahedron.n_edges, tetrahedron.n_faces
        (4, 6, 4)
        >>> round(float(ddgjax.mesh.enclosed_volume(tetrahedron)), 6)
        0.166667
    """

    vertices: Float[Array, "nv 3"]
    faces: Int[Array, "nf 3"]
    edges: Int[Array, "ne 2"]
    face_edges: Int[Array, "nf 3"]
    face_edge_signs: Int[Array, "nf 3"]
    edge_faces: Int[Array, "ne m"]
    edge_face_corners: Int[Array, "ne m"]
    topology: MeshTopology | None = eqx.field(static=True)

    parameter_name = "mesh"

    def __init__(self, *args, **kwargs):
        raise DDGInputError(
            "Mesh(...): build a mesh with ddgjax.Mesh.from_arrays(vertices, faces) (it checks the arrays and "
            "builds the connectivity) or ddgjax.io.load_mesh(path)"
        )

    @classmethod
    def from_arrays(cls, vertices, faces) -> "Mesh":
        """Build a mesh from `(nv, 3)` vertex positions and `(nf, 3)` integer faces.

        Raises `DDGInputError` on bad shapes or dtypes, NaN/inf coordinates, an empty mesh, face
        indices out of range and faces repeating a vertex. Data problems (non-manifold, inconsistent
        orientation, unreferenced vertices, zero-area faces, zero-length edges, duplicate faces) are
        accepted and reported by `ddgjax.mesh.check_mesh`; operators that cannot handle them refuse
        with `MeshDataError`. Positions are never refused for their geometry alone (they move under
        optimisation, inside `jit`): faces of zero or near-zero area are found, once per mesh object,
        the first time a problem that needs them non-degenerate runs on concrete positions, and it
        then refuses them naming the faces and `robust=True` (`ddgjax.mesh._check`, module docstring).
        """
        if is_traced(vertices):
            raise DDGInputError(
                "vertices: Mesh.from_arrays builds topology on the host and needs concrete arrays; inside "
                "jit use mesh.with_vertices(V) on a mesh made outside"
            )
        host_vertices = check_float_array("vertices", vertices, (3,))
        topology = build_topology(validate_simplices("faces", faces, host_vertices.shape[0], width=3), host_vertices.shape[0])
        return cls.from_topology(as_float_vertices(vertices), topology)

    @classmethod
    def from_topology(cls, vertices: Float[Array, "nv 3"], topology: MeshTopology) -> "Mesh":
        """A mesh with the given (already built) topology and vertex positions."""
        arrays = jax.device_put(
            {
                "faces": topology.faces,
                "edges": topology.edges,
                "face_edges": topology.face_edges,
                "face_edge_signs": topology.face_edge_signs.astype(np.int32),
                "edge_faces": topology.edge_faces,
                "edge_face_corners": topology.edge_face_corners.astype(np.int32),
            }
        )
        return _assemble(vertices=vertices, **arrays, topology=topology)

    # `vertices` is annotated unshaped on purpose: bad shapes and dtypes get this method's own
    # `DDGInputError` (naming the argument) rather than a run-time type-checker's message.
    def with_vertices(self, vertices: ArrayLike) -> "Mesh":
        """The same connectivity with new vertex positions `(nv, 3)` (works under jit, grad and vmap).

        A concrete (non-traced) array is checked on the host like `from_arrays` does: it must have
        shape `(nv, 3)` with this mesh's `nv`, a real dtype and finite values, else `DDGInputError`
        naming `vertices`, what was expected and the first offending rows. NumPy arrays are accepted
        and converted (e.g. from `jax.test_util.check_grads`); integer arrays become JAX's default
        float dtype. Traced arrays (inside `jit`, `grad`, `vmap`) get the same shape and dtype checks;
        their values cannot be inspected.
        """
        return eqx.tree_at(lambda mesh: mesh.vertices, self, checked_vertices(vertices, self.n_vertices))

    @property
    def n_vertices(self) -> int:
        """Number of vertices `nv`, unreferenced ones included (`vertices.shape[0]`; libigl `V.shape[0]`)."""
        return self.vertices.shape[0]

    @property
    def n_faces(self) -> int:
        """Number of triangles `nf` (`faces.shape[0]`; libigl `F.shape[0]`)."""
        return self.faces.shape[0]

    @property
    def n_edges(self) -> int:
        """Number of distinct undirected edges `ne` (`edges.shape[0]`); `nv - ne + nf` is the Euler
        characteristic when no vertex is unreferenced. libigl: `igl.edges(F).shape[0]`."""
        return self.edges.shape[0]

    @classmethod
    def how_to_build(cls, value: object) -> str:
        """How to make a `Mesh` from what was given (`Domain.require`'s hint)."""
        if isinstance(value, tuple) and len(value) == 2:
            return "for a (vertices, faces) pair use ddgjax.Mesh.from_arrays(vertices, faces)"
        return "build one with ddgjax.Mesh.from_arrays(vertices, faces) or ddgjax.io.load_mesh(path)"

    def for_kernel(self, operation: str | None) -> "Mesh":
        """The mesh a compiled kernel traces (`without_topology`), after `MeshTopology.require_oriented(operation)`."""
        if operation is not None and self.topology is not None:
            self.topology.require_oriented(operation)
        return self.without_topology()

    def without_topology(self) -> "Mesh":
        """The same arrays with `topology=None`: what ddgjax's compiled kernels trace (`ddgjax._compile.kernel`)."""
        if self.topology is None:
            return self
        return _assemble(**{name: getattr(self, name) for name in _ARRAY_FIELDS}, topology=None)


_ARRAY_FIELDS = ("vertices", "faces", "edges", "face_edges", "face_edge_signs", "edge_faces", "edge_face_corners")


def _assemble(**fields) -> Mesh:
    """A `Mesh` from its fields, as equinox rebuilds a module when it unflattens one (`Mesh.__init__` is for users)."""
    mesh = object.__new__(Mesh)
    for name, value in fields.items():
        object.__setattr__(mesh, name, value)
    return mesh


def require_mesh(name: str, value) -> Mesh:
    """`value` if it is a `Mesh`, else `DDGInputError` naming the argument and saying how to make one.

    Args:
        name: the argument's name, for the error message.
        value: the object to check.

    Returns:
        `value` itself, when it is a `Mesh`.

    Raises:
        DDGInputError: `value` is not a `Mesh`.
    """
    return Mesh.require(name, value)


def checked_vertices(vertices, n_vertices: int) -> Float[Array, "nv 3"]:
    """New positions for a mesh of `n_vertices` (`Mesh.with_vertices`, `ddgjax.volume.TetMesh.with_vertices`):
    shape `(n_vertices, 3)` and a real dtype always, finite values when concrete (`DDGInputError` naming
    `vertices`), then `as_float_vertices`."""
    if np.shape(vertices) != (n_vertices, 3):
        raise DDGInputError(f"vertices: expected shape ({n_vertices}, 3), got {np.shape(vertices)}")
    if is_traced(vertices):
        check_float_shape("vertices", vertices, (3,))
    else:
        check_float_array("vertices", vertices, (3,))
    return as_float_vertices(vertices)


def as_float_vertices(vertices) -> Float[Array, "nv 3"]:
    """Vertex positions as a float JAX array (integers become JAX's default float), moved without an eager program."""
    if not isinstance(vertices, jax.Array) and not np.issubdtype(np.asarray(vertices).dtype, np.floating):
        vertices = np.asarray(vertices, dtype=float)  # converted on the host: nothing compiled per size
    array = device_array(vertices)
    if not jnp.issubdtype(array.dtype, jnp.floating):
        array = array.astype(jnp.result_type(float))
    return array
