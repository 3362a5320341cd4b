"""Graphs of degenerate input: coincident points, edges of weight zero (issue 41: never NaN, one behaviour)."""

from __future__ import annotations

import jax
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ddgjax import RESULTS
from ddgjax.graph import epsilon_graph, gaussian_weights, harmonic_interpolation, knn_graph


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(3, 30), st.integers(1, 4))
def test_knn_weights_of_coincident_points_are_finite(seed, n, n_distinct):
    """Clouds whose points coincide in a few places (all of them in one, at the extreme): every weight lies in
    (0, 1], every coincident pair weighs exactly 1, and the gradient in the points is finite."""
    rng = np.random.default_rng(seed)
    points = rng.normal(size=(n_distinct, 3))[rng.integers(0, n_distinct, size=n)]
    edges, weights = knn_graph(points, n_neighbors=min(3, n - 1))
    weights = np.asarray(weights)
    assert np.isfinite(weights).all() and (weights > 0).all() and (weights <= 1).all()
    coincident = np.all(points[edges[:, 0]] == points[edges[:, 1]], axis=1)
    np.testing.assert_array_equal(weights[coincident], 1.0)
    gradient = jax.grad(lambda p: gaussian_weights(p, edges).sum())(points)
    assert np.isfinite(np.asarray(gradient)).all()


def test_epsilon_graph_of_one_repeated_point_weighs_one():
    edges, weights = epsilon_graph(np.ones((5, 2)), radius=0.1)
    assert edges.shape == (10, 2)
    np.testing.assert_array_equal(np.asarray(weights), 1.0)


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2**31 - 1))
def test_zero_weights_act_as_missing_edges(seed):
    """Harmonic interpolation on a random graph with some weights 0 equals the same graph without those edges:
    a piece that only zero-weight edges join to the fixed vertices gets 0, as a piece with no edges does."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(4, 25))
    pairs = np.array([(i, j) for i in range(n) for j in range(i + 1, n)])
    edges = pairs[rng.random(len(pairs)) < 3.0 / n]
    if len(edges) == 0:
        edges = pairs[:1]
    weights = rng.random(len(edges)) + 0.1
    weights[rng.random(len(edges)) < 0.3] = 0.0
    fixed = rng.choice(n, size=int(rng.integers(1, 3)), replace=False)
    values = rng.normal(size=fixed.size)
    kept = weights > 0
    with_zeros = harmonic_interpolation(edges, fixed_vertices=fixed, fixed_values=values, edge_weights=weights, n_vertices=n)
    if kept.any():
        without = harmonic_interpolation(
            edges[kept], fixed_vertices=fixed, fixed_values=values, edge_weights=weights[kept], n_vertices=n
        )
    else:
        without = np.zeros(n)
        without[fixed] = values
    # Two factorisations of the same reduced system (one with extra explicit zeros): round-off apart.
    np.testing.assert_allclose(np.asarray(with_zeros), np.asarray(without), rtol=1e-12, atol=1e-12)


def test_a_cut_under_jit_is_a_failed_outcome_naming_graphs():
    """Traced weights have no host values: a zero weight that cuts a piece off the fixed vertices leaves the
    system singular, reported through `throw=` (the message names the graph case), never a silent answer."""
    edges = np.array([[0, 1], [1, 2], [2, 3]])

    def run(w):
        return harmonic_interpolation(
            edges, fixed_vertices=np.array([0]), fixed_values=np.array([1.0]), edge_weights=w, n_vertices=4, throw=False
        )

    cut = np.array([1.0, 0.0, 1.0])
    assert jax.jit(run)(cut).result != RESULTS.successful
    assert jax.jit(run)(np.array([1.0, 0.5, 1.0])).result == RESULTS.successful
    throwing = jax.jit(
        lambda w: harmonic_interpolation(
            edges, fixed_vertices=np.array([0]), fixed_values=np.array([1.0]), edge_weights=w, n_vertices=4
        )
    )
    with pytest.raises(Exception, match="zero edge weights"):
        jax.block_until_ready(throwing(cut))


@pytest.mark.parametrize("weights", [[1.0, 0.0, 1.0], [0.0, 0.0, 0.0]])
def test_zero_weights_eagerly_give_zero_on_the_cut_piece(weights):
    edges = np.array([[0, 1], [1, 2], [2, 3]])
    f = harmonic_interpolation(
        edges, fixed_vertices=np.array([0]), fixed_values=np.array([2.0]), edge_weights=np.array(weights), n_vertices=4
    )
    expected = [2.0, 2.0, 0.0, 0.0] if weights[0] else [2.0, 0.0, 0.0, 0.0]
    np.testing.assert_array_equal(np.asarray(f), expected)


def test_spectral_layout_counts_components_of_positive_weight():
    """A graph held together only by zero-weight edges is disconnected for the layout too: refused by name, as a
    graph of several components is (it used to fail inside the eigensolver with a message about meshes)."""
    from ddgjax import DDGInputError
    from ddgjax.graph import spectral_layout

    edges = np.array([[0, 1], [1, 2], [2, 3], [3, 0], [0, 2]])
    with pytest.raises(DDGInputError, match="2 connected components .counting only edges of positive weight"):
        spectral_layout(edges, n_vertices=4, edge_weights=np.array([1.0, 0.0, 1.0, 0.0, 0.0]))
    layout = spectral_layout(edges, n_vertices=4, edge_weights=np.array([1.0, 1.0, 0.0, 1.0, 1.0]))
    assert np.isfinite(np.asarray(layout)).all()
