"""Whether a curve flow stayed simple at every step, certified at O(n) cost per step.

`is_simple` costs O(n^2); testing every step of a 10,000-step flow that way would cost far more than
the flow. The flows track simplicity as `check_simple` says (`curve_shortening_flow`):

- `"certified"` (default): exact, at O(n) per step. A full O(n^2) test of a reference state `r` also
  measures its clearances (`near_and_far_clearances`: how far apart the edges that must not meet
  are). A later state `p` is provably simple while every pair of edges that must not meet stays
  apart: a pair `gap` apart in `r` stays apart while the largest relative displacement of its
  endpoints is below `gap` (a point of an edge is a convex combination of its endpoints). Two
  bounds share the work (`_certified`):
  - near pairs (at most `NEAR_EDGES` apart along the curve): the relative motion of vertices a few
    apart, small in a smooth flow however far the curve travels;
  - far pairs: a similarity (rotation, uniform scale, translation) keeps a curve simple and scales
    its gaps by its factor `|a|`, so after the best similarity `S` from `r`,
    `2 max_i |p_i - S(r_i)| < |a| gap` suffices: shrinking, rescaled and rigidly moving curves stay
    certified.
  When either bound fails, a full test at `p` decides and `p` becomes the new reference (a few
  times per ten thousand steps in a smooth flow; every step once edges nearly touch).
- `"every_step"`: the full O(n^2) test after every step.
- `"saved"`: no tracking between saves (the driver tests the saved states).

The tracking state is a `ddgjax._loop.Failure` (the first failing step and its outcome:
`RESULTS.self_intersection` or `RESULTS.nonfinite`) and the reference. It is bookkeeping only: nothing
here is differentiated (`stop_gradient`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from .._compile import kernel
from .._loop import Failure, failed_before, no_failure, record
from .._numerics import safe_div, safe_reciprocal
from .._results import RESULTS
from ._curve import unchecked_curve
from ._invariants import NEAR_EDGES, is_simple, near_and_far_clearances

SIMPLICITY_CHECKS = ("certified", "saved", "every_step")
"""The `check_simple=` of `curve_shortening_flow` (module docstring)."""


def state_outcome(points: Float[Array, "n 2"], closed: bool, simple: Bool[Array, ""] | None = None) -> RESULTS:
    """The outcome of a flow state: `nonfinite` (NaN / inf positions), `self_intersection` (not simple) or `successful`.

    `simple` is `is_simple` of the state when already known.
    """
    if simple is None:
        simple = is_simple(unchecked_curve(points, closed))
    finite = jnp.all(jnp.isfinite(points))
    return RESULTS.where(finite, RESULTS.where(simple, RESULTS.successful, RESULTS.self_intersection), RESULTS.nonfinite)


def _certificate(points, closed):
    """Full test of a reference state: `(its outcome, reference)`.

    The reference holds what the cheap per-step bound needs: the points, their centred
    coordinates and `sum |r|^2` (for the similarity fit), and the reciprocal squared margins of
    near and far edge pairs: their clearances (`near_and_far_clearances`) less a rounding allowance,
    so that a state they certify would also pass `is_simple`'s rounding-aware test.
    """
    simple, near, far = near_and_far_clearances(unchecked_curve(points, closed))
    allowance = 64 * jnp.finfo(points.dtype).eps * jnp.max(jnp.abs(points))
    centred = points - jnp.mean(points, axis=0)
    margins = jnp.maximum(jnp.stack([near, far]) - allowance, 0.0)
    reference = (points, centred, jnp.sum(centred * centred), safe_reciprocal(margins * margins))
    return state_outcome(points, closed, simple), reference


def _certified(p, reference) -> Bool[Array, ""]:
    """Whether `p` is provably simple given its fully tested `reference` (module docstring), in O(n).

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


# A kernel: the progress-bar path calls it outside any program, where op-by-op dispatch of the
# O(n^2) sweep would recompile its loop at every call.
@kernel(static_argnames=("closed", "check"))
def tracker_start(points: Float[Array, "n 2"], closed: bool, check: str) -> tuple[Failure, tuple | None]:
    """The tracking state before the first step: `(failure, reference)`; the input is step 0 (`"certified"` tests it)."""
    if check != "certified":
        return no_failure(), None
    outcome, reference = _certificate(jax.lax.stop_gradient(points), closed)
    return record(no_failure(), 0, outcome), reference


def track(p: Float[Array, "n 2"], k, tracker: tuple[Failure, tuple | None], closed: bool, check: str):
    """The tracking state after step `k` produced `p` (module docstring)."""
    failure, reference = tracker
    if check == "every_step":
        return record(failure, k, state_outcome(p, closed)), reference
    if check != "certified":
        return tracker
    p = jax.lax.stop_gradient(p)

    def full_test(_):  # only runs before the first failure, so a failure here is the first one
        outcome, new_reference = _certificate(p, closed)
        return record(failure, k, outcome), new_reference

    keep = failed_before(failure, k) | _certified(p, reference)
    return jax.lax.cond(keep, lambda _: tracker, full_test, None)
