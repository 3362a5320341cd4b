"""Built-in closed polygons (regular, flower, star, random, the Figure 3 polygon) and a file loader.

Every shape is built with NumPy in float64 on the host, deterministically, and wrapped in a
`Curve` whose points have the float dtype `dtype=` (default: JAX's default float, float32 unless the
caller enabled x64; the library never changes `jax.config`), as the `ddgjax.mesh` shapes do. Options
after the vertex count are keyword-only. All built-in shapes are simple and
traversed counterclockwise (positive signed area, turning number +1), the orientation for which
the turning angles are positive (DESIGN.md, Plane curves).
"""

from __future__ import annotations

import os

import jax.numpy as jnp
import numpy as np

from .._errors import DDGInputError, check_count, check_float_array, check_positive
from ._curve import Curve

__all__ = ["figure3_polygon", "flower", "load_polygon", "random_polygon", "regular_polygon", "star"]


def _closed(points: np.ndarray, dtype) -> Curve:
    """A closed `Curve` through the float64 `points`, in `dtype` (default: JAX's default float)."""
    return Curve(jnp.asarray(points, dtype=jnp.result_type(float) if dtype is None else dtype), closed=True)


def _radial(angles: np.ndarray, radii: np.ndarray, center=(0.0, 0.0), dtype=None) -> Curve:
    """The closed polygon with vertices `center + radii * (cos, sin)(angles)`.

    With increasing angles spanning less than one turn and gaps below pi, each edge stays in its
    own angular sector around `center`, so the polygon is simple, star-shaped and counterclockwise.
    """
    c = np.asarray(center, dtype=np.float64).reshape(2)
    return _closed(c + radii[:, None] * np.stack([np.cos(angles), np.sin(angles)], axis=1), dtype)


def regular_polygon(n: int, *, radius: float = 1.0, center: tuple[float, float] = (0.0, 0.0), dtype=None) -> Curve:
    """Regular `n`-gon inscribed in the circle of `radius` about `center`, counterclockwise.

    Vertex `k` is `center + radius * (cos(2 pi k / n), sin(2 pi k / n))`. Every turning angle is
    `2 pi / n`, so `kappa_A = 2 pi / n`, `kappa_B = 2 sin(pi / n)`, `kappa_C = 2 tan(pi / n)` and
    `kappa_D = 1 / radius` exactly: the closed-form test case for the four curvatures.

    Args:
        n: number of vertices, at least 3.
        radius: circumradius, > 0.
        center: the circle's centre `(x, y)`.
        dtype: float dtype of the points (default: JAX's default float).

    Returns:
        A closed `Curve` with points of shape `(n, 2)`.

    Equivalent: `gpytoolbox.regular_circle_polyline(n + 1)[0][:-1]` for the unit circle (gpytoolbox
    repeats the first vertex at the end).
    """
    n = check_count("n", n, 3)
    radius = check_positive("radius", radius)
    angles = 2 * np.pi * np.arange(n) / n
    return _radial(angles, np.full(n, radius), center, dtype)


def flower(n: int = 128, *, petals: int = 5, amplitude: float = 0.3, radius: float = 1.0, dtype=None) -> Curve:
    """Flower-shaped polygon: the polar curve `r(phi) = radius (1 + amplitude cos(petals phi))`.

    Sampled at `n` equally spaced angles. Simple for `0 <= amplitude < 1` (star-shaped about the
    origin); non-convex once `amplitude` exceeds `1 / (1 + petals^2)`.

    Args:
        n: number of vertices, at least 3.
        petals: number of lobes, at least 1.
        amplitude: relative depth of the lobes, in `[0, 1)`.
        radius: mean radius, > 0.
        dtype: float dtype of the points (default: JAX's default float).

    Returns:
        A closed counterclockwise `Curve` with points of shape `(n, 2)`.
    """
    n = check_count("n", n, 3)
    petals = check_count("petals", petals, 1)
    radius = check_positive("radius", radius)
    if not 0 <= amplitude < 1:
        raise DDGInputError(f"amplitude: expected a number in [0, 1) so the flower stays simple, got {amplitude!r}")
    angles = 2 * np.pi * np.arange(n) / n
    return _radial(angles, radius * (1 + amplitude * np.cos(petals * angles)), dtype=dtype)


def star(tips: int = 5, *, inner_radius: float = 0.5, outer_radius: float = 1.0, subdivisions: int = 8, dtype=None) -> Curve:
    """Star polygon with `tips` points, each edge split into `subdivisions` equal segments.

    The corners alternate between `outer_radius` (at angles `2 pi k / tips`) and `inner_radius`
    (halfway between); subdividing the straight edges gives the flows vertices to move without
    changing the shape. `tips * 2 * subdivisions` vertices in all.

    Args:
        tips: number of star points, at least 2.
        inner_radius: radius of the reflex corners, `0 < inner_radius < outer_radius`.
        outer_radius: radius of the tips, > 0.
        subdivisions: segments per straight edge, at least 1.
        dtype: float dtype of the points (default: JAX's default float).

    Returns:
        A closed counterclockwise `Curve` with points of shape `(2 * tips * subdivisions, 2)`.
    """
    tips = check_count("tips", tips, 2)
    subdivisions = check_count("subdivisions", subdivisions, 1)
    outer_radius = check_positive("outer_radius", outer_radius)
    inner_radius = check_positive("inner_radius", inner_radius)
    if inner_radius >= outer_radius:
        raise DDGInputError(f"inner_radius: expected < outer_radius = {outer_radius}, got {inner_radius}")
    angles = np.pi * np.arange(2 * tips) / tips
    radii = np.where(np.arange(2 * tips) % 2 == 0, outer_radius, inner_radius)
    corners = radii[:, None] * np.stack([np.cos(angles), np.sin(angles)], axis=1)
    t = np.arange(subdivisions)[None, :, None] / subdivisions
    points = (1 - t) * corners[:, None, :] + t * np.roll(corners, -1, axis=0)[:, None, :]
    return _closed(points.reshape(-1, 2), dtype)


def random_polygon(n: int, *, key: int = 0, amplitude: float = 0.4, modes: int = 6, jitter: float = 0.4, dtype=None) -> Curve:
    """Random simple, generally non-convex polygon: a random radial function sampled at jittered angles.

    `r(phi) = 1 + sum_{m=2}^{modes} (a_m cos(m phi) + b_m sin(m phi))` with Gaussian `a_m, b_m`
    decaying like `1/m`, rescaled so that `max |r - 1| = amplitude`; the angles are the uniform
    grid `2 pi k / n` shifted by up to `jitter` of a grid step, so the spacing is uneven too.
    Star-shaped about the origin with positive radii and angle gaps below pi, hence simple and
    counterclockwise. Deterministic for a given `key` (an integer seed of NumPy's `default_rng`: the polygon is made on the host).

    Args:
        n: number of vertices, at least 3.
        key: the integer seed (the vocabulary's `key=`; NumPy's `default_rng`).
        amplitude: largest relative radial perturbation, in `[0, 1)`.
        modes: highest Fourier mode of the perturbation, at least 2.
        jitter: largest angular shift of a vertex as a fraction of the grid step, in `[0, 0.5)`.
        dtype: float dtype of the points (default: JAX's default float).

    Returns:
        A closed counterclockwise `Curve` with points of shape `(n, 2)`.
    """
    n = check_count("n", n, 3)
    modes = check_count("modes", modes, 2)
    if not 0 <= amplitude < 1:
        raise DDGInputError(f"amplitude: expected a number in [0, 1) so the radii stay positive, got {amplitude!r}")
    if not 0 <= jitter < 0.5:
        raise DDGInputError(f"jitter: expected a number in [0, 0.5) so the angles stay sorted, got {jitter!r}")
    rng = np.random.default_rng(key)
    angles = 2 * np.pi * (np.arange(n) + jitter * rng.uniform(-1, 1, n)) / n
    m = np.arange(2, modes + 1)
    a, b = rng.standard_normal((2, m.size)) / m
    perturbation = np.cos(np.outer(angles, m)) @ a + np.sin(np.outer(angles, m)) @ b
    scale = np.max(np.abs(perturbation))
    return _radial(angles, 1 + amplitude * perturbation / np.where(scale > 0, scale, 1.0), dtype=dtype)


def figure3_polygon(*, dtype=None) -> Curve:
    """The non-convex polygon of the `ddgjax flow` demo, in the spirit of the reading report's Figure 3.

    A 64-vertex star-shaped polygon with two deep bays and unevenly spaced vertices (denser on the
    left), so that the discrete flows visibly disagree: the unequal spacing makes the
    `kappa_A` flow drift its vertex centroid while the `kappa_B` flow keeps it, and the bays make the
    path to a cyclic polygon under the `kappa_D` flow long enough to watch. Its polar radius is
    `r(phi) = 1 + 0.3 cos(2 phi) + 0.25 sin(3 phi) + 0.1 cos(5 phi)`, sampled at
    `phi_k = t_k + 0.35 sin(t_k)`, `t_k = 2 pi k / 64`.

    Args:
        dtype: float dtype of the points (default: JAX's default float).

    Returns:
        A closed counterclockwise `Curve` with points of shape `(64, 2)`.
    """
    t = 2 * np.pi * np.arange(64) / 64
    angles = t + 0.35 * np.sin(t)
    radii = 1 + 0.3 * np.cos(2 * angles) + 0.25 * np.sin(3 * angles) + 0.1 * np.cos(5 * angles)
    return _radial(angles, radii, dtype=dtype)


def load_polygon(path: str | os.PathLike) -> Curve:
    """Read a closed polygon from a `.npy` file of shape `(n, 2)` or a text file of `x,y` lines.

    Text files (`.csv`, `.txt`, anything not `.npy`) hold one point per line, separated by a comma
    or whitespace; a first line that is not numeric is taken as a header, and lines starting with
    `#` are comments. A last point equal to the first (a repeated closing point) is dropped. The
    orientation is kept as given.

    Args:
        path: file to read.

    Returns:
        A closed `Curve` with points of shape `(n, 2)`, `n >= 3`.

    Raises:
        DDGInputError: missing or unreadable file, wrong shape, non-numeric entries, NaN/inf,
            fewer than 3 distinct points.
    """
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise DDGInputError(f"path: expected an existing .npy or CSV file of (x, y) points, got {path!r}")
    if path.lower().endswith(".npy"):
        try:
            points = np.load(path, allow_pickle=False)
        except (ValueError, OSError) as error:
            raise DDGInputError(f"path: expected a .npy array of shape (n, 2), could not read {path!r}: {error}") from None
    else:
        points = _read_text_points(path)
    points = check_float_array(f"points in {path!r}", points, (2,), min_rows=1).astype(np.float64)
    if points.shape[0] > 1 and np.array_equal(points[0], points[-1]):
        points = points[:-1]
    if points.shape[0] < 3:
        raise DDGInputError(
            f"points in {path!r}: expected at least 3 distinct points for a closed polygon, got {points.shape[0]}"
        )
    return Curve(jnp.asarray(points), closed=True)


def _read_text_points(path: str) -> np.ndarray:
    """Rows of numbers from a comma- or whitespace-separated text file, skipping one header line."""
    try:
        with open(path, encoding="utf-8") as handle:
            lines = [line.split("#", 1)[0].strip() for line in handle]
    except (OSError, UnicodeDecodeError) as error:
        raise DDGInputError(f"path: expected a text file of x,y lines, could not read {path!r}: {error}") from None
    rows = [(number, line) for number, line in enumerate(lines, start=1) if line]
    parsed = []
    for position, (number, line) in enumerate(rows):
        fields = line.replace(",", " ").split()
        try:
            parsed.append([float(field) for field in fields])
        except ValueError:
            if position == 0:
                continue
            raise DDGInputError(f"{path!r} line {number}: expected two numbers 'x,y', got {line!r}") from None
        if len(fields) != 2:
            raise DDGInputError(f"{path!r} line {number}: expected two numbers 'x,y', got {len(fields)} fields: {line!r}")
    if not parsed:
        raise DDGInputError(f"path: expected at least 3 lines of x,y points, found none in {path!r}")
    return np.asarray(parsed, dtype=np.float64)
