"""The level set of the indicator as a triangle mesh (marching cubes), its vertices as JAX functions of the indicator,
and the sample density at them.

Extraction: scikit-image's marching cubes (Lewiner et al. 2003, topologically consistent, so a closed
level set gives a closed manifold mesh) runs on the host. Each of its vertices lies on a grid edge
between nodes `a` and `b` where the indicator crosses the level `c`,

    x = (1 - t) x_a + t x_b,   t = (c - chi_a) / (chi_b - chi_a),

so for the extracted topology (the edges crossed, the triangles) the vertices are a differentiable
function of the indicator: `level_set_vertices` recomputes them in JAX from `(a, b)`, and gradients
reach the points and normals through `poisson_indicator`.

Density (Open3D's `densities`, to trim surface the samples do not support): at each vertex, the
number of samples per grid cell volume around it, a Gaussian kernel density estimate of
standard deviation `2 h` read at the vertex (`sum_i G(x - p_i) h^3`).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from .._compile import kernel
from .._errors import DDGInputError
from ._grid import ReconstructionGrid
from ._indicator import Indicator, cell_corners, interpolate, smoothed_spectrum, splat

#: The density estimate's standard deviation, in grid spacings.
DENSITY_SMOOTHING = 2.0


def extract_level_set(values: np.ndarray, level: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`(vertices in grid coordinates (nv, 3), faces (nf, 3), edge nodes (nv, 2) flat indices)` of the level set.

    Faces are oriented with their normals towards decreasing values (outward: the indicator is high inside).
    Vertices no face uses (left by degenerate triangles) are dropped.
    """
    from skimage.measure import marching_cubes

    n = values.shape[0]
    if not (values.min() < level < values.max()):
        raise DDGInputError(
            f"the indicator ({values.min():.3g} to {values.max():.3g}) never crosses its level {level:.3g}: the points' "
            "normals do not describe the boundary of a solid (check that they are not all zero or cancelling)"
        )
    # scikit-image's float32 path takes a writable buffer, and a JAX array's host view is read-only.
    values = np.require(values, requirements=["C", "W"])
    vertices, faces, _, _ = marching_cubes(values, level=level, allow_degenerate=False)
    if faces.shape[0] == 0:
        raise DDGInputError("the indicator's level set has no triangle at this depth: raise the depth")
    used = np.zeros(vertices.shape[0], bool)
    used[faces.ravel()] = True
    index = np.cumsum(used) - 1
    # scikit-image orients its faces towards increasing values (inward here): reversed, they face outward.
    vertices, faces = vertices[used].astype(np.float64), index[faces[:, ::-1]].astype(np.int32)
    return vertices, faces, edge_nodes(vertices, n)


def edge_nodes(coordinates: np.ndarray, n: int) -> np.ndarray:
    """`(nv, 2)` the flat indices of the grid nodes `a`, `b = a + e_axis` whose edge each vertex lies on.

    The axis is the one along which the vertex's grid coordinate is not an integer (a vertex on a
    node, `t = 0`, takes axis 0: its position then depends on `a` alone).
    """
    nearest = np.rint(coordinates)
    offset = np.abs(coordinates - nearest)
    axis = np.argmax(offset, axis=1)
    rows = np.arange(coordinates.shape[0])
    low = nearest.astype(np.int64)
    low[rows, axis] = np.floor(coordinates[rows, axis]).astype(np.int64)
    high = low.copy()
    high[rows, axis] += 1
    low, high = low % n, high % n

    def flat(nodes):
        return (nodes[:, 0] * n + nodes[:, 1]) * n + nodes[:, 2]

    return np.stack([flat(low), flat(high)], axis=1).astype(np.int32)


def level_set_vertices(indicator: Indicator, grid: ReconstructionGrid, vertex_edges: Int[Array, "nv 2"]) -> Float[Array, "nv 3"]:
    """The level-set vertices on the grid edges `vertex_edges` for `indicator`: `(1 - t) x_a + t x_b` (module docstring).

    Differentiable in `indicator` (so, through `poisson_indicator`, in the points and normals) for the
    fixed extraction topology of a `PoissonReconstruction` (`reconstruction.vertex_edges`).

    Args:
        indicator: an `Indicator` on `grid` (`poisson_indicator(points, normals, grid=grid)`).
        grid: the `ReconstructionGrid` it lives on.
        vertex_edges: `(nv, 2)` flat node indices `(a N + b) N + c` of the two ends of each vertex's grid edge.

    Returns:
        `(nv, 3)` vertex positions.

    Examples:
        >>> import jax
        >>> jax.config.update("jax_enable_x64", True)
        >>> from ddgjax.mesh import icosphere
        >>> from ddgjax.reconstruct import level_set_vertices, poisson_indicator, poisson_reconstruction
        >>> sphere = icosphere(4)
        >>> points, normals = sphere.vertices, sphere.vertices
        >>> reconstruction = poisson_reconstruction(points, normals, depth=5)
        >>> indicator = poisson_indicator(points, normals, grid=reconstruction.grid)
        >>> moved = level_set_vertices(indicator, reconstruction.grid, reconstruction.vertex_edges)
        >>> bool(jax.numpy.allclose(moved, reconstruction.value.vertices, atol=1e-4))  # the solves stop at their rtol
        True
    """
    return _vertices(indicator.values, indicator.iso_value, grid.origin, grid.spacing, jnp.asarray(vertex_edges))


@kernel
def _vertices(values, iso_value, origin, spacing, vertex_edges):
    n = values.shape[0]
    flat = values.reshape(-1)
    low, high = flat[vertex_edges[:, 0]], flat[vertex_edges[:, 1]]
    difference = high - low
    t = jnp.clip((iso_value - low) / jnp.where(difference == 0, 1.0, difference), 0.0, 1.0)
    a = jnp.stack(jnp.unravel_index(vertex_edges[:, 0], (n, n, n)), axis=1).astype(values.dtype)
    b = jnp.stack(jnp.unravel_index(vertex_edges[:, 1], (n, n, n)), axis=1).astype(values.dtype)
    # The edge's far end may have wrapped round the periodic grid; the vertex lies beyond `a` along the edge.
    step = jnp.where(b == a, 0.0, 1.0)
    return origin + spacing * (a + t[:, None] * step)


@kernel(static_argnames=("depth",))
def _densities(points, mask, vertices, origin, spacing, *, depth):
    n = 1 << depth
    flat, weights = cell_corners(points, origin, spacing, n)
    counts = splat(flat, weights, mask[:, None], n)[..., 0]
    density = jnp.fft.irfftn(smoothed_spectrum(counts, spacing, DENSITY_SMOOTHING), s=(n, n, n))
    at_flat, at_weights = cell_corners(vertices, origin, spacing, n)
    return interpolate(at_flat, at_weights, density)


def vertex_densities(padded_points, mask, vertices, grid: ReconstructionGrid) -> Float[Array, " nv"]:
    """`(nv,)` the sample density at each vertex (module docstring), from the padded points and their mask."""
    return _densities(padded_points, mask, vertices, grid.origin, grid.spacing, depth=grid.depth)
