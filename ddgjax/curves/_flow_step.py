"""One step of the discrete curve-shortening flows, `p_i <- p_i + tau kappa_i N_i`, and its derivative.

Every kind's curvature vector is a weighted second difference of the positions,

    kappa_i N_i = alpha_i (p_{i-1} - p_i) + beta_i (p_{i+1} - p_i),

with weights that depend on the curve (`u = p_i - p_{i-1}`, `v = p_{i+1} - p_i`, `theta_i` the
turning angle):

| kind | `alpha_i` | `beta_i` |
|------|-----------|----------|
| `"B"` | `1 / |u|` | `1 / |v|` |
| `"A"` | `r_i / |u|` | `r_i / |v|`, `r_i = theta_i / (2 sin(theta_i / 2))` |
| `"C"` | `r_i / |u|` | `r_i / |v|`, `r_i = 1 / cos(theta_i / 2)` |
| `"D"` | `2 u.(u+v) / (|u|^2 |u+v|^2)` | `2 v.(u+v) / (|v|^2 |u+v|^2)` |

(B: `kappa^B N = v/|v| - u/|u|`, minus the length gradient; A and C are B scaled by
`kappa^A / kappa^B` and `kappa^C / kappa^B`; D is `(c_i - p_i) / R_i^2` with `c_i` the circumcentre,
smooth through collinear vertices.) With `L(p)` the matrix of these weights (`(L p)_i = kappa_i N_i`):

- `method="explicit"`: `p <- p + tau L(p) p`, exactly the report's iteration.
- `method="semi-implicit"`: `(I - tau L(p)) p_new = p` with the weights frozen at the current curve
  (a linearly implicit / backward Euler step), one cyclic tridiagonal solve per step. For B the
  matrix is `I + tau L_w` with `L_w` the graph Laplacian of weights `1 / |edge|` (`L_w p` is the
  length gradient; curvey's `Curve.laplacian`). `I - tau L(p)` is diagonally dominant with
  non-positive off-diagonals whenever the weights are positive (always for A, B, C; for D unless an
  edge turns back past its neighbour, `u.(u+v) < 0`), so each step is a stable implicit average for
  any `tau`. It discretises the same curvature as the explicit step (`kappa_i N_i` of `kind`,
  natural form), with the weights lagged and the positions implicit.

Curvature is in the report's natural form: integrated for A, B, C (`kappa ~ curvature x dual
length`), pointwise for D. So the A, B, C flows move a vertex by `tau` times an angle: their time
is not the smooth flow's time (smooth time ~ `tau` times the dual length), and the explicit step
is stable for `tau` below about half the shortest edge. The D flow is pointwise (smooth time);
its explicit step needs `tau` below about `(shortest edge)^2 / 4`. The semi-implicit method has no
such limit (each step still moves the curve by a finite, frozen-coefficient amount; large steps
lose accuracy, not stability).

Derivatives: the explicit step carries its tangent in closed form (`_explicit_step_jvp`, linear in
the tangents, so reverse mode is its transpose); the semi-implicit step is differentiated by
autodiff through `jax.lax.linalg.tridiagonal_solve`.

References: the MA5210 reading report, "Curvature" (Figure 3); Dziuk, "Convergence of a semi-discrete
scheme for the curve shortening flow", Math. Models Methods Appl. Sci. 1994 (the linearly
implicit scheme); curvey's `CurveShorteningFlow` (explicit, with resampling).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from .._cyclic import cyclic_shift
from .._numerics import cross2, half_angle_ratio, safe_div, safe_norm, safe_reciprocal, safe_sqrt
from ._curvature import _interior_mask, length
from ._curve import unchecked_curve
from ._invariants import centroid, enclosed_area

METHODS = ("explicit", "semi-implicit")
"""The `method=` of `curve_shortening_flow` (module docstring)."""
RESCALES = (None, "length", "area")
"""The `rescale=` of `curve_shortening_flow`: `None`, or what `rescaled` keeps."""


def _flow_weights(edges: Float[Array, "n 2"], closed: bool, kind: str):
    """Weights `alpha, beta` with `kappa_i N_i = alpha_i (p_{i-1} - p_i) + beta_i (p_{i+1} - p_i)` (module docstring).

    `edges[i] = p_{i+1} - p_i` (cyclically). Everything is algebraic in the unit edges
    `t_u, t_v` of the two edges at a vertex, using `|t_v - t_u| = 2 sin(theta/2)` and
    `|t_u + t_v| = 2 cos(theta/2)`: one square root per edge and no float64 transcendental (the
    A-flow's `(theta/2) / sin(theta/2)` is `half_angle_ratio`, a rational function).
    """
    if kind == "D":
        # 2 u.w / (|u|^2 |w|^2) and 2 v.w / (|v|^2 |w|^2), w = u + v = p_{i+1} - p_{i-1}: no square
        # root, and every term from the two edges at the vertex (dot products written out: XLA does
        # not vectorise reductions over a size-2 axis).
        u = jnp.roll(edges, 1, axis=0)
        ux, uy, vx, vy = u[:, 0], u[:, 1], edges[:, 0], edges[:, 1]
        wx, wy = ux + vx, uy + vy
        scale = 2 * safe_reciprocal(wx * wx + wy * wy)
        alpha = scale * safe_div(ux * wx + uy * wy, ux * ux + uy * uy)
        beta = scale * safe_div(vx * wx + vy * wy, vx * vx + vy * vy)
    else:
        inverse = safe_reciprocal(safe_norm(edges))
        unit_v = edges * inverse[:, None]
        unit_u, inverse_u = jnp.roll(unit_v, 1, axis=0), jnp.roll(inverse, 1)
        if kind == "B":
            ratio = 1.0
        elif kind == "C":
            ratio = 2 * safe_reciprocal(safe_norm(unit_u + unit_v))  # 1 / cos(theta / 2)
        else:
            ratio = half_angle_ratio(0.5 * safe_norm(unit_u + unit_v))  # (theta/2) / sin(theta/2), from cos(theta/2)
        alpha, beta = ratio * inverse_u, ratio * inverse
    if not closed:
        interior = _interior_mask(edges.shape[0], closed)
        alpha, beta = jnp.where(interior, alpha, 0.0), jnp.where(interior, beta, 0.0)
    return alpha, beta


def _edge_vectors(points: Float[Array, "n 2"]) -> Float[Array, "n 2"]:
    """`e_i = p_{i+1} - p_i` (cyclically); `cyclic_shift` so that its transpose is a roll too."""
    return cyclic_shift(points, -1) - points


@functools.partial(jax.custom_jvp, nondiff_argnums=(2, 3))
def _explicit_step(points, tau, closed, kind):
    """`p + tau kappa N`: the report's iteration (derivatives in closed form, `_explicit_step_jvp`)."""
    edges = _edge_vectors(points)
    alpha, beta = _flow_weights(edges, closed, kind)
    return points + tau * (beta[:, None] * edges - alpha[:, None] * jnp.roll(edges, 1, axis=0))


def _dot(a: Float[Array, "n 2"], b: Float[Array, "n 2"]) -> Float[Array, " n"]:
    return jnp.sum(a * b, axis=-1)


def _ratio_and_slope(unit_u, unit_v, kind):
    """`r = kappa^kind / kappa^B` as a function of the turning angle, and `dr/d|theta|`.

    With `s = sin(theta/2) = |t_v - t_u| / 2`, `c = cos(theta/2) = |t_u + t_v| / 2`:
    A: `r = (theta/2) / s`, `dr/d|theta| = (1 - r c) / (2 s)` (series `c (s/6 + 3 s^3/20)` for tiny `s`,
    where the quotient loses its digits); C: `r = 1 / c`, `dr/d|theta| = s / (2 c^2)`.
    """
    difference = unit_v - unit_u
    sine_sq = 0.25 * _dot(difference, difference)
    cosine = 0.5 * safe_norm(unit_u + unit_v)
    if kind == "C":
        return safe_reciprocal(cosine), 0.5 * safe_div(safe_sqrt(sine_sq), cosine * cosine)
    ratio = half_angle_ratio(cosine)
    small = sine_sq < 1e-8
    sine = jnp.where(small, 1.0, safe_sqrt(sine_sq))
    slope = jnp.where(small, cosine * safe_sqrt(sine_sq) * (1 / 6 + 0.15 * sine_sq), 0.5 * (1 - ratio * cosine) / sine)
    return ratio, slope


@_explicit_step.defjvp
def _explicit_step_jvp(closed, kind, primals, tangents):
    """Closed-form tangent of the explicit step: linear in `(dp, dtau)`, so reverse mode is its transpose.

    Written out rather than left to autodiff, which would differentiate every helper of the primal
    (NaN-safe wheres, the rational `half_angle_ratio`) and transpose all of it per step. With
    `e_i = p_{i+1} - p_i`, `u = e_{i-1}`, `t = e / |e|`:

    - A, B, C: `kappa N = r d`, `d_i = t_i - t_{i-1}`. In the plane `I - t t^T = n n^T` with `n` the
      unit normal (`t` turned a quarter counterclockwise), so `dt_i = n_i a_i` with one scalar per
      edge, `a_i = n_i . de_i / |e_i|`, and the turning angle changes by `dtheta_i = a_i - a_{i-1}`.
      With `s = r'(|theta|) sign(theta)` (`_ratio_and_slope`; `r = 1`, `s = 0` for B):

          d(kappa N)_i = s_i d_i (a_i - a_{i-1}) + r_i (n_i a_i - n_{i-1} a_{i-1}),

      differences of per-edge terms, whose transpose is as short: one dot product per term (the
      equivalent grouping `(s d + r n_i) a_i - (s d + r n_{i-1}) a_{i-1}` transposes into two).
    - D: `kappa N = q (b e - a u)` with `w = u + e`, `a = u.w / |u|^2`, `b = e.w / |e|^2`,
      `q = 2 / |w|^2`; `da = (du.w + u.dw - 2 a u.du) / |u|^2` (likewise `db`), `dq = -q^2 w.dw`.

    The tangent's rolls are `cyclic_shift`, whose transpose is the opposite roll (`jnp.roll`
    transposes into padded copies, each its own kernel). Zero-length edges keep the NaN-safe zeros
    of the primal (every reciprocal is `safe_reciprocal`).
    """
    points, tau = primals
    d_points, d_tau = tangents
    edges, d_edges = _edge_vectors(points), _edge_vectors(d_points)
    if kind == "D":
        u, du = jnp.roll(edges, 1, axis=0), cyclic_shift(d_edges, 1)
        w, dw = u + edges, du + d_edges
        inverse_u, inverse_v = safe_reciprocal(_dot(u, u)), safe_reciprocal(_dot(edges, edges))
        q = 2 * safe_reciprocal(_dot(w, w))
        a, b = _dot(u, w) * inverse_u, _dot(edges, w) * inverse_v
        da = (_dot(du, w) + _dot(u, dw) - 2 * a * _dot(u, du)) * inverse_u
        db = (_dot(d_edges, w) + _dot(edges, dw) - 2 * b * _dot(edges, d_edges)) * inverse_v
        dq = -q * q * _dot(w, dw)
        direction = b[:, None] * edges - a[:, None] * u
        vector = q[:, None] * direction
        d_vector = dq[:, None] * direction + q[:, None] * (
            db[:, None] * edges + b[:, None] * d_edges - da[:, None] * u - a[:, None] * du
        )
    else:
        inverse = safe_reciprocal(safe_norm(edges))
        unit_v = edges * inverse[:, None]
        unit_u = jnp.roll(unit_v, 1, axis=0)
        # n = (-t_y, t_x) as a reversal of the last axis, which XLA fuses into a vectorised kernel
        # (a stack of the two components is a concatenation, which it does not vectorise).
        normal_v = unit_v[:, ::-1] * jnp.array([-1.0, 1.0], unit_v.dtype)
        vector = unit_v - unit_u
        a = _dot(normal_v, d_edges) * inverse
        d_unit = normal_v * a[:, None]  # dt_i = n_i a_i
        d_vector = d_unit - cyclic_shift(d_unit, 1)
        if kind != "B":
            ratio, slope = _ratio_and_slope(unit_u, unit_v, kind)
            d_ratio = slope * jnp.sign(cross2(unit_u, unit_v)) * (a - cyclic_shift(a, 1))
            vector, d_vector = ratio[:, None] * vector, d_ratio[:, None] * vector + ratio[:, None] * d_vector
    if not closed:
        interior = _interior_mask(points.shape[0], closed)[:, None]
        vector, d_vector = jnp.where(interior, vector, 0.0), jnp.where(interior, d_vector, 0.0)
    return points + tau * vector, d_points + d_tau * vector + tau * d_vector


def _semi_implicit_step(points, tau, closed, kind):
    """Solve `(I - tau L) p_new = p`, L cyclic tridiagonal (Sherman-Morrison for the two corners)."""
    alpha, beta = _flow_weights(_edge_vectors(points), closed, kind)
    n = points.shape[0]
    sub, diag, sup = -tau * alpha, 1 + tau * (alpha + beta), -tau * beta
    first, last = jnp.arange(n) == 0, jnp.arange(n) == n - 1
    if not closed:
        # Endpoints have zero weights: their rows are the identity, nothing couples them cyclically.
        return jax.lax.linalg.tridiagonal_solve(jnp.where(first, 0.0, sub), diag, jnp.where(last, 0.0, sup), points)
    corner_low, corner_high = sup[n - 1], sub[0]  # A[n-1, 0] and A[0, n-1]
    gamma = -diag[0]
    diag = diag.at[0].add(-gamma).at[n - 1].add(-corner_low * corner_high / gamma)
    correction = jnp.zeros(n, points.dtype).at[0].set(gamma).at[n - 1].set(corner_low)
    solved = jax.lax.linalg.tridiagonal_solve(
        jnp.where(first, 0.0, sub), diag, jnp.where(last, 0.0, sup), jnp.concatenate([points, correction[:, None]], axis=1)
    )
    x, z = solved[:, :2], solved[:, 2]
    factor = (x[0] + corner_high * x[n - 1] / gamma) / (1 + z[0] + corner_high * z[n - 1] / gamma)
    return x - factor * z[:, None]


def rescaled(points, closed, rescale, target):
    """Scale about the vertex centroid so that the length (or |area|) equals `target`."""
    curve = unchecked_curve(points, closed)
    if rescale == "length":
        scale = safe_div(target, length(curve), fill=1.0)
    else:
        scale = jnp.sqrt(safe_div(target, jnp.abs(enclosed_area(curve)), fill=1.0))
    middle = centroid(curve)
    return middle + scale * (points - middle)


def size(points, closed, rescale):
    """The length, or the absolute enclosed area, of the curve through `points`: what `rescale` keeps."""
    curve = unchecked_curve(points, closed)
    return length(curve) if rescale == "length" else jnp.abs(enclosed_area(curve))


def flow_step(points: Float[Array, "n 2"], tau, *, closed: bool, kind: str, method: str) -> Float[Array, "n 2"]:
    """One step of the flow of `kind` by `method` from `points` (`(n, 2)`): the explicit or the semi-implicit step."""
    return (_explicit_step if method == "explicit" else _semi_implicit_step)(points, tau, closed, kind)
