"""Curve-shortening flows: the reading report's claims (Figure 3) as measurements, plus solver properties."""

from __future__ import annotations

import math

import curvey
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import shapely
from curvey.flow import CurveShorteningFlow

from ddgjax import DDGInputError
from ddgjax.curves import (
    RESULTS,
    Curve,
    curvature_vectors,
    curve_shortening_flow,
    edge_lengths,
    enclosed_area,
    flower,
    length,
    random_polygon,
    star,
    turning_angles,
)
from ddgjax.curves._flow_step import _explicit_step, _flow_weights, _semi_implicit_step

from finite_differences import central_difference


@pytest.fixture(scope="module")
def polygon():
    """Non-convex, unevenly spaced random polygon (40 vertices, shortest edge ~0.06)."""
    return random_polygon(40, key=1)


# The report's claims are measured on non-convex random polygons (no symmetry to help) and on two
# simple symmetric shapes. All have 40 vertices, so each flow compiles once.
SHAPES = {
    "random-1": lambda: random_polygon(40, key=1),
    "random-5": lambda: random_polygon(40, key=5),
    "random-11": lambda: random_polygon(40, key=11, amplitude=0.5),
    "flower": lambda: flower(40),
    "star": lambda: star(5, inner_radius=0.5, subdivisions=4),
}
RANDOM_SHAPES = ("random-1", "random-5", "random-11")


@pytest.fixture(scope="module", params=list(SHAPES))
def shape_runs(request):
    """The report's three flows to their limit shapes, rescaled to the initial area so they do not collapse.

    Rescaling is about the vertex centroid, so it changes neither the centroid nor the total curvature
    nor the cyclic residual: every conservation law below is the flow's own. Time steps are a tenth
    (A, B) and a half (D) of the explicit stability limits (`tau < l/2` for A, B; `tau < l^2/4` for
    D; `l` the shortest edge). A and B run to about the time of least rescaled length: beyond it the
    integrated flows bunch the vertices and the rescaled length grows again (measured, e.g. 0.83 ->
    0.98 of the initial length on random-5 at 5x this time), so they are not run to a limit shape.
    `throw=False`: the A and B flows self-intersect for a moment (`test_no_flow_guarantees_simplicity`).
    """
    curve = SHAPES[request.param]()
    shortest = float(jnp.min(edge_lengths(curve)))
    tau_d = shortest**2 / 8
    steps_d = 1000 * math.ceil(8 / tau_d / 1000)  # the D flow runs to time 8
    settings = {"A": (shortest / 20, 1000), "B": (shortest / 20, 1000), "D": (tau_d, steps_d)}
    runs = {
        kind: curve_shortening_flow(curve, kind=kind, tau=tau, steps=steps, save_every=steps // 10, rescale="area", throw=False)
        for kind, (tau, steps) in settings.items()
    }
    return request.param, curve, runs


def test_saved_states_and_times(shape_runs):
    name, curve, runs = shape_runs
    result = runs["A"]
    assert result.points.shape == (11, 40, 2)
    np.testing.assert_array_equal(result.steps, 100 * np.arange(11))
    np.testing.assert_allclose(result.times, result.tau * 100 * np.arange(11), rtol=1e-15)
    np.testing.assert_array_equal(result.points[0], curve.points)
    assert bool(jnp.any(turning_angles(curve) < 0)), f"{name} should be non-convex"
    for run in runs.values():
        assert bool(run.result != RESULTS.nonfinite) and np.all(np.asarray(run.is_simple))
        # rescale="area" holds |A| at its initial value; the length falls (curve shortening)
        np.testing.assert_allclose(run.area, run.area[0], rtol=1e-12)
        assert float(run.length[-1]) < 0.9 * float(run.length[0])


def test_a_flow_keeps_total_curvature(shape_runs):
    _, _, runs = shape_runs
    np.testing.assert_allclose(runs["A"].total_curvature, 2 * np.pi, rtol=1e-14)


def test_b_flow_keeps_the_vertex_centroid(shape_runs):
    _, _, runs = shape_runs
    drift = np.abs(np.asarray(runs["B"].centroid) - np.asarray(runs["B"].centroid[0])).max()
    assert drift < 1e-13  # round-off over 1,000 steps (measured <= 1e-15)


def test_d_flow_tends_to_a_cyclic_polygon(shape_runs):
    _, _, runs = shape_runs
    residual = np.asarray(runs["D"].cyclic_residual)
    assert residual[-1] < 1e-3 * residual[0]  # measured: 0.2-0.26 -> 3e-9 to 5e-8 (random), 1e-15 (flower, star)
    converging = residual[residual > 1e-12]  # symmetric shapes reach round-off, where it jitters
    assert np.all(np.diff(converging) < 0)  # monotone along the saved states


def test_no_flow_keeps_all_three(shape_runs):
    name, _, runs = shape_runs
    if name not in RANDOM_SHAPES:
        # A symmetric shape keeps its centroid under every flow (by symmetry): the test needs no symmetry.
        # Round-off over 3,000-4,000 steps: measured <= 8e-15.
        assert np.abs(np.asarray(runs["D"].centroid[-1]) - np.asarray(runs["D"].centroid[0])).max() < 1e-12
        return

    def drift(run):
        return np.abs(np.asarray(run.centroid[-1]) - np.asarray(run.centroid[0])).max()

    # A: keeps the turning number but moves the centroid (unequal spacing) and does not become cyclic
    # (drifts measured 1.7e-4 and up, eleven orders above the B-flow's round-off; residuals 0.038 and up)
    assert drift(runs["A"]) > 1e-5 and float(runs["A"].cyclic_residual[-1]) > 0.03
    # B: keeps the centroid but does not become cyclic (measured 2e6x to 1e7x the D-flow's residual)
    assert float(runs["B"].cyclic_residual[-1]) > 100 * float(runs["D"].cyclic_residual[-1])
    # D: becomes cyclic but moves the centroid
    assert drift(runs["D"]) > 1e-3


@pytest.mark.slow
def test_no_flow_guarantees_simplicity(shape_runs):
    """The report: "none of the flows can guarantee that the polygonal curve stays simple".

    Measured: the integrated A and B flows self-intersect for a moment on the random polygons and the
    star (a short edge collapses and its end vertices pass through each other, see
    `test_b_flow_shrinks_every_edge_at_a_length_free_rate`), at the same flow time whatever `tau`; the
    saved states before and after are simple, so only the every-step tracking sees it. The D flow
    and the symmetric, evenly spaced flower stay simple.
    """
    name, curve, runs = shape_runs
    assert bool(runs["D"].result == RESULTS.successful)
    assert int(runs["D"].first_failure_step) == int(runs["D"].steps[-1]) + 1  # "after the run"
    for kind in "AB":
        run = runs[kind]
        first = int(run.first_failure_step)
        if name == "flower":
            assert bool(run.result == RESULTS.successful) and first == int(run.steps[-1]) + 1
            continue
        assert bool(run.result == RESULTS.self_intersection), (name, kind)
        assert 0 < first <= int(run.steps[-1]), (name, kind)
        # Independent confirmation with shapely (exact predicates) on the states around that step.
        around = curve_shortening_flow(
            curve, kind=kind, tau=run.tau, steps=first + 1, save_every=1, rescale="area", check_simple="saved", throw=False
        ).points
        assert shapely.LinearRing(np.asarray(around[first - 1])).is_simple
        assert not shapely.LinearRing(np.asarray(around[first])).is_simple


def test_b_flow_shrinks_every_edge_at_a_length_free_rate(polygon):
    # d|e_i|/dt = t_i . (t_{i+1} - 2 t_i + t_{i-1}) = cos(theta_i) + cos(theta_{i+1}) - 2 under
    # dp/dt = kappa^B N = t_i - t_{i-1}: independent of |e_i|, so the shortest edges at the corners
    # reach zero length in finite time (the collapse behind the transient self-intersections).
    velocity = curvature_vectors(polygon, kind="B")
    _, rate = jax.jvp(lambda P: edge_lengths(Curve(P)), (polygon.points,), (velocity,))
    theta = turning_angles(polygon)
    np.testing.assert_allclose(rate, np.cos(theta) + np.cos(np.roll(theta, -1)) - 2, rtol=1e-12, atol=1e-15)


@pytest.mark.filterwarnings("ignore:Arrays of 2-dimensional vectors:DeprecationWarning")  # inside curvey
@pytest.mark.slow
def test_d_flow_matches_curveys_flow(polygon):
    # curvey's vertex normal is the D normal (perpendicular to p_{i+1} - p_{i-1}); with kappa_D built
    # from curvey's own turning angles its CurveShorteningFlow is the report's D iteration, in NumPy.
    def kappa_d(reference):
        chord = np.roll(reference.points, -1, axis=0) - np.roll(reference.points, 1, axis=0)
        return 2 * np.sin(reference.turning_angle) / np.linalg.norm(chord, axis=1)

    solver = CurveShorteningFlow(resample_mode=None, curvature_fn=kappa_d).solver(
        curvey.Curve(np.asarray(polygon.points)), timestep=2e-4, max_step=300, history=False
    )
    solver.run()
    ours = curve_shortening_flow(polygon, kind="D", tau=2e-4, steps=300).points[-1]
    np.testing.assert_allclose(ours, solver.current.points, rtol=0, atol=1e-13)  # measured 2e-16


@jax.jit
def _one_step_each(points):
    """Explicit and semi-implicit steps of every kind, from one compiled program."""
    return {
        (kind, method): step(points, 1e-3, True, kind)
        for kind in "ABCD"
        for method, step in (("explicit", _explicit_step), ("semi-implicit", _semi_implicit_step))
    }


@pytest.mark.slow
def test_one_step_is_the_reports_iteration(polygon):
    # the public path for one kind, the step function for all four
    np.testing.assert_allclose(
        curve_shortening_flow(polygon, kind="A", tau=1e-3, steps=1).points[-1],
        polygon.points + 1e-3 * curvature_vectors(polygon, kind="A"),
        rtol=1e-14,
        atol=1e-15,
    )
    steps = _one_step_each(polygon.points)
    for kind in "ABCD":
        expected = polygon.points + 1e-3 * curvature_vectors(polygon, kind=kind)
        np.testing.assert_allclose(steps[kind, "explicit"], expected, rtol=1e-14, atol=1e-15)


def _tangling_star_flow(**options):
    """A flow that self-intersects: a star with sharp tips, `tau` far above the explicit limit."""
    curve = star(5, inner_radius=0.3, subdivisions=2)
    return curve_shortening_flow(curve, kind="A", tau=0.4, steps=20, save_every=5, **options)


@pytest.mark.slow
def test_self_intersection_is_reported():
    saved = _tangling_star_flow(check_simple="saved", throw=False)
    every = _tangling_star_flow(check_simple="every_step", throw=False)
    certified = _tangling_star_flow(throw=False)
    for run in (saved, every, certified):
        assert bool(run.result == RESULTS.self_intersection)
    first_saved = int(np.argmin(np.asarray(saved.is_simple)))
    assert int(saved.first_failure_step) == int(saved.steps[first_saved])
    # the exact step lies after the last simple saved state and no later than the first non-simple one
    assert int(saved.steps[first_saved - 1]) < int(every.first_failure_step) <= int(saved.first_failure_step)
    assert float(every.first_failure_time) == pytest.approx(0.4 * int(every.first_failure_step), rel=1e-15)
    assert int(certified.first_failure_step) == int(every.first_failure_step)


@pytest.mark.slow
def test_throw_raises_on_failure_eagerly_and_under_jit():
    # Eagerly (and under equinox.filter_jit) equinox raises its own error; a plain jax.jit wraps the
    # same message in a JaxRuntimeError. Both are RuntimeErrors.
    with pytest.raises(eqx.EquinoxRuntimeError, match="The curve was not simple"):
        _tangling_star_flow()
    with pytest.raises(jax.errors.JaxRuntimeError, match="The curve was not simple"):
        jax.block_until_ready(jax.jit(lambda: _tangling_star_flow().points)())
    # nothing raises on a successful run, and throw=False never raises
    assert bool(curve_shortening_flow(star(5), kind="A", tau=1e-3, steps=20).result == RESULTS.successful)
    assert int(_tangling_star_flow(throw=False).first_failure_step) <= 20


@pytest.mark.slow
def test_nonfinite_input_is_reported():
    # Traced points are not validated (Curve's checks need concrete values), so NaN reaches the flow.
    points = star(5).points.at[3, 0].set(jnp.nan)
    flow = jax.jit(lambda P, throw: curve_shortening_flow(Curve(P), kind="B", tau=1e-3, steps=4, throw=throw), static_argnums=1)
    result = flow(points, False)
    assert bool(result.result == RESULTS.nonfinite) and int(result.first_failure_step) == 0
    assert float(result.first_failure_time) == 0.0
    with pytest.raises(jax.errors.JaxRuntimeError, match="NaN or inf"):
        jax.block_until_ready(flow(points, True).points)


@pytest.mark.slow
def test_throw_under_vmap_raises_if_any_member_failed():
    simple = star(5).points
    tangled = simple.at[jnp.array([0, 40])].set(simple[jnp.array([40, 0])])  # two far vertices swapped
    mixed = jnp.stack([simple, tangled])

    def run(P, throw):
        return curve_shortening_flow(Curve(P), kind="B", tau=1e-3, steps=4, check_simple="saved", throw=throw)

    inspected = jax.vmap(lambda P: run(P, False))(mixed)
    np.testing.assert_array_equal(inspected.result == RESULTS.self_intersection, [False, True])
    np.testing.assert_array_equal(inspected.first_failure_step, [5, 0])
    jax.block_until_ready(jax.vmap(lambda P: run(P, True).points)(jnp.stack([simple, 2 * simple])))  # no failure, no error
    with pytest.raises(eqx.EquinoxRuntimeError, match="The curve was not simple"):
        jax.vmap(lambda P: run(P, True))(mixed)


def _step_by_step_simplicity(curve, kind, tau, steps):
    """`is_simple` of every state, one explicit step at a time (the reference for the trackers)."""
    states = curve_shortening_flow(curve, kind=kind, tau=tau, steps=steps, save_every=1, check_simple="saved", throw=False)
    return np.asarray(states.is_simple)


@pytest.mark.slow
def test_a_transient_crossing_between_saves_is_reported(polygon):
    # The B flow collapses a short edge of this polygon at step 76 (tau = shortest edge / 20): the
    # curve is non-simple for a moment and simple again at the next save, which "saved" cannot see.
    tau = float(jnp.min(edge_lengths(polygon))) / 20
    reference = _step_by_step_simplicity(polygon, "B", tau, 100)
    first = int(np.argmin(reference))
    assert first > 0 and reference[-1], "the reference run should cross and untangle"
    saved = curve_shortening_flow(polygon, kind="B", tau=tau, steps=100, save_every=50, check_simple="saved")
    assert bool(saved.result == RESULTS.successful)  # what a check of the saved states alone reports
    assert int(saved.first_failure_step) == 101  # one past the last step: no failure
    for check in ("certified", "every_step"):
        result = curve_shortening_flow(polygon, kind="B", tau=tau, steps=100, save_every=50, check_simple=check, throw=False)
        assert bool(result.result == RESULTS.self_intersection), check
        assert int(result.first_failure_step) == first, check


@pytest.mark.slow
def test_certified_tracking_is_exact_on_a_simple_run(polygon):
    # up to flow time 0.2, before the edge collapse of the test above (at 0.23)
    result = curve_shortening_flow(polygon, kind="B", tau=2e-3, steps=100, save_every=100)
    assert bool(result.result == RESULTS.successful) and int(result.first_failure_step) == 101
    assert float(result.first_failure_time) == np.inf
    assert _step_by_step_simplicity(polygon, "B", 2e-3, 100).all()
    # a non-simple start is step 0
    bow_tie = Curve(np.array([[0.0, 0.0], [1.0, 1.0], [1.0, 0.0], [0.0, 1.0]]))
    started = curve_shortening_flow(bow_tie, kind="B", tau=1e-3, steps=4, throw=False)
    assert bool(started.result == RESULTS.self_intersection) and int(started.first_failure_step) == 0


def _plain_explicit_step(points, tau, closed, kind):
    """The explicit step from its weights, differentiated by plain autodiff (the reference)."""
    edges = jnp.roll(points, -1, axis=0) - points
    alpha, beta = _flow_weights(edges, closed, kind)
    return points + tau * (beta[:, None] * edges - alpha[:, None] * jnp.roll(edges, 1, axis=0))


@pytest.mark.parametrize("closed", [True, False])
@pytest.mark.slow
def test_closed_form_step_derivatives_match_autodiff(polygon, closed):
    # _explicit_step carries a hand-derived tangent (custom_jvp); both modes must equal autodiff.
    rng = np.random.default_rng(3)
    P = polygon.points
    V, G = jnp.asarray(rng.normal(size=P.shape)), jnp.asarray(rng.normal(size=P.shape))
    # add a straight vertex (theta = 0, the series branch of dr/dtheta) and a sharp turn (theta ~ pi - 0.3;
    # at exactly pi the step is not differentiable: |theta| has a kink there)
    rotation = jnp.array([[np.cos(0.3), -np.sin(0.3)], [np.sin(0.3), np.cos(0.3)]])
    P = P.at[5].set(0.5 * (P[4] + P[6])).at[20].set(P[19] + 0.9 * rotation @ (P[19] - P[21]))
    for kind in "ABCD":
        ours = jax.jvp(lambda Q, t, kind=kind: _explicit_step(Q, t, closed, kind), (P, 1e-2), (V, 0.3))[1]
        plain = jax.jvp(lambda Q, t, kind=kind: _plain_explicit_step(Q, t, closed, kind), (P, 1e-2), (V, 0.3))[1]
        np.testing.assert_allclose(ours, plain, rtol=1e-12, atol=1e-14, err_msg=kind)
        grads = [
            jax.grad(lambda Q, t, step=step, kind=kind: jnp.sum(G * step(Q, t, closed, kind)), argnums=(0, 1))(P, 1e-2)
            for step in (_explicit_step, _plain_explicit_step)
        ]
        np.testing.assert_allclose(grads[0][0], grads[1][0], rtol=1e-12, atol=1e-14, err_msg=kind)
        np.testing.assert_allclose(grads[0][1], grads[1][1], rtol=1e-12, err_msg=kind)


@pytest.mark.slow
def test_step_derivatives_are_finite_on_degenerate_curves():
    # coincident consecutive points (a zero-length edge) and an exact reversal (theta = pi)
    points = jnp.array([[0.0, 0.0], [1.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0], [0.5, 1.0], [0.2, 1.0]])
    for kind in "ABCD":
        value, tangent = jax.jvp(lambda Q, kind=kind: _explicit_step(Q, 1e-2, True, kind), (points,), (jnp.ones_like(points),))
        gradient = jax.grad(lambda Q, kind=kind: jnp.sum(_explicit_step(Q, 1e-2, True, kind) ** 2))(points)
        assert np.isfinite(np.asarray(value)).all() and np.isfinite(np.asarray(tangent)).all(), kind
        assert np.isfinite(np.asarray(gradient)).all(), kind


@pytest.mark.slow  # the fast tier's time limit (its checks run in the full suite)
def test_semi_implicit_solves_the_linearly_implicit_system(polygon):
    steps = _one_step_each(polygon.points)
    for kind in "ABCD":
        tau = 1e-3
        new = steps[kind, "semi-implicit"]
        alpha, beta = _flow_weights(jnp.roll(polygon.points, -1, 0) - polygon.points, True, kind)
        n = polygon.n_points
        operator = np.diag(-(alpha + beta)) + np.diag(beta[:-1], 1) + np.diag(alpha[1:], -1)
        operator[0, -1], operator[-1, 0] = alpha[0], beta[-1]
        residual = (np.eye(n) - tau * operator) @ np.asarray(new) - np.asarray(polygon.points)
        assert np.abs(residual).max() < 1e-13, kind


@pytest.mark.slow
def test_semi_implicit_is_stable_far_beyond_the_explicit_limit(polygon):
    tau = 0.5  # ~16x the shortest edge: explicit B is unstable
    explicit = curve_shortening_flow(polygon, kind="B", tau=tau, steps=20, save_every=2, throw=False)
    implicit = curve_shortening_flow(polygon, kind="B", tau=tau, steps=20, save_every=2, method="semi-implicit")
    assert bool(explicit.result == RESULTS.self_intersection)
    assert bool(implicit.result == RESULTS.successful)
    assert np.all(np.diff(np.asarray(implicit.length)) < 0)
    np.testing.assert_allclose(implicit.total_curvature, 2 * np.pi, rtol=1e-14)


def test_semi_implicit_agrees_with_explicit_to_first_order(polygon):
    difference = jax.jit(lambda P, tau: jnp.abs(_explicit_step(P, tau, True, "D") - _semi_implicit_step(P, tau, True, "D")).max())
    errors = [float(difference(polygon.points, tau)) for tau in (4e-4, 2e-4)]
    # One step differs by O(tau^2); the O(tau^3) term of the stiff D operator (~1 / l^2, shortest edge
    # l ~ 0.06) moves the ratio by a few % at these tau: measured 3.84.
    assert errors[0] / errors[1] == pytest.approx(4.0, rel=0.05)


@pytest.mark.slow
def test_rescale_length_keeps_the_length(polygon):
    # throw=False: rescaled or not, the B flow collapses a short edge of this polygon and crosses
    # itself for a moment (test_a_transient_crossing_between_saves_is_reported); the length is kept all the same.
    result = curve_shortening_flow(polygon, kind="B", tau=2e-3, steps=200, save_every=50, rescale="length", throw=False)
    np.testing.assert_allclose(result.length, length(polygon), rtol=1e-13)
    assert float(result.isoperimetric_ratio[-1]) > float(result.isoperimetric_ratio[0])


@pytest.mark.slow
def test_open_curve_keeps_its_endpoints(polygon):
    curve = Curve(polygon.points[:15], closed=False)
    result = curve_shortening_flow(curve, kind="B", tau=2e-3, steps=300, save_every=100)
    ends = np.asarray(result.points)[:, [0, -1]]
    np.testing.assert_array_equal(ends, np.broadcast_to(np.asarray(curve.points)[[0, -1]], (4, 2, 2)))
    assert np.all(np.diff(np.asarray(result.length)) < 0)


@pytest.fixture(scope="module")
def small():
    return random_polygon(10, key=4)


def _loss(points, tau, method):
    # throw=True (the default): the gradient passes through the failure check's equinox.error_if
    final = curve_shortening_flow(Curve(points), kind="A", tau=tau, steps=40, method=method).points[-1]
    return jnp.sum(final[:, 0] ** 2 + 0.3 * final[:, 1]) + enclosed_area(Curve(final))


@pytest.mark.parametrize("method", ["explicit", "semi-implicit"])
@pytest.mark.slow
def test_gradient_through_the_whole_flow_matches_finite_differences(small, method):
    value_and_grad = jax.jit(jax.value_and_grad(lambda P, tau: _loss(P, tau, method), argnums=(0, 1)))

    def loss(P, tau):
        return value_and_grad(P, tau)[0]

    P, tau = small.points, jnp.asarray(0.01)
    g_points, g_tau = value_and_grad(P, tau)[1]
    v = jnp.asarray(np.random.default_rng(0).normal(size=P.shape))
    numeric = central_difference(lambda Q: loss(Q, tau), P, v, eps=1e-6)
    # central differences: error ~eps^2 + ulp/eps ~1e-10 relative
    np.testing.assert_allclose(jnp.sum(g_points * v), numeric, rtol=1e-7)
    numeric_tau = central_difference(lambda t: loss(P, t), tau, 1.0, eps=1e-8)
    np.testing.assert_allclose(g_tau, numeric_tau, rtol=1e-6)  # step 1e-8 on tau: round-off ~1e-8 relative


@pytest.mark.slow
def test_vmap_matches_single_runs(small):
    batch = jnp.stack([small.points, 1.5 * small.points, small.points[::-1]])
    run = lambda P: curve_shortening_flow(Curve(P), kind="D", tau=1e-3, steps=30, save_every=10).cyclic_residual
    batched = jax.vmap(run)(batch)  # traced (vmap) against the eager call (its own jitted scan)
    for row, points in zip(batched, batch):
        np.testing.assert_allclose(row, run(points), rtol=1e-13, atol=1e-16)


@pytest.mark.slow
def test_progress_bar_path_matches_the_pure_path(small, capsys):
    pure = curve_shortening_flow(small, kind="B", tau=1e-3, steps=30, save_every=10)
    shown = curve_shortening_flow(small, kind="B", tau=1e-3, steps=30, save_every=10, progress=True)
    np.testing.assert_array_equal(shown.points, pure.points)
    np.testing.assert_array_equal(shown.is_simple, pure.is_simple)
    assert "curve-shortening flow B" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"kind": "E"}, "kind: expected one of"),
        ({"method": "implicit"}, "method: expected one of"),
        ({"rescale": "volume"}, "rescale: expected one of"),
        ({"check_simple": "never"}, "check_simple: expected one of"),
        ({"steps": 0}, "steps: expected an integer >= 1, got 0"),
        ({"steps": 10, "save_every": 3}, "save_every: expected a divisor of steps = 10, got 3"),
        ({"tau": -1.0}, "tau: expected a finite time step > 0"),
        ({"tau": float("nan")}, "tau: expected a finite time step > 0"),
    ],
)
def test_bad_arguments(small, kwargs, match):
    arguments = {"kind": "A", "tau": 1e-3, "steps": 10} | kwargs
    with pytest.raises(DDGInputError, match=match):
        curve_shortening_flow(small, **arguments)


def test_bad_combinations(small):
    with pytest.raises(DDGInputError, match="rescale: expected None for an open curve"):
        curve_shortening_flow(Curve(small.points, closed=False), kind="A", tau=1e-3, steps=2, rescale="length")
    with pytest.raises(DDGInputError, match="progress: expected concrete inputs"):
        jax.jit(lambda P: curve_shortening_flow(Curve(P), kind="A", tau=1e-3, steps=2, progress=True).points)(small.points)
