"""The `Curve` pytree: an ordered polygon in the plane, open or closed; the check every curve function makes."""

from __future__ import annotations

import functools
import inspect

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .._domain import Domain
from .._errors import DDGInputError, check_finite, check_float_array, check_float_shape, first_indices, is_traced


class Curve(Domain):
    r"""A polygonal plane curve: points in order, joined by straight edges.

    Every quantity in `ddgjax.curves` is a pure JAX function of `curve.points`; differentiate with

        jax.grad(lambda P: length(Curve(P)))(curve.points)

    and batch with `jax.vmap(lambda P: curvature(Curve(P), kind="A"))(Ps)` for `Ps` of shape `(b, n, 2)`.

    Conventions (DESIGN.md, Plane curves): a closed curve traversed counterclockwise has positive
    turning angles and total curvature $2\pi \cdot \text{turning number}$. Edge `i` of a closed curve joins
    point `i` to point `(i + 1) mod n` (`n` edges); an open curve has the `n - 1` edges `i -> i + 1`
    and no turning angle, curvature or normal at its two endpoints (those entries are 0; see
    `interior_vertex_mask`).

    Attributes:
        points: `(n, 2)` positions in the caller's float dtype (integers become the default float).
        closed: whether the last point joins the first (static: changing it recompiles).

    Raises:
        DDGInputError: on the wrong shape or a non-real dtype, fewer than 3 points (closed) or 2
            points (open), and, for concrete input, NaN/inf coordinates or two consecutive points
            that coincide (including the last and the first point of a closed curve). The values of
            traced points (inside jit, grad or vmap) cannot be checked: there the functions stay
            finite on degenerate input; their shape is checked all the same.

    Examples:
        >>> import jax.numpy as jnp
        >>> import ddgjax
        >>> square = ddgjax.Curve(jnp.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]))
        >>> float(ddgjax.curves.length(square)), float(ddgjax.curves.enclosed_area(square))
        (4.0, 1.0)
        >>> int(ddgjax.curves.turning_number(square))
        1
    """

    points: Float[Array, "n 2"]
    closed: bool = eqx.field(static=True)

    parameter_name = "curve"

    def __init__(self, points: ArrayLike, closed: bool = True):
        if not isinstance(closed, (bool, np.bool_)):
            raise DDGInputError(f"closed: expected a Python bool, got {closed!r}")
        closed = bool(closed)
        _check_point_shape(points, closed)  # shapes are known under jit / grad / vmap too
        if not is_traced(points):
            _check_point_values(points, closed)
        array = jnp.asarray(points)
        if not jnp.issubdtype(array.dtype, jnp.floating):
            array = array.astype(jnp.result_type(float))
        self.points = array
        self.closed = closed

    @classmethod
    def how_to_build(cls, value: object) -> str:
        """How to make a `Curve` from what was given (`Domain.require`'s hint)."""
        return "wrap the (n, 2) points with ddgjax.curves.Curve(points, closed=True) (closed=False for an open polyline)"

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


def _check_point_shape(points: ArrayLike, closed: bool) -> None:
    """Refuse a shape other than `(n, 2)`, a non-real dtype and too few points."""
    check_float_shape("points", points, (2,))
    minimum = 3 if closed else 2
    if np.shape(points)[0] < minimum:
        kind = "closed" if closed else "open"
        raise DDGInputError(f"points: a {kind} curve needs at least {minimum} points, got {np.shape(points)[0]}")


def _check_point_values(points: ArrayLike, closed: bool) -> None:
    """Refuse NaN/inf and coincident consecutive points (concrete arrays only)."""
    host = check_float_array("points", points, (2,))
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


def require_curve(name: str, value) -> Curve:
    """`value` if it is a `Curve`, else `DDGInputError` naming the argument and saying how to make one.

    Args:
        name: the argument's name, for the error message.
        value: the object to check.

    Returns:
        `value` itself, when it is a `Curve`.

    Raises:
        DDGInputError: `value` is not a `Curve`.
    """
    return Curve.require(name, value)


def takes_curve(function):
    """Wrap a public `function(curve, ...)` so that its arguments are checked before anything else sees them.

    A first argument that is not a `Curve` gets `require_curve`'s message, and an option passed by
    position gets Python's message naming the keyword-only options (`curvature(curve, "A")`:
    `curvature() takes 1 positional argument but 2 were given; pass its options by keyword:
    curvature(curve, kind=..., pointwise=...)`), rather than a run-time type checker's or `jit`'s
    complaint about a non-array argument. A `kernel` checks its curve itself; this wrapper is for the
    public functions that are not kernels, and gives the kernels that take options the hint.
    """
    parameters = inspect.signature(function).parameters.values()
    positional = sum(parameter.kind in (parameter.POSITIONAL_ONLY, parameter.POSITIONAL_OR_KEYWORD) for parameter in parameters)
    options = ", ".join(f"{parameter.name}=..." for parameter in parameters if parameter.kind == parameter.KEYWORD_ONLY)
    name = function.__name__

    @functools.wraps(function)
    def checked(curve, *args, **kwargs):
        if 1 + len(args) > positional:
            hint = f"; pass its options by keyword: {name}(curve, {options})" if options else ""
            raise TypeError(f"{name}() takes {positional} positional argument(s) but {1 + len(args)} were given{hint}")
        return function(require_curve("curve", curve), *args, **kwargs)

    return checked
