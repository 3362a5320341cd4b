"""Tet meshes the volume tests share (a module beside the tests, as mesh_union.py)."""

from __future__ import annotations

import numpy as np
import scipy.spatial

from ddgjax import volume


def jittered_grid_tets(n: int = 5, jitter: float = 0.05, seed: int = 0) -> volume.TetMesh:
    """Delaunay tets of a jittered `n^3` grid in [-1, 1]^3 (few slivers: libigl's formulas stay accurate on it)."""
    rng = np.random.default_rng(seed)
    axis = np.linspace(-1.0, 1.0, n)
    points = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), axis=-1).reshape(-1, 3)
    points = points + jitter * rng.uniform(-1, 1, size=points.shape)
    return volume.TetMesh.from_arrays(points, scipy.spatial.Delaunay(points).simplices)
