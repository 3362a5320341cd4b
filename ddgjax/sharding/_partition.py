"""The vertices of one large mesh split across devices: a host-side partition with explicit halos.

`partition_vertices(mesh, n_devices=...)` reorders the vertices for locality (reverse Cuthill-McKee on
the vertex adjacency, so that neighbours get nearby numbers), pads their count to a multiple of
the device count, and gives device `d` the contiguous block of `n_local` vertices
`[d n_local, (d + 1) n_local)` of that order. Everything a device needs to compute its rows of the
cotan Laplacian lives on it, in its own local numbering:

- its *local faces*: every face with at least one vertex it owns (faces on a block boundary are on
  both devices; their cotangents are computed twice, which costs less than exchanging them);
- its *halo*: the vertices of its local faces that other devices own, received once per product
  with one `jax.lax.all_to_all` (`send_index`: which of its own vertices each device sends to
  each other device; a block of `n_halo` slots per pair, padded);
- the directed edges of its rows in ELL form (`neighbours`, `width` per row) and the corner ->
  edge-slot incidence (`slot_corners` / `corner_slots`, for `ddgjax.sparse.gather_sum`) that puts
  each face's cotangents on them, and the corner -> vertex incidence for the lumped mass.

Local vertex numbering on device `d`: `[0, n_local)` its own vertices, then `n_local + e n_halo + t`
the `t`-th vertex received from device `e`. Every array is stored with the devices stacked along its
leading axis and sharded `P("vertices")`, so `jax.shard_map` hands each device its own block.
Built once per connectivity with NumPy (DESIGN.md, two phases); nothing here runs under `jit`.

Why not let XLA partition the existing `laplacian_apply` (`jax.jit` with the vertex arrays
sharded)? Measured on an icosphere(6) with 8 host devices: XLA's SPMD partitioner cannot see the
locality of the face -> vertex gathers, so it all-reduces the corner positions of *every* face to
every device, computes all faces everywhere and all-gathers `u`: per-device memory and work stay
those of the whole mesh (figures: benchmarks/README.md, sharding). The explicit halo keeps both
proportional to the local block.

Reference: E. Cuthill, J. McKee, "Reducing the bandwidth of sparse symmetric matrices" (1969);
SciPy `scipy.sparse.csgraph.reverse_cuthill_mckee`; JAX documentation, "Manual parallelism with
shard_map" (`jax.shard_map`, `jax.lax.all_to_all`).
"""

from __future__ import annotations

from collections.abc import Sequence

import equinox as eqx
import jax
import numpy as np
import scipy.sparse as sp
from jax.sharding import NamedSharding
from jax.sharding import PartitionSpec as P
from jaxtyping import Array, ArrayLike, Float, Int
from scipy.sparse.csgraph import reverse_cuthill_mckee

from .._errors import DDGInputError, check_choice
from ..mesh import Mesh, require_mesh
from ._devices import device_mesh

VERTICES = "vertices"
"""The name of the device-mesh axis the vertices of a partitioned mesh are split along."""

ORDERS = ("rcm", "none")


class LocalPlan(eqx.Module):
    """Device-side index arrays of a `VertexPartition` (module docstring), each `(n_devices * rows, ...)`, sharded `P("vertices")`.

    Attributes:
        faces: `(n_devices * f_local, 3)` local faces in local numbering; padding faces are `(0, 0, 0)`
            (zero area: they contribute nothing).
        send_index: `(n_devices * n_devices * n_halo,)` own vertices sent to each device, block by block.
        neighbours: `(n_devices * n_local, width)` local column of each directed edge of a row; padding
            repeats the row (a zero difference).
        slot_corners, corner_slots: the corner -> edge-slot incidence and its transpose
            (`gather_sum`); flat corners `3 f + k`, slots `row * width + position`.
        vertex_corners, corner_vertices: the corner -> own-vertex incidence and its transpose.
        padding: `(n_devices * n_local,)` 1.0 on the padding vertices, 0.0 on the mesh's.
    """

    faces: Int[Array, "fl 3"]
    send_index: Int[Array, " sends"]
    neighbours: Int[Array, "nl width"]
    slot_corners: Int[Array, "slots m"]
    corner_slots: Int[Array, "corners 2"]
    vertex_corners: Int[Array, "nl valence"]
    corner_vertices: Int[Array, "corners 1"]
    padding: Float[Array, " nl"]


class VertexPartition:
    """The vertices of one mesh split across the devices of a one-axis device mesh (module docstring).

    Made by `partition_vertices`. Arrays in *partitioned layout* are `(n_padded, ...)` with
    `n_padded = n_devices * n_local`: the vertices in locality order, padded, sharded
    `P("vertices")`. `shard(u)` and `unshard(x)` move per-vertex values between the mesh's order and
    that layout.

    Attributes:
        sharding: `NamedSharding(device_mesh, P("vertices"))`.
        order: `(nv,)` NumPy, the mesh's vertex at each position of the locality order.
        n_vertices, n_local, n_halo, width: sizes (vertices of the mesh, per device, halo slots per
            pair of devices, ELL width).
        plan: the `LocalPlan` (device arrays).
        vertices: `(n_padded, 3)` the mesh's positions in partitioned layout (padding at the origin).
    """

    def __init__(
        self, sharding: NamedSharding, order: np.ndarray, n_vertices: int, n_local: int, n_halo: int, plan: LocalPlan, vertices
    ):
        self.sharding, self.order, self.n_vertices = sharding, order, n_vertices
        self.n_local, self.n_halo, self.width = n_local, n_halo, plan.neighbours.shape[1]
        self.plan, self.vertices = plan, vertices

    @property
    def n_devices(self) -> int:
        return self.sharding.mesh.size

    @property
    def n_padded(self) -> int:
        return self.n_devices * self.n_local

    def __repr__(self) -> str:
        return (
            f"VertexPartition(n_vertices={self.n_vertices}, n_devices={self.n_devices}, n_local={self.n_local}, "
            f"n_halo={self.n_halo}, width={self.width})"
        )

    def shard(self, values: Float[ArrayLike, "nv *k"]) -> Float[Array, "n_padded *k"]:
        """Per-vertex `values` in the mesh's order -> partitioned layout (reordered, zero-padded, sharded)."""
        values = np.asarray(values)
        if values.ndim == 0 or values.shape[0] != self.n_vertices:
            raise DDGInputError(f"values: expected shape ({self.n_vertices}, ...), got {values.shape}")
        padded = np.zeros((self.n_padded,) + values.shape[1:], values.dtype)
        padded[: self.n_vertices] = values[self.order]
        return jax.device_put(padded, self.sharding)

    def unshard(self, values: Float[ArrayLike, "n_padded *k"]) -> np.ndarray:
        """Partitioned layout -> the mesh's vertex order (a NumPy array on the host; padding dropped)."""
        values = np.asarray(values)
        if values.ndim == 0 or values.shape[0] != self.n_padded:
            raise DDGInputError(f"values: expected shape ({self.n_padded}, ...), got {values.shape}")
        result = np.empty((self.n_vertices,) + values.shape[1:], values.dtype)
        result[self.order] = values[: self.n_vertices]
        return result


def locality_order(mesh: Mesh, *, ordering: str = "rcm") -> np.ndarray:
    """`(nv,)` a vertex order that keeps neighbours close: reverse Cuthill-McKee of the vertex adjacency (`"rcm"`) or the identity (`"none"`).

    Contiguous blocks of this order are what `partition_vertices` gives each device; a small
    bandwidth means small halos. Host-side, once per connectivity. SciPy:
    `scipy.sparse.csgraph.reverse_cuthill_mckee(adjacency, symmetric_mode=True)`.

    Args:
        mesh: the mesh (its edges are read on the host).
        ordering: `"rcm"` (default, reverse Cuthill-McKee) or `"none"` (the mesh's own order) (keyword-only).

    Returns:
        `(nv,)` integer NumPy array, a permutation of the vertex indices: position `p` holds the old index.
    """
    mesh = require_mesh("mesh", mesh)
    check_choice("ordering", ordering, ORDERS)
    n = mesh.n_vertices
    if ordering == "none":
        return np.arange(n)
    edges = np.asarray(mesh.edges)
    adjacency = sp.coo_matrix((np.ones(len(edges), np.int8), (edges[:, 0], edges[:, 1])), shape=(n, n)).tocsr()
    return np.asarray(reverse_cuthill_mckee((adjacency + adjacency.T).tocsr(), symmetric_mode=True))


def partition_vertices(
    mesh: Mesh, *, n_devices: int | None = None, devices: Sequence[jax.Device] | None = None, ordering: str = "rcm"
) -> VertexPartition:
    """Split `mesh`'s vertices into contiguous blocks of a locality order, one per device, with halos (module docstring).

    Args:
        mesh: any triangle mesh (with its topology: made outside `jit`).
        n_devices: how many devices (default: all of `jax.devices()`, every host's after
            `jax.distributed.initialize()`).
        devices: the devices to use instead of `jax.devices()`.
        ordering: `"rcm"` (default, reverse Cuthill-McKee) or `"none"` (the mesh's own order).

    Returns:
        A `VertexPartition`; `sharded_laplacian_apply` and `sharded_cg` run on it.
    """
    mesh = require_mesh("mesh", mesh)
    if mesh.topology is None:
        raise DDGInputError("mesh: partition_vertices needs the mesh's topology; call it outside jit")
    sharding = NamedSharding(device_mesh(VERTICES, n_devices=n_devices, devices=devices), P(VERTICES))
    n_dev, n = sharding.mesh.size, mesh.n_vertices
    permutation = locality_order(mesh, ordering=ordering)
    n_local = -(-n // n_dev)
    rank = np.empty(n, np.int64)
    rank[permutation] = np.arange(n)
    faces, edges = rank[np.asarray(mesh.faces)], rank[np.asarray(mesh.edges)]
    directed = np.concatenate([edges, edges[:, ::-1]])
    directed = directed[np.lexsort((directed[:, 1], directed[:, 0]))]
    width = max(1, int(np.bincount(directed[:, 0], minlength=n).max(initial=0)))
    blocks = [_device_block(d, n_dev, n_local, faces, directed) for d in range(n_dev)]
    n_halo = max(1, max(len(needed) for block in blocks for needed in block["needed"]))
    sends = np.zeros((n_dev, n_dev, n_halo), np.int32)
    for d, block in enumerate(blocks):
        for e, needed in enumerate(block["needed"]):
            sends[e, d, : len(needed)] = needed - e * n_local
    plan = _stack([_local_arrays(block, d, n_local, n_halo, width) for d, block in enumerate(blocks)], n_local, width)
    padding = np.zeros(n_dev * n_local)
    padding[n:] = 1.0
    vertices = np.zeros((n_dev * n_local, 3), np.asarray(mesh.vertices).dtype)
    vertices[:n] = np.asarray(mesh.vertices)[permutation]
    arrays = jax.device_put(
        {"send_index": sends.reshape(-1), "padding": padding, "vertices": vertices, **plan},
        sharding,
    )
    vertices = arrays.pop("vertices")
    return VertexPartition(sharding, permutation, n, n_local, n_halo, LocalPlan(**arrays), vertices)


def _device_block(d: int, n_dev: int, n_local: int, faces: np.ndarray, directed: np.ndarray) -> dict:
    """Device `d`'s local faces and directed edges (global ids in locality order) and the halo it needs from each device."""
    owners = faces // n_local
    local_faces = faces[np.any(owners == d, axis=1)]
    halo = np.unique(local_faces[local_faces // n_local != d])
    halo_owner = halo // n_local
    needed = [halo[halo_owner == e] for e in range(n_dev)]
    rows = directed[:, 0] // n_local == d
    return {"faces": local_faces, "edges": directed[rows], "needed": needed}


def _local_arrays(block: dict, d: int, n_local: int, n_halo: int, width: int) -> dict:
    """Device `d`'s faces, ELL neighbours and incidence pairs in local numbering (`_stack` pads them to common sizes)."""
    first = d * n_local
    local = np.full(len(block["needed"]) * n_local, -1, np.int64)  # global id (locality order) -> local id
    local[first : first + n_local] = np.arange(n_local)
    for e, needed in enumerate(block["needed"]):
        local[needed] = n_local + e * n_halo + np.arange(len(needed))
    faces = local[block["faces"]]
    # Directed edges (row, column) sorted by row: the position within its row is the ELL column.
    rows, columns = block["edges"][:, 0] - first, local[block["edges"][:, 1]]
    positions = np.arange(len(rows)) - np.searchsorted(rows, rows)
    neighbours = np.tile(np.arange(n_local)[:, None], (1, width))
    neighbours[rows, positions] = columns
    n_columns = n_local + len(block["needed"]) * n_halo
    keys = rows * n_columns + columns
    key_order = np.argsort(keys)
    slot_pairs, vertex_pairs = [], []
    corner = 3 * np.arange(len(faces))
    for k in range(3):
        a, b, own = faces[:, (k + 1) % 3], faces[:, (k + 2) % 3], faces[:, k]
        # A corner's value belongs to the edge opposite it, in each direction whose row is this device's.
        for row, column in ((a, b), (b, a)):
            mine = row < n_local
            found = key_order[np.searchsorted(keys, row[mine] * n_columns + column[mine], sorter=key_order)]
            slot_pairs.append(np.stack([rows[found] * width + positions[found], corner[mine] + k], axis=1))
        mine = own < n_local
        vertex_pairs.append(np.stack([own[mine], corner[mine] + k], axis=1))
    return {
        "faces": faces,
        "neighbours": neighbours,
        "slots": np.concatenate(slot_pairs),
        "vertices": np.concatenate(vertex_pairs),
    }


def _stack(locals_: list[dict], n_local: int, width: int) -> dict:
    """The per-device arrays padded to common sizes (padding indices point past the end: they read 0) and stacked."""
    f_local = max(1, max(len(item["faces"]) for item in locals_))
    m = max(_multiplicity(item["slots"][:, 0]) for item in locals_)
    valence = max(_multiplicity(item["vertices"][:, 0]) for item in locals_)
    n_corners, n_slots = 3 * f_local, n_local * width
    arrays = {name: [] for name in ("faces", "neighbours", "slot_corners", "corner_slots", "vertex_corners", "corner_vertices")}
    for item in locals_:
        faces = np.zeros((f_local, 3), np.int32)
        faces[: len(item["faces"])] = item["faces"]
        slots, vertices = item["slots"], item["vertices"]
        arrays["faces"].append(faces)
        arrays["neighbours"].append(item["neighbours"].astype(np.int32))
        arrays["slot_corners"].append(_table(slots[:, 0], slots[:, 1], n_slots, m, n_corners))
        arrays["corner_slots"].append(_table(slots[:, 1], slots[:, 0], n_corners, 2, n_slots))
        arrays["vertex_corners"].append(_table(vertices[:, 0], vertices[:, 1], n_local, valence, n_corners))
        arrays["corner_vertices"].append(_table(vertices[:, 1], vertices[:, 0], n_corners, 1, n_local))
    return {name: np.concatenate(parts) for name, parts in arrays.items()}


def _multiplicity(keys: np.ndarray) -> int:
    return max(1, int(np.bincount(keys).max(initial=0)) if len(keys) else 0)


def _table(keys: np.ndarray, values: np.ndarray, n: int, width: int, fill: int) -> np.ndarray:
    """`(n, width)` int32: row `i` lists the `values` paired with key `i` (ascending), then `fill`."""
    order = np.lexsort((values, keys))
    keys, values = keys[order], values[order]
    table = np.full((n, width), fill, np.int32)
    table[keys, np.arange(len(keys)) - np.searchsorted(keys, keys)] = values
    return table
