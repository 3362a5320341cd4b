"""Built-in polygons and `load_polygon` (ddgjax/curves/_shapes.py)."""

from __future__ import annotations

import itertools
from fractions import Fraction

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ddgjax import DDGInputError
from ddgjax.curves import (
    Curve,
    enclosed_area,
    figure3_polygon,
    flower,
    is_simple,
    load_polygon,
    random_polygon,
    regular_polygon,
    star,
    turning_number,
)

# Mostly 40 vertices, so the jitted checks below compile for two sizes only.
SHAPES = {
    "regular": lambda: regular_polygon(40, radius=2.0, center=(1.0, -3.0)),
    "flower": lambda: flower(40, petals=5, amplitude=0.45),
    "star": lambda: star(5, inner_radius=0.4, subdivisions=4),
    "random-0": lambda: random_polygon(40, key=0),
    "random-7": lambda: random_polygon(40, key=7, amplitude=0.7, modes=9, jitter=0.45),
    "figure3": figure3_polygon,
}


@jax.jit
def _library_checks(points):
    curve = Curve(points)
    return is_simple(curve), enclosed_area(curve), turning_number(curve)


def _orientation(a, b, c) -> int:
    """Exact sign of `(b - a) x (c - a)` in rational arithmetic (no rounding: collinear means collinear)."""
    value = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
    return (value > 0) - (value < 0)


def _exactly_simple(points: np.ndarray) -> bool:
    """Independent simplicity test: exact orientation predicates on every pair of non-adjacent edges."""
    exact = [(Fraction(float(x)), Fraction(float(y))) for x, y in points]
    n = len(exact)
    edges = [(exact[i], exact[(i + 1) % n]) for i in range(n)]

    def on_segment(p, q, r):  # r collinear with p q: inside its bounding box?
        return min(p[0], q[0]) <= r[0] <= max(p[0], q[0]) and min(p[1], q[1]) <= r[1] <= max(p[1], q[1])

    for i, j in itertools.combinations(range(n), 2):
        if j - i in (1, n - 1):
            continue
        (p1, q1), (p2, q2) = edges[i], edges[j]
        d1, d2 = _orientation(p1, q1, p2), _orientation(p1, q1, q2)
        d3, d4 = _orientation(p2, q2, p1), _orientation(p2, q2, q1)
        if d1 * d2 < 0 and d3 * d4 < 0:
            return False
        if any(
            d == 0 and on_segment(*seg, r)
            for d, seg, r in [(d1, (p1, q1), p2), (d2, (p1, q1), q2), (d3, (p2, q2), p1), (d4, (p2, q2), q1)]
        ):
            return False
    return True


@pytest.mark.parametrize("name", SHAPES)
def test_shapes_are_simple_and_counterclockwise(name):
    curve = SHAPES[name]()
    points = np.asarray(curve.points)
    assert curve.closed and points.shape[1] == 2
    assert _exactly_simple(points)
    simple, area, turns = _library_checks(curve.points)
    assert bool(simple) and float(area) > 0 and int(turns) == 1


def test_nonconvex_shapes_have_reflex_vertices():
    """The demo shapes must be visibly non-convex: some vertices turn right (negative cross product)."""
    for name in ("flower", "star", "random-0", "figure3"):
        points = np.asarray(SHAPES[name]().points)
        u = points - np.roll(points, 1, axis=0)
        v = np.roll(points, -1, axis=0) - points
        assert np.any(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0] < -1e-3), name


def test_regular_polygon_vertices_on_circle():
    curve = regular_polygon(9, radius=2.5, center=(0.5, -1.0))
    points = np.asarray(curve.points)
    np.testing.assert_allclose(np.linalg.norm(points - [0.5, -1.0], axis=1), 2.5, rtol=0, atol=1e-14)
    np.testing.assert_allclose(points[0], [3.0, -1.0], atol=1e-15)
    # Equal edges 2 r sin(pi / n) and the closed-form area (n / 2) r^2 sin(2 pi / n).
    edges = np.linalg.norm(np.roll(points, -1, axis=0) - points, axis=1)
    np.testing.assert_allclose(edges, 2 * 2.5 * np.sin(np.pi / 9), rtol=1e-14)
    np.testing.assert_allclose(float(enclosed_area(curve)), 4.5 * 2.5**2 * np.sin(2 * np.pi / 9), rtol=1e-14)


def test_regular_polygon_matches_gpytoolbox():
    gpytoolbox = pytest.importorskip("gpytoolbox")
    vertices, _ = gpytoolbox.regular_circle_polyline(13)
    np.testing.assert_allclose(regular_polygon(12).points, vertices[:-1], rtol=0, atol=1e-15)


def test_sizes_and_determinism():
    assert figure3_polygon().points.shape == (64, 2)
    assert star(6, subdivisions=3).points.shape == (36, 2)
    np.testing.assert_array_equal(random_polygon(30, key=3).points, random_polygon(30, key=3).points)
    assert not np.array_equal(random_polygon(30, key=3).points, random_polygon(30, key=4).points)


def test_shapes_follow_default_dtype():
    """float64 under the x64 the tests enable (the shapes never force a dtype of their own)."""
    assert figure3_polygon().points.dtype == jnp.result_type(float) == jnp.float64


@pytest.mark.parametrize(
    "build",
    [
        lambda: regular_polygon(2),
        lambda: regular_polygon(5, radius=-1.0),
        lambda: flower(amplitude=1.0),
        lambda: star(inner_radius=1.0, outer_radius=1.0),
        lambda: star(subdivisions=0),
        lambda: random_polygon(20, jitter=0.5),
        lambda: random_polygon(20, modes=1),
        lambda: random_polygon(2),
    ],
)
def test_bad_shape_parameters_refused(build):
    with pytest.raises(DDGInputError):
        build()


@pytest.fixture
def square():
    return np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])


def test_load_polygon_round_trips_npy(tmp_path, square):
    path = tmp_path / "square.npy"
    np.save(path, square)
    curve = load_polygon(path)
    assert isinstance(curve, Curve) and curve.closed
    np.testing.assert_array_equal(curve.points, square)


@pytest.mark.parametrize(
    "text",
    [
        "x,y\n0,0\n1,0\n1,1\n0,1\n",
        "# a comment\n0 0\n1 0\n\n1 1   # trailing comment\n0 1\n0 0\n",  # whitespace, repeated closing point
        "0.0, 0.0\n1.0, 0.0\n1.0, 1.0\n0.0, 1.0",
    ],
)
def test_load_polygon_round_trips_csv(tmp_path, square, text):
    path = tmp_path / "square.csv"
    path.write_text(text)
    np.testing.assert_array_equal(load_polygon(path).points, square)


def test_load_polygon_round_trips_figure3_csv(tmp_path):
    points = np.asarray(figure3_polygon().points)
    path = tmp_path / "figure3.csv"
    np.savetxt(path, points, delimiter=",", header="x,y", fmt="%.17g")
    np.testing.assert_array_equal(load_polygon(path).points, points)


@pytest.mark.parametrize(
    ("name", "content", "message"),
    [
        ("missing.csv", None, "existing"),
        ("three.csv", "0,0,0\n1,0,0\n1,1,0\n", "two numbers"),
        ("words.csv", "x,y\n0,0\n1,zero\n1,1\n", "line 3"),
        ("short.csv", "0,0\n1,0\n0,0\n", "at least 3"),
        ("empty.csv", "", "none"),
        ("nan.csv", "0,0\n1,nan\n1,1\n", "NaN"),
        ("flat.npy", np.zeros(6), "shape"),
        ("cube.npy", np.zeros((4, 3)), "shape"),
        ("text.npy", "not numpy", "could not read"),
        ("repeat.npy", np.array([[0.0, 0.0], [0.0, 0.0], [1.0, 0.0], [1.0, 1.0]]), "differ"),
    ],
)
def test_load_polygon_refuses_bad_files(tmp_path, name, content, message):
    path = tmp_path / name
    if isinstance(content, np.ndarray):
        np.save(path, content)
    elif content is not None:
        path.write_text(content)
    with pytest.raises(DDGInputError, match=message):
        load_polygon(path)
