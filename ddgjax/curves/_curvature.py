"""Edge lengths, turning angles and the four discrete curvatures of the reading report, with normals.

Conventions (DESIGN.md, Plane curves). At vertex `i` let `u = p_i - p_{i-1}` and `v = p_{i+1} - p_i`
(indices mod `n` on a closed curve). The turning angle `theta_i` is the signed angle from `u` to `v`,
counterclockwise positive, in `(-pi, pi)`. The four curvatures are

| kind | curvature | form | normal |
|------|-----------|------|--------|
| `"A"` | `theta` | integrated | `N_i`: left normal of the bisecting tangent `u/|u| + v/|v|` |
| `"B"` | `2 sin(theta / 2)` | integrated | `N_i` |
| `"C"` | `2 tan(theta / 2)` | integrated | `N_i` |
| `"D"` | `2 sin(theta) / |p_{i+1} - p_{i-1}|` = `1 / R_i` | pointwise | `N^D_i`: along the circumradius |

`N_i` is the report's internal angle bisector: for a counterclockwise convex curve it points
inside, and in general it lies on the left of the direction of travel. Curvatures are signed
(negative at reflex vertices of a counterclockwise curve), so `kappa N` always points towards the
locally convex side, whatever the orientation: it is the velocity of the curve-shortening flow.
`N^D_i` is oriented to the same (left) side, so `kappa^D N^D = (c_i - p_i) / R_i^2` always points
towards the circumcentre `c_i` of `p_{i-1}, p_i, p_{i+1}`.

Integrated and pointwise forms differ by the dual length `d_i = (|u| + |v|) / 2`
(`vertex_dual_lengths`): pointwise = integrated / `d_i`.

Open curves have no turning angle at their two endpoints: there every curvature, normal and
curvature vector is 0 (`interior_vertex_mask` marks the other vertices), and the dual length is half
the one incident edge.

Reference: Crane & Wardetzky, "A glimpse into discrete differential geometry", Notices AMS 2017;
the MA5210 reading report, "Curvature". The four curvatures are Table 1 of Vouga (2014), "Lectures
in discrete differential geometry 2: plane curves".
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from .._compile import kernel
from .._errors import DDGInputError, check_choice
from .._numerics import cross2, safe_div, safe_norm, safe_normalize, signed_angle_2d
from ._curve import Curve, takes_curve

KINDS = ("A", "B", "C", "D")
"""The reading report's four curvatures, the choices of every `kind=` option in `ddgjax.curves`."""


def _left(x: Float[Array, "... 2"]) -> Float[Array, "... 2"]:
    """Rotate plane vectors counterclockwise by 90 degrees."""
    return jnp.stack([-x[..., 1], x[..., 0]], axis=-1)


def _interior_mask(n: int, closed: bool) -> np.ndarray:
    mask = np.ones(n, dtype=bool)
    if not closed:
        mask[[0, -1]] = False
    return mask


def _vertex_edges(points: Float[Array, "n 2"]):
    """Incoming `u = p_i - p_{i-1}` and outgoing `v = p_{i+1} - p_i` edge vectors at every vertex.

    Computed cyclically for both kinds of curve; on an open curve the endpoint rows wrap around and
    are meaningless, so every caller masks them with `_interior_mask`.
    """
    u = points - jnp.roll(points, 1, axis=0)
    v = jnp.roll(points, -1, axis=0) - points
    return u, v


@takes_curve
def interior_vertex_mask(curve: Curve) -> Bool[Array, " n"]:
    """`(n,)` booleans: true where a vertex has a turning angle (all of a closed curve; not the endpoints of an open one).

    Args:
        curve: a closed or open plane curve.

    Returns:
        `(n,)` booleans, a host-known pattern (all true when closed, false at the two endpoints when open).
    """
    return jnp.asarray(_interior_mask(curve.n_points, curve.closed))


def _edge_lengths(points: Float[Array, "n 2"], closed: bool) -> Float[Array, " ne"]:
    following = jnp.roll(points, -1, axis=0) if closed else points[1:]
    return safe_norm(following - points[: following.shape[0]])


@kernel
def edge_lengths(curve: Curve) -> Float[Array, " ne"]:
    """Length of every edge: `(n,)` for a closed curve (edge `i` is `p_i -> p_{(i+1) mod n}`), `(n-1,)` when open.

    `|p_{i+1} - p_i|`, with value and gradient 0 (not NaN) at coincident points.
    Equivalent: `curvey.Curve.edge_length`.

    Args:
        curve: a closed or open plane curve.

    Returns:
        `(n,)` (closed) or `(n - 1,)` (open) edge lengths, in the points' dtype.
    """
    return _edge_lengths(curve.points, curve.closed)


@kernel
def length(curve: Curve) -> Float[Array, ""]:
    """Total length `L = sum_i |p_{i+1} - p_i|` (including the closing edge of a closed curve).

    Its gradient is the integrated B curvature vector with a minus sign: at every vertex with a
    turning angle, `jax.grad(lambda P: length(Curve(P)))(P)[i] == -kappa^B_i N_i`
    (`-curvature_vectors(curve, kind="B")`); at the endpoints of an open curve it is the unit edge
    pointing away from the curve. Equivalent: `curvey.Curve.length`.

    Args:
        curve: a closed or open plane curve.

    Returns:
        The total length, a scalar `()` in the points' dtype.
    """
    return jnp.sum(edge_lengths(curve))


@kernel
def vertex_dual_lengths(curve: Curve) -> Float[Array, " n"]:
    """Dual length `d_i = (|p_i - p_{i-1}| + |p_{i+1} - p_i|) / 2` of every vertex, `(n,)`.

    The length of the curve that vertex `i` stands for; the dual lengths sum to `length(curve)`.
    At the endpoints of an open curve it is half the one incident edge.
    Equivalent: `curvey.Curve.dual_edge_length`.

    Args:
        curve: a closed or open plane curve.

    Returns:
        `(n,)` dual lengths, in the points' dtype.
    """
    lengths = edge_lengths(curve)
    if curve.closed:
        return 0.5 * (lengths + jnp.roll(lengths, 1))
    zero = jnp.zeros((1,), lengths.dtype)
    return 0.5 * (jnp.concatenate([zero, lengths]) + jnp.concatenate([lengths, zero]))


def _turning_angles(points: Float[Array, "n 2"], closed: bool) -> Float[Array, " n"]:
    u, v = _vertex_edges(points)
    return jnp.where(_interior_mask(points.shape[0], closed), signed_angle_2d(u, v), 0.0)


@kernel
def turning_angles(curve: Curve) -> Float[Array, " n"]:
    """Signed turning angle `theta_i` from edge `p_{i-1} p_i` to edge `p_i p_{i+1}`, `(n,)`, in `(-pi, pi)`.

    `theta_i = atan2(u x v, u . v)` with `u = p_i - p_{i-1}`, `v = p_{i+1} - p_i`: counterclockwise
    turns are positive. Integrated curvature `kappa^A`. 0 at the endpoints of an open curve and at
    coincident points (finite gradients). An exact reversal of direction gives `pi` or `-pi` by the
    sign of the zero cross product. Equivalent: `curvey.Curve.turning_angle`.

    Args:
        curve: a closed or open plane curve.

    Returns:
        `(n,)` turning angles in radians (integrated curvature), in the points' dtype; 0 at the endpoints of an
        open curve.
    """
    return _turning_angles(curve.points, curve.closed)


@kernel
def total_curvature(curve: Curve) -> Float[Array, ""]:
    """Total signed curvature `sum_i theta_i` (integrated `kappa^A`).

    `2 pi * turning_number` on a closed curve (discrete Gauss-Bonnet for plane curves); the
    net rotation of the tangent from the first to the last edge on an open curve.

    Args:
        curve: a closed or open plane curve.

    Returns:
        The sum of the turning angles in radians, a scalar `()` in the points' dtype.
    """
    return jnp.sum(turning_angles(curve))


@kernel
def turning_number(curve: Curve) -> Array:
    """Turning number of a closed curve, the integer `round(total_curvature / (2 pi))` (int32 scalar).

    +1 for a simple counterclockwise curve, -1 clockwise. Not differentiable (an integer).

    Args:
        curve: a closed plane curve.

    Returns:
        The turning number, an int32 scalar `()`.

    Raises:
        DDGInputError: on an open curve, whose tangent need not return to its start.
    """
    if not curve.closed:
        raise DDGInputError("curve: turning_number needs a closed curve, got closed=False")
    return jnp.round(total_curvature(curve) / (2 * jnp.pi)).astype(jnp.int32)


def _natural_is_pointwise(kind: str) -> bool:
    return kind == "D"


def _curvature_and_normals(points: Float[Array, "n 2"], closed: bool, kind: str):
    """Curvature in the report's natural form (integrated A, B, C; pointwise D) and its unit normal."""
    u, v = _vertex_edges(points)
    interior = _interior_mask(points.shape[0], closed)
    lu, lv = safe_norm(u), safe_norm(v)
    if kind == "D":
        # kappa_D = 2 (u x v) / (|u| |v| |u + v|) and the left normal of the circumcircle's tangent
        # |v|^2 u + |u|^2 v: both smooth through collinear vertices (kappa_D = 0 there, R = infinity).
        kappa = safe_div(2 * cross2(u, v), lu * lv * safe_norm(u + v))
        normals = safe_normalize(_left((lv**2)[:, None] * u + (lu**2)[:, None] * v))
    else:
        theta = signed_angle_2d(u, v)
        unit_u, unit_v = safe_normalize(u), safe_normalize(v)
        bisector = safe_normalize(_left(unit_u + unit_v))
        # Where the curve exactly reverses (theta = +-pi) the bisector vanishes; -sign(theta) u/|u|
        # is its limit from that side, so kappa N stays continuous through the reversal.
        reversal = jnp.all(bisector == 0, axis=-1, keepdims=True)
        normals = jnp.where(reversal, -jnp.sign(theta)[:, None] * unit_u, bisector)
        kappa = {"A": theta, "B": 2 * jnp.sin(theta / 2), "C": 2 * jnp.tan(theta / 2)}[kind]
    kappa = jnp.where(interior, kappa, 0.0)
    normals = jnp.where(interior[:, None], normals, 0.0)
    return kappa, normals


def _to_form(curve: Curve, kind: str, kappa: Float[Array, " n"], pointwise: bool | None) -> Float[Array, " n"]:
    """Convert curvature from the natural form of `kind` to the requested one."""
    if pointwise is None or pointwise == _natural_is_pointwise(kind):
        return kappa
    dual = vertex_dual_lengths(curve)
    return safe_div(kappa, dual) if pointwise else kappa * dual


@takes_curve
@kernel(static_argnames=("kind", "pointwise"))
def curvature(curve: Curve, *, kind: str, pointwise: bool | None = None) -> Float[Array, " n"]:
    r"""Discrete curvature of `kind` (`"A"`, `"B"`, `"C"` or `"D"`) at every vertex, `(n,)`, signed.

    With $\theta_i$ the turning angle (`turning_angles`) and $d_i$ the dual length
    (`vertex_dual_lengths`):

    - `"A"`: $\theta_i$ (turning angle; integrated),
    - `"B"`: $2 \sin(\theta_i / 2)$ (length variation; integrated),
    - `"C"`: $2 \tan(\theta_i / 2)$ (offset by extended edges; integrated; unbounded as
      $\lvert\theta\rvert \to \pi$),
    - `"D"`: $2 \sin\theta_i / \lVert p_{i+1} - p_{i-1} \rVert = 1 / R_i$, the inverse circumradius of
      $p_{i-1}, p_i, p_{i+1}$ (pointwise; 0 on collinear vertices).

    Args:
        curve: the curve.
        kind: `"A"`, `"B"`, `"C"` or `"D"` (keyword-only, as everywhere in `ddgjax.curves`).
        pointwise: `None` (default) returns the reading report's natural form (A, B, C integrated, D
            pointwise); `True` returns the pointwise curvature (A, B, C divided by `d_i`);
            `False` the integrated one (D multiplied by `d_i`).

    Returns:
        `(n,)` curvatures, positive where a counterclockwise curve turns left; 0 at the endpoints of
        an open curve. Finite, with finite gradients, at coincident points.

    Raises:
        DDGInputError: `kind` not one of `KINDS`, or `curve` not a `Curve`.

    On a regular `n`-gon of circumradius `r`: `kappa^D = 1 / r` exactly and every pointwise form
    tends to `1 / r` as `n` grows. Equivalent: `curvey.Curve.curvature` is the pointwise A form.

    Examples:
        >>> import jax.numpy as jnp
        >>> import ddgjax
        >>> hexagon = ddgjax.curves.regular_polygon(6, radius=2.0)
        >>> bool(jnp.allclose(ddgjax.curves.curvature(hexagon, kind="D"), 0.5))  # 1 / r exactly
        True
        >>> round(float(ddgjax.curves.curvature(hexagon, kind="A").sum() / jnp.pi), 6)  # turning angles: 2 pi
        2.0
    """
    check_choice("kind", kind, KINDS)
    kappa, _ = _curvature_and_normals(curve.points, curve.closed, kind)
    return _to_form(curve, kind, kappa, pointwise)


@takes_curve
@kernel(static_argnames=("kind",))
def curvature_normals(curve: Curve, *, kind: str) -> Float[Array, "n 2"]:
    """Unit normal the reading report pairs with curvature `kind`, `(n, 2)`.

    A, B, C: the internal angle bisector, the left normal of `u/|u| + v/|v|` (inside a
    counterclockwise convex curve). D: the unit vector along the circumradius, the left normal of
    `|v|^2 u + |u|^2 v` (the circumcircle's tangent at `p_i`), so that `kappa^D N^D` points to the
    circumcentre. Zero at the endpoints of an open curve. For equal edge lengths the two normals agree.

    Args:
        curve: a closed or open plane curve.
        kind: `"A"`, `"B"`, `"C"` or `"D"` (keyword-only, static; `KINDS`, module docstring).

    Returns:
        `(n, 2)` unit normals, in the points' dtype; zero rows at the endpoints of an open curve.
    """
    check_choice("kind", kind, KINDS)
    return _curvature_and_normals(curve.points, curve.closed, kind)[1]


@takes_curve
@kernel(static_argnames=("kind", "pointwise"))
def curvature_vectors(curve: Curve, *, kind: str, pointwise: bool | None = None) -> Float[Array, "n 2"]:
    """Curvature vector `kappa_i N_i` of `kind`, `(n, 2)`: the velocity of the curve-shortening flow.

    The integrated B vector is minus the length gradient (the
    reading report's length variation): `kappa^B_i N_i = v/|v| - u/|u| =
    -jax.grad(lambda P: length(Curve(P)))(P)[i]` at every vertex with a turning angle.

    Args:
        curve: a closed or open plane curve.
        kind: `"A"`, `"B"`, `"C"` or `"D"` (keyword-only, static; `KINDS`, module docstring).
        pointwise: `None` (default) gives the natural form of `kind` (A, B, C integrated, D pointwise); `True`
            the pointwise vector (divided by the dual length `d_i`), `False` the integrated one (keyword-only,
            static; as in `curvature`).

    Returns:
        `(n, 2)` curvature vectors `kappa_i N_i`, in the points' dtype; zero rows at the endpoints of an open curve.
    """
    check_choice("kind", kind, KINDS)
    kappa, normals = _curvature_and_normals(curve.points, curve.closed, kind)
    return _to_form(curve, kind, kappa, pointwise)[:, None] * normals
