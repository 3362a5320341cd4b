"""Discrete curve-shortening flows: the reading report's iteration `p_i <- p_i + tau kappa_i N_i`, in one `lax.scan`.

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

References: the MA5210 reading report, "Curvature" (Figure 3); Dziuk, "Convergence of a semi-discrete
scheme for the curve shortening flow", Math. Models Methods Appl. Sci. 1994 (the linearly
implicit scheme); curvey's `CurveShorteningFlow` (explicit, with resampling).
"""

from __future__ import annotations

import functools
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from .._compile import kernel
from .._cyclic import cyclic_shift
from .._errors import DDGInputError, check_choice, check_count, is_traced
from .._numerics import cross2, half_angle_ratio, safe_div, safe_norm, safe_reciprocal, safe_sqrt
from .._results import RESULTS, is_failure, raise_if_failed
from ._curvature import KINDS, _interior_mask, length, total_curvature
from ._curve import Curve, takes_curve, unchecked_curve
from ._invariants import (
    NEAR_EDGES,
    centroid,
    cyclic_residual,
    enclosed_area,
    is_simple,
    isoperimetric_ratio,
    near_and_far_clearances,
)

METHODS = ("explicit", "semi-implicit")
RESCALES = (None, "length", "area")
SIMPLICITY_CHECKS = ("certified", "saved", "every_step")


class CurveFlowResult(eqx.Module):
    """Saved states of a curve-shortening flow and the invariants the reading report discusses.

    `s = steps // save_every + 1` states are saved: the initial curve and every `save_every` steps.

    Attributes:
        points: `(s, n, 2)` positions.
        times: `(s,)` flow times `step * tau`.
        steps: `(s,)` step numbers.
        total_curvature: `(s,)` `sum theta` (the A-flow keeps `2 pi`).
        centroid: `(s, 2)` vertex centroid (the B-flow keeps it).
        length: `(s,)` total length (rescale="length" keeps it).
        area: `(s,)` signed enclosed area (rescale="area" keeps its absolute value).
        isoperimetric_ratio: `(s,)` `4 pi |A| / L^2` (tends to `pi / (n tan(pi / n))` for a
            regular polygon, 1 for a circle).
        cyclic_residual: `(s,)` relative spread of the vertices' distances to the fitted circle's
            centre (the D-flow drives it to 0).
        is_simple: `(s,)` no self-intersection (False also for non-finite points).
        result: `RESULTS.successful`; `RESULTS.nonfinite` if a saved state holds NaN/inf
            (non-finite traced input, or an overflow); else `RESULTS.self_intersection` if a
            checked state was not simple.
            `curve_shortening_flow(..., throw=True)` (the default) raises instead of returning a
            failed result.
        first_failure_step: int scalar, the first step whose state was not simple or not finite,
            and `steps + 1` (one past the last step) when none was: so a saved state precedes every
            failure exactly when `steps < first_failure_step`, and `result` is successful exactly
            when `first_failure_step == steps[-1] + 1`. Exact with `check_simple="certified"` (the
            default) or `"every_step"`; the first failing saved step with `"saved"`.
        tau: the time step.
        kind, method, rescale, closed: the flow's settings (static).
    """

    points: Float[Array, "s n 2"]
    times: Float[Array, " s"]
    steps: Int[Array, " s"]
    total_curvature: Float[Array, " s"]
    centroid: Float[Array, "s 2"]
    length: Float[Array, " s"]
    area: Float[Array, " s"]
    isoperimetric_ratio: Float[Array, " s"]
    cyclic_residual: Float[Array, " s"]
    is_simple: Bool[Array, " s"]
    result: RESULTS
    first_failure_step: Int[Array, ""]
    tau: Float[Array, ""]
    kind: str = eqx.field(static=True)
    method: str = eqx.field(static=True)
    rescale: str | None = eqx.field(static=True)
    closed: bool = eqx.field(static=True)

    @property
    def first_failure_time(self) -> Float[Array, ""]:
        """Flow time `first_failure_step * tau` of the first failing state, `inf` when the run succeeded."""
        return jnp.where(is_failure(self.result), self.first_failure_step * self.tau, jnp.inf)

    def curve(self, index: int = -1) -> Curve:
        """Saved state `index` (default: the final curve) as a `Curve` (not re-validated: it may be degenerate)."""
        return unchecked_curve(self.points[index], self.closed)


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


def _rescaled(points, closed, rescale, target):
    """Scale about the vertex centroid so that the length (or |area|) equals `target`."""
    curve = Curve(points, closed=closed)
    if rescale == "length":
        scale = safe_div(target, length(curve), fill=1.0)
    else:
        scale = jnp.sqrt(safe_div(target, jnp.abs(enclosed_area(curve)), fill=1.0))
    middle = centroid(curve)
    return middle + scale * (points - middle)


def _size(points, closed, rescale):
    curve = Curve(points, closed=closed)
    return length(curve) if rescale == "length" else jnp.abs(enclosed_area(curve))


def _simple_and_finite(points, closed) -> Bool[Array, ""]:
    return is_simple(Curve(points, closed=closed)) & jnp.all(jnp.isfinite(points))


def _certificate(points, closed):
    """Full test of a reference state for `_track`: `(simple and finite, reference)`.

    The reference holds what the cheap per-step bound needs: the points, their centred
    coordinates and `sum |r|^2` (for the similarity fit), and the reciprocal squared margins of
    near and far edge pairs: their clearances (`near_and_far_clearances`) less a rounding allowance,
    so that a state they certify would also pass `is_simple`'s rounding-aware test.
    """
    simple, near, far = near_and_far_clearances(Curve(points, closed=closed))
    allowance = 64 * jnp.finfo(points.dtype).eps * jnp.max(jnp.abs(points))
    centred = points - jnp.mean(points, axis=0)
    margins = jnp.maximum(jnp.stack([near, far]) - allowance, 0.0)
    reference = (points, centred, jnp.sum(centred * centred), safe_reciprocal(margins * margins))
    return simple & jnp.all(jnp.isfinite(points)), reference


def _certified(p, reference) -> Bool[Array, ""]:
    """Whether `p` is provably simple given its fully tested `reference` (`_track`), in O(n).

    Written as two reductions over component arrays (XLA's reductions over a size-2 axis, and many
    small reductions, would cost more than the flow step itself).
    """
    points, centred, norm_sq, inverse_margins_sq = reference
    x, y, rx, ry = p[:, 0], p[:, 1], centred[:, 0], centred[:, 1]
    sums = jnp.sum(jnp.stack([x, y, rx * x + ry * y, rx * y - ry * x]), axis=1)
    # Least-squares similarity S(r) = a r + b (complex a): a = sum conj(r) p / sum |r|^2, b = mean p.
    a_re, a_im = safe_div(sums[2], norm_sq), safe_div(sums[3], norm_sq)
    dx = x - sums[0] / x.shape[0] - (a_re * rx - a_im * ry)
    dy = y - sums[1] / x.shape[0] - (a_re * ry + a_im * rx)
    far = 4 * (dx * dx + dy * dy) * inverse_margins_sq[1] * safe_reciprocal(a_re * a_re + a_im * a_im)
    mx, my = x - points[:, 0], y - points[:, 1]
    near = jnp.zeros_like(x)
    for offset in range(1, NEAR_EDGES + 2):  # vertices of one near edge pair are at most NEAR_EDGES + 1 apart
        # cyclic: on an open curve this adds pairs across the ends (the safe side)
        rx_, ry_ = jnp.roll(mx, -offset) - mx, jnp.roll(my, -offset) - my
        near = jnp.maximum(near, rx_ * rx_ + ry_ * ry_)
    # NaN (a diverged step) fails the comparison, so it gets a full test.
    return jnp.max(jnp.maximum(far, near * inverse_margins_sq[0])) < 1


# The tracked first failing step before any failure: above every step, so that a failure at step k
# is `minimum(first, k)` and "a failure lies before step k" is `first < k`. `_saved_invariants`
# lowers it to `steps + 1` for the result.
_NO_FAILURE_YET = np.iinfo(np.int32).max


def _tracker_start(points, closed, check):
    """Initial simplicity-tracking state `(first failing step, reference)` (reference: `_certificate`)."""
    if check != "certified":
        return jnp.full((), _NO_FAILURE_YET, jnp.int32), None
    simple, reference = _certificate(jax.lax.stop_gradient(points), closed)
    return jnp.where(simple, _NO_FAILURE_YET, 0).astype(jnp.int32), reference


def _track(p, k, first, reference, closed, check):
    """Update the tracking state after step `k` produced `p` (see `curve_shortening_flow`, `check_simple`).

    Certified mode: `p` is simple if every pair of edges that must not meet stays apart. A pair
    `gap` apart in the last fully tested state `r` stays apart while the largest relative
    displacement of its endpoints is below `gap` (a point of an edge is a convex combination of
    its endpoints). Two bounds share the work (`_certified`):
    - near pairs (at most `NEAR_EDGES` apart along the curve): the relative motion of vertices a
      few apart, small in a smooth flow however far the curve travels;
    - far pairs: a similarity (rotation, uniform scale, translation) keeps a curve simple and scales
      its gaps by its factor `|a|`, so after the best similarity `S` from `r`, `2 max_i |p_i -
      S(r_i)| < |a| gap` suffices: shrinking, rescaled and rigidly moving curves stay certified.
    When either bound fails, a full O(n^2) test at `p` decides and becomes the new reference.
    """
    if check == "every_step":
        return jnp.where(_simple_and_finite(p, closed), first, jnp.minimum(first, k)), reference
    if check != "certified":
        return first, reference
    p = jax.lax.stop_gradient(p)  # bookkeeping only: nothing here is differentiated

    def full_test(_):  # only runs before the first failure, so a failure here is the first one
        simple, new_reference = _certificate(p, closed)
        return jnp.where(simple, first, k), new_reference

    keep = (first < k) | _certified(p, reference)
    return jax.lax.cond(keep, lambda _: (first, reference), full_test, None)


# XLA:CPU splits a flow step's costliest kernels across threads; below this size a kernel is too
# short for the thread handoff to pay (benchmarks/curves.py times both).
_SERIAL_BELOW = 100_000
_SERIAL_KERNELS = {"xla_disable_hlo_passes": "cpu-parallel-task-assigner"}


def _serial_kernels(points, *args, **kwargs) -> dict[str, str]:
    """Extra CPU compiler options for a flow on `points` (`kernel`): single-threaded kernels below `_SERIAL_BELOW` vertices.

    Chosen from the static shape at call time; under a caller's own `jit`, `grad` or `vmap` the
    caller's compilation settings apply instead (`ddgjax._compile`).
    """
    return _SERIAL_KERNELS if points.shape[-2] < _SERIAL_BELOW else {}


@kernel(static_argnames=("closed", "kind", "method", "rescale", "count", "check"), extra_cpu_options=_serial_kernels)
def _advance(points, step, tracker, tau, target, *, closed, kind, method, rescale, count, check):
    """`count` steps from `points` at step number `step`, tracking simplicity as `check` says."""
    update = _explicit_step if method == "explicit" else _semi_implicit_step

    # Checkpointing each step makes reverse mode store only the positions per step (O(steps n)
    # memory) and recompute the step's few cheap internals, which costs less than writing and
    # rereading them all.
    @jax.checkpoint
    def body(carry, _):
        p, k, tracker = carry
        p = update(p, tau, closed, kind)
        if rescale is not None:
            p = _rescaled(p, closed, rescale, target)
        k = k + 1
        return (p, k, _track(p, k, *tracker, closed, check)), None

    (points, step, tracker), _ = jax.lax.scan(body, (points, step, tracker), None, length=count)
    return points, step, tracker


def _frame_invariants(frames, closed):
    def one(p):
        curve = Curve(p, closed=closed)
        return (
            total_curvature(curve),
            centroid(curve),
            length(curve),
            enclosed_area(curve),
            isoperimetric_ratio(curve),
            cyclic_residual(curve),
            _simple_and_finite(p, closed),
            jnp.all(jnp.isfinite(p)),
        )

    return jax.vmap(one)(frames)


@kernel(
    static_argnames=("closed", "kind", "method", "rescale", "steps", "save_every", "check"), extra_cpu_options=_serial_kernels
)
def _run(points, tau, *, closed, kind, method, rescale, steps, save_every, check):
    """The whole flow as one scan over saved chunks (each an inner scan of `save_every` steps)."""
    settings = {"closed": closed, "kind": kind, "method": method, "rescale": rescale, "count": save_every, "check": check}
    target = _size(points, closed, rescale) if rescale is not None else jnp.zeros((), points.dtype)

    def chunk(carry, _):
        carry = _advance(*carry, tau, target, **settings)
        return carry, carry[0]

    start = (points, jnp.zeros((), jnp.int32), _tracker_start(points, closed, check))
    (_, _, (first_failure, *_)), frames = jax.lax.scan(chunk, start, None, length=steps // save_every)
    return jnp.concatenate([points[None], frames]), first_failure


@takes_curve
def curve_shortening_flow(
    curve: Curve,
    *,
    kind: str,
    tau: float | Float[Array, ""],
    steps: int,
    save_every: int | None = None,
    method: str = "explicit",
    rescale: str | None = None,
    check_simple: str = "certified",
    progress: bool = False,
    throw: bool = True,
) -> CurveFlowResult:
    """Evolve a curve by the discrete curve-shortening flow of `kind`: `p_i <- p_i + tau kappa_i N_i`.

    `kappa_i N_i` is `curvature_vectors(curve, kind=kind)` in the reading report's natural form
    (integrated for `"A"`, `"B"`, `"C"`; pointwise for `"D"`). The whole run is one `lax.scan`
    under `jit` (a scan over saved chunks of `save_every` steps), differentiable end to end with
    respect to the initial points and `tau`, and `vmap`-able over a batch of curves:

        jax.vmap(lambda P: curve_shortening_flow(Curve(P), kind="B", tau=1e-3, steps=100, check_simple="saved").points[-1])(Ps)

    (under `vmap`, `check_simple="saved"`: see below).

    What the report says each flow keeps (and the tests measure): A keeps the total curvature
    `2 pi`; B keeps the vertex centroid; D tends to a cyclic polygon; none keeps all three, and
    none is guaranteed to stay simple. Endpoints of an open curve stay fixed (they have no
    curvature).

    Failures follow ddgjax's results convention (`ddgjax._results`): a state that is not simple
    (self-intersecting or touching, the initial curve included) gives
    `RESULTS.self_intersection`, NaN/inf positions give `RESULTS.nonfinite`, with
    `first_failure_step` saying when. With `throw=True` (the default) such a run raises through
    `equinox.error_if` with the item's message: `equinox.EquinoxRuntimeError` when called
    eagerly or under `equinox.filter_jit`, a `jax.errors.JaxRuntimeError` carrying the same
    message under a plain `jax.jit`; under `vmap` it raises when any member failed. With
    `throw=False` it returns the states and the caller inspects `result`.

    Stability (see the module docstring): explicit A, B, C need `tau` below about half the
    shortest edge; explicit D needs `tau` below about `(shortest edge)^2 / 4`; above it the
    curve tangles (self-intersects; the NaN-safe weights keep it finite).
    `method="semi-implicit"` solves `(I - tau L(p)) p_new = p` with the curvature weights frozen
    at the current curve: stable for steps far beyond the explicit limit.

    Args:
        curve: initial curve (open or closed).
        kind: `"A"`, `"B"`, `"C"` or `"D"` (`curvature`).
        tau: time step, > 0 (may be traced: differentiate with respect to it, no recompilation).
        steps: number of steps, >= 1.
        save_every: save the state every this many steps; must divide `steps`. Default `steps`
            (save the initial and the final curve only).
        method: `"explicit"` (the report's iteration) or `"semi-implicit"`.
        rescale: `None`, `"length"` or `"area"`: after each step scale the curve about its vertex
            centroid back to the initial length / absolute area, so the limit shape can be watched.
            Closed curves only.
        check_simple: how the steps between saves are watched for self-intersection (the saved
            states are always tested).
            - `"certified"` (default): the exact first non-simple step at O(n) cost per step. A
              full O(n^2) test also measures the clearances (`near_and_far_clearances`: how far
              apart the edges that must not meet are); each later step only bounds how far the
              curve has moved since (the relative motion of nearby vertices, and the departure from
              the best rotation + scaling + translation), and while that stays under the clearance
              the curve provably is still simple (`_track`). A new full test runs when it does not
              (a few times per ten thousand steps in a smooth flow; every step once edges nearly
              touch). Under `jax.vmap` the lazy test becomes an every-step test (`lax.cond` turns
              into a select): use `"saved"` there.
            - `"saved"`: only the saved states; a self-intersection that appears and disappears
              between two saves goes unseen.
            - `"every_step"`: the full O(n^2) test after every step.
        progress: show a tqdm progress bar over the saved chunks (runs one jitted chunk per save
            from a host loop; needs concrete points, i.e. not inside jit / vmap / grad).
        throw: raise when the run failed (default), or return the failed run to be inspected
            through `result` and `first_failure_step`.

    Returns:
        `CurveFlowResult` with the saved points `(s, n, 2)`, times, invariants and `result`.

    Raises:
        DDGInputError: `curve` not a `Curve`; bad `kind`, `method`, `rescale`, `check_simple`,
            `steps`, `save_every`; a concrete `tau` that is not finite and positive;
            `rescale` on an open curve; `progress=True` on traced points.
        equinox.EquinoxRuntimeError: with `throw=True`, a run that self-intersected or went
            non-finite (a `jax.errors.JaxRuntimeError` under a plain `jax.jit`; see above).

    Equivalent: curvey's `CurveShorteningFlow(resample_mode=None, curvature_fn=...)` (explicit,
    with curvey's finite-difference normals, host loop).
    """
    check_choice("kind", kind, KINDS)
    check_choice("method", method, METHODS)
    check_choice("rescale", rescale, RESCALES)
    check_choice("check_simple", check_simple, SIMPLICITY_CHECKS)
    steps = check_count("steps", steps)
    save_every = steps if save_every is None else check_count("save_every", save_every)
    if steps % save_every:
        raise DDGInputError(f"save_every: expected a divisor of steps = {steps}, got {save_every}")
    if rescale is not None and not curve.closed:
        raise DDGInputError(f"rescale: expected None for an open curve (its endpoints are fixed), got {rescale!r}")
    if not is_traced(tau) and not (np.ndim(tau) == 0 and math.isfinite(float(tau)) and float(tau) > 0):
        raise DDGInputError(f"tau: expected a finite time step > 0, got {tau!r}")
    points = curve.points
    tau = jnp.asarray(tau, dtype=points.dtype)
    closed = curve.closed
    if progress and (is_traced(points) or is_traced(tau)):
        raise DDGInputError(
            "progress: expected concrete points and tau (a host loop drives the bar); use progress=False under jit / vmap / grad"
        )
    run = _run_with_progress if progress else _run
    frames, first_failure = run(
        points,
        tau,
        closed=closed,
        kind=kind,
        method=method,
        rescale=rescale,
        steps=steps,
        save_every=save_every,
        check=check_simple,
    )
    # save_every goes in as an array: a new value does not recompile.
    fields = _saved_invariants(frames, first_failure, tau, jnp.asarray(save_every, jnp.int32), closed=closed)
    flow = CurveFlowResult(**fields, kind=kind, method=method, rescale=rescale, closed=closed)
    # Outside `_saved_invariants`' jit, so that an eager call raises equinox's own error type.
    return raise_if_failed(flow, flow.result, throw)


def _run_with_progress(points, tau, *, closed, kind, method, rescale, steps, save_every, check):
    """Same chunks as `_run`, driven from the host so that tqdm can show them."""
    from tqdm.auto import tqdm

    target = _size(points, closed, rescale) if rescale is not None else jnp.zeros((), points.dtype)
    carry = (points, jnp.zeros((), jnp.int32), _tracker_start(points, closed, check))
    frames = [points]
    with tqdm(total=steps, desc=f"curve-shortening flow {kind}", unit="step") as bar:
        for _ in range(steps // save_every):
            carry = _advance(
                *carry, tau, target, closed=closed, kind=kind, method=method, rescale=rescale, count=save_every, check=check
            )
            carry[0].block_until_ready()
            frames.append(carry[0])
            bar.update(save_every)
    return jnp.stack(frames), carry[2][0]


@kernel(static_argnames=("closed",))
def _saved_invariants(frames, tracked_failure, tau, save_every, *, closed) -> dict:
    """The array fields of `CurveFlowResult` (one compiled program per shape, whatever the kind / method / rescale)."""
    total, middle, size, area, ratio, residual, simple, finite = _frame_invariants(frames, closed)
    steps = save_every * jnp.arange(frames.shape[0], dtype=jnp.int32)
    # `simple` is false for non-finite states too; `steps[-1] + 1` stands for "after the run".
    saved_failure = jnp.min(jnp.where(simple, steps[-1] + 1, steps))
    first_failure = jnp.minimum(tracked_failure, saved_failure)
    result = RESULTS.where(
        jnp.any(~finite),
        RESULTS.nonfinite,
        RESULTS.where(first_failure <= steps[-1], RESULTS.self_intersection, RESULTS.successful),
    )
    return {
        "points": frames,
        "times": steps * tau,
        "steps": steps,
        "total_curvature": total,
        "centroid": middle,
        "length": size,
        "area": area,
        "isoperimetric_ratio": ratio,
        "cyclic_residual": residual,
        "is_simple": simple,
        "result": result,
        "first_failure_step": first_failure,
        "tau": tau,
    }
