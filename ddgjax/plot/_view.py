"""The camera both drawings share: `(azimuth, elevation)` views, the rotation they make, the up axis."""

from __future__ import annotations

from numbers import Real

import numpy as np

from ..mesh import Mesh

#: `(azimuth, elevation)` in degrees of `plot_mesh_function`'s default view of a non-flat mesh.
OBLIQUE_VIEW = (-60.0, 20.0)
#: The view from `+z` (x to the right, y up): the default for a mesh flat in z.
TOP_VIEW = (0.0, 90.0)
# Rotations that carry the named axis to +z (a proper rotation each, so orientation is kept).
UP_ROTATIONS = {
    "z": np.eye(3),
    "y": np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]]),
    "x": np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]]),
}


def view_rotation(azimuth: Real, elevation: Real) -> np.ndarray:
    """`(3, 3)` rotation of an orthographic camera: rows 0 and 2 are screen x and up, row 1 the depth.

    The camera turns by `azimuth` degrees about `z`, then looks down by `elevation` degrees; `(0, 90)`
    looks from `+z` with `x` to the right and `y` up, `(0, 0)` from `-y` with `z` up.

    Args:
        azimuth: the turn about `z`, in degrees.
        elevation: the angle the camera looks down, in degrees.

    Returns:
        `(3, 3)` float64 NumPy rotation matrix.
    """
    a, e = np.radians(azimuth), np.radians(elevation)
    about_z = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])
    about_x = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(e), -np.sin(e)], [0.0, np.sin(e), np.cos(e)]])
    return about_x @ about_z


def is_flat(mesh: Mesh) -> bool:
    """Whether every vertex of `mesh` lies in one plane `z = const` (to 1e-12 of its extent).

    Args:
        mesh: the mesh (concrete vertices: read on the host).

    Returns:
        A Python `bool`.
    """
    return points_are_flat(np.asarray(mesh.vertices))


def points_are_flat(points: np.ndarray) -> bool:
    """Whether the `(n, 3)` `points` lie in one plane `z = const` (to 1e-12 of their extent)."""
    extent = float(np.ptp(points, axis=0).max())
    return bool(np.ptp(points[:, 2]) <= 1e-12 * max(extent, np.finfo(float).tiny))
