"""Edge lengths, turning angles, the four curvatures and their normals (ddgjax.curves._curvature)."""

from __future__ import annotations

import curvey
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ddgjax import DDGInputError
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

from finite_differences import central_difference

KINDS = ("A", "B", "C", "D")


@pytest.fixture(scope="module")
def wobbly():
    """Non-convex, unevenly spaced, counterclockwise."""
    return random_polygon(24, key=7)


@jax.jit
def summary(curve):
    """Every per-vertex quantity of a curve from one compiled program (compiling per function and shape is what costs time)."""
    out = {
        "edge_lengths": edge_lengths(curve),
        "dual": vertex_dual_lengths(curve),
        "theta": turning_angles(curve),
        "length": length(curve),
        "total": total_curvature(curve),
    }
    for kind in KINDS:
        out[kind] = curvature(curve, kind=kind)
        out[kind + "_pointwise"] = curvature(curve, kind=kind, pointwise=True)
        out[kind + "_integrated"] = curvature(curve, kind=kind, pointwise=False)
        out[kind + "_normals"] = curvature_normals(curve, kind=kind)
        out[kind + "_vectors"] = curvature_vectors(curve, kind=kind)
    return out


@pytest.fixture(scope="module")
def wobbly_summary(wobbly):
    return summary(wobbly)


def _rotation(angle):
    return np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])


@pytest.mark.parametrize("n", [3, 40])
@pytest.mark.slow
def test_regular_polygon_closed_forms(n):
    r = 1.7
    curve = regular_polygon(n, radius=r, center=(0.3, -2.0))
    values = summary(curve)
    theta = 2 * np.pi / n
    expected = {"A": theta, "B": 2 * np.sin(theta / 2), "C": 2 * np.tan(theta / 2), "D": 1 / r}
    for kind, value in expected.items():
        np.testing.assert_allclose(values[kind], value, rtol=1e-13)
    np.testing.assert_allclose(values["theta"], theta, rtol=1e-13)
    np.testing.assert_allclose(values["edge_lengths"], 2 * r * np.sin(np.pi / n), rtol=1e-13)
    np.testing.assert_allclose(values["dual"], 2 * r * np.sin(np.pi / n), rtol=1e-13)
    inward = (np.array([0.3, -2.0]) - np.asarray(curve.points)) / r
    for kind in KINDS:  # bisector and circumradius coincide on a regular polygon: towards the centre
        np.testing.assert_allclose(values[kind + "_normals"], inward, atol=1e-13)
    # pointwise B of an equilateral polygon equals kappa_D exactly
    np.testing.assert_allclose(values["B_pointwise"], 1 / r, rtol=1e-13)


@pytest.mark.slow
def test_pointwise_curvatures_converge_to_one_over_r_with_rate_two():
    r = 0.8
    ns = np.array([16, 32, 64, 128])
    pointwise = jax.jit(lambda curve: jnp.stack([curvature(curve, kind=kind, pointwise=True)[0] for kind in ("A", "C")]))
    errors = np.abs(np.array([pointwise(regular_polygon(int(n), radius=r)) for n in ns]) - 1 / r)
    rates = -np.polyfit(np.log(ns), np.log(errors), 1)[0]
    # A: (pi/n) / sin(pi/n) - 1 ~ (pi/n)^2 / 6, C: tan(pi/n) / (pi/n) ... second order; fit within 1%.
    np.testing.assert_allclose(rates, 2.0, atol=0.02)


def test_natural_pointwise_and_integrated_forms(wobbly_summary):
    dual = wobbly_summary["dual"]
    for kind in KINDS:
        natural = wobbly_summary[kind]
        integrated = wobbly_summary[kind + "_integrated"]
        pointwise = wobbly_summary[kind + "_pointwise"]
        np.testing.assert_allclose(natural, pointwise if kind == "D" else integrated, rtol=1e-15)
        np.testing.assert_allclose(integrated, pointwise * dual, rtol=1e-13)


def test_kinds_from_the_turning_angle(wobbly, wobbly_summary):
    theta = np.asarray(wobbly_summary["theta"])
    P = np.asarray(wobbly.points)
    chord = np.linalg.norm(np.roll(P, -1, 0) - np.roll(P, 1, 0), axis=1)
    np.testing.assert_allclose(curvature(wobbly, kind="A"), theta, rtol=1e-15)  # the public call, as users make it
    np.testing.assert_allclose(wobbly_summary["B"], 2 * np.sin(theta / 2), rtol=1e-14)
    np.testing.assert_allclose(wobbly_summary["C"], 2 * np.tan(theta / 2), rtol=1e-14)
    np.testing.assert_allclose(wobbly_summary["D"], 2 * np.sin(theta) / chord, rtol=1e-13)
    assert (theta < 0).any() and (theta > 0).any()  # non-convex: reflex vertices have negative curvature


def test_kappa_d_is_inverse_circumradius_and_points_to_the_circumcentre(wobbly, wobbly_summary):
    P = np.asarray(wobbly.points)
    a, p, b = np.roll(P, 1, 0), P, np.roll(P, -1, 0)
    # circumcentre c solves 2 (p - a) . c = |p|^2 - |a|^2, 2 (b - a) . c = |b|^2 - |a|^2
    system = np.stack([2 * (p - a), 2 * (b - a)], axis=1)
    rhs = np.stack([np.sum(p * p - a * a, 1), np.sum(b * b - a * a, 1)], axis=1)
    centre = np.linalg.solve(system, rhs[..., None])[..., 0]
    to_centre = centre - p
    radius = np.linalg.norm(to_centre, axis=1)
    # np.linalg.solve on nearly flat triangles (large R) limits the reference to ~1e-11
    np.testing.assert_allclose(np.abs(wobbly_summary["D"]), 1 / radius, rtol=1e-11)
    np.testing.assert_allclose(wobbly_summary["D_vectors"], to_centre / radius[:, None] ** 2, rtol=1e-10, atol=1e-12)


def test_normals_are_unit_and_on_the_left(wobbly, wobbly_summary):
    P = np.asarray(wobbly.points)
    travel = np.roll(P, -1, 0) - np.roll(P, 1, 0)
    for kind in KINDS:
        normals = np.asarray(wobbly_summary[kind + "_normals"])
        np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, rtol=1e-14)
        assert np.all(travel[:, 0] * normals[:, 1] - travel[:, 1] * normals[:, 0] > 0), kind


@pytest.mark.slow
def test_length_gradient_is_minus_kappa_b_times_n(wobbly):
    for closed in (True, False):
        curve = Curve(wobbly.points, closed=closed)
        gradient = jax.jit(jax.grad(lambda P, closed=closed: length(Curve(P, closed=closed))))(curve.points)
        values = summary(curve)
        kappa_n = values["B"][:, None] * values["B_normals"]
        inside = np.asarray(interior_vertex_mask(curve))
        np.testing.assert_allclose(gradient[inside], -kappa_n[inside], atol=1e-14)
        np.testing.assert_allclose(values["B_vectors"], kappa_n, atol=1e-15)
        if not closed:  # endpoints: the unit edge pointing away from the curve
            P = np.asarray(curve.points)
            np.testing.assert_allclose(gradient[0], (P[0] - P[1]) / np.linalg.norm(P[0] - P[1]), atol=1e-15)


def test_rigid_motion_and_scaling(wobbly, wobbly_summary):
    P = np.asarray(wobbly.points)
    s = 3.5
    moved = summary(Curve(P @ _rotation(0.7).T + np.array([3.0, -1.0])))
    scaled = summary(Curve(s * P))
    reversed_ = summary(Curve(P[::-1]))
    for kind in KINDS:
        base = np.asarray(wobbly_summary[kind])
        # rotation by 0.7 rad costs a few ulps of the coordinates
        np.testing.assert_allclose(moved[kind], base, rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(
            moved[kind + "_normals"], np.asarray(wobbly_summary[kind + "_normals"]) @ _rotation(0.7).T, atol=1e-13
        )
        np.testing.assert_allclose(scaled[kind], base / s if kind == "D" else base, rtol=1e-13, atol=1e-15)
        # reversing the orientation flips the sign of kappa, and of N, leaving kappa N unchanged
        np.testing.assert_allclose(reversed_[kind][::-1], -base, rtol=1e-13, atol=1e-15)
        np.testing.assert_allclose(reversed_[kind + "_vectors"][::-1], wobbly_summary[kind + "_vectors"], rtol=1e-12, atol=1e-14)


@pytest.mark.filterwarnings("ignore:Arrays of 2-dimensional vectors:DeprecationWarning")  # inside curvey
def test_against_curvey(wobbly, wobbly_summary):
    reference = curvey.Curve(np.asarray(wobbly.points))
    np.testing.assert_allclose(wobbly_summary["edge_lengths"], reference.edge_length, rtol=1e-15)
    np.testing.assert_allclose(wobbly_summary["length"], reference.length, rtol=1e-15)
    np.testing.assert_allclose(wobbly_summary["dual"], reference.dual_edge_length, rtol=1e-15)
    np.testing.assert_allclose(wobbly_summary["theta"], reference.turning_angle, rtol=1e-14)
    # curvey's Curve.curvature is the pointwise turning-angle curvature
    np.testing.assert_allclose(wobbly_summary["A_pointwise"], reference.curvature, rtol=1e-14)


def test_open_curve_endpoints(wobbly, wobbly_summary):
    curve = Curve(wobbly.points[:10], closed=False)
    values = summary(curve)
    mask = np.asarray(interior_vertex_mask(curve))
    assert not mask[0] and not mask[-1] and mask[1:-1].all()
    assert values["edge_lengths"].shape == (9,)
    dual = values["dual"]
    np.testing.assert_allclose(jnp.sum(dual), values["length"], rtol=1e-15)
    np.testing.assert_allclose(dual[0], values["edge_lengths"][0] / 2, rtol=1e-15)
    for kind in KINDS:
        for key in (kind, kind + "_pointwise", kind + "_normals", kind + "_vectors"):
            assert np.all(np.asarray(values[key])[[0, -1]] == 0), key
        np.testing.assert_allclose(values[kind][1:-1], wobbly_summary[kind][1:9], rtol=1e-14)
    np.testing.assert_allclose(values["total"], jnp.sum(wobbly_summary["A"][1:9]), rtol=1e-14)
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


@pytest.mark.slow
def test_collinear_and_reversing_vertices_stay_finite():
    # vertex 1 is collinear (kappa_D = 0, R = infinity); vertex 3 reverses direction exactly
    P = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [2.0, 1.0], [2.0, 0.5], [0.0, 1.0]])
    values = summary(Curve(P))
    for kind in KINDS:
        assert np.isfinite(np.asarray(values[kind])).all() and np.isfinite(np.asarray(values[kind + "_normals"])).all()
        assert values[kind][1] == 0.0
    assert abs(float(values["theta"][3])) == pytest.approx(np.pi, rel=1e-15)
    # kappa N is continuous through the reversal: -kappa_A u/|u| with the limit normal
    np.testing.assert_allclose(values["A_vectors"][3], [0.0, -np.pi], atol=1e-15)


def _curve_energy(points, closed=True):
    """A scalar touching every curvature, normal and form, for gradient checks."""
    curve = Curve(points, closed=closed)
    weights = jnp.linspace(0.5, 1.5, points.shape[0])
    total = length(curve) + total_curvature(curve) + jnp.sum(weights * curvature(curve, kind="A", pointwise=True) ** 2)
    for kind in KINDS:
        total = (
            total
            + jnp.sum(weights * curvature(curve, kind=kind))
            + jnp.sum(weights[:, None] * curvature_vectors(curve, kind=kind))
        )
    return total


# One compiled value-and-gradient of the energy per `closed`, shared by the tests below.
_energy_value_and_grad = jax.jit(jax.value_and_grad(_curve_energy), static_argnums=1)


@pytest.mark.slow
def test_coincident_points_give_finite_values_and_gradients_under_jit(wobbly):
    duplicated = np.asarray(wobbly.points).copy()
    duplicated[6] = duplicated[5]  # same size as wobbly: the closed program is the gradient test's
    for closed in (True, False):
        value, gradient = _energy_value_and_grad(jnp.asarray(duplicated), closed)  # a NaN in any term survives the sums
        assert np.isfinite(float(value)) and np.isfinite(np.asarray(gradient)).all()


# rtol: central differences are good to ~1e-10 relative here (the docstring)
def assert_matches_central_differences(f, derivative, x, *, eps=1e-6, rtol=1e-7, directions=4):
    """`derivative(x, v)` against `(f(x + eps v) - f(x - eps v)) / (2 eps)` along random directions.

    What `jax.test_util.check_grads` does, with every function jitted once (check_grads runs the
    VJP op by op, which on these programs costs tens of seconds). Central differences are accurate
    to ~eps^2 |third derivative| + ulp / eps, about 1e-10 relative here, hence rtol 1e-7.
    """
    rng = np.random.default_rng(0)
    for _ in range(directions):
        v = jnp.asarray(rng.normal(size=x.shape))
        numeric = central_difference(f, x, v, eps)
        np.testing.assert_allclose(derivative(x, v), numeric, rtol=rtol, atol=rtol * np.max(np.abs(numeric)))


@pytest.mark.slow
def test_gradients_match_finite_differences(wobbly):
    # first and second derivatives (a Newton step on a curve energy needs the Hessian)
    assert_matches_central_differences(
        lambda x: _energy_value_and_grad(x, True)[0],
        lambda x, v: jnp.sum(_energy_value_and_grad(x, True)[1] * v),
        wobbly.points,
    )

    def bending(P):  # a smaller energy for the Hessian check (second derivatives compile slowly)
        return length(Curve(P)) + jnp.sum(curvature(Curve(P), kind="A") ** 2)

    # gradient and Hessian-vector product from one compiled program
    gradient_and_hessian_times = jax.jit(lambda x, v: jax.jvp(jax.grad(bending), (x,), (v,)))
    zero = jnp.zeros_like(wobbly.points)
    assert_matches_central_differences(
        lambda x: gradient_and_hessian_times(x, zero)[0], lambda x, v: gradient_and_hessian_times(x, v)[1], wobbly.points
    )


@pytest.mark.slow
def test_jit_equals_eager_and_vmap(wobbly, wobbly_summary):
    batch = jnp.stack([wobbly.points, 2 * wobbly.points])
    with jax.disable_jit():
        eager = curvature(wobbly, kind="A")
    np.testing.assert_allclose(wobbly_summary["A"], eager, rtol=1e-14, atol=1e-16)  # XLA fusion reorders a few operations
    batched = jax.vmap(lambda P: curvature_vectors(Curve(P), kind="D"))(batch)  # the idiom from the docs
    np.testing.assert_allclose(batched[0], wobbly_summary["D_vectors"], rtol=1e-14, atol=1e-15)
    np.testing.assert_allclose(batched[1], wobbly_summary["D_vectors"] / 2, rtol=1e-14, atol=1e-15)


def test_bad_kind():
    with pytest.raises(DDGInputError, match="kind: expected one of 'A', 'B', 'C', 'D'"):
        curvature(regular_polygon(5), kind="E")


@jax.jit
def _identities(points):
    curve = Curve(points)
    return (
        total_curvature(curve),
        turning_number(curve),
        jnp.sum(vertex_dual_lengths(curve)),
        length(curve),
        turning_angles(curve),
    )


@settings(max_examples=25, deadline=None)
@given(n=st.sampled_from([3, 11]), seed=st.integers(0, 2**31 - 1))
def test_property_gauss_bonnet_and_dual_lengths(n, seed):
    # Any closed polygon (random points, self-intersecting or not): total curvature is 2 pi times an integer.
    points = np.random.default_rng(seed).normal(size=(n, 2))
    total, number, dual, size, angles = _identities(Curve(points).points)
    assert float(total) == pytest.approx(2 * np.pi * int(number), abs=1e-11)
    assert float(dual) == pytest.approx(float(size), rel=1e-13)
    assert np.all(np.abs(np.asarray(angles)) <= np.pi)
