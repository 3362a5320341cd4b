"""Edge lengths, turning angles, the four curvatures and their normals (ddgjax.curves._curvature)."""

from __future__ import annotations

import curvey
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from jax.test_util import check_grads

from ddgjax._errors import DDGInputError
from ddgjax.curves import (
    Curve,
    curvature,
    curvature_normals,
    curvature_vectors,
    edge_lengths,
    interior_vertex_mask,
    length,
    random_polygon,
    regular_polygon,
    total_curvature,
    turning_angles,
    turning_number,
    vertex_dual_lengths,
)

KINDS = ("A", "B", "C", "D")


@pytest.fixture(scope="module")
def wobbly():
    """Non-convex, unevenly spaced, counterclockwise."""
    return random_polygon(24, seed=7)


def _rotation(angle):
    return np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])


@pytest.mark.parametrize("n", [3, 7, 40])
def test_regular_polygon_closed_forms(n):
    r = 1.7
    curve = regular_polygon(n, radius=r, center=(0.3, -2.0))
    theta = 2 * np.pi / n
    expected = {"A": theta, "B": 2 * np.sin(theta / 2), "C": 2 * np.tan(theta / 2), "D": 1 / r}
    for kind, value in expected.items():
        np.testing.assert_allclose(curvature(curve, kind), value, rtol=1e-13)
    np.testing.assert_allclose(turning_angles(curve), theta, rtol=1e-13)
    np.testing.assert_allclose(edge_lengths(curve), 2 * r * np.sin(np.pi / n), rtol=1e-13)
    np.testing.assert_allclose(vertex_dual_lengths(curve), 2 * r * np.sin(np.pi / n), rtol=1e-13)
    inward = (np.array([0.3, -2.0]) - np.asarray(curve.points)) / r
    for kind in KINDS:  # bisector and circumradius coincide on a regular polygon: towards the centre
        np.testing.assert_allclose(curvature_normals(curve, kind), inward, atol=1e-13)
    # pointwise B of an equilateral polygon equals kappa_D exactly
    np.testing.assert_allclose(curvature(curve, "B", pointwise=True), 1 / r, rtol=1e-13)


def test_pointwise_curvatures_converge_to_one_over_r_with_rate_two():
    r = 0.8
    ns = np.array([16, 32, 64, 128, 256])
    for kind in ("A", "C"):
        errors = [abs(float(curvature(regular_polygon(int(n), radius=r), kind, pointwise=True)[0]) - 1 / r) for n in ns]
        rate = -np.polyfit(np.log(ns), np.log(errors), 1)[0]
        # (pi/n) / sin(pi/n) - 1 ~ (pi/n)^2 / 6: second order; the fit over 5 sizes is within 1%.
        assert rate == pytest.approx(2.0, abs=0.02), (kind, rate)


def test_natural_pointwise_and_integrated_forms(wobbly):
    dual = vertex_dual_lengths(wobbly)
    for kind in KINDS:
        natural = curvature(wobbly, kind)
        integrated = curvature(wobbly, kind, pointwise=False)
        pointwise = curvature(wobbly, kind, pointwise=True)
        np.testing.assert_allclose(natural, pointwise if kind == "D" else integrated, rtol=1e-15)
        np.testing.assert_allclose(integrated, pointwise * dual, rtol=1e-13)


def test_kinds_from_the_turning_angle(wobbly):
    theta = np.asarray(turning_angles(wobbly))
    P = np.asarray(wobbly.points)
    chord = np.linalg.norm(np.roll(P, -1, 0) - np.roll(P, 1, 0), axis=1)
    np.testing.assert_allclose(curvature(wobbly, "A"), theta, rtol=1e-15)
    np.testing.assert_allclose(curvature(wobbly, "B"), 2 * np.sin(theta / 2), rtol=1e-14)
    np.testing.assert_allclose(curvature(wobbly, "C"), 2 * np.tan(theta / 2), rtol=1e-14)
    np.testing.assert_allclose(curvature(wobbly, "D"), 2 * np.sin(theta) / chord, rtol=1e-13)
    assert (theta < 0).any() and (theta > 0).any()  # non-convex: reflex vertices have negative curvature


def test_kappa_d_is_inverse_circumradius_and_points_to_the_circumcentre(wobbly):
    P = np.asarray(wobbly.points)
    a, p, b = np.roll(P, 1, 0), P, np.roll(P, -1, 0)
    # circumcentre c solves 2 (p - a) . c = |p|^2 - |a|^2, 2 (b - a) . c = |b|^2 - |a|^2
    system = np.stack([2 * (p - a), 2 * (b - a)], axis=1)
    rhs = np.stack([np.sum(p * p - a * a, 1), np.sum(b * b - a * a, 1)], axis=1)
    centre = np.linalg.solve(system, rhs[..., None])[..., 0]
    to_centre = centre - p
    radius = np.linalg.norm(to_centre, axis=1)
    np.testing.assert_allclose(np.abs(curvature(wobbly, "D")), 1 / radius, rtol=1e-11)  # np.linalg.solve conditioning
    np.testing.assert_allclose(curvature_vectors(wobbly, "D"), to_centre / radius[:, None] ** 2, rtol=1e-10, atol=1e-12)


def test_normals_are_unit_and_on_the_left(wobbly):
    P = np.asarray(wobbly.points)
    travel = np.roll(P, -1, 0) - np.roll(P, 1, 0)
    for kind in KINDS:
        normals = np.asarray(curvature_normals(wobbly, kind))
        np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, rtol=1e-14)
        assert np.all(travel[:, 0] * normals[:, 1] - travel[:, 1] * normals[:, 0] > 0), kind


def test_length_gradient_is_minus_kappa_b_times_n(wobbly):
    for closed in (True, False):
        curve = Curve(wobbly.points, closed=closed)
        gradient = jax.grad(lambda P: length(Curve(P, closed=closed)))(curve.points)
        kappa_n = curvature(curve, "B")[:, None] * curvature_normals(curve, "B")
        inside = np.asarray(interior_vertex_mask(curve))
        np.testing.assert_allclose(gradient[inside], -kappa_n[inside], atol=1e-14)
        np.testing.assert_allclose(curvature_vectors(curve, "B"), kappa_n, atol=1e-15)
        if not closed:  # endpoints: the unit edge pointing away from the curve
            P = np.asarray(curve.points)
            np.testing.assert_allclose(gradient[0], (P[0] - P[1]) / np.linalg.norm(P[0] - P[1]), atol=1e-15)


@pytest.mark.parametrize("kind", KINDS)
def test_rigid_motion_and_scaling(wobbly, kind):
    P = np.asarray(wobbly.points)
    base = np.asarray(curvature(wobbly, kind))
    moved = Curve(P @ _rotation(0.7).T + np.array([3.0, -1.0]))
    np.testing.assert_allclose(curvature(moved, kind), base, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(
        curvature_normals(moved, kind), np.asarray(curvature_normals(wobbly, kind)) @ _rotation(0.7).T, atol=1e-13
    )
    s = 3.5
    scaled = np.asarray(curvature(Curve(s * P), kind))
    np.testing.assert_allclose(scaled, base / s if kind == "D" else base, rtol=1e-13, atol=1e-15)
    # reversing the orientation flips the sign of kappa, and of N, leaving kappa N unchanged
    reversed_curve = Curve(P[::-1])
    np.testing.assert_allclose(curvature(reversed_curve, kind)[::-1], -base, rtol=1e-13, atol=1e-15)
    np.testing.assert_allclose(
        curvature_vectors(reversed_curve, kind)[::-1], curvature_vectors(wobbly, kind), rtol=1e-12, atol=1e-14
    )


def test_against_curvey(wobbly):
    reference = curvey.Curve(np.asarray(wobbly.points))
    np.testing.assert_allclose(edge_lengths(wobbly), reference.edge_length, rtol=1e-15)
    np.testing.assert_allclose(length(wobbly), reference.length, rtol=1e-15)
    np.testing.assert_allclose(vertex_dual_lengths(wobbly), reference.dual_edge_length, rtol=1e-15)
    np.testing.assert_allclose(turning_angles(wobbly), reference.turning_angle, rtol=1e-14)
    # curvey's Curve.curvature is the pointwise turning-angle curvature
    np.testing.assert_allclose(curvature(wobbly, "A", pointwise=True), reference.curvature, rtol=1e-14)


def test_open_curve_endpoints(wobbly):
    curve = Curve(wobbly.points[:10], closed=False)
    mask = np.asarray(interior_vertex_mask(curve))
    assert not mask[0] and not mask[-1] and mask[1:-1].all()
    assert edge_lengths(curve).shape == (9,)
    dual = vertex_dual_lengths(curve)
    np.testing.assert_allclose(jnp.sum(dual), length(curve), rtol=1e-15)
    np.testing.assert_allclose(dual[0], edge_lengths(curve)[0] / 2, rtol=1e-15)
    closed_values = curvature(wobbly, "A")[1:9]
    for kind in KINDS:
        kappa = curvature(curve, kind)
        assert kappa[0] == 0 and kappa[-1] == 0
        assert np.all(np.asarray(curvature_normals(curve, kind))[[0, -1]] == 0)
    np.testing.assert_allclose(curvature(curve, "A")[1:-1], closed_values, rtol=1e-15)
    np.testing.assert_allclose(total_curvature(curve), jnp.sum(closed_values), rtol=1e-14)
    with pytest.raises(DDGInputError, match="closed curve"):
        turning_number(curve)


def test_turning_number_and_total_curvature(wobbly):
    assert int(turning_number(wobbly)) == 1
    assert float(total_curvature(wobbly)) == pytest.approx(2 * np.pi, abs=1e-13)
    assert int(turning_number(Curve(np.asarray(wobbly.points)[::-1]))) == -1
    t = np.linspace(0, 2 * np.pi, 40, endpoint=False)
    figure_eight = Curve(np.stack([np.sin(2 * t), np.sin(t)], axis=1))
    assert int(turning_number(figure_eight)) == 0
    double_loop = Curve(np.stack([np.cos(2 * t), np.sin(2 * t)], axis=1) * (1 + 0.1 * t)[:, None])
    assert int(turning_number(double_loop)) == 2


def test_collinear_and_reversing_vertices_stay_finite():
    # vertex 1 is collinear (kappa_D = 0, R = infinity); vertex 3 reverses direction exactly
    P = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [2.0, 1.0], [2.0, 0.5], [0.0, 1.0]])
    curve = Curve(P)
    for kind in KINDS:
        values = np.asarray(curvature(curve, kind))
        assert np.isfinite(values).all() and np.isfinite(np.asarray(curvature_normals(curve, kind))).all()
        assert values[1] == 0.0
    assert abs(float(turning_angles(curve)[3])) == pytest.approx(np.pi)
    # kappa N is continuous through the reversal: -kappa_A u/|u| with the limit normal
    np.testing.assert_allclose(curvature_vectors(curve, "A")[3], [0.0, -np.pi], atol=1e-15)


def test_coincident_points_give_finite_values_and_gradients_under_jit(wobbly):
    P = np.asarray(wobbly.points)
    duplicated = jnp.asarray(np.insert(P, 5, P[5], axis=0))
    for closed in (True, False):
        for kind in KINDS:
            for pointwise in (None, True, False):

                def total(points, kind=kind, pointwise=pointwise):
                    curve = Curve(points, closed=closed)
                    return jnp.sum(curvature(curve, kind, pointwise=pointwise) ** 2) + jnp.sum(
                        curvature_vectors(curve, kind) ** 2
                    )

                value, gradient = jax.jit(jax.value_and_grad(total))(duplicated)
                assert np.isfinite(value) and np.isfinite(np.asarray(gradient)).all(), (kind, pointwise, closed)
        gradient = jax.jit(jax.grad(lambda points: length(Curve(points, closed=closed)) + total_curvature(Curve(points, closed=closed))))(duplicated)
        assert np.isfinite(np.asarray(gradient)).all()


@pytest.mark.parametrize("kind", KINDS)
def test_gradients_match_finite_differences(wobbly, kind):
    weights = jnp.linspace(0.5, 1.5, wobbly.n_points)
    check_grads(lambda P: jnp.sum(weights * curvature(Curve(P), kind)), (wobbly.points,), order=2, modes=["rev", "fwd"])
    check_grads(lambda P: curvature_vectors(Curve(P), kind, pointwise=True), (wobbly.points,), order=1, modes=["rev"])


def test_jit_equals_eager_and_vmap(wobbly):
    batch = jnp.stack([wobbly.points, 2 * wobbly.points, wobbly.points @ jnp.asarray(_rotation(1.0)).T])
    for kind in KINDS:
        eager = curvature(wobbly, kind)
        np.testing.assert_array_equal(jax.jit(lambda P, kind=kind: curvature(Curve(P), kind))(wobbly.points), eager)
        batched = jax.vmap(lambda P, kind=kind: curvature(Curve(P), kind))(batch)
        for row, points in zip(batched, batch):
            np.testing.assert_allclose(row, curvature(Curve(points), kind), rtol=1e-14, atol=1e-15)


def test_bad_kind():
    with pytest.raises(DDGInputError, match="kind: expected one of 'A', 'B', 'C', 'D'"):
        curvature(regular_polygon(5), "E")


@settings(max_examples=25, deadline=None)
@given(n=st.integers(3, 30), seed=st.integers(0, 2**31 - 1))
def test_property_gauss_bonnet_and_dual_lengths(n, seed):
    # Any closed polygon (random points, self-intersecting or not): total curvature is 2 pi times an integer.
    points = np.random.default_rng(seed).normal(size=(n, 2))
    curve = Curve(points)
    total = float(total_curvature(curve))
    assert total == pytest.approx(2 * np.pi * int(turning_number(curve)), abs=1e-11)
    np.testing.assert_allclose(jnp.sum(vertex_dual_lengths(curve)), length(curve), rtol=1e-13)
    assert np.all(np.abs(np.asarray(turning_angles(curve))) <= np.pi)
