"""`MeshBatch`: triangle meshes of different sizes padded to bucketed shapes, one pytree of `(B, ...)` arrays.

A learning pipeline feeds many meshes of different sizes through one program. XLA compiles one
program per array shape, so the batch pads every mesh's vertices to `nvp = bucket(max nv)` and its
faces to `nfp = bucket(max nf)` (`ddgjax.batch.bucket`), and every array of the batch, the per-mesh
counts and the index plan of the batched operators included, has the batch axis first. Two batches
in one bucket then have the same tree structure, shapes and dtypes: one compiled program serves
both, and `jax.jit`, `jax.vmap` and sharding along axis 0 (`ddgjax.sharding.shard_batch`) apply
as to any pytree of arrays. PyTorch3D's `Meshes` keeps the same padded and packed views (it pads to
the exact maximum size); jraph's `pad_with_graphs` rounds up as here.

Padding: padded vertices sit at the origin and belong to no face; padded faces read their corners
from an out-of-range index (a gather of zeros), so they are degenerate at the origin and every
operator gives them exactly zero, with finite values and gradients (`ddgjax.batch._operators`).

The index plan is built on the host from the faces alone (DESIGN.md, two phases), with widths that
are constants and overflow parts whose lengths are functions of `(nvp, nfp)`, so the shapes of a
batch depend on its bucket only, never on its meshes' local structure (valence, degree,
non-manifold edges), as the single-mesh Laplacian's ELL-plus-tail pattern (`ddgjax.sparse`) does
for one mesh. `vertex_corners` lists the corners `3 f + k` at each vertex, eight per row, with
overflow rows for high-valence vertices, and `corner_rows` is its transpose, so both the corner ->
row sum and the row -> corner gather are `ddgjax.sparse.gather_sum` calls whose derivatives are
fixed gathers; the overflow rows fold into their vertices with one sorted `segment_sum` of `R` rows
(`overflow_vertices`). The Laplacian's directed-edge slots (`vertex_neighbors`: six per vertex,
slot-major ELL; `overflow_edges`: the rest, sorted by tail; `slot_corners` / `corner_slots`: at most
two corners per slot) come from each mesh's edges, as `ddgjax.laplacian`'s storage plan does for one mesh.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from .._compile import device_array
from .._domain import Domain
from .._errors import DDGInputError, check_count, check_float_array, is_traced
from ..mesh import Mesh
from ._bucket import bucket

#: Widths of the per-vertex tables, constants so that a batch's shapes depend on its padded sizes only:
#: eight corners per row of `vertex_corners` (a vertex of higher valence continues in overflow
#: rows) and six directed edges per vertex in `vertex_neighbors` (the rest in `overflow_edges`), so
#: regular meshes (valence 6) need no overflow. The overflow lengths cover the meshes measured
#: (the shared kitten, spot, armadillo, nefertiti, fertility, beetle, camelhead, bunny, teddy; convex
#: hulls of random points on a sphere, 100 to 5,000): at most 7.1 % of their vertices need an overflow
#: row of corners (`nvp // 8` rows are kept) and at most 0.51 nv directed edges overflow (the random
#: hulls; armadillo 0.47 nv; `3 nfp // 8`, about `0.75 nvp`, are kept: `nfp // 4` gave 5 of 60
#: batches of random hulls a bucket of their own).
CORNERS_PER_ROW = 8
NEIGHBORS_PER_VERTEX = 6
#: The fewest overflow rows / directed edges kept, so small meshes with a high-valence vertex fit.
_MIN_OVERFLOW = 16


class PackedMeshes(NamedTuple):
    """The packed view of a batch (PyTorch3D's `verts_packed`, `faces_packed`, `verts_packed_to_mesh_idx`, ...).

    Attributes:
        vertices: `(sum nv, 3)` the meshes' vertices, one after the other.
        faces: `(sum nf, 3)` their faces, indices into the packed `vertices`.
        vertex_meshes: `(sum nv,)` the mesh of each packed vertex.
        face_meshes: `(sum nf,)` the mesh of each packed face.
    """

    vertices: Float[np.ndarray, "n 3"]
    faces: Int[np.ndarray, "m 3"]
    vertex_meshes: Int[np.ndarray, " n"]
    face_meshes: Int[np.ndarray, " m"]


class MeshBatch(Domain):
    r"""`B` triangle meshes of different sizes, padded to bucketed sizes (module docstring).

    Make one with `MeshBatch.from_meshes(meshes)`; differentiate with
    `jax.grad(lambda V: loss(batch.with_vertices(V)))(batch.vertices)`. Every field is an array with
    the batch axis first (no static data), so batches of one bucket share one compiled program.

    Mesh $b$ holds $n_v^{(b)} \le n_{vp}$ vertices and $n_f^{(b)} \le n_{fp}$ faces; the rest is padding.

    Attributes:
        vertices: `(B, nvp, 3)` positions; mesh `b`'s in rows `[0, n_vertices[b])`, zeros after.
        faces: `(B, nfp, 3)` int32 vertex indices; padding faces are `(0, 0, 0)` (and masked).
        vertex_mask: `(B, nvp)` True on a mesh's own vertices.
        face_mask: `(B, nfp)` True on a mesh's own faces.
        n_vertices: `(B,)` int32 vertex count of each mesh (arrays, not static ints: the tree structure
            stays the same across a bucket).
        n_faces: `(B,)` int32 face count of each mesh.
        vertex_corners: `(B, nvp + R, 8)` int32 the corners `3 f + k` at each vertex, eight per row
            (`CORNERS_PER_ROW`), padded with `3 nfp`: row `i < nvp` holds vertex `i`'s first eight, a
            vertex of higher valence continues in overflow rows `nvp + r` (`R = max(16, nvp // 8)`,
            or the bucket of what a batch needs where it needs more: rare, a new program).
        corner_rows: `(B, nfp, 3)` int32 its transpose: the row of `vertex_corners` that lists each
            corner, `nvp + R` on padding faces.
        overflow_vertices: `(B, R)` int32 the vertex of each overflow row (increasing), `nvp` pads.
        vertex_neighbors: `(B, 6, nvp)` int32 the first six directed edges `i -> j` leaving each
            vertex (`NEIGHBORS_PER_VERTEX`), slot-major ELL: slot `s nvp + i` holds head `j` at
            `[s, i]`, `nvp` pads.
        overflow_edges: `(B, K, 2)` int32 the directed edges beyond six per vertex as `(tail, head)`
            sorted by tail, slot `6 nvp + k` (`K = max(16, 3 nfp // 8)`, or the bucket of a batch's
            need), `nvp` pads. A non-manifold edge with `n` faces has `ceil(n / 2)` parallel
            directed edges each way, so every slot has at most two corners.
        slot_corners: `(B, 6 nvp + K, 2)` int32 the corners opposite the edge of each slot, padded
            with `3 nfp`.
        corner_slots: `(B, 3 nfp, 2)` int32 its transpose: the two slots (`i -> j`, `j -> i`) holding
            each corner, `6 nvp + K` on padding faces.

    Every width is a constant and `R`, `K` are functions of `(nvp, nfp)`, so batches of one bucket
    share shapes (and one compiled program) whatever their meshes' valences, degrees and
    non-manifold edges.

    Examples:
        >>> import ddgjax
        >>> batch = ddgjax.batch.MeshBatch.from_meshes([ddgjax.mesh.icosphere(1), ddgjax.mesh.icosphere(2)])
        >>> batch.batch_size, batch.vertices.shape, batch.n_vertices.tolist()
        (2, (2, 192, 3), [42, 162])
        >>> [round(float(area), 2) for area in ddgjax.batch.face_areas(batch).sum(axis=1)]
        [11.67, 12.33]
    """

    vertices: Float[Array, "B nvp 3"]
    faces: Int[Array, "B nfp 3"]
    vertex_mask: Bool[Array, "B nvp"]
    face_mask: Bool[Array, "B nfp"]
    n_vertices: Int[Array, " B"]
    n_faces: Int[Array, " B"]
    vertex_corners: Int[Array, "B n_rows 8"]
    corner_rows: Int[Array, "B nfp 3"]
    overflow_vertices: Int[Array, "B R"]
    vertex_neighbors: Int[Array, "B 6 nvp"]
    overflow_edges: Int[Array, "B K 2"]
    slot_corners: Int[Array, "B n_slots 2"]
    corner_slots: Int[Array, "B n_corners 2"]

    parameter_name = "batch"

    @classmethod
    def how_to_build(cls, value: object) -> str:
        """How to make a `MeshBatch` from what was given (`Domain.require`'s hint)."""
        single = "; for a single mesh use the function of the same name in ddgjax.mesh / ddgjax.laplacian"
        return "build one with MeshBatch.from_meshes([mesh, ...])" + (single if isinstance(value, Mesh) else "")

    # `meshes` is annotated loosely on purpose: a wrong element gets this method's `DDGInputError` naming
    # its index rather than a run-time type-checker's message.
    @classmethod
    def from_meshes(cls, meshes: Sequence, *, n_vertices: int | None = None, n_faces: int | None = None) -> "MeshBatch":
        """Pad `meshes` (a non-empty sequence of `ddgjax.Mesh`, or `(vertices, faces)` pairs) into one batch.

        Args:
            meshes: the meshes, in batch order; a `(vertices, faces)` pair is built with `Mesh.from_arrays`.
            n_vertices: the padded vertex count `nvp` (default `bucket(max nv)`); at least the largest `nv`.
            n_faces: the padded face count `nfp` (default `bucket(max nf)`); at least the largest `nf`.

        Returns:
            `MeshBatch`, its vertices in the meshes' common floating dtype.

        Raises `DDGInputError` for an empty sequence, an element that is not a mesh, or a padded size
        smaller than a mesh. PyTorch3D: `Meshes(verts=list, faces=list)` (padded to the exact maximum).
        """
        items = _as_meshes(meshes)
        largest_nv = max(mesh.n_vertices for mesh in items)
        largest_nf = max(mesh.n_faces for mesh in items)
        nvp = bucket(largest_nv) if n_vertices is None else check_count("n_vertices", n_vertices)
        nfp = bucket(largest_nf) if n_faces is None else check_count("n_faces", n_faces)
        if nvp < largest_nv:
            raise DDGInputError(f"n_vertices: expected at least {largest_nv} (the largest mesh's vertex count), got {nvp}")
        if nfp < largest_nf:
            raise DDGInputError(f"n_faces: expected at least {largest_nf} (the largest mesh's face count), got {nfp}")
        dtype = jnp.result_type(*(mesh.vertices.dtype for mesh in items))
        size = len(items)
        vertices = np.zeros((size, nvp, 3), dtype)
        faces = np.zeros((size, nfp, 3), np.int32)
        counts = np.array([[mesh.n_vertices, mesh.n_faces] for mesh in items], np.int32)
        host_faces = [np.asarray(mesh.faces) for mesh in items]
        for b, mesh in enumerate(items):
            vertices[b, : mesh.n_vertices] = np.asarray(mesh.vertices)
            faces[b, : mesh.n_faces] = host_faces[b]
        vertex_mask = np.arange(nvp)[None, :] < counts[:, :1]
        face_mask = np.arange(nfp)[None, :] < counts[:, 1:]
        vertex_corners, corner_rows, overflow_vertices = _corner_rows(host_faces, nvp, nfp)
        vertex_neighbors, overflow_edges, slot_corners, corner_slots = _edge_slots(items, nvp, nfp)
        arrays = jax.device_put(
            {
                "vertices": vertices,
                "faces": faces,
                "vertex_mask": vertex_mask,
                "face_mask": face_mask,
                "n_vertices": counts[:, 0],
                "n_faces": counts[:, 1],
                "vertex_corners": vertex_corners,
                "corner_rows": corner_rows,
                "overflow_vertices": overflow_vertices,
                "vertex_neighbors": vertex_neighbors,
                "overflow_edges": overflow_edges,
                "slot_corners": slot_corners,
                "corner_slots": corner_slots,
            }
        )
        return cls(**arrays)

    @property
    def batch_size(self) -> int:
        """Number of meshes `B`."""
        return self.vertices.shape[0]

    @property
    def n_padded_vertices(self) -> int:
        """The padded vertex count `nvp` (a static int: the array shape)."""
        return self.vertices.shape[1]

    @property
    def n_padded_faces(self) -> int:
        """The padded face count `nfp` (a static int: the array shape)."""
        return self.faces.shape[1]

    # `vertices` is annotated unshaped on purpose: a bad shape gets this method's own `DDGInputError`.
    def with_vertices(self, vertices: ArrayLike) -> "MeshBatch":
        """The same batch with new padded positions `(B, nvp, 3)` (as `Mesh.with_vertices`; jit, grad, vmap).

        Values in padded rows are never read by an operator (their gradient is 0).
        """
        expected = self.vertices.shape
        if np.shape(vertices) != expected:
            raise DDGInputError(f"vertices: expected shape {expected} (the batch's padded positions), got {np.shape(vertices)}")
        if not is_traced(vertices):
            check_float_array("vertices", np.asarray(vertices).reshape(-1, 3), (3,))
        array = device_array(vertices)
        if not jnp.issubdtype(array.dtype, jnp.floating):
            array = array.astype(self.vertices.dtype)
        return eqx.tree_at(lambda batch: batch.vertices, self, array)

    def packed(self) -> PackedMeshes:
        """The packed view (`PackedMeshes`): every mesh's vertices and faces concatenated, faces globally indexed (host)."""
        nv, nf = self._counts()
        vertices, faces = np.asarray(self.vertices), np.asarray(self.faces)
        offsets = np.concatenate([[0], np.cumsum(nv)[:-1]])
        return PackedMeshes(
            vertices=np.concatenate([vertices[b, : nv[b]] for b in range(nv.size)]),
            faces=np.concatenate([faces[b, : nf[b]] + offsets[b] for b in range(nv.size)]),
            vertex_meshes=np.repeat(np.arange(nv.size), nv),
            face_meshes=np.repeat(np.arange(nv.size), nf),
        )

    def meshes(self) -> list[Mesh]:
        """The meshes of the batch, each rebuilt with `Mesh.from_arrays` from its unpadded rows (host)."""
        nv, nf = self._counts()
        vertices, faces = np.asarray(self.vertices), np.asarray(self.faces)
        return [Mesh.from_arrays(vertices[b, : nv[b]], faces[b, : nf[b]]) for b in range(nv.size)]

    def unpad(self, values: ArrayLike, *, at: str = "vertices") -> list[np.ndarray]:
        """`unpad(self, values, at=at)`."""
        return unpad(self, values, at=at)

    def _counts(self) -> tuple[np.ndarray, np.ndarray]:
        if is_traced(self.n_vertices) or is_traced(self.n_faces):
            raise DDGInputError("batch: unpadding reads the per-mesh counts on the host; call it outside jit")
        return np.asarray(self.n_vertices), np.asarray(self.n_faces)


def require_batch(name: str, value) -> MeshBatch:
    """`value` if it is a `MeshBatch`, else `DDGInputError` naming the argument and saying how to make one.

    Args:
        name: the argument's name, for the error message.
        value: the object to check.

    Returns:
        `value` itself, when it is a `MeshBatch`.

    Raises:
        DDGInputError: `value` is not a `MeshBatch`.
    """
    return MeshBatch.require(name, value)


def pad_vertex_values(values: Sequence, *, n_vertices: int | None = None) -> Float[Array, "B nvp *rest"]:
    """Stack per-mesh vertex values `(nv_i, *rest)` into one `(B, nvp, *rest)` array, zeros in the padded rows.

    Args:
        values: a non-empty sequence of arrays with one trailing shape `rest` and one dtype kind.
        n_vertices: the padded count `nvp` (default `bucket(max nv_i)`, what `MeshBatch.from_meshes`
            pads to; pass `batch.n_padded_vertices` to match a batch made with another size).

    Returns:
        `(B, nvp, *rest)`. PyTorch3D: `list_to_padded`.

    Raises `DDGInputError` for an empty sequence, a 0-d array, mismatched trailing shapes or a
    `nvp` smaller than an array.
    """
    if isinstance(values, (np.ndarray, jax.Array)) or not isinstance(values, Sequence) or len(values) == 0:
        raise DDGInputError(f"values: expected a non-empty list of (nv_i, ...) arrays, got {type(values).__name__}")
    hosts = [np.asarray(value) for value in values]
    if any(host.ndim == 0 for host in hosts):
        raise DDGInputError("values: expected arrays of shape (nv_i, ...), got a 0-d value")
    rest = hosts[0].shape[1:]
    mismatched = [i for i, host in enumerate(hosts) if host.shape[1:] != rest]
    if mismatched:
        raise DDGInputError(
            f"values: expected one trailing shape {rest} for every array, got {hosts[mismatched[0]].shape} at index {mismatched[0]}"
        )
    largest = max(host.shape[0] for host in hosts)
    nvp = bucket(largest) if n_vertices is None else check_count("n_vertices", n_vertices)
    if nvp < largest:
        raise DDGInputError(f"n_vertices: expected at least {largest} (the longest array), got {nvp}")
    padded = np.zeros((len(hosts), nvp, *rest), np.result_type(*hosts))
    for b, host in enumerate(hosts):
        padded[b, : host.shape[0]] = host
    return device_array(padded)


def unpad(batch: object, values: ArrayLike, *, at: str = "vertices") -> list[np.ndarray]:
    """Split padded per-vertex (or per-face) values `(B, nvp, ...)` into the list of each mesh's `(nv_b, ...)` (host).

    Args:
        batch: the `MeshBatch` the values belong to.
        values: `(B, nvp, ...)` for `at="vertices"` (default), `(B, nfp, ...)` for `at="faces"`.
        at: `"vertices"` or `"faces"` (keyword-only; the `at=` of `ddgjax.dec.sharp` and `ddgjax.fluids`).

    Returns:
        A list of `B` NumPy arrays. PyTorch3D: `padded_to_list(x, split_size=num_verts_per_mesh())`.
    """
    batch = require_batch("batch", batch)
    if at not in ("vertices", "faces"):
        raise DDGInputError(f"at: expected one of 'vertices', 'faces', got {at!r}")
    nv, nf = batch._counts()
    counts, padded = (nv, batch.n_padded_vertices) if at == "vertices" else (nf, batch.n_padded_faces)
    if is_traced(values):
        raise DDGInputError("values: unpad returns host arrays; call it outside jit")
    host = np.asarray(values)
    if host.ndim < 2 or host.shape[:2] != (batch.batch_size, padded):
        raise DDGInputError(f"values: expected shape ({batch.batch_size}, {padded}, ...) per {at[:-1]}, got {host.shape}")
    return [host[b, : counts[b]] for b in range(counts.size)]


def _as_meshes(meshes) -> list[Mesh]:
    if isinstance(meshes, Mesh) or not isinstance(meshes, Sequence) or isinstance(meshes, str):
        raise DDGInputError(f"meshes: expected a non-empty sequence of ddgjax Meshes, got {type(meshes).__name__}")
    if len(meshes) == 0:
        raise DDGInputError("meshes: expected a non-empty sequence of ddgjax Meshes, got an empty one")
    items = []
    for i, mesh in enumerate(meshes):
        if isinstance(mesh, tuple) and len(mesh) == 2:
            mesh = Mesh.from_arrays(*mesh)
        if not isinstance(mesh, Mesh):
            raise DDGInputError(
                f"meshes[{i}]: expected a ddgjax Mesh or a (vertices, faces) pair, got {type(mesh).__name__}; "
                "build one with ddgjax.Mesh.from_arrays(vertices, faces)"
            )
        if mesh.topology is None:
            raise DDGInputError(f"meshes[{i}]: expected a mesh with its topology (made by Mesh.from_arrays), got one without")
        if is_traced(mesh.vertices):
            raise DDGInputError(f"meshes[{i}]: MeshBatch.from_meshes pads on the host; inside jit use batch.with_vertices(V)")
        items.append(mesh)
    return items


def _ell_places(owners: np.ndarray, n_owners: int, width: int, overflow_width: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where each entry goes in an ELL table of `width` columns per owner plus overflow rows of `overflow_width`.

    Entries are listed per owner in their given order (one stable sort): owner `i`'s first `width`
    go to row `i`, the rest to overflow rows `n_owners + r`, `overflow_width` per row, the rows of
    one owner consecutive and the owners in increasing order (so the overflow rows' owners are sorted).

    Returns:
        `(row, column, overflow_owners)`: per entry its row and column, and the owner of each overflow row.
    """
    order = np.argsort(owners, kind="stable")
    counts = np.bincount(owners, minlength=n_owners)
    starts = np.cumsum(counts) - counts
    position = np.empty(owners.size, np.int64)
    position[order] = np.arange(owners.size) - starts[owners[order]]
    extra = -(-np.maximum(counts - width, 0) // overflow_width)
    extra_starts = np.cumsum(extra) - extra
    beyond = position - width
    row = np.where(beyond < 0, owners, n_owners + extra_starts[owners] + beyond // overflow_width)
    column = np.where(beyond < 0, position, beyond % overflow_width)
    return row, column, np.repeat(np.arange(n_owners), extra)


def _overflow_size(needed: int, default: int) -> int:
    """`default` (a function of the padded sizes) unless a batch needs more; then the bucket of the need (a rare new program)."""
    return default if needed <= default else bucket(needed)


def _corner_rows(faces: list[np.ndarray], nvp: int, nfp: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`(vertex_corners, corner_rows, overflow_vertices)` of `MeshBatch` (one stable sort per mesh)."""
    places = [_ell_places(host.reshape(-1).astype(np.int64), nvp, CORNERS_PER_ROW, CORNERS_PER_ROW) for host in faces]
    n_rows = nvp + _overflow_size(max(owners.size for _, _, owners in places), max(_MIN_OVERFLOW, nvp // 8))
    table = np.full((len(faces), n_rows, CORNERS_PER_ROW), 3 * nfp, np.int32)
    corner_rows = np.full((len(faces), 3 * nfp), n_rows, np.int32)
    overflow_vertices = np.full((len(faces), n_rows - nvp), nvp, np.int32)
    for b, (row, column, owners) in enumerate(places):
        table[b, row, column] = np.arange(row.size)
        corner_rows[b, : row.size] = row
        overflow_vertices[b, : owners.size] = owners
    return table, corner_rows.reshape(len(faces), nfp, 3), overflow_vertices


def _edge_slots(meshes: list[Mesh], nvp: int, nfp: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """`(vertex_neighbors, overflow_edges, slot_corners, corner_slots)` of `MeshBatch` from each mesh's edges.

    An edge with `k` faces gets `ceil(k / 2)` directed-edge entries each way, each holding (up to) two
    of its opposite corners: one on a manifold edge, parallel entries with the same head on a
    non-manifold one (their weights add up in `L u`). Entries are placed per tail vertex by `_ell_places`.
    """
    built = []
    for mesh in meshes:
        topology = mesh.topology
        edges = np.asarray(topology.edges, np.int64)
        corners = np.where(topology.edge_faces >= 0, 3 * topology.edge_faces.astype(np.int64) + topology.edge_face_corners, -1)
        counts = np.sum(corners >= 0, axis=1)
        chunks = (counts + 1) // 2
        entry_edge = np.repeat(np.arange(edges.shape[0]), chunks)
        entry_first = 2 * (np.arange(entry_edge.size) - np.repeat(np.cumsum(chunks) - chunks, chunks))
        padded = np.concatenate([corners, np.full((corners.shape[0], 2), -1)], axis=1)
        entry_corners = np.stack([padded[entry_edge, entry_first], padded[entry_edge, entry_first + 1]], axis=1)
        tails = np.concatenate([edges[entry_edge, 0], edges[entry_edge, 1]])
        heads = np.concatenate([edges[entry_edge, 1], edges[entry_edge, 0]])
        built.append((tails, heads, entry_corners, _ell_places(tails, nvp, NEIGHBORS_PER_VERTEX, 1)))
    n_overflow = _overflow_size(max(place[2].size for *_, place in built), max(_MIN_OVERFLOW, 3 * nfp // 8))
    n_slots = NEIGHBORS_PER_VERTEX * nvp + n_overflow
    neighbors = np.full((len(meshes), NEIGHBORS_PER_VERTEX * nvp), nvp, np.int32)
    overflow_edges = np.full((len(meshes), n_overflow, 2), nvp, np.int32)
    slot_corners = np.full((len(meshes), n_slots, 2), 3 * nfp, np.int32)
    corner_slots = np.full((len(meshes), 3 * nfp, 2), n_slots, np.int32)
    for b, (tails, heads, entry_corners, (row, column, _)) in enumerate(built):
        in_ell = row < nvp
        slots = np.where(in_ell, column * nvp + row, NEIGHBORS_PER_VERTEX * nvp + row - nvp)
        neighbors[b, slots[in_ell]] = heads[in_ell]
        overflow_edges[b, row[~in_ell] - nvp] = np.stack([tails[~in_ell], heads[~in_ell]], axis=1)
        both = np.concatenate([entry_corners, entry_corners])
        slot_corners[b, slots] = np.where(both >= 0, both, 3 * nfp)
        # Each corner sits in one entry: its two directed slots (tail -> head, head -> tail).
        n_entries = entry_corners.shape[0]
        entry_slots = np.stack([slots[:n_entries], slots[n_entries:]], axis=1)
        valid = entry_corners >= 0
        corner_slots[b, entry_corners[valid]] = entry_slots[np.nonzero(valid)[0]]
    return neighbors.reshape(len(meshes), NEIGHBORS_PER_VERTEX, nvp), overflow_edges, slot_corners, corner_slots
