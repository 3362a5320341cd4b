"""The `Curve` pytree: validation of concrete input, dtype handling, pytree behaviour."""

from __future__ import annotations

import inspect

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import ddgjax.curves as dc
from ddgjax import DDGInputError
from ddgjax.curves import Curve, length

SQUARE = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])


def test_points_and_flags_are_kept():
    curve = Curve(SQUARE)
    assert curve.closed and curve.n_points == 4 and curve.n_edges == 4
    np.testing.assert_array_equal(curve.points, SQUARE)
    assert Curve(SQUARE, closed=False).n_edges == 3


def test_dtype_is_kept_and_integers_become_default_float():
    assert Curve(SQUARE.astype(np.float32)).points.dtype == jnp.float32
    assert Curve(SQUARE.astype(np.int64)).points.dtype == jnp.result_type(float)


@pytest.mark.parametrize(
    ("points", "closed", "match"),
    [
        (np.zeros((4, 3)), True, r"shape \(n, 2\)"),
        (np.zeros(8), True, r"shape \(n, 2\)"),
        (SQUARE.astype(np.complex128), True, "floating-point"),
        (SQUARE.astype(bool), True, "floating-point"),
        (SQUARE[:2], True, "closed curve needs at least 3 points, got 2"),
        (SQUARE[:1], False, "open curve needs at least 2 points, got 1"),
        (np.where(np.arange(4)[:, None] == 2, np.nan, SQUARE), True, r"NaN/inf at rows \[2\]"),
        (np.where(np.arange(4)[:, None] == 1, np.inf, SQUARE), True, r"NaN/inf at rows \[1\]"),
        (SQUARE[[0, 1, 1, 2, 3]], True, r"at i = \[1\]"),
        (np.vstack([SQUARE, SQUARE[:1]]), True, r"\(mod n\) at i = \[4\]"),
    ],
)
def test_bad_input_is_refused_with_a_clear_message(points, closed, match):
    with pytest.raises(DDGInputError, match=match):
        Curve(points, closed=closed)


def test_open_curve_may_end_where_it_starts():
    # Only consecutive points must differ; an open curve returning to its start is legitimate.
    Curve(np.vstack([SQUARE, SQUARE[:1]]), closed=False)


def test_closed_must_be_a_bool():
    # Under the suite's run-time type checking the annotation catches it first (a TypeError).
    with pytest.raises((DDGInputError, TypeError), match="closed"):
        Curve(SQUARE, closed="yes")


def test_pytree_has_one_leaf_and_closed_is_static():
    leaves, treedef = jax.tree.flatten(Curve(SQUARE, closed=False))
    assert len(leaves) == 1
    rebuilt = jax.tree.unflatten(treedef, [leaves[0] * 2])
    assert not rebuilt.closed
    np.testing.assert_array_equal(rebuilt.points, 2 * SQUARE)


def test_traced_points_are_not_checked():
    # Inside jit the coincident points cannot be seen; the functions must stay finite instead.
    duplicated = SQUARE[[0, 1, 1, 2, 3]]
    value = jax.jit(lambda P: length(Curve(P)))(duplicated)
    assert value == pytest.approx(4.0, abs=1e-15)


def test_with_points_checks_shape_and_finiteness():
    curve = Curve(SQUARE)
    moved = curve.with_points(SQUARE + 1)
    np.testing.assert_array_equal(moved.points, SQUARE + 1)
    assert moved.closed
    degenerate = curve.with_points(np.zeros((4, 2)))  # flows may hand back degenerate curves
    assert float(length(degenerate)) == 0.0
    with pytest.raises(DDGInputError, match=r"expected shape \(4, 2\), got \(3, 2\)"):
        curve.with_points(SQUARE[:3])
    bad = SQUARE.copy()
    bad[2, 1] = np.nan
    with pytest.raises(DDGInputError, match=r"NaN/inf at rows \[2\]"):
        curve.with_points(bad)
    # Traced points pass through; a NaN there propagates to the result instead of vanishing.
    assert np.isnan(jax.jit(lambda P: length(curve.with_points(P)))(bad))


def test_vmap_over_curves():
    batch = np.stack([SQUARE, 2 * SQUARE, 3 * SQUARE])
    np.testing.assert_allclose(jax.vmap(lambda P: length(Curve(P)))(batch), [4.0, 8.0, 12.0], rtol=1e-15)


@settings(max_examples=30, deadline=None)
@given(
    n=st.integers(3, 12),
    row=st.integers(0, 11),
    bad=st.sampled_from([np.nan, np.inf, -np.inf]),
    column=st.integers(0, 1),
)
def test_property_any_nonfinite_coordinate_is_named(n, row, bad, column):
    row = row % n
    points = np.stack([np.cos(np.arange(n)), np.sin(np.arange(n)) + np.arange(n)], axis=1)
    points[row, column] = bad
    with pytest.raises(DDGInputError, match=rf"rows \[{row}\]"):
        Curve(points)


@settings(max_examples=30, deadline=None)
@given(n=st.integers(3, 12), row=st.integers(0, 11))
def test_property_any_repeated_consecutive_point_is_named(n, row):
    row = row % n
    points = np.stack([np.cos(np.arange(n) * 0.5), np.sin(np.arange(n) * 0.5)], axis=1) * (1 + np.arange(n))[:, None]
    points[(row + 1) % n] = points[row]
    with pytest.raises(DDGInputError, match=rf"at i = \[{row}\]"):
        Curve(points)


# Every public function of ddgjax.curves that takes a curve, with the options it needs.
CURVE_FUNCTIONS = {
    "area_centroid": {},
    "centroid": {},
    "curvature": {"kind": "A"},
    "curvature_normals": {"kind": "A"},
    "curvature_vectors": {"kind": "A"},
    "curve_shortening_flow": {"kind": "B", "tau": 1e-3, "steps": 1},
    "cyclic_residual": {},
    "edge_lengths": {},
    "enclosed_area": {},
    "interior_vertex_mask": {},
    "is_simple": {},
    "isoperimetric_ratio": {},
    "length": {},
    "simplicity_and_clearance": {},
    "total_curvature": {},
    "turning_angles": {},
    "turning_number": {},
    "vertex_dual_lengths": {},
}


def test_the_list_of_curve_functions_is_complete():
    takes_a_curve = {
        name
        for name, value in vars(dc).items()
        if inspect.isfunction(value) and next(iter(inspect.signature(value).parameters), None) == "curve"
    }
    assert takes_a_curve == set(CURVE_FUNCTIONS)


@pytest.mark.parametrize("name", sorted(CURVE_FUNCTIONS))
@pytest.mark.parametrize(
    ("value", "given"),
    [
        (SQUARE, r"an array of shape \(4, 2\)"),
        (jnp.asarray(SQUARE), r"an array of shape \(4, 2\)"),
        ((SQUARE, True), "a tuple"),
        (SQUARE.tolist(), "a list"),
    ],
    ids=["numpy", "jax", "tuple", "list"],
)
def test_a_non_curve_is_refused_naming_the_argument(name, value, given):
    with pytest.raises(DDGInputError, match=rf"^curve: expected a ddgjax Curve, got {given}; .*Curve\(points, closed=True\)"):
        getattr(dc, name)(value, **CURVE_FUNCTIONS[name])


def test_a_non_curve_is_refused_under_jit():
    with pytest.raises(DDGInputError, match=r"curve: expected a ddgjax Curve, got an array of shape \(4, 2\)"):
        jax.jit(lambda P: length(P))(SQUARE)


def test_options_are_keyword_only():
    with pytest.raises(
        TypeError, match=r"curvature\(\) takes 1 positional argument.*curvature\(curve, kind=\.\.\., pointwise=\.\.\.\)"
    ):
        dc.curvature(Curve(SQUARE), "A")
    with pytest.raises(TypeError, match=r"curvature_normals\(\) takes 1 positional argument.*kind=\.\.\."):
        dc.curvature_normals(Curve(SQUARE), "A")


@pytest.mark.parametrize(
    "points, message",
    [
        (jnp.zeros((5, 3)), r"points: expected shape \(n, 2\), got \(5, 3\)"),
        (jnp.zeros(10), r"points: expected shape \(n, 2\), got \(10,\)"),
        (jnp.zeros((2, 2)), "points: a closed curve needs at least 3 points, got 2"),
        (jnp.zeros((4, 2), dtype=complex), "points: expected a real floating-point array, got dtype complex128"),
    ],
)
def test_bad_shapes_get_the_same_message_under_jit(points, message):
    with pytest.raises(DDGInputError, match=message):
        Curve(points)
    with pytest.raises(DDGInputError, match=message):
        jax.jit(lambda p: Curve(p).points)(points)
