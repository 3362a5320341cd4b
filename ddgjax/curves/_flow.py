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

from .._errors import DDGInputError, is_traced
from .._numerics import first_quadrant_atan2, safe_div, safe_norm
from ._curvature import _interior_mask, check_kind, length, total_curvature
from ._curve import Curve, unchecked_curve
from ._invariants import centroid, cyclic_residual, enclosed_area, is_simple, isoperimetric_ratio, simplicity_and_clearance

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
        first_nonsimple_step: int scalar, the first step at which the curve was not simple, -1 if
            none: exact with `check_simple="certified"` (the default) or `"every_step"`, the first
            non-simple saved step with `"saved"`.
        first_nonfinite_step: int scalar, the first saved step with NaN/inf points (an unstable
            explicit step), -1 if none.
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
    first_nonsimple_step: Int[Array, ""]
    first_nonfinite_step: Int[Array, ""]
    tau: Float[Array, ""]
    kind: str = eqx.field(static=True)
    method: str = eqx.field(static=True)
    rescale: str | None = eqx.field(static=True)
    closed: bool = eqx.field(static=True)

    @property
    def self_intersected(self) -> Bool[Array, ""]:
        """True if a checked step made the curve self-intersect (see `first_nonsimple_step`)."""
        return self.first_nonsimple_step >= 0

    @property
    def first_nonsimple_time(self) -> Float[Array, ""]:
        """Flow time of `first_nonsimple_step`, `inf` if the curve stayed simple."""
        return jnp.where(self.self_intersected, self.first_nonsimple_step * self.tau, jnp.inf)

    def curve(self, index: int = -1) -> Curve:
        """Saved state `index` (default: the final curve) as a `Curve` (not re-validated: it may be degenerate)."""
        return unchecked_curve(self.points[index], self.closed)


def _reciprocal(x: Float[Array, "..."]) -> Float[Array, "..."]:
    """`1 / x`, 0 where `x == 0` (coincident points), finite gradients."""
    return safe_div(jnp.ones_like(x), x)


def _flow_weights(edges: Float[Array, "n 2"], closed: bool, kind: str):
    """Weights `alpha, beta` with `kappa_i N_i = alpha_i (p_{i-1} - p_i) + beta_i (p_{i+1} - p_i)` (module docstring).

    `edges[i] = p_{i+1} - p_i` (cyclically). Everything is algebraic in the unit edges
    `t_u, t_v` of the two edges at a vertex, using `|t_v - t_u| = 2 sin(theta/2)` and
    `|t_u + t_v| = 2 cos(theta/2)`: one square root per edge, no float64 transcendental but the
    A-flow's arctangent.
    """
    inverse = _reciprocal(safe_norm(edges))
    unit_v = edges * inverse[:, None]
    unit_u, inverse_u = jnp.roll(unit_v, 1, axis=0), jnp.roll(inverse, 1)
    if kind == "D":
        chord = edges + jnp.roll(edges, 1, axis=0)  # p_{i+1} - p_{i-1}
        scale = 2 * _reciprocal(jnp.sum(chord * chord, axis=-1))
        alpha = scale * jnp.sum(unit_u * chord, axis=-1) * inverse_u
        beta = scale * jnp.sum(unit_v * chord, axis=-1) * inverse
    else:
        if kind == "B":
            ratio = 1.0
        elif kind == "C":
            ratio = 2 * _reciprocal(safe_norm(unit_u + unit_v))  # 1 / cos(theta / 2)
        else:
            sine, cosine = 0.5 * safe_norm(unit_v - unit_u), 0.5 * safe_norm(unit_u + unit_v)
            # (theta/2) / sin(theta/2); its series 1 + s^2/6 below 1e-4, where the quotient loses digits.
            small = sine < 1e-4
            ratio = jnp.where(
                small, 1 + sine**2 / 6, first_quadrant_atan2(sine, cosine) / jnp.where(small, 1.0, sine)
            )
        alpha, beta = ratio * inverse_u, ratio * inverse
    if not closed:
        interior = _interior_mask(edges.shape[0], closed)
        alpha, beta = jnp.where(interior, alpha, 0.0), jnp.where(interior, beta, 0.0)
    return alpha, beta


def _edge_vectors(points: Float[Array, "n 2"]) -> Float[Array, "n 2"]:
    return jnp.roll(points, -1, axis=0) - points


def _explicit_step(points, tau, closed, kind):
    edges = _edge_vectors(points)
    alpha, beta = _flow_weights(edges, closed, kind)
    return points + tau * (beta[:, None] * edges - alpha[:, None] * jnp.roll(edges, 1, axis=0))


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
    """`(simple and finite, margin)`: every state within `margin / 2` per vertex of `points` is simple too.

    The margin is the clearance (`simplicity_and_clearance`) less a rounding allowance, so that a
    state it certifies would also pass `is_simple`'s rounding-aware test.
    """
    simple, clearance = simplicity_and_clearance(Curve(points, closed=closed))
    allowance = 64 * jnp.finfo(points.dtype).eps * jnp.max(jnp.abs(points))
    return simple & jnp.all(jnp.isfinite(points)), clearance - allowance


def _tracker_start(points, closed, check):
    """Initial simplicity-tracking state `(first non-simple step, reference points, margin)`."""
    if check != "certified":
        return jnp.full((), -1, jnp.int32), points, jnp.zeros((), points.dtype)
    simple, margin = _certificate(jax.lax.stop_gradient(points), closed)
    return jnp.where(simple, -1, 0).astype(jnp.int32), points, margin


def _track(p, k, bad, reference, margin, closed, check):
    """Update the tracking state after step `k` produced `p` (see `curve_shortening_flow`, `check_simple`)."""
    if check == "every_step":
        return jnp.where((bad < 0) & ~_simple_and_finite(p, closed), k, bad), reference, margin
    if check != "certified":
        return bad, reference, margin
    p = jax.lax.stop_gradient(p)  # bookkeeping only: nothing here is differentiated
    offset = p - reference
    moved_sq = jnp.max(offset[:, 0] ** 2 + offset[:, 1] ** 2)
    # Certified while every vertex moved less than margin / 2 since the last full test (NaN is not).
    certified = (bad >= 0) | (4 * moved_sq < jnp.maximum(margin, 0.0) ** 2)

    def full_test(_):
        simple, new_margin = _certificate(p, closed)
        return jnp.where(simple, bad, k), p, new_margin

    return jax.lax.cond(certified, lambda _: (bad, reference, margin), full_test, None)


@functools.partial(jax.jit, static_argnames=("closed", "kind", "method", "rescale", "count", "check"))
def _advance(points, step, tracker, tau, target, *, closed, kind, method, rescale, count, check):
    """`count` steps from `points` at step number `step`, tracking simplicity as `check` says."""
    update = _explicit_step if method == "explicit" else _semi_implicit_step

    # Checkpointing each step makes reverse mode store only the positions per step and recompute
    # the step's internals: 3x faster gradients here than storing every intermediate (measured,
    # benchmarks/README.md), and O(steps * n) memory.
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


@functools.partial(jax.jit, static_argnames=("closed", "kind", "method", "rescale", "steps", "save_every", "check"))
def _run(points, tau, *, closed, kind, method, rescale, steps, save_every, check):
    """The whole flow as one scan over saved chunks (each an inner scan of `save_every` steps)."""
    settings = {"closed": closed, "kind": kind, "method": method, "rescale": rescale, "count": save_every, "check": check}
    target = _size(points, closed, rescale) if rescale is not None else jnp.zeros((), points.dtype)

    def chunk(carry, _):
        carry = _advance(*carry, tau, target, **settings)
        return carry, carry[0]

    start = (points, jnp.zeros((), jnp.int32), _tracker_start(points, closed, check))
    (_, _, (first_nonsimple, _, _)), frames = jax.lax.scan(chunk, start, None, length=steps // save_every)
    return jnp.concatenate([points[None], frames]), first_nonsimple


def _check_count(name: str, value, minimum: int = 1) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise DDGInputError(f"{name}: expected an integer >= {minimum}, got {value!r}")
    return int(value)


def _check_choice(name: str, value, choices) -> None:
    if value not in choices:
        raise DDGInputError(f"{name}: expected one of {', '.join(map(repr, choices))}, got {value!r}")


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
) -> CurveFlowResult:
    """Evolve a curve by the discrete curve-shortening flow of `kind`: `p_i <- p_i + tau kappa_i N_i`.

    `kappa_i N_i` is `curvature_vectors(curve, kind)` in the reading report's natural form
    (integrated for `"A"`, `"B"`, `"C"`; pointwise for `"D"`). The whole run is one `lax.scan`
    under `jit` (a scan over saved chunks of `save_every` steps), differentiable end to end with
    respect to the initial points and `tau`, and `vmap`-able over a batch of curves:

        jax.vmap(lambda P: curve_shortening_flow(Curve(P), kind="B", tau=1e-3, steps=100).points[-1])(Ps)

    What the report says each flow keeps (and the tests measure): A keeps the total curvature
    `2 pi`; B keeps the vertex centroid; D tends to a cyclic polygon; none keeps all three, and
    none is guaranteed to stay simple, so self-intersection is reported (`first_nonsimple_step`),
    never hidden. Endpoints of an open curve stay fixed (they have no curvature).

    Stability (see the module docstring): explicit A, B, C need `tau` below about half the
    shortest edge; explicit D needs `tau` below about `(shortest edge)^2 / 4`. Unstable runs show
    up as `first_nonfinite_step >= 0` or a non-simple curve. `method="semi-implicit"` solves
    `(I - tau L(p)) p_new = p` with the curvature weights frozen at the current curve: stable for
    steps far beyond the explicit limit.

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
        check_simple: how `first_nonsimple_step` watches the steps between saves (the saved
            states are always tested).
            - `"certified"` (default): the exact first non-simple step at near-O(n) cost. A full
              O(n^2) test also measures the clearance (`simplicity_and_clearance`: how far apart
              the edges that must not meet are); each later step only tracks how far any vertex has
              moved since, and while that stays under half the clearance the curve provably is
              still simple. A new full test runs when it does not (a few per thousand steps in a
              smooth flow; every step once edges nearly touch). Under `jax.vmap` the lazy test
              becomes an every-step test (`lax.cond` turns into a select): use `"saved"` there.
            - `"saved"`: only the saved states; a self-intersection that appears and disappears
              between two saves goes unseen.
            - `"every_step"`: the full O(n^2) test after every step.
        progress: show a tqdm progress bar over the saved chunks (runs one jitted chunk per save
            from a host loop; needs concrete points, i.e. not inside jit / vmap / grad).

    Returns:
        `CurveFlowResult` with the saved points `(s, n, 2)`, times and invariants.

    Raises:
        DDGInputError: bad `kind`, `method`, `rescale`, `check_simple`, `steps`, `save_every`, a
            concrete `tau` that is not finite and positive, `rescale` on an open curve, or
            `progress=True` on traced points.

    Equivalent: curvey's `CurveShorteningFlow(resample_mode=None, curvature_fn=...)` (explicit,
    with curvey's finite-difference normals, host loop).
    """
    kind = check_kind(kind)
    _check_choice("method", method, METHODS)
    _check_choice("rescale", rescale, RESCALES)
    _check_choice("check_simple", check_simple, SIMPLICITY_CHECKS)
    steps = _check_count("steps", steps)
    save_every = steps if save_every is None else _check_count("save_every", save_every)
    if steps % save_every:
        raise DDGInputError(f"save_every: expected a divisor of steps = {steps}, got {save_every}")
    if rescale is not None and not curve.closed:
        raise DDGInputError(f"rescale: expected None for an open curve (its endpoints are fixed), got {rescale!r}")
    if not is_traced(tau) and not (np.ndim(tau) == 0 and math.isfinite(float(tau)) and float(tau) > 0):
        raise DDGInputError(f"tau: expected a finite time step > 0, got {tau!r}")
    points = curve.points
    tau = jnp.asarray(tau, dtype=points.dtype)
    closed = curve.closed
    if progress:
        if is_traced(points) or is_traced(tau):
            raise DDGInputError("progress: expected concrete points and tau (a host loop drives the bar); use progress=False under jit / vmap / grad")
        frames, first_nonsimple = _run_with_progress(
            points, tau, closed=closed, kind=kind, method=method, rescale=rescale, steps=steps, save_every=save_every, check=check_simple
        )
    else:
        frames, first_nonsimple = _run(
            points, tau, closed=closed, kind=kind, method=method, rescale=rescale, steps=steps, save_every=save_every, check=check_simple
        )
    return _result(frames, first_nonsimple, tau, save_every, closed=closed, kind=kind, method=method, rescale=rescale)


def _run_with_progress(points, tau, *, closed, kind, method, rescale, steps, save_every, check):
    """Same chunks as `_run`, driven from the host so that tqdm can show them."""
    from tqdm.auto import tqdm

    target = _size(points, closed, rescale) if rescale is not None else jnp.zeros((), points.dtype)
    carry = (points, jnp.zeros((), jnp.int32), _tracker_start(points, closed, check))
    frames = [points]
    with tqdm(total=steps, desc=f"curve-shortening flow {kind}", unit="step") as bar:
        for _ in range(steps // save_every):
            carry = _advance(*carry, tau, target, closed=closed, kind=kind, method=method, rescale=rescale, count=save_every, check=check)
            carry[0].block_until_ready()
            frames.append(carry[0])
            bar.update(save_every)
    return jnp.stack(frames), carry[2][0]


@functools.partial(jax.jit, static_argnames=("closed",))
def _saved_invariants(frames, first_nonsimple, tau, save_every, *, closed) -> dict:
    """The invariant fields of `CurveFlowResult` (one compiled program per shape, whatever the kind / method / rescale)."""
    total, middle, size, area, ratio, residual, simple, finite = _frame_invariants(frames, closed)
    steps = save_every * jnp.arange(frames.shape[0], dtype=jnp.int32)
    never = jnp.iinfo(jnp.int32).max
    first_saved_nonsimple = jnp.where(jnp.any(~simple), steps[jnp.argmax(~simple)], never)
    first_nonsimple = jnp.minimum(first_saved_nonsimple, jnp.where(first_nonsimple >= 0, first_nonsimple, never))
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
        "first_nonsimple_step": jnp.where(first_nonsimple < never, first_nonsimple, -1),
        "first_nonfinite_step": jnp.where(jnp.any(~finite), steps[jnp.argmax(~finite)], -1),
        "tau": tau,
    }


def _result(frames, first_nonsimple, tau, save_every, *, closed, kind, method, rescale) -> CurveFlowResult:
    # save_every goes in as an array: a new value does not recompile.
    fields = _saved_invariants(frames, first_nonsimple, tau, jnp.asarray(save_every, jnp.int32), closed=closed)
    return CurveFlowResult(**fields, kind=kind, method=method, rescale=rescale, closed=closed)
