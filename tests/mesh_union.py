"""Test helper: join meshes into one disjoint union, so that per-element quantities of many meshes
come from ONE compiled call (compiling, not running, dominates the mesh tests' time)."""

from __future__ import annotations

import dataclasses

import numpy as np

from ddgjax.mesh import Mesh


@dataclasses.dataclass(frozen=True)
class Union:
    mesh: Mesh
    vertex_offsets: np.ndarray
    face_offsets: np.ndarray
    edge_owner: np.ndarray

    def vertices_of(self, part: int) -> slice:
        return slice(int(self.vertex_offsets[part]), int(self.vertex_offsets[part + 1]))

    def faces_of(self, part: int) -> slice:
        return slice(int(self.face_offsets[part]), int(self.face_offsets[part + 1]))

    def edges_of(self, part: int) -> np.ndarray:
        return np.flatnonzero(self.edge_owner == part)


def disjoint_union(parts: list[tuple[np.ndarray, np.ndarray]]) -> Union:
    """One mesh made of the `(vertices, faces)` parts, in order (part k's vertices and faces are
    contiguous; its edges are those whose lower vertex lies in its vertex range)."""
    vertex_offsets = np.concatenate([[0], np.cumsum([np.shape(v)[0] for v, _ in parts])])
    face_offsets = np.concatenate([[0], np.cumsum([np.shape(f)[0] for _, f in parts])])
    mesh = Mesh.from_arrays(
        np.concatenate([np.asarray(v, dtype=np.float64) for v, _ in parts]),
        np.concatenate([np.asarray(f) + o for (_, f), o in zip(parts, vertex_offsets[:-1])]),
    )
    edge_owner = np.searchsorted(vertex_offsets, mesh.topology.edges[:, 0], side="right") - 1
    return Union(mesh, vertex_offsets, face_offsets, edge_owner)
