"""Centroids, enclosed area, isoperimetric ratio, cyclic residual and simplicity (ddgjax.curves._invariants)."""

from __future__ import annotations

import curvey
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import shapely
from hypothesis import given, settings
from hypothesis import strategies as st

from ddgjax.curves import (
    Curve,
    area_centroid,
    centroid,
    cyclic_residual,
    enclosed_area,
    is_simple,
    isoperimetric_ratio,
    random_polygon,
    regular_polygon,
    simplicity_and_clearance,
    star,
)
from ddgjax.curves._invariants import NEAR_EDGES, near_and_far_clearances

from finite_differences import central_difference


@jax.jit
def invariants(curve):
    """All invariants from one compiled program per shape."""
    return {
        "centroid": centroid(curve),
        "area_centroid": area_centroid(curve),
        "area": enclosed_area(curve),
        "ratio": isoperimetric_ratio(curve),
        "residual": cyclic_residual(curve),
        "simple": is_simple(curve),
    }


@pytest.fixture(scope="module")
def wobbly():
    return random_polygon(24, key=7)


def test_regular_polygon_closed_forms():
    n, r = 9, 1.3
    values = invariants(regular_polygon(n, radius=r, center=(2.0, -1.0)))
    np.testing.assert_allclose(values["area"], 0.5 * n * r**2 * np.sin(2 * np.pi / n), rtol=1e-14)
    np.testing.assert_allclose(values["ratio"], np.pi / (n * np.tan(np.pi / n)), rtol=1e-14)
    np.testing.assert_allclose(values["centroid"], [2.0, -1.0], rtol=1e-15)
    np.testing.assert_allclose(values["area_centroid"], [2.0, -1.0], rtol=1e-14)
    assert float(values["residual"]) < 1e-15 and bool(values["simple"])


def test_against_curvey(wobbly):
    reference = curvey.Curve(np.asarray(wobbly.points))
    values = invariants(wobbly)
    np.testing.assert_allclose(values["area"], reference.signed_area, rtol=1e-14)
    np.testing.assert_allclose(values["area_centroid"], reference.centroid, rtol=1e-13, atol=1e-15)
    np.testing.assert_allclose(values["centroid"], reference.center, rtol=1e-14, atol=1e-16)
    np.testing.assert_allclose(values["ratio"], 1 / reference.roundness, rtol=1e-14)
    assert bool(values["simple"]) == reference.is_simple is True


def test_orientation_sign_and_motions(wobbly):
    P = np.asarray(wobbly.points)
    base = invariants(wobbly)
    rotation = np.array([[np.cos(1.1), -np.sin(1.1)], [np.sin(1.1), np.cos(1.1)]])
    moved = invariants(Curve(2.5 * P @ rotation.T + np.array([10.0, 4.0])))
    np.testing.assert_allclose(moved["area"], 2.5**2 * base["area"], rtol=1e-13)
    for key in ("ratio", "residual"):  # scale and rigid-motion invariant
        np.testing.assert_allclose(moved[key], base[key], rtol=1e-12)
    np.testing.assert_allclose(
        moved["area_centroid"], 2.5 * rotation @ np.asarray(base["area_centroid"]) + [10.0, 4.0], rtol=1e-13
    )
    flipped = invariants(Curve(P[::-1]))
    np.testing.assert_allclose(flipped["area"], -base["area"], rtol=1e-14)
    np.testing.assert_allclose(flipped["ratio"], base["ratio"], rtol=1e-14)


def test_cyclic_residual_zero_on_a_circle_positive_elsewhere(wobbly):
    angles = np.sort(np.random.default_rng(3).uniform(0, 2 * np.pi, 24))  # uneven: cyclic, not regular
    cyclic = Curve(np.array([5.0, -3.0]) + 0.01 * np.stack([np.cos(angles), np.sin(angles)], axis=1))
    values = invariants(cyclic)
    assert float(values["residual"]) < 1e-12  # relative to radius 0.01 at centre distance 5.8: ~1e-13 cancellation
    assert float(invariants(wobbly)["residual"]) > 0.05
    half_circle = Curve(np.stack([np.cos(angles / 2), np.sin(angles / 2)], axis=1), closed=False)
    assert float(cyclic_residual(half_circle)) < 1e-14  # a fit to an arc finds the whole circle


def test_open_curves_are_closed_by_their_chord(wobbly):
    curve = Curve(wobbly.points, closed=False)
    values = invariants(curve)
    closed = invariants(wobbly)
    for key in ("area", "area_centroid", "ratio"):
        np.testing.assert_allclose(values[key], closed[key], rtol=1e-14)
    square = Curve(np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]), closed=False)
    assert float(enclosed_area(square)) == pytest.approx(1.0, rel=1e-15)


@pytest.mark.parametrize(
    ("points", "closed", "simple"),
    [
        ([[0, 0], [1, 0], [1, 1], [0, 1]], True, True),
        ([[0, 0], [1, 1], [1, 0], [0, 1]], True, False),  # bow tie
        ([[0, 0], [1, 1], [1, 0], [0, 1]], False, False),
        ([[0, 0], [1, 0], [1, 1], [0, 1]], False, True),
        ([[0, 0], [2, 0], [2, 1], [1, 0], [0, 1]], True, False),  # vertex touching an edge
        ([[0, 0], [2, 0], [1, 0], [1, 1]], True, False),  # folds back along itself
        ([[0, 0], [1, 0], [1, 1], [0, 0], [-1, 1], [-1, 0]], True, False),  # repeated vertex, non-adjacent
        ([[0, 0], [1, 0], [2, 0], [1, 1]], True, True),  # collinear consecutive edges are fine
        ([[0, 0], [1, 0], [0.5, 1]], True, True),
        # vertex on a diagonal edge, up to the rounding of 1/3: touching (exact predicates would miss it)
        ([[0, 0], [3, 1], [3, 2], [1, 1 / 3], [0, 2]], True, False),
    ],
)
@pytest.mark.slow
def test_is_simple_cases(points, closed, simple):
    assert bool(is_simple(Curve(np.asarray(points, dtype=float), closed=closed))) is simple


@pytest.mark.parametrize("kwargs", [{}, {"tips": 7, "inner_radius": 0.2, "outer_radius": 3.0, "subdivisions": 16}])
def test_is_simple_on_straight_sides_with_rounding(kwargs):
    # Regression: disjoint edges on one straight side of star() (e.g. edges 16 and 23 of the
    # default star) are collinear only up to rounding, so the exact orientation products had tiny
    # opposite signs and the pair was reported as crossing.
    curve = star(**kwargs)
    assert bool(is_simple(curve))
    # the same side with its last vertex pushed onto an earlier edge of that side: touching
    points = np.asarray(curve.points).copy()
    side = points[16:25].copy()
    points[23] = 0.5 * (side[1] + side[2])
    assert not bool(is_simple(Curve(points)))


def test_is_simple_agrees_with_shapely_on_random_polygons():
    rng = np.random.default_rng(11)
    simple_fn = jax.jit(jax.vmap(lambda P: is_simple(Curve(P))))
    batch = rng.normal(size=(200, 7, 2))
    batch[:100] = np.asarray(random_polygon(7, key=1).points) + 0.15 * rng.normal(size=(100, 7, 2))
    ours = np.asarray(simple_fn(batch))
    reference = np.array([curvey.Curve(P).is_simple for P in batch])
    np.testing.assert_array_equal(ours, reference)
    assert 0 < ours.sum() < len(ours)  # both outcomes are exercised


@pytest.mark.slow
def test_degenerate_input_is_finite_with_finite_gradients_under_jit(wobbly):
    P = np.asarray(wobbly.points)

    def total(points):
        values = invariants(Curve(points))
        return sum(jnp.sum(v) for k, v in values.items() if k != "simple")

    value_and_grad = jax.jit(jax.value_and_grad(total))
    # a repeated point, all points coincident (zero area, zero length), all points collinear
    for points in (np.insert(P, 3, P[3], axis=0), np.zeros((25, 2)), np.stack([np.arange(25.0), np.zeros(25)], axis=1)):
        value, gradient = value_and_grad(jnp.asarray(points))
        assert np.isfinite(float(value)) and np.isfinite(np.asarray(gradient)).all()


@pytest.mark.slow
def test_gradients_against_closed_forms(wobbly):
    P = np.asarray(wobbly.points)
    # d(area)/dp_i = (1/2) J^T (p_{i+1} - p_{i-1}) with J the 90-degree rotation
    chord = np.roll(P, -1, 0) - np.roll(P, 1, 0)
    np.testing.assert_allclose(
        jax.grad(lambda Q: enclosed_area(Curve(Q)))(wobbly.points),
        0.5 * np.stack([chord[:, 1], -chord[:, 0]], 1),
        rtol=1e-14,
        atol=1e-16,
    )
    np.testing.assert_allclose(
        jax.grad(lambda Q: centroid(Curve(Q))[0])(wobbly.points), np.stack([np.full(24, 1 / 24), np.zeros(24)], 1), rtol=1e-15
    )
    # the cyclic residual is differentiable: compare a directional derivative with central differences
    f = jax.jit(lambda Q: cyclic_residual(Curve(Q)) + isoperimetric_ratio(Curve(Q)) + jnp.sum(area_centroid(Curve(Q))))
    v = jnp.asarray(np.random.default_rng(0).normal(size=P.shape))
    numeric = central_difference(f, wobbly.points, v)
    # Central differences with step 1e-6: truncation ~1e-12 and round-off ~1e-16 |f| / 1e-6 (measured 1.5e-9).
    np.testing.assert_allclose(jnp.sum(jax.jit(jax.grad(f))(wobbly.points) * v), numeric, rtol=1e-7)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), scale=st.floats(1e-3, 1e3), angle=st.floats(0, 2 * np.pi))
def test_property_invariance(seed, scale, angle):
    P = np.random.default_rng(seed).normal(size=(9, 2))
    rotation = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    base, moved = invariants(Curve(P)), invariants(Curve(scale * P @ rotation.T + 3.0))
    np.testing.assert_allclose(moved["area"], scale**2 * base["area"], rtol=1e-11, atol=1e-12 * scale**2)
    # The shift by 3 at scale 1e-3 leaves ~1e3 x the rotation's round-off in the points (measured over 400 draws:
    # 1.9e-11 for the ratio, whose area cancels, and 6e-13 for the residual).
    np.testing.assert_allclose(moved["ratio"], base["ratio"], rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(moved["residual"], base["residual"], rtol=1e-10, atol=1e-12)
    assert bool(moved["simple"]) == bool(base["simple"])


@pytest.mark.slow
def test_clearance_against_shapely():
    for curve in (star(), random_polygon(30, key=2), Curve(np.asarray(star().points)[:12], closed=False)):
        simple, clearance = simplicity_and_clearance(curve)
        points = np.asarray(curve.points)
        n, m = len(points), curve.n_edges
        edges = [shapely.LineString([points[i], points[(i + 1) % n]]) for i in range(m)]
        expected = np.inf
        for i in range(m):
            for j in range(i + 1, m):
                if j == i + 1:  # adjacent: only the far endpoints count
                    gap = min(shapely.Point(points[(j + 1) % n]).distance(edges[i]), shapely.Point(points[i]).distance(edges[j]))
                elif curve.closed and i == 0 and j == m - 1:
                    gap = min(shapely.Point(points[j]).distance(edges[i]), shapely.Point(points[1]).distance(edges[j]))
                else:
                    gap = edges[i].distance(edges[j])
                expected = min(expected, gap)
        assert bool(simple)
        np.testing.assert_allclose(clearance, expected, rtol=1e-12)


def test_near_and_far_clearances_split_by_distance_along_the_curve():
    curve = random_polygon(24, key=2)
    points = np.asarray(curve.points)
    n = len(points)
    edges = [shapely.LineString([points[i], points[(i + 1) % n]]) for i in range(n)]
    near = far = np.inf
    for i in range(n):
        for j in range(i + 1, n):
            apart = min(j - i, n - (j - i))
            if apart == 1:  # adjacent: the far endpoints only
                a, b = (i, j) if j == i + 1 else (j, i)  # edge b follows edge a
                gap = min(shapely.Point(points[(b + 1) % n]).distance(edges[a]), shapely.Point(points[a]).distance(edges[b]))
            else:
                gap = edges[i].distance(edges[j])
            if apart <= NEAR_EDGES:
                near = min(near, gap)
            else:
                far = min(far, gap)
    simple, ours_near, ours_far = near_and_far_clearances(curve)
    assert bool(simple)
    np.testing.assert_allclose([ours_near, ours_far], [near, far], rtol=1e-12)


@pytest.mark.slow
def test_clearance_gradient_matches_finite_differences_and_stays_finite():
    curve = random_polygon(16, key=3)
    clearance = jax.jit(lambda P: simplicity_and_clearance(Curve(P))[1])
    P = curve.points
    v = jnp.asarray(np.random.default_rng(1).normal(size=P.shape))
    numeric = central_difference(clearance, P, v)
    # central differences of a piecewise-smooth min: ~1e-10 relative away from kinks (measured 4.8e-10)
    np.testing.assert_allclose(jnp.sum(jax.grad(clearance)(P) * v), numeric, rtol=1e-8)
    # a repeated vertex: clearance 0, gradient finite
    touching = jnp.asarray(np.insert(np.asarray(P), 3, np.asarray(P)[3], axis=0))
    assert float(clearance(touching)) == 0.0
    assert np.isfinite(np.asarray(jax.grad(clearance)(touching))).all()
