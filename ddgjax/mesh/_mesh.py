"""The `Mesh` pytree: vertex positions plus integer connectivity built once in NumPy."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int

from .._errors import DDGInputError, check_float_array, is_traced
from .._host import to_device
from ..sparse._pattern import SparsityPattern
from ._topology import MeshTopology, build_topology, validate_faces


class Mesh(eqx.Module):
    """A triangle mesh: vertex positions (differentiable) and connectivity (fixed).

    Make one with `Mesh.from_arrays(vertices, faces)` or `ddgjax.io.load_mesh(path)`. Every geometric
    quantity in ddgjax is a pure JAX function of `mesh.vertices`; differentiate with

        jax.grad(lambda V: energy(mesh.with_vertices(V)))(mesh.vertices)

    Integer arrays are pytree leaves (so large meshes are jit arguments, not baked-in constants);
    `topology` (NumPy, static, hashed by identity) holds the rest of the connectivity and the checks,
    so moving vertices never triggers recompilation. (A function you jit with the mesh as an argument
    compiles once per mesh object; ddgjax's own operators called outside jit run kernels compiled
    once per mesh size, see `ddgjax.mesh._compiled`.)

    Attributes:
        vertices: `(nv, 3)` positions, in the caller's float dtype.
        faces: `(nf, 3)` int32 vertex indices (counterclockwise seen from outside, for oriented meshes).
        edges: `(ne, 2)` int32, oriented low -> high, sorted.
        face_edges: `(nf, 3)` edge opposite each corner (libigl / gpytoolbox order).
        face_edge_signs: `(nf, 3)` int32 +1 / -1: does the face traverse that edge low -> high.
        edge_faces, edge_face_corners: `(ne, m)` faces of each edge and the corner opposite it, -1 padded.
        vertex_pattern: sparsity pattern of vertex-vertex operators (diagonal plus edges; ELL storage,
            symmetric), shared by the cotan Laplacian and the Galerkin mass matrix.
        vertex_pattern_source: `(nnz,)` for each storage slot, its index in the list
            `[diagonal (nv) | edges low->high (ne) | edges high->low (ne)]`, or `nv + 2 ne` for an ELL
            padding slot, so operator values assemble with one gather:
            `jnp.take(entries, vertex_pattern_source, mode="fill", fill_value=0)`.
        vertex_pattern_corners: `(nnz - nv, m)` for each off-diagonal storage slot `nv + s`, the flat
            corners `3 f + k` opposite its edge (`3 nf` pads), so per-corner values (cotangents) land
            in storage order with one gather; `corner_pattern_slots` `(3 nf, 2)` is its transpose (the
            two off-diagonal slots of each corner's edge), for a scatter-free reverse pass
            (`ddgjax.sparse.gather_sum`).
        topology: `MeshTopology` (static).
    """

    vertices: Float[Array, "nv 3"]
    faces: Int[Array, "nf 3"]
    edges: Int[Array, "ne 2"]
    face_edges: Int[Array, "nf 3"]
    face_edge_signs: Int[Array, "nf 3"]
    edge_faces: Int[Array, "ne m"]
    edge_face_corners: Int[Array, "ne m"]
    vertex_pattern: SparsityPattern
    vertex_pattern_source: Int[Array, " nnz"]
    vertex_pattern_corners: Int[Array, "n_off m"]
    corner_pattern_slots: Int[Array, "n_corners 2"]
    topology: MeshTopology = eqx.field(static=True)

    @classmethod
    def from_arrays(cls, vertices, faces) -> "Mesh":
        """Build a mesh from `(nv, 3)` vertex positions and `(nf, 3)` integer faces.

        Raises `DDGInputError` on bad shapes or dtypes, NaN/inf coordinates, an empty mesh, face
        indices out of range and faces repeating a vertex. Data problems (non-manifold, inconsistent
        orientation, unreferenced vertices, zero-area faces) are accepted and reported by
        `ddgjax.mesh.check_mesh`; operators that cannot handle them refuse with `MeshDataError`.
        """
        if is_traced(vertices):
            raise DDGInputError(
                "vertices: Mesh.from_arrays builds topology on the host and needs concrete arrays; inside "
                "jit use mesh.with_vertices(V) on a mesh made outside"
            )
        host_vertices = check_float_array("vertices", vertices, (3,))
        topology = build_topology(validate_faces(faces, host_vertices.shape[0]), host_vertices.shape[0])
        return cls.from_topology(_as_float_array(vertices), topology)

    @classmethod
    def from_topology(cls, vertices: Float[Array, "nv 3"], topology: MeshTopology) -> "Mesh":
        """A mesh with the given (already built) topology and vertex positions."""
        pattern, source = SparsityPattern.from_edges(topology.edges, topology.n_vertices)
        slot_corners, corner_slots = _pattern_corner_maps(topology, source)
        device = to_device(
            faces=topology.faces,
            edges=topology.edges,
            face_edges=topology.face_edges,
            face_edge_signs=topology.face_edge_signs.astype(np.int32),
            edge_faces=topology.edge_faces,
            edge_face_corners=topology.edge_face_corners.astype(np.int32),
            vertex_pattern_source=source,
            vertex_pattern_corners=slot_corners,
            corner_pattern_slots=corner_slots,
        )
        return cls(
            vertices=vertices,
            vertex_pattern=pattern,
            **device,
            topology=topology,
        )

    # `vertices` is annotated unshaped on purpose: bad shapes and dtypes get this method's own
    # `DDGInputError` (naming the argument) rather than a run-time type-checker's message.
    def with_vertices(self, vertices: ArrayLike) -> "Mesh":
        """The same connectivity with new vertex positions `(nv, 3)` (works under jit, grad and vmap).

        A concrete (non-traced) array is checked on the host like `from_arrays` does: it must have
        shape `(nv, 3)` with this mesh's `nv`, a real dtype and finite values, else `DDGInputError`
        naming `vertices`, what was expected and the first offending rows. NumPy arrays are accepted
        and converted (e.g. from `jax.test_util.check_grads`); integer arrays become JAX's default
        float dtype. Traced arrays (inside `jit`, `grad`, `vmap`) cannot be inspected and pass
        through unchecked; their shape is fixed by the trace.
        """
        if is_traced(vertices):
            return eqx.tree_at(lambda mesh: mesh.vertices, self, vertices)
        host = check_float_array("vertices", vertices, (3,))
        if host.shape[0] != self.topology.n_vertices:
            raise DDGInputError(f"vertices: expected shape ({self.topology.n_vertices}, 3), got {host.shape}")
        return eqx.tree_at(lambda mesh: mesh.vertices, self, _as_float_array(vertices))

    @property
    def n_vertices(self) -> int:
        """Number of vertices `nv`, unreferenced ones included (`vertices.shape[0]`; libigl `V.shape[0]`)."""
        return self.topology.n_vertices

    @property
    def n_faces(self) -> int:
        """Number of triangles `nf` (`faces.shape[0]`; libigl `F.shape[0]`)."""
        return self.topology.n_faces

    @property
    def n_edges(self) -> int:
        """Number of distinct undirected edges `ne` (`edges.shape[0]`); `nv - ne + nf` is the Euler
        characteristic when no vertex is unreferenced. libigl: `igl.edges(F).shape[0]`."""
        return self.topology.n_edges


def _pattern_corner_maps(topology: MeshTopology, source: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Off-diagonal storage slot -> corners opposite its edge, and corner -> its edge's two slots."""
    nv, ne, nf = topology.n_vertices, topology.n_edges, topology.n_faces
    # Storage slots 0..nv-1 are the diagonal (the vertex pattern is diagonal-first ELL). int32 throughout:
    # every index here is below nv + 2 ne + 3 nf.
    off_source = source[nv:].astype(np.int32)
    edge = off_source - np.int32(nv)
    np.subtract(edge, np.int32(ne), out=edge, where=edge >= ne)  # high -> low entries; padding (2 ne) lands on ne, the padding row
    edge_corners = np.full((ne + 1, topology.edge_faces.shape[1]), 3 * nf, dtype=np.int32)
    np.copyto(edge_corners[:ne], 3 * topology.edge_faces + topology.edge_face_corners, where=topology.edge_faces >= 0)
    slot_corners = np.take(edge_corners, edge, axis=0)
    slot_of_source = np.empty(nv + 2 * ne + 1, dtype=np.int32)
    slot_of_source[off_source] = np.arange(off_source.size, dtype=np.int32)
    corner_edges = topology.face_edges.reshape(-1)
    corner_slots = np.empty((corner_edges.size, 2), dtype=np.int32)
    corner_slots[:, 0] = np.take(slot_of_source[nv : nv + ne], corner_edges)
    corner_slots[:, 1] = np.take(slot_of_source[nv + ne : nv + 2 * ne], corner_edges)
    return slot_corners, corner_slots


def _as_float_array(vertices) -> Float[Array, "nv 3"]:
    array = jnp.asarray(vertices)
    if not jnp.issubdtype(array.dtype, jnp.floating):
        array = array.astype(jnp.result_type(float))
    return array
