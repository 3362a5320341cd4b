"""The indicator function of oriented points by a spectral Poisson solve on a periodic grid (Shape As Points).

Oriented points `(p_i, n_i)` sample the gradient of the indicator `chi` of the solid they bound:
`grad chi = -n delta_S` (the outward normal, times a delta on the surface `S`). Spread onto the grid,

    V = sum_i n_i K(x - p_i)        (K: trilinear weights to the 8 nodes around p_i),

the indicator solves `Delta chi = -div V` (Kazhdan, Bolitho & Hoppe 2006), which on the periodic grid
is diagonal in Fourier space (Peng et al. 2021, Shape As Points):

    chi^(k) = G(k) i k . V^(k) / |k|^2,   chi^(0) = 0,   G(k) = exp(-sigma^2 |k|^2 / 2),

with `k` the angular wave vectors of the grid (`2 pi fftfreq(N, h)`), `G` a Gaussian of standard
deviation `sigma = smoothing * h` that smooths the sampled field (and damps the spectral
derivative's ringing). `chi` is then read at the points by the same trilinear weights, and scaled
to the indicator's units: 0 on the grid's outer faces (outside the shape), `1/2` on average at the
points, so the surface is its `1/2` level set and the solid is where it exceeds `1/2`

    indicator = (chi - chi_outside) / (2 (mean_i chi(p_i) - chi_outside)).

Screening (Kazhdan & Hoppe 2013) adds `w sum_i (indicator(p_i) - 1/2)^2` to the Dirichlet energy
`|grad chi - grad chi_0|^2` (`chi_0` the unscreened indicator), pulling the level set onto the points,
with `w = alpha E_0 / n` (`alpha = screening`, `E_0` the unscreened Dirichlet energy: `alpha` is
dimensionless). The correction `delta = chi - chi_0` solves the normal equations
`(L_h + w S^T S) delta = w S^T (1/2 - S chi_0)` (`L_h` the 7-point `-Delta`, `S` the trilinear evaluation
at the points), by conjugate gradients preconditioned by a multigrid V-cycle (`_multigrid`: the screening
makes the system too stiff near the points for a spectral preconditioner), differentiable by implicit differentiation
(`jax.lax.custom_linear_solve`). Measured (benchmarks/README.md): `alpha = 60` brings the Chamfer error
from 2-4x Open3D's to 0.6-0.85x; the finite-difference energy is softer than the spectral one at the grid
scale, and from `alpha = 100` on, outliers kept near a noisy surface raise bubbles of one node.

Everything is a JAX function of the points and normals (the trilinear weights are differentiable in
the positions; the cells they fall in are piecewise constant), compiled once per depth and padded
point count (`ddgjax.batch.bucket`: points of weight 0 fill the padding, so nearby counts share a
program).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._compile import device_array, kernel
from .._errors import DDGInputError, check_count, check_float_shape
from ..batch import bucket
from ._grid import ReconstructionGrid
from ._multigrid import grid_laplacian, screened_system

#: The corners of a grid cell, as offsets from its lowest node.
_OFFSETS = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)], dtype=np.int32)


class Indicator(NamedTuple):
    """The indicator function on a reconstruction's grid.

    Attributes:
        values: `(N, N, N)` its values at the nodes (`N = 2^depth`; entry `[a, b, c]` at node `(a, b, c)`),
            about 1 inside the solid and 0 outside.
        iso_value: `()` the mean of the indicator at the points (`1/2` by its scaling): the surface's level.
    """

    values: Float[Array, "N N N"]
    iso_value: Float[Array, ""]


def poisson_indicator(
    points,
    normals,
    /,
    *,
    grid: ReconstructionGrid,
    screening: float = 60.0,
    smoothing: float = 1.0,
    rtol: float = 1e-6,
    max_steps: int = 200,
) -> Indicator:
    """The indicator function of oriented points on `grid` (module docstring), differentiable in both.

    `jax.grad` of any function of `Indicator.values` (and of `level_set_vertices`) with respect to
    `points` and `normals` works under `jit`; build the grid once on concrete points
    (`reconstruction_grid`, or `poisson_reconstruction(...).grid`) and keep it fixed.

    Args:
        points: `(n, 3)` positions inside the grid.
        normals: `(n, 3)` outward normals (their lengths weigh the points: unit normals for uniform samples).
        grid: the `ReconstructionGrid` to solve on (keyword-only).
        screening: the screening weight `alpha >= 0`, relative to the unscreened Dirichlet energy (keyword-only;
            default 60; 0: the plain spectral solve).
        smoothing: the Gaussian's standard deviation in grid spacings (keyword-only; default 1).
        rtol: the screened solve's relative residual tolerance (keyword-only; unused without screening). The
            gradient is that of the exact solve (implicit differentiation): a looser tolerance makes it approximate.
        max_steps: the most conjugate-gradient steps of the screened solve (keyword-only).

    Returns:
        `Indicator(values, iso_value)`.

    Reference: S. Peng, C. Jiang, Y. Liao, M. Niemeyer, M. Pollefeys, A. Geiger, "Shape As Points: A
    Differentiable Poisson Solver", NeurIPS 2021; M. Kazhdan, M. Bolitho, H. Hoppe, "Poisson Surface
    Reconstruction", SGP 2006; M. Kazhdan, H. Hoppe, "Screened Poisson Surface Reconstruction", ACM TOG 2013.

    Examples:
        >>> import jax, jax.numpy as jnp
        >>> jax.config.update("jax_enable_x64", True)
        >>> from ddgjax.reconstruct import poisson_indicator, reconstruction_grid
        >>> normals = jax.random.normal(jax.random.key(0), (2000, 3))
        >>> normals = normals / jnp.linalg.norm(normals, axis=1, keepdims=True)
        >>> grid = reconstruction_grid(normals, depth=5)  # points on the unit sphere
        >>> indicator = poisson_indicator(normals, normals, grid=grid)
        >>> float(indicator.values[16, 16, 16]) > 0.9, float(indicator.values[0, 0, 0]) < 0.1
        (True, True)
    """
    if not isinstance(grid, ReconstructionGrid):
        raise DDGInputError(f"grid: expected a ReconstructionGrid (reconstruction_grid(points)), got {type(grid).__name__}")
    check_float_shape("points", points, (3,))
    check_float_shape("normals", normals, (3,))
    if np.shape(normals) != np.shape(points):
        raise DDGInputError(f"normals: expected the points' shape {np.shape(points)}, got {np.shape(normals)}")
    screening = _nonnegative("screening", screening)
    smoothing = _nonnegative("smoothing", smoothing)
    rtol = _nonnegative("rtol", rtol)
    max_steps = check_count("max_steps", max_steps)
    values, iso_value, _ = solve_indicator(
        points, normals, grid, screening=screening, smoothing=smoothing, rtol=rtol, max_steps=max_steps
    )
    return Indicator(values, iso_value)


def solve_indicator(
    points, normals, grid: ReconstructionGrid, *, screening: float, smoothing: float, rtol: float, max_steps: int
):
    """`(values, iso_value, stats)` of the indicator, the points padded to a bucket of the ladder with weight 0."""
    points, normals, mask = padded_points(points, normals, grid)
    return _indicator(
        points,
        normals,
        mask,
        grid.origin.astype(points.dtype),
        grid.spacing.astype(points.dtype),
        jnp.asarray(screening, points.dtype),
        jnp.asarray(smoothing, points.dtype),
        jnp.asarray(rtol, points.dtype),
        depth=grid.depth,
        max_steps=max_steps,
        screened=screening > 0,
    )


def padded_points(points, normals, grid: ReconstructionGrid):
    """`(points, normals, mask)` padded to `bucket(n)` rows: the padding at the grid's centre with zero normals and
    mask 0, so it adds nothing to the field and is left out of the means (nearby counts share one program)."""
    points = device_array(points)
    normals = device_array(normals, points.dtype)
    n = points.shape[0]
    extra = bucket(n) - n
    mask = jnp.concatenate([jnp.ones(n, points.dtype), jnp.zeros(extra, points.dtype)])
    centre = grid.node_positions(jnp.full(3, ((1 << grid.depth) - 1) / 2, points.dtype))
    points = jnp.concatenate([points, jnp.broadcast_to(centre, (extra, 3)).astype(points.dtype)])
    normals = jnp.concatenate([normals, jnp.zeros((extra, 3), points.dtype)])
    return points, normals, mask


def _nonnegative(name: str, value) -> float:
    number = float(value) if np.ndim(value) == 0 and np.asarray(value).dtype.kind in "iuf" else float("nan")
    if not (np.isfinite(number) and number >= 0):
        raise DDGInputError(f"{name}: expected a finite number >= 0, got {value!r}")
    return number


def cell_corners(points, origin, spacing, n: int):
    """`(flat, weights)` `(m, 8)`: the flat indices (`(a N + b) N + c`) of the 8 nodes around each point, and its
    trilinear weights (differentiable in the points; the cell is piecewise constant)."""
    u = (points - origin) / spacing
    base = jnp.floor(jax.lax.stop_gradient(u))
    fraction = u - base
    nodes = (base.astype(jnp.int32)[:, None, :] + _OFFSETS) % n
    weights = jnp.prod(jnp.where(_OFFSETS == 1, fraction[:, None, :], 1.0 - fraction[:, None, :]), axis=-1)
    flat = (nodes[..., 0] * n + nodes[..., 1]) * n + nodes[..., 2]
    return flat, weights


def splat(flat, weights, values, n: int):
    """`(N, N, N, d)` the sum over points of `weights * values` at their corners (`values` `(m, d)`)."""
    contributions = (weights[..., None] * values[:, None, :]).reshape(-1, values.shape[-1])
    grid = jnp.zeros((n * n * n, values.shape[-1]), values.dtype).at[flat.reshape(-1)].add(contributions)
    return grid.reshape(n, n, n, -1)


def interpolate(flat, weights, field):
    """The trilinear interpolation of the node values `field` `(N, N, N)` at the points of `(flat, weights)`."""
    return jnp.sum(weights * field.reshape(-1)[flat], axis=-1)


def wave_vectors(n: int, spacing, dtype):
    """`(kx, ky, kz)`, broadcastable to the `rfftn` half-spectrum `(N, N, N // 2 + 1)`: `2 pi fftfreq(N, h)` per axis."""
    full = 2 * jnp.pi * jnp.fft.fftfreq(n).astype(dtype) / spacing
    half = 2 * jnp.pi * jnp.fft.rfftfreq(n).astype(dtype) / spacing
    return full[:, None, None], full[None, :, None], half[None, None, :]


def smoothed_spectrum(field, spacing, smoothing):
    """The `rfftn` of `(N, N, N)` `field` times the Gaussian of `smoothing` spacings (module docstring's `G`)."""
    n = field.shape[0]
    kx, ky, kz = wave_vectors(n, spacing, field.dtype)
    gaussian = jnp.exp(-0.5 * (smoothing * spacing) ** 2 * (kx * kx + ky * ky + kz * kz))
    return jnp.fft.rfftn(field) * gaussian


@kernel(static_argnames=("depth", "max_steps", "screened"))
def _indicator(points, normals, mask, origin, spacing, screening, smoothing, rtol, *, depth, max_steps, screened):
    n = 1 << depth
    flat, weights = cell_corners(points, origin, spacing, n)
    field = splat(flat, weights, normals, n)
    kx, ky, kz = wave_vectors(n, spacing, points.dtype)
    k_sq = kx * kx + ky * ky + kz * kz
    gaussian = jnp.exp(-0.5 * (smoothing * spacing) ** 2 * k_sq)
    spectra = [jnp.fft.rfftn(field[..., axis]) for axis in range(3)]
    divergence = 1j * (kx * spectra[0] + ky * spectra[1] + kz * spectra[2]) * gaussian
    inverse_k_sq = jnp.where(k_sq > 0, 1.0 / jnp.where(k_sq > 0, k_sq, 1.0), 0.0)
    chi = jnp.fft.irfftn(divergence * inverse_k_sq, s=(n, n, n))
    count = jnp.sum(mask)

    def scaled(chi):
        outside = (jnp.mean(chi[0]) + jnp.mean(chi[:, 0]) + jnp.mean(chi[:, :, 0])) / 3
        at_points = jnp.sum(mask * interpolate(flat, weights, chi)) / count
        return (chi - outside) / (2 * (at_points - outside))

    indicator = scaled(chi)
    stats = {"steps": jnp.asarray(0), "residual": jnp.asarray(0.0, points.dtype)}
    if screened:
        indicator, stats = _screened(indicator, flat, weights, mask, count, screening, rtol, max_steps)
        indicator = scaled(indicator)
    iso_value = jnp.sum(mask * interpolate(flat, weights, indicator)) / count
    return indicator, iso_value, stats


def _screened(indicator, flat, weights, mask, count, screening, rtol, max_steps):
    """The screened indicator `x0 + delta` (module docstring), `delta` by conjugate gradients on
    `(L_h + w S^T S) delta = w S^T (1/2 - S x0)` preconditioned by a multigrid V-cycle (`_multigrid`), to `rtol` or
    `max_steps`, with `w = alpha E0 / n` and `E0 = x0 . L_h x0` the unscreened solution's Dirichlet energy (which
    makes `alpha` independent of the depth and the points' scale).
    """
    n = indicator.shape[0]
    weights = weights * mask[:, None]
    # `L_h`, `w` and so `A` and `b` all scale as `1 / h^2`, and `delta` does not: solved in units of one spacing.
    spacing = 1.0
    flat_indicator = indicator.reshape(-1)
    per_point = screening * jnp.vdot(flat_indicator, grid_laplacian(flat_indicator, n, spacing)) / count
    operator, preconditioner = screened_system(flat, weights, per_point, n, spacing)
    b = per_point * splat(flat, weights, (0.5 - interpolate(flat, weights, indicator))[:, None], n).reshape(-1)

    def solve(matvec, b):
        return _pcg(matvec, preconditioner, b, rtol, max_steps)

    correction, steps = jax.lax.custom_linear_solve(operator, b, solve, symmetric=True, has_aux=True)
    fixed_b, fixed_x = jax.lax.stop_gradient((b, correction))
    residual = jnp.linalg.norm(fixed_b - operator(fixed_x)) / jnp.maximum(jnp.linalg.norm(fixed_b), jnp.finfo(b.dtype).tiny)
    return indicator + correction.reshape(n, n, n), {"steps": steps, "residual": residual}


def _pcg(matvec, preconditioner, b, rtol, max_steps: int):
    """`(x, steps)`: preconditioned CG from 0 until `|r| <= rtol |b|` or `max_steps` steps. Only called inside
    `jax.lax.custom_linear_solve`, which differentiates the solution implicitly, so the loop need not be."""
    z = preconditioner(b)
    bound = (rtol * jnp.linalg.norm(b)) ** 2

    def more(state):
        _, r, _, _, _, steps = state
        return (steps < max_steps) & (jnp.vdot(r, r) > bound)

    def step(state):
        x, r, z, p, rz, steps = state
        ap = matvec(p)
        alpha = rz / jnp.vdot(p, ap)
        x, r = x + alpha * p, r - alpha * ap
        z = preconditioner(r)
        rz_new = jnp.vdot(r, z)
        return x, r, z, z + (rz_new / rz) * p, rz_new, steps + 1

    state = jax.lax.while_loop(more, step, (jnp.zeros_like(b), b, z, z, jnp.vdot(b, z), jnp.asarray(0)))
    return state[0], state[-1]
