"""Built-in triangle meshes: icosphere, UV sphere, torus, open cylinder, flat disk and grid.

Each is deterministic, manifold and consistently oriented; closed shapes have outward normals, flat
ones lie in the plane `z = 0` with normals `+z` (faces counterclockwise seen from above). Topology is
built with vectorised NumPy (no per-element Python loops, so a 1.3 M-face icosphere takes about a
second); vertices come back as a JAX array in JAX's default float dtype unless `dtype` is given. Counts are
integers (Python or NumPy) and sizes positive numbers; anything else raises `DDGInputError`. A shape's
resolution counts may be passed by position, its sizes and `dtype` by name only; every argument of
`torus` is keyword-only (libraries disagree on the order of its radii and counts).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from .._errors import DDGInputError, check_count, check_positive
from ._mesh import Mesh


def icosphere(subdivisions=3, *, radius=1.0, dtype=None) -> Mesh:
    r"""Geodesic sphere: an icosahedron, each face split into four `subdivisions` times.

    Every new vertex is the midpoint of an edge pushed onto the sphere $\lVert p \rVert = r$, $r$ = `radius` (centred at
    the origin), so all vertices lie on it. Returns a closed genus-0 `Mesh` with outward normals:
    vertices `(10 * 4**s + 2, 3)`, faces `(20 * 4**s, 3)`, `30 * 4**s` edges; every angle is
    between about 54 and 72 degrees (no obtuse faces). Area tends to $4\pi r^2$ at rate $O(h^2)$
    ($h \sim 2^{-s}$). `radius` and `dtype` (float dtype of the vertices, default JAX's default float)
    are keyword-only.
    Reference: J. R. Baumgardner, P. O. Frederickson, "Icosahedral discretization of the two-sphere"
    (SIAM J. Numer. Anal., 1985). Equivalents: `trimesh.creation.icosphere(s, radius)` (the same faces up to
    vertex numbering, positions within 1e-7), `gpytoolbox.icosphere(s)` (same counts, another
    base icosahedron).

    Args:
        subdivisions: how many times each face is split into four, `s >= 0` (default 3).
        radius: the sphere's radius, `> 0` (keyword-only).
        dtype: the float dtype of the vertices (keyword-only; default JAX's default float).

    Returns:
        `Mesh` with vertices `(10 * 4**s + 2, 3)` and faces `(20 * 4**s, 3)`.

    Examples:
        >>> import ddgjax
        >>> sphere = ddgjax.mesh.icosphere(2)
        >>> sphere.vertices.shape, sphere.faces.shape
        ((162, 3), (320, 3))
        >>> round(float(ddgjax.mesh.total_area(sphere)), 2)  # 4 pi = 12.566 in the limit
        12.33
    """
    check_count("subdivisions", subdivisions, 0)
    check_positive("radius", radius)
    phi = (1.0 + np.sqrt(5.0)) / 2.0
    vertices = np.array(
        [
            [-1, phi, 0],
            [1, phi, 0],
            [-1, -phi, 0],
            [1, -phi, 0],
            [0, -1, phi],
            [0, 1, phi],
            [0, -1, -phi],
            [0, 1, -phi],
            [phi, 0, -1],
            [phi, 0, 1],
            [-phi, 0, -1],
            [-phi, 0, 1],
        ],
        dtype=np.float64,
    )
    faces = np.array(
        [
            [0, 11, 5],
            [0, 5, 1],
            [0, 1, 7],
            [0, 7, 10],
            [0, 10, 11],
            [1, 5, 9],
            [5, 11, 4],
            [11, 10, 2],
            [10, 7, 6],
            [7, 1, 8],
            [3, 9, 4],
            [3, 4, 2],
            [3, 2, 6],
            [3, 6, 8],
            [3, 8, 9],
            [4, 9, 5],
            [2, 4, 11],
            [6, 2, 10],
            [8, 6, 7],
            [9, 8, 1],
        ],
        dtype=np.int64,
    )
    vertices /= np.linalg.norm(vertices, axis=1, keepdims=True)
    for _ in range(subdivisions):
        vertices, faces = _split_faces(vertices, faces)
    return _mesh(radius * vertices, faces, dtype)


def _split_faces(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One 1-to-4 midpoint subdivision with new vertices projected to the unit sphere."""
    nv = vertices.shape[0]
    # Edge opposite corner k joins corners k+1 and k+2; midpoints are numbered after the old vertices.
    a, b = faces[:, [1, 2, 0]], faces[:, [2, 0, 1]]
    keys = (np.minimum(a, b) * nv + np.maximum(a, b)).ravel()
    unique_keys, inverse = np.unique(keys, return_inverse=True)
    midpoints = vertices[unique_keys // nv] + vertices[unique_keys % nv]
    midpoints /= np.linalg.norm(midpoints, axis=1, keepdims=True)
    m = (nv + inverse).reshape(-1, 3)  # m[:, k]: midpoint of the edge opposite corner k
    c0, c1, c2 = faces[:, 0], faces[:, 1], faces[:, 2]
    new_faces = np.concatenate(
        [
            np.stack([c0, m[:, 2], m[:, 1]], axis=1),
            np.stack([c1, m[:, 0], m[:, 2]], axis=1),
            np.stack([c2, m[:, 1], m[:, 0]], axis=1),
            m,
        ]
    )
    return np.concatenate([vertices, midpoints]), new_faces


def uv_sphere(n_lat=16, n_lon=32, *, radius=1.0, dtype=None) -> Mesh:
    r"""Latitude-longitude sphere: two poles and `n_lat - 1` rings of `n_lon` vertices.

    Returns a closed genus-0 `Mesh` with outward normals: vertices `((n_lat - 1) n_lon + 2, 3)`,
    faces `(2 (n_lat - 1) n_lon, 3)` (fans at the poles, each band of quads split along one
    diagonal). Vertex 0 is the north pole `(0, 0, radius)`, the last the south pole; ring `k` (polar
    angle `pi k / n_lat`) holds vertices `1 + (k - 1) n_lon ...`. Faces near the poles are thin
    (angles `O(1 / n_lon)`). Area tends to $4\pi r^2$ ($r$ = `radius`) at rate $O(h^2)$.
    Equivalent: `trimesh.creation.uv_sphere(radius, count=...)`, a latitude-longitude sphere with
    its own counts convention, numbering and pole treatment.

    Args:
        n_lat: the number of latitude bands, `>= 2` (default 16): `n_lat - 1` rings between the poles.
        n_lon: the number of vertices per ring, `>= 3` (default 32).
        radius: the sphere's radius, `> 0` (keyword-only).
        dtype: the float dtype of the vertices (keyword-only; default JAX's default float).

    Returns:
        `Mesh` with vertices `((n_lat - 1) n_lon + 2, 3)` and faces `(2 (n_lat - 1) n_lon, 3)`.
    """
    check_count("n_lat", n_lat, 2)
    check_count("n_lon", n_lon, 3)
    check_positive("radius", radius)
    polar = np.pi * np.arange(1, n_lat) / n_lat
    azimuth = 2.0 * np.pi * np.arange(n_lon) / n_lon
    p, a = np.meshgrid(polar, azimuth, indexing="ij")
    ring_points = np.stack([np.sin(p) * np.cos(a), np.sin(p) * np.sin(a), np.cos(p)], axis=-1).reshape(-1, 3)
    south = 1 + ring_points.shape[0]
    vertices = np.concatenate([[[0.0, 0.0, 1.0]], ring_points, [[0.0, 0.0, -1.0]]])
    ring = 1 + np.arange(n_lat - 1)[:, None] * n_lon
    j, j1 = np.arange(n_lon), (np.arange(n_lon) + 1) % n_lon
    top = np.stack([np.zeros(n_lon, dtype=np.int64), 1 + j, 1 + j1], axis=1)
    bottom = np.stack([np.full(n_lon, south), ring[-1] + j1, ring[-1] + j], axis=1)
    upper, lower = ring[:-1], ring[1:]
    band = _quads_to_triangles(upper + j, lower + j, lower + j1, upper + j1)
    return _mesh(radius * vertices, np.concatenate([top, band, bottom]), dtype)


def torus(*, major_radius=1.0, minor_radius=0.25, n_major=48, n_minor=16, dtype=None) -> Mesh:
    """Torus of revolution about the z axis: a tube of radius `minor_radius` around a circle of radius `major_radius` in z = 0.

    With `R = major_radius` and `r = minor_radius`, vertex `(i, j)` (index `i * n_minor + j`) sits at
    `((R + r cos v) cos u, (R + r cos v) sin u, r sin v)` with `u = 2 pi i / n_major`,
    `v = 2 pi j / n_minor`; `n_major n_minor` vertices, twice as many faces: vertices
    `(n_major n_minor, 3)`, faces `(2 n_major n_minor, 3)`, closed, genus 1, outward normals. Area
    tends to `4 pi^2 R r` at rate `O(h^2)`. Exact curvatures (for tests): Gaussian
    `cos v / (r (R + r cos v))`, mean `(R + 2 r cos v) / (2 r (R + r cos v))`.
    (`../shared/meshes/torus.obj` is the same surface with the axis along y.) Equivalents:
    `gpytoolbox.torus(n_major, n_minor, R=R, r=r)`, `trimesh.creation.torus(R, r, n_major, n_minor)`
    (other vertex numberings).

    Args:
        major_radius: `R`, the radius of the tube's centre circle, `> 0` (keyword-only).
        minor_radius: `r`, the tube's radius, `0 < r < R` (keyword-only).
        n_major: the number of vertices around the z axis (`u`), `>= 3` (keyword-only).
        n_minor: the number of vertices around the tube (`v`), `>= 3` (keyword-only).
        dtype: the float dtype of the vertices (keyword-only; default JAX's default float).

    Returns:
        `Mesh` with vertices `(n_major n_minor, 3)` and faces `(2 n_major n_minor, 3)`.

    Raises:
        DDGInputError: a count or size out of range, or `minor_radius >= major_radius`.
    """
    check_count("n_major", n_major, 3)
    check_count("n_minor", n_minor, 3)
    check_positive("major_radius", major_radius)
    check_positive("minor_radius", minor_radius)
    if minor_radius >= major_radius:
        raise DDGInputError(
            f"minor_radius: expected a tube radius smaller than major_radius={major_radius} (a torus without "
            f"self-intersection), got {minor_radius}"
        )
    R, r = major_radius, minor_radius
    u = 2.0 * np.pi * np.arange(n_major) / n_major
    v = 2.0 * np.pi * np.arange(n_minor) / n_minor
    uu, vv = np.meshgrid(u, v, indexing="ij")
    rho = R + r * np.cos(vv)
    vertices = np.stack([rho * np.cos(uu), rho * np.sin(uu), r * np.sin(vv)], axis=-1).reshape(-1, 3)
    i, j = np.arange(n_major)[:, None], np.arange(n_minor)[None, :]
    i1, j1 = (i + 1) % n_major, (j + 1) % n_minor
    faces = _quads_to_triangles(i * n_minor + j, i1 * n_minor + j, i1 * n_minor + j1, i * n_minor + j1)
    return _mesh(vertices, faces, dtype)


def cylinder(n_around=32, n_along=8, *, radius=1.0, height=2.0, dtype=None) -> Mesh:
    """Open cylinder about the z axis, radius `radius`, over `z in [-height / 2, height / 2]`, without caps.

    Vertex `(i, j)` (index `i * n_around + j`) sits at `(radius cos u, radius sin u, -height / 2 + i height
    / n_along)` with `u = 2 pi j / n_around`: `(n_along + 1) n_around` vertices, `2 n_along n_around`
    faces, outward normals; two boundary loops, the rings `i = 0` (vertices `0 .. n_around - 1`) and
    `i = n_along` (the last `n_around`). Genus 0 with two holes: Euler characteristic 0. The start of a
    minimal surface between two rings (the catenoid). Equivalent: `trimesh.creation.cylinder` (capped).

    Args:
        n_around: the number of vertices per ring, `>= 3` (default 32).
        n_along: the number of bands between the `n_along + 1` rings, `>= 1` (default 8).
        radius: the cylinder's radius, `> 0` (keyword-only).
        height: its length along z, `> 0` (keyword-only).
        dtype: the float dtype of the vertices (keyword-only; default JAX's default float).

    Returns:
        `Mesh` with vertices `((n_along + 1) n_around, 3)` and faces `(2 n_along n_around, 3)`.
    """
    check_count("n_around", n_around, 3)
    check_count("n_along", n_along, 1)
    check_positive("radius", radius)
    check_positive("height", height)
    u = 2.0 * np.pi * np.arange(n_around) / n_around
    z = np.linspace(-height / 2, height / 2, n_along + 1)
    zz, uu = np.meshgrid(z, u, indexing="ij")
    vertices = np.stack([radius * np.cos(uu), radius * np.sin(uu), zz], axis=-1).reshape(-1, 3)
    i, j = np.arange(n_along)[:, None], np.arange(n_around)[None, :]
    j1 = (j + 1) % n_around
    faces = _quads_to_triangles(i * n_around + j, i * n_around + j1, (i + 1) * n_around + j1, (i + 1) * n_around + j)
    return _mesh(vertices, faces, dtype)


def disk(n_rings=8, *, radius=1.0, dtype=None) -> Mesh:
    r"""Flat disk in z = 0: a centre vertex and `n_rings` concentric rings, ring `k` with `6k` vertices.

    Ring `k` has radius `k radius / n_rings`; consecutive rings are zipped together by angle, giving nearly
    equilateral triangles (exactly the hexagonal lattice for `n_rings = 1`), faces counterclockwise
    seen from `+z`. Vertices `(3 n (n + 1) + 1, 3)` (vertex 0 the centre), faces `(6 n^2, 3)`, one
    boundary loop (the outer ring, counterclockwise). Area (of the inscribed polygon) tends to
    $\pi r^2$ ($r$ = `radius`) at rate $O(h^2)$, $h = r / n_\mathrm{rings}$. libigl / gpytoolbox
    build disks by triangulating a boundary polygon instead (`gpytoolbox.regular_circle_polyline` +
    `gpytoolbox.triangulate`), with other interior points.

    Args:
        n_rings: the number `n` of rings around the centre, `>= 1` (default 8).
        radius: the disk's radius, `> 0` (keyword-only).
        dtype: the float dtype of the vertices (keyword-only; default JAX's default float).

    Returns:
        `Mesh` with vertices `(3 n (n + 1) + 1, 3)` and faces `(6 n^2, 3)`.
    """
    check_count("n_rings", n_rings, 1)
    check_positive("radius", radius)
    counts = 6 * np.arange(n_rings + 1)
    counts[0] = 1
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    ring_of = np.repeat(np.arange(n_rings + 1), counts)
    slot = np.arange(counts.sum()) - starts[ring_of]
    angle = 2.0 * np.pi * slot / counts[ring_of]
    rho = radius * ring_of / n_rings
    vertices = np.stack([rho * np.cos(angle), rho * np.sin(angle), np.zeros_like(rho)], axis=1)
    rings = [(int(starts[k]), int(counts[k])) for k in range(n_rings + 1)]
    faces = np.concatenate([_zip_rings(*rings[k - 1], *rings[k]) for k in range(1, n_rings + 1)])
    return _mesh(vertices, faces, dtype)


def _zip_rings(inner_start: int, m_inner: int, outer_start: int, m_outer: int) -> np.ndarray:
    """Triangles between two concentric rings, sweeping once around by angle (counterclockwise)."""
    # Each event advances one ring by one vertex, i.e. emits the triangle on that ring's next edge;
    # sorting events by the angle of the edge's midpoint keeps triangles near-equilateral (outer first
    # on ties). The centre (one vertex) never advances.
    n_inner_events = m_inner if m_inner > 1 else 0
    angles = np.concatenate([(np.arange(m_outer) + 0.5) / m_outer, (np.arange(n_inner_events) + 0.5) / m_inner])
    is_outer = np.concatenate([np.ones(m_outer, dtype=bool), np.zeros(n_inner_events, dtype=bool)])
    order = np.lexsort((~is_outer, angles))
    is_outer = is_outer[order]
    outer_before = np.cumsum(is_outer) - is_outer
    inner_before = np.cumsum(~is_outer) - ~is_outer
    inner = inner_start + inner_before % m_inner
    outer = outer_start + outer_before % m_outer
    third = np.where(is_outer, outer_start + (outer_before + 1) % m_outer, inner_start + (inner_before + 1) % m_inner)
    return np.stack([inner, outer, third], axis=1)


def grid(nx=8, ny=8, *, size=1.0, dtype=None) -> Mesh:
    """Flat square `[-size/2, size/2]^2` in z = 0, split into `nx` by `ny` cells of two triangles each.

    Vertex `(i, j)` (index `j * (nx + 1) + i`) is at `(-size/2 + i size/nx, -size/2 + j size/ny, 0)`;
    every cell is cut along its diagonal from `(i, j)` to `(i+1, j+1)`, faces counterclockwise seen
    from `+z`. Vertices `((nx+1)(ny+1), 3)`, faces `(2 nx ny, 3)`, one boundary loop; right
    triangles, so the circumcentric cotan weight of every diagonal is 0. Area exactly `size^2`.
    Equivalents: `igl.triangulated_grid(nx + 1, ny + 1)` and `gpytoolbox.regular_square_mesh(nx + 1, ny + 1)`
    (on `[0, 1]^2` and `[-1, 1]^2`, 2-D vertices, possibly other diagonals).

    Args:
        nx: the number of cells along x, `>= 1` (default 8).
        ny: the number of cells along y, `>= 1` (default 8).
        size: the side length of the square, `> 0` (keyword-only).
        dtype: the float dtype of the vertices (keyword-only; default JAX's default float).

    Returns:
        `Mesh` with vertices `((nx + 1)(ny + 1), 3)` and faces `(2 nx ny, 3)`.
    """
    check_count("nx", nx, 1)
    check_count("ny", ny, 1)
    check_positive("size", size)
    x = size * (np.arange(nx + 1) / nx - 0.5)
    y = size * (np.arange(ny + 1) / ny - 0.5)
    xx, yy = np.meshgrid(x, y, indexing="xy")
    vertices = np.stack([xx, yy, np.zeros_like(xx)], axis=-1).reshape(-1, 3)
    i, j = np.arange(nx)[None, :], np.arange(ny)[:, None]
    corner = j * (nx + 1) + i
    faces = _quads_to_triangles(corner, corner + 1, corner + nx + 2, corner + nx + 1)
    return _mesh(vertices, faces, dtype)


def _quads_to_triangles(a, b, c, d) -> np.ndarray:
    """Counterclockwise quads `(a, b, c, d)` (broadcast arrays) as triangles `(a, b, c)` and `(a, c, d)`."""
    a, b, c, d = (np.ravel(x) for x in np.broadcast_arrays(a, b, c, d))
    return np.concatenate([np.stack([a, b, c], axis=1), np.stack([a, c, d], axis=1)])


def _mesh(vertices: np.ndarray, faces: np.ndarray, dtype) -> Mesh:
    mesh = Mesh.from_arrays(vertices, faces)
    return mesh if dtype is None else mesh.with_vertices(jnp.asarray(vertices, dtype=dtype))
