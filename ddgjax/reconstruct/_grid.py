"""The regular grid a Poisson reconstruction solves on, the checks of its input, and the memory it needs.

The grid has `N = 2^depth` nodes per axis, node `j = (j_x, j_y, j_z)` at `origin + spacing * j`, and is
periodic (the spectral solve's domain is the torus of side `N * spacing`). It is a cube of side
`scale` times the largest extent of the points' bounding box, centred on that box (Open3D's and
PoissonRecon's `scale=1.1`), so the points keep at least `(scale - 1) / 2` of the extent from its
faces and the indicator's periodic images do not meet them.
"""

from __future__ import annotations

import os

import equinox as eqx
import jax
import numpy as np
from jaxtyping import Array, Float

from .._errors import DDGInputError, check_count, check_finite, check_float_shape, first_indices, is_traced

#: The fewest points a reconstruction takes: fewer cannot describe a surface (and PCA normals need neighbours).
MIN_POINTS = 10

#: Grid-sized arrays held at once by a reconstruction at its peak: the splatted normals (3), their transforms (3
#: half-size complex ones, as much as 3 real), the indicator, the conjugate-gradient vectors of the screened solve
#: (5) and its V-cycle's (a half-size set), and the indicator's host copy. Measured from the peak resident memory
#: (11.1 at depth 8); the gradient holds about twice this.
GRID_ARRAYS = 12

#: The relative thickness below which a cloud counts as flat (its smallest principal extent over its largest).
FLAT_TOLERANCE = 1e-6


class ReconstructionGrid(eqx.Module):
    """The periodic grid of a reconstruction: `2^depth` nodes per axis, node `j` at `origin + spacing * j`.

    Attributes:
        origin: `(3,)` the position of node `(0, 0, 0)`.
        spacing: `()` the distance between neighbouring nodes.
        depth: the grid has `2^depth` nodes per axis (static).
    """

    origin: Float[Array, "3"]
    spacing: Float[Array, ""]
    depth: int = eqx.field(static=True)

    @property
    def resolution(self) -> int:
        """`N = 2^depth`, the nodes per axis."""
        return 1 << self.depth

    def node_positions(self, nodes) -> Float[Array, "... 3"]:
        """The positions of `(..., 3)` integer node indices (or fractional grid coordinates)."""
        return self.origin + self.spacing * nodes


def reconstruction_grid(points, *, depth: int = 8, scale: float = 1.1) -> ReconstructionGrid:
    """The grid `poisson_reconstruction` solves on for `points` (module docstring), after the memory check.

    Args:
        points: `(n, 3)` concrete finite positions.
        depth: `2^depth` grid nodes per axis (keyword-only; default 8, Open3D's).
        scale: the grid's side over the largest extent of the points' bounding box (keyword-only;
            default 1.1, Open3D's); at least 1.05 so that the periodic images stay apart.

    Returns:
        A `ReconstructionGrid` in the points' dtype.

    Raises:
        DDGInputError: a depth outside `[2, 12]`, a scale below 1.05, or a grid whose arrays would not fit in the
            memory available now (the message gives the bytes it needs).
    """
    depth = check_count("depth", depth, minimum=2)
    if depth > 12:
        raise DDGInputError(f"depth: expected at most 12 (a grid of 4096^3 nodes), got {depth}")
    scale = float(scale)
    if not scale >= 1.05:
        raise DDGInputError(f"scale: expected a number >= 1.05 (the grid's side over the points' extent), got {scale!r}")
    if is_traced(points):
        raise DDGInputError("points: the grid is placed on the host from the points' bounding box; pass concrete points")
    host = np.asarray(points, dtype=np.float64)
    check_memory(depth, np.dtype(getattr(points, "dtype", np.float64)))
    low, high = host.min(axis=0), host.max(axis=0)
    extent = float(np.max(high - low))
    n = 1 << depth
    spacing = scale * extent / n
    # Centred on the box: node coordinates of the centre are (N - 1) / 2, the middle of the nodes.
    origin = 0.5 * (low + high) - spacing * (n - 1) / 2
    dtype = jax.dtypes.canonicalize_dtype(getattr(points, "dtype", np.float64))
    return ReconstructionGrid(jax.device_put(origin.astype(dtype)), jax.device_put(np.asarray(spacing, dtype)), depth)


def grid_bytes(depth: int, dtype) -> int:
    """The bytes the forward solve's grid arrays take at their peak (`GRID_ARRAYS` arrays of `(2^depth)^3` values)."""
    return GRID_ARRAYS * (1 << (3 * depth)) * np.dtype(dtype).itemsize


def available_memory() -> int | None:
    """The bytes of memory available now (Linux's `MemAvailable`, else free physical pages), or `None` if unknown."""
    try:
        with open("/proc/meminfo") as info:
            for line in info:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def check_memory(depth: int, dtype) -> None:
    """Refuse a depth whose grid would not fit in the memory available now, with the bytes it would need."""
    needed = grid_bytes(depth, dtype)
    available = available_memory()
    if available is not None and needed > available:
        n = 1 << depth
        raise DDGInputError(
            f"depth: a grid of {n}^3 nodes needs about {needed / 2**30:.3g} GiB ({needed} bytes: {GRID_ARRAYS} arrays of "
            f"{n}^3 {np.dtype(dtype).name} values) but {available / 2**30:.3g} GiB are available; lower the depth "
            f"(each step down divides it by 8)"
        )


def check_oriented_points(points, normals) -> tuple[np.ndarray, np.ndarray | None]:
    """Host float64 copies of `points` `(n, 3)` and `normals` `(n, 3)` or `None`, refusing what cannot be reconstructed.

    Refused: a shape other than `(n, 3)`, fewer than `MIN_POINTS` points, NaN / inf, normals of zero
    length, and points all on one plane or line (they bound no volume, and the Poisson problem has no
    inside to find).
    """
    check_float_shape("points", points, (3,), min_rows=MIN_POINTS)
    if is_traced(points) or is_traced(normals):
        raise DDGInputError(
            "points, normals: poisson_reconstruction places its grid and extracts its mesh on the host and needs "
            "concrete arrays; differentiate poisson_indicator (with the reconstruction's grid) instead"
        )
    host = np.asarray(points, dtype=np.float64)
    check_finite("points", host)
    host_normals = None
    if normals is not None:
        check_float_shape("normals", normals, (3,))
        host_normals = np.asarray(normals, dtype=np.float64)
        if host_normals.shape[0] != host.shape[0]:
            raise DDGInputError(f"normals: expected one per point, shape ({host.shape[0]}, 3), got {host_normals.shape}")
        check_finite("normals", host_normals)
        lengths = np.linalg.norm(host_normals, axis=1)
        zero = ~(lengths > 1e-12 * max(float(lengths.max()), 1e-300))
        if zero.any():
            raise DDGInputError(
                f"normals: expected nonzero normals, got ones of zero length at rows {first_indices(zero)}; drop those "
                "points or estimate the normals (estimate_normals(points), or normals=None)"
            )
    centred = host - host.mean(axis=0)
    extents = np.linalg.svd(centred, compute_uv=False)
    if not extents[-1] > FLAT_TOLERANCE * extents[0]:
        raise DDGInputError(
            f"points: all {host.shape[0]} points lie on one plane (thickness {extents[-1] / max(extents[0], 1e-300):.2g} "
            "of their extent): they bound no volume, so there is no inside for the indicator to find"
        )
    return host, host_normals
