"""The `Curve` pytree: an ordered polygon in the plane, open or closed."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .._errors import DDGInputError, check_finite, check_float_array, first_indices, is_traced


class Curve(eqx.Module):
    """A polygonal plane curve: points in order, joined by straight edges.

    Every quantity in `ddgjax.curves` is a pure JAX function of `curve.points`; differentiate with

        jax.grad(lambda P: length(Curve(P)))(curve.points)

    and batch with `jax.vmap(lambda P: curvature(Curve(P), "A"))(Ps)` for `Ps` of shape `(b, n, 2)`.

    Conventions (DESIGN.md, Plane curves): a closed curve traversed counterclockwise has positive
    turning angles and total curvature `2 pi * turning number`. Edge `i` of a closed curve joins
    point `i` to point `(i + 1) mod n` (`n` edges); an open curve has the `n - 1` edges `i -> i + 1`
    and no turning angle, curvature or normal at its two endpoints (those entries are 0; see
    `interior_vertex_mask`).

    Attributes:
        points: `(n, 2)` positions in the caller's float dtype (integers become the default float).
        closed: whether the last point joins the first (static: changing it recompiles).

    Raises:
        DDGInputError: on concrete input with the wrong shape or a non-real dtype, NaN/inf coordinates,
            fewer than 3 points (closed) or 2 points (open), or two consecutive points that coincide
            (including the last and the first point of a closed curve). Traced points (inside jit,
            grad or vmap) are not checked: there the functions stay finite on degenerate input.
    """

    points: Float[Array, "n 2"]
    closed: bool = eqx.field(static=True)

    def __init__(self, points: ArrayLike, closed: bool = True):
        if not isinstance(closed, (bool, np.bool_)):
            raise DDGInputError(f"closed: expected a Python bool, got {closed!r}")
        closed = bool(closed)
        if not is_traced(points):
            _validate_points(points, closed)
        array = jnp.asarray(points)
        if not jnp.issubdtype(array.dtype, jnp.floating):
            array = array.astype(jnp.result_type(float))
        self.points = array
        self.closed = closed

    def with_points(self, points: ArrayLike) -> Curve:
        """The same kind of curve (open / closed) through new points of the same shape.

        Checks the shape and, for concrete arrays, that every coordinate is finite; coincident
        points are allowed (unlike the constructor): this is how a flow or an optimiser hands back
        a curve, possibly degenerate, whose quantities stay finite. Traced points (jit, grad, vmap)
        are not checked.

        Raises:
            DDGInputError: a shape other than `curve.points.shape`, or NaN/inf in concrete points.
        """
        if np.shape(points) != self.points.shape:
            raise DDGInputError(f"points: expected shape {self.points.shape}, got {np.shape(points)}")
        if not is_traced(points):
            check_finite("points", np.asarray(points))
        return unchecked_curve(jnp.asarray(points), self.closed)

    @property
    def n_points(self) -> int:
        """Number of vertices `n`."""
        return self.points.shape[-2]

    @property
    def n_edges(self) -> int:
        """Number of edges: `n` when closed, `n - 1` when open."""
        return self.n_points if self.closed else self.n_points - 1


def _validate_points(points: ArrayLike, closed: bool) -> None:
    """Refuse bad shape or dtype, NaN/inf, too few points and coincident consecutive points."""
    minimum = 3 if closed else 2
    host = check_float_array("points", points, (2,))
    if host.shape[0] < minimum:
        kind = "closed" if closed else "open"
        raise DDGInputError(f"points: a {kind} curve needs at least {minimum} points, got {host.shape[0]}")
    following = np.roll(host, -1, axis=0) if closed else host[1:]
    repeated = np.all(following == host[: following.shape[0]], axis=1)
    if repeated.any():
        raise DDGInputError(
            "points: expected consecutive points to differ (a zero-length edge has no direction), got point i "
            f"equal to point i + 1{' (mod n)' if closed else ''} at i = {first_indices(repeated)}"
        )


def unchecked_curve(points: Float[Array, "n 2"], closed: bool) -> Curve:
    """A `Curve` without the constructor's value checks (for states a flow produced, maybe degenerate)."""
    curve = object.__new__(Curve)
    object.__setattr__(curve, "points", points)
    object.__setattr__(curve, "closed", closed)
    return curve
