"""Global quantities the curve-shortening flows keep or change: centroids, area, roundness, simplicity.

Length, total curvature and turning number live with the curvatures (`_curvature.py`). Area-type
quantities (`enclosed_area`, `area_centroid`, `isoperimetric_ratio`) treat an open
curve as closed by the chord from its last point back to its first.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from .._compile import kernel
from .._numerics import cross2, safe_div, safe_norm, safe_reciprocal, safe_sqrt
from ._curvature import _edge_lengths
from ._curve import Curve, takes_curve


@kernel
def centroid(curve: Curve) -> Float[Array, "2"]:
    """Vertex centroid `(1/n) sum_i p_i`, `(2,)`: the centre of mass the reading report's B-flow keeps.

    Args:
        curve: a closed or open plane curve.

    Returns:
        `(2,)` mean of the points, in their dtype.

    Equivalent: `curvey.Curve.center`.
    """
    return jnp.mean(curve.points, axis=0)


def _shoelace_terms(points: Float[Array, "n 2"]):
    """Points relative to their mean (less cancellation), and `p_i x p_{i+1}` for every closing-cyclic edge."""
    origin = jnp.mean(points, axis=0)
    relative = points - origin
    following = jnp.roll(relative, -1, axis=0)
    return origin, relative, following, cross2(relative, following)


@kernel
def enclosed_area(curve: Curve) -> Float[Array, ""]:
    """Signed enclosed area by the shoelace formula, `A = (1/2) sum_i p_i x p_{i+1}`.

    Positive for counterclockwise curves; for a self-intersecting curve, the sum over regions of
    area times winding number. Translation invariant (computed relative to the vertex centroid).
    Open curves are closed by their chord. Equivalent: `curvey.Curve.signed_area`.

    Args:
        curve: a closed or open plane curve (an open one is closed by its chord).

    Returns:
        The signed area, a scalar `()` in the points' dtype; positive when counterclockwise.
    """
    return 0.5 * jnp.sum(_shoelace_terms(curve.points)[3])


@kernel
def area_centroid(curve: Curve) -> Float[Array, "2"]:
    """Centre of mass of the enclosed region, `(2,)`: `(1 / 6A) sum_i (p_i + p_{i+1}) (p_i x p_{i+1})`.

    Falls back to the vertex centroid when the signed area is exactly 0 (finite gradients there).
    Open curves are closed by their chord. Equivalent: `curvey.Curve.centroid`.

    Args:
        curve: a closed or open plane curve (an open one is closed by its chord).

    Returns:
        `(2,)` centroid of the enclosed region, in the points' dtype.
    """
    origin, relative, following, cross = _shoelace_terms(curve.points)
    moment = jnp.sum((relative + following) * cross[:, None], axis=0) / 6
    return origin + safe_div(moment, 0.5 * jnp.sum(cross))


@kernel
def isoperimetric_ratio(curve: Curve) -> Float[Array, ""]:
    """Isoperimetric ratio `4 pi |A| / L^2`: 1 for a circle, `pi / (n tan(pi / n))` for a regular n-gon, less otherwise.

    `A` is `enclosed_area`, `L` the perimeter; an open curve is closed by its chord (in both).
    Scale and rigid-motion invariant. The inverse of `curvey.Curve.roundness`.

    Args:
        curve: a closed or open plane curve (an open one is closed by its chord).

    Returns:
        The ratio, a dimensionless scalar `()` in `[0, 1]`, in the points' dtype.
    """
    perimeter = jnp.sum(_edge_lengths(curve.points, closed=True))
    return safe_div(4 * jnp.pi * jnp.abs(enclosed_area(curve)), perimeter**2)


@kernel
def cyclic_residual(curve: Curve) -> Float[Array, ""]:
    """How far the vertices are from lying on one circle: `std_i |p_i - c| / mean_i |p_i - c|`.

    `c` is the centre of the algebraic least-squares circle (Kasa fit), which minimises
    `sum_i (|p_i - c|^2 - r^2)^2` over `c` and `r` and, with the points taken relative to their
    mean `m`, solves the 2x2 system `S (c - m) = (1/2) sum_i q_i |q_i|^2` (`q_i = p_i - m`,
    `S = sum_i q_i q_i^T`). 0 exactly for a cyclic polygon (all vertices on one circle), scale and
    rigid-motion invariant. Collinear points (`det S = 0`) use `c = m`.

    Args:
        curve: a closed or open plane curve.

    Returns:
        The relative spread of the distances to the fitted centre, a dimensionless scalar `() >= 0`.

    Reference: I. Kasa, "A circle fitting procedure and its error analysis", IEEE Trans. Instrum.
    Meas. 1976.
    """
    points = curve.points
    mean = jnp.mean(points, axis=0)
    q = points - mean
    sxx, syy, sxy = jnp.sum(q[:, 0] ** 2), jnp.sum(q[:, 1] ** 2), jnp.sum(q[:, 0] * q[:, 1])
    rhs = 0.5 * jnp.sum(q * jnp.sum(q * q, axis=1, keepdims=True), axis=0)
    det = sxx * syy - sxy**2
    centre = safe_div(jnp.stack([syy * rhs[0] - sxy * rhs[1], sxx * rhs[1] - sxy * rhs[0]]), det)
    distances = safe_norm(q - centre)
    return safe_div(jnp.std(distances), jnp.mean(distances))


def _sides(d, w, tolerance):
    """Whether the point `a0 + w` lies strictly left of / strictly right of the line through `a0` along `d`.

    "Strictly" means by more than the rounding error of `d x w` when the coordinates carry an
    absolute error of about `eps max|coordinate|`: `tolerance (|d|_1 + |w|_1)` with
    `tolerance = 16 eps max|coordinate|`; a point within it counts as on the line.
    """
    o = cross2(d, w)
    slack = tolerance * (jnp.abs(d[..., 0]) + jnp.abs(d[..., 1]) + jnp.abs(w[..., 0]) + jnp.abs(w[..., 1]))
    return o > slack, o < -slack


def _segments_intersect(a0, a1, b0, b1, tolerance) -> Bool[Array, "..."]:
    """Closed segments `a0 a1` and `b0 b1` share a point (proper crossing, touching or collinear overlap), up to rounding.

    Orientations within their rounding error (`_sides`) count as 0, so a point within rounding of a
    segment touches it, and nearly collinear segments are classified as collinear, not by the
    signs of their rounding errors.
    """
    da, db = a1 - a0, b1 - b0
    left1, right1 = _sides(da, b0 - a0, tolerance)
    left2, right2 = _sides(da, b1 - a0, tolerance)
    left3, right3 = _sides(db, a0 - b0, tolerance)
    left4, right4 = _sides(db, a1 - b0, tolerance)
    apart = (left1 & left2) | (right1 & right2) | (left3 & left4) | (right3 & right4)
    # Collinear segments (every endpoint on the other's line) meet iff their boxes overlap.
    collinear = ~(left1 | right1 | left2 | right2 | left3 | right3 | left4 | right4)
    overlaps = (jnp.minimum(a0, a1) <= jnp.maximum(b0, b1) + tolerance) & (jnp.minimum(b0, b1) <= jnp.maximum(a0, a1) + tolerance)
    boxes = overlaps[..., 0] & overlaps[..., 1]  # not jnp.all(axis=-1): XLA does not vectorise size-2 reductions
    return jnp.where(collinear, boxes, ~apart)


def _point_segment_distances_sq(point, start, direction, inverse_length_sq) -> Float[Array, "..."]:
    """Squared distance from `point` to the closed segment `start + t direction`, `t` in [0, 1].

    Points and vectors are `(x, y)` pairs of arrays (component form: no reduction over a size-2
    axis, which XLA does not vectorise).
    """
    ox, oy = point[0] - start[0], point[1] - start[1]
    t = jnp.clip((ox * direction[0] + oy * direction[1]) * inverse_length_sq, 0.0, 1.0)
    rx, ry = ox - t * direction[0], oy - t * direction[1]
    return rx * rx + ry * ry


# Edge pairs at most this far apart along the curve are "near" in `near_and_far_clearances`. The
# flows' certified tracking bounds their relative motion step by step (O(NEAR_EDGES n) per step) and
# the far ones by a similarity fit. Too few near pairs leave close, non-rigidly moving neighbours to
# the far bound; too many put vertices far apart along the curve, whose relative motion is large,
# under the near bound. Either failure costs a full O(n^2) test; 8 gave the fewest on the benchmark
# flower.
NEAR_EDGES = 8


def _edge_pair_sweep(curve: Curve, block: int, with_clearance: bool):
    """`(simple, near clearance, far clearance)` by one O(n^2) sweep over edge pairs; see `is_simple`.

    The clearances (None unless asked for) are split at `NEAR_EDGES` edges apart along the curve.
    """
    points = curve.points
    starts = points if curve.closed else points[:-1]
    ends = jnp.roll(points, -1, axis=0)[: starts.shape[0]]
    m = starts.shape[0]
    index = jnp.arange(m)
    tolerance = 16 * jnp.finfo(points.dtype).eps * jnp.max(jnp.abs(points))
    directions = ends - starts
    start_x, start_y, end_x, end_y = starts[:, 0], starts[:, 1], ends[:, 0], ends[:, 1]
    direction_x, direction_y = end_x - start_x, end_y - start_y
    inverse_lengths_sq = safe_reciprocal(direction_x**2 + direction_y**2)

    def row(i):
        cross = _segments_intersect(starts[i], ends[i], starts, ends, tolerance)
        gap = jnp.abs(index - i)
        adjacent = (gap == 1) | (curve.closed & (gap == m - 1))
        left, right = _sides(directions[i], directions, tolerance)
        backwards = directions[i, 0] * directions[:, 0] + directions[i, 1] * directions[:, 1] < 0
        folded = ~left & ~right & backwards
        later = index > i
        hits = jnp.any(jnp.where(adjacent, folded, cross) & later)
        if not with_clearance:
            return hits
        # Endpoint-to-edge squared distances: edge j's start / end to edge i, edge i's start / end to edge j.
        start_i, direction_i = (start_x[i], start_y[i]), (direction_x[i], direction_y[i])
        start_to_i = _point_segment_distances_sq((start_x, start_y), start_i, direction_i, inverse_lengths_sq[i])
        end_to_i = _point_segment_distances_sq((end_x, end_y), start_i, direction_i, inverse_lengths_sq[i])
        every_start, every_direction = (start_x, start_y), (direction_x, direction_y)
        i_start_to = _point_segment_distances_sq(start_i, every_start, every_direction, inverse_lengths_sq)
        i_end_to = _point_segment_distances_sq((end_x[i], end_y[i]), every_start, every_direction, inverse_lengths_sq)
        # Adjacent edges share one vertex; only their far endpoints count. Edge j follows edge i
        # (j = i + 1) or, across the closing vertex, precedes it (i = 0, j = m - 1).
        follows = index == i + 1
        adjacent_gap = jnp.where(follows, jnp.minimum(end_to_i, i_start_to), jnp.minimum(start_to_i, i_end_to))
        every_gap = jnp.minimum(jnp.minimum(start_to_i, end_to_i), jnp.minimum(i_start_to, i_end_to))
        gaps = jnp.where(later, jnp.where(adjacent, adjacent_gap, every_gap), jnp.inf)
        apart = jnp.minimum(gap, m - gap) if curve.closed else gap
        near = apart <= NEAR_EDGES
        return hits, jnp.min(jnp.where(near, gaps, jnp.inf)), jnp.min(jnp.where(near, jnp.inf, gaps))

    swept = jax.lax.map(row, index, batch_size=min(block, m))
    if not with_clearance:
        return ~jnp.any(swept), None, None
    hits, near_sq, far_sq = swept
    # safe_sqrt: a clearance of 0 (touching edges) keeps a finite gradient, so it can serve as a penalty.
    return ~jnp.any(hits), safe_sqrt(jnp.min(near_sq)), safe_sqrt(jnp.min(far_sq))


class SimplicityAndClearance(NamedTuple):
    """What `simplicity_and_clearance` returns (a named tuple: `simple, clearance = ...` still unpacks).

    Attributes:
        is_simple: boolean scalar, `is_simple(curve)`.
        clearance: scalar, the smallest distance between two edges that must not meet.
    """

    is_simple: Bool[Array, ""]
    clearance: Float[Array, ""]


@takes_curve
@kernel(static_argnames=("block",))
def simplicity_and_clearance(curve: Curve, *, block: int = 128) -> SimplicityAndClearance:
    """`SimplicityAndClearance(is_simple, clearance)`: whether the curve is simple, and by how much.

    The clearance is the smallest distance between two edges that must not meet: between
    non-adjacent edges the segment distance (the least endpoint-to-segment distance, as they do not
    cross on a simple curve), and between adjacent edges the distance from each one's far endpoint
    to the other (they fold onto each other only when that reaches 0). It certifies nearby states:
    moving every vertex by less than `clearance / 2` moves every point of every edge by less than
    that (a point of an edge is a convex combination of its endpoints), so no two edges that were
    `clearance` apart can meet and the curve stays simple. Meaningless (but finite) for a non-simple
    curve. The same O(n^2) blocked sweep as `is_simple`, with four endpoint-to-segment distances
    per pair. Differentiable (finite gradients also where the clearance is 0, e.g. as a penalty that
    keeps a curve simple during shape optimisation). Equivalent: the least `shapely` `distance`
    between the edges' `LineString`s, taking adjacent edges by their far endpoints (the tests check
    exactly that); the flows' certificate of simplicity (`ddgjax.curves._flow_certificate`) rests on it.

    Args:
        curve: any curve (open or closed).
        block: edges tested against all edges at a time (static; O(block * n) memory).

    Returns:
        `SimplicityAndClearance`: `is_simple` (boolean scalar) and `clearance` (scalar, length units).
    """
    simple, near, far = _edge_pair_sweep(curve, block, with_clearance=True)
    return SimplicityAndClearance(simple, jnp.minimum(near, far))


def near_and_far_clearances(curve: Curve, *, block: int = 128) -> tuple[Bool[Array, ""], Float[Array, ""], Float[Array, ""]]:
    """`simplicity_and_clearance` with the clearance split between near and far edge pairs.

    Near: edges at most `NEAR_EDGES` apart along the curve (`inf` if there are none); far: the
    rest (`inf` if none). Near edges move almost together in a smooth flow, so the flows certify
    them by the relative motion of nearby vertices and the far ones by the total motion
    (`ddgjax.curves._flow_certificate`).
    """
    return _edge_pair_sweep(curve, block, with_clearance=True)


@takes_curve
@kernel(static_argnames=("block",))
def is_simple(curve: Curve, *, block: int = 128) -> Bool[Array, ""]:
    """True when the curve does not intersect or touch itself (boolean scalar, jit-compatible).

    Every pair of non-adjacent edges is tested with orientation signs (crossings, touching points
    and collinear overlaps all count); adjacent edges, which share an endpoint, count as
    intersecting only when they fold back onto each other (turning angle `pi`). Coincident vertices
    therefore make a curve non-simple. An orientation `d x w` counts as 0 when it is within its
    rounding error, `16 eps max|coordinate| (|d|_1 + |w|_1)` (`eps` of the points' dtype): points
    on a straight side of a polygon that rounding moved off it by a few ulps stay collinear (exact
    signs would see crossings there), and gaps below about
    `16 eps max|coordinate| (1 + |w| / |d|)` count as touching. O(n^2) work in blocks of
    `block` edges against all edges (O(block * n) memory). Equivalent: `curvey.Curve.is_simple`
    (shapely, which uses exact predicates on the rounded coordinates).

    Args:
        curve: a closed or open plane curve.
        block: how many edges are tested against all the others at a time (keyword-only, static, default
            128); it trades memory for fewer loop steps and does not change the answer.

    Returns:
        Boolean scalar `()`: whether the curve is simple.
    """
    return _edge_pair_sweep(curve, block, with_clearance=False)[0]
