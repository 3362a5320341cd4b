"""ddgjax.graph: graph Laplacians, graphs of point sets, learning on graphs, drawing, networkx interop.

Every check compares with something computed independently here: networkx, SciPy (`spsolve`,
`cdist`, dense `eigh`), closed forms (a weighted path, a cycle), finite differences.
"""

from __future__ import annotations

import sys

import jax
import jax.numpy as jnp
import networkx as nx
import numpy as np
import pytest
import scipy.linalg
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from jax.test_util import check_grads
from jaxtyping import TypeCheckError
from scipy.spatial.distance import cdist

import ddgjax
from ddgjax.graph import (
    epsilon_graph,
    from_networkx,
    gaussian_weights,
    graph_laplacian,
    harmonic_interpolation,
    knn_graph,
    spectral_layout,
    tikhonov_smoothing,
    to_networkx,
    tutte_layout,
)


def _random_graph(n=40, seed=0):
    """A connected random graph (a Watts-Strogatz ring) with edge_weights in [0.5, 2]: `(edges, edge_weights, G)`."""
    graph = nx.connected_watts_strogatz_graph(n, 4, 0.3, seed=seed)
    rng = np.random.default_rng(seed)
    edges = np.array(graph.edges, dtype=np.int64)
    edge_weights = rng.uniform(0.5, 2.0, len(edges))
    for (i, j), w in zip(edges, edge_weights, strict=True):
        graph[i][j]["weight"] = w
    return edges, edge_weights, graph


def _reference_laplacian(edges, edge_weights, n):
    """`D - W` by SciPy from a COO adjacency (duplicates summed by SciPy)."""
    adjacency = sp.coo_matrix((edge_weights, (edges[:, 0], edges[:, 1])), shape=(n, n)).tocsr()
    adjacency = adjacency + adjacency.T
    return (sp.diags(np.asarray(adjacency.sum(axis=1)).ravel()) - adjacency).tocsc()


# ---------------------------------------------------------------------------------------------- Laplacian


def test_laplacian_matches_networkx_with_parallel_edges_and_isolated_vertices():
    rng = np.random.default_rng(1)
    multigraph = nx.MultiGraph()
    multigraph.add_nodes_from(range(25))  # 20..24 stay isolated
    listed = rng.integers(0, 20, size=(70, 2))
    listed = listed[listed[:, 0] != listed[:, 1]]
    listed[::7] = listed[::7, ::-1]  # both orientations of some edges
    edge_weights = rng.uniform(0.1, 3.0, len(listed))
    for (i, j), w in zip(listed, edge_weights, strict=True):
        multigraph.add_edge(int(i), int(j), weight=w)
    assert len({tuple(sorted(e)) for e in listed.tolist()}) < len(listed)  # parallel edges present
    L = graph_laplacian(listed, edge_weights=edge_weights, n_vertices=25)
    expected = nx.laplacian_matrix(multigraph, nodelist=range(25), weight="weight").toarray()
    np.testing.assert_allclose(L.todense(), expected, rtol=0, atol=1e-13)
    np.testing.assert_allclose(L.to_scipy().toarray(), expected, rtol=0, atol=1e-13)
    assert L.symmetric and L.positive_semidefinite
    np.testing.assert_allclose(L @ jnp.ones(25), 0.0, atol=1e-13)
    # Unit edge_weights by default.
    unweighted = nx.laplacian_matrix(multigraph, nodelist=range(25), weight=None).toarray()
    np.testing.assert_array_equal(graph_laplacian(listed, n_vertices=25).todense(), unweighted)


@pytest.mark.parametrize(
    ("edges", "edge_weights", "n_vertices", "match"),
    [
        (np.array([[0, 1], [2, 2]]), None, 3, "edges: self-loops"),
        (np.array([[0, 1], [1, 3]]), None, 3, r"edges: vertex indices must lie in \[0, n_vertices\)"),
        (np.array([[0, 1], [1, 2]]), np.array([1.0, -0.5]), 3, "edge_weights: expected finite non-negative"),
        (np.array([[0, 1], [1, 2]]), np.array([1.0, np.nan]), 3, "edge_weights: expected finite non-negative"),
        (np.array([[0, 1]]), None, 0, "n_vertices: expected an integer >= 1"),
    ],
)
def test_laplacian_refuses_bad_input(edges, edge_weights, n_vertices, match):
    with pytest.raises(ddgjax.DDGInputError, match=match):
        graph_laplacian(edges, edge_weights=edge_weights, n_vertices=n_vertices)


@pytest.mark.parametrize(
    ("edges", "edge_weights", "name"),
    [
        (np.array([[0, 1], [1, 2]]), np.array([1.0, 2.0, 3.0]), "edge_weights"),
        (np.array([[0.0, 1.0]]), None, "edges"),
        (np.array([0, 1, 2]), None, "edges"),
    ],
)
def test_laplacian_refuses_bad_shapes(edges, edge_weights, name):
    # The test run checks the jaxtyping annotations first (TypeCheckError); without that hook the
    # function's own DDGInputError names the argument. Either names it.
    with pytest.raises((ddgjax.DDGInputError, TypeCheckError), match=name):
        graph_laplacian(edges, edge_weights=edge_weights, n_vertices=3)


def test_laplacian_refuses_traced_edges():
    with pytest.raises(ddgjax.DDGInputError, match="edges: .* concrete host data"):
        jax.jit(lambda e: graph_laplacian(e, n_vertices=3).values)(jnp.array([[0, 1], [1, 2]]))


def test_laplacian_gradient_in_weights_is_the_squared_differences():
    """`d(u^T L u)/dw_e = (u_i - u_j)^2` (closed form), duplicates included; jit and vmap agree with eager."""
    edges, edge_weights, _ = _random_graph(30, seed=2)
    edges = np.concatenate([edges, edges[:5, ::-1]])  # five edges listed twice
    edge_weights = np.concatenate([edge_weights, edge_weights[:5]])
    u = np.random.default_rng(3).normal(size=30)

    def energy(w):
        L = graph_laplacian(edges, edge_weights=w, n_vertices=30)
        return u @ (L @ u)

    grad = jax.jit(jax.grad(energy))(edge_weights)
    np.testing.assert_allclose(grad, (u[edges[:, 0]] - u[edges[:, 1]]) ** 2, rtol=1e-12, atol=1e-13)
    value = np.sum(edge_weights * (u[edges[:, 0]] - u[edges[:, 1]]) ** 2)
    batch = np.stack([edge_weights, 2 * edge_weights])
    np.testing.assert_allclose(jax.jit(jax.vmap(energy))(batch), [value, 2 * value], rtol=1e-12)


# ---------------------------------------------------------------------------------------------- point-set graphs


def _brute_force_pairs(points, *, n_neighbors=None, radius=None):
    distances = cdist(points, points)
    n = len(points)
    if radius is not None:
        i, j = np.nonzero(np.triu(distances <= radius, k=1))
    else:
        np.fill_diagonal(distances, np.inf)
        nearest = np.argsort(distances, axis=1, kind="stable")[:, :n_neighbors]
        adjacency = np.zeros((n, n), dtype=bool)
        adjacency[np.repeat(np.arange(n), n_neighbors), nearest.ravel()] = True
        i, j = np.nonzero(np.triu(adjacency | adjacency.T, k=1))
    return np.stack([i, j], axis=1), cdist(points, points)[i, j]


def test_knn_graph_matches_brute_force():
    points = np.random.default_rng(4).normal(size=(80, 3))
    edges, edge_weights = knn_graph(points, n_neighbors=6)
    expected_edges, lengths = _brute_force_pairs(points, n_neighbors=6)
    np.testing.assert_array_equal(edges, expected_edges)
    sigma = lengths.mean()  # the default: the mean edge length
    np.testing.assert_allclose(edge_weights, np.exp(-(lengths**2) / (2 * sigma**2)), rtol=1e-13)
    _, weights_given = knn_graph(points, n_neighbors=6, sigma=0.3)
    np.testing.assert_allclose(weights_given, np.exp(-(lengths**2) / (2 * 0.3**2)), rtol=1e-13)


def test_knn_graph_with_coincident_points_has_no_self_loops():
    points = np.random.default_rng(5).normal(size=(20, 2))
    points[7] = points[3]
    edges, edge_weights = knn_graph(points, n_neighbors=3)
    assert (edges[:, 0] < edges[:, 1]).all()
    assert any((e == [3, 7]).all() for e in edges)
    assert np.isfinite(np.asarray(edge_weights)).all()


def test_epsilon_graph_matches_brute_force():
    points = np.random.default_rng(6).uniform(size=(100, 2))
    edges, edge_weights = epsilon_graph(points, radius=0.15)
    expected_edges, lengths = _brute_force_pairs(points, radius=0.15)
    np.testing.assert_array_equal(edges, expected_edges)
    np.testing.assert_allclose(edge_weights, np.exp(-(lengths**2) / (2 * lengths.mean() ** 2)), rtol=1e-13)
    empty_edges, empty_weights = epsilon_graph(points, radius=1e-6)
    assert empty_edges.shape == (0, 2) and empty_weights.shape == (0,)


def test_point_graph_options_are_checked():
    points = np.zeros((5, 2))
    with pytest.raises(ddgjax.DDGInputError, match="n_neighbors: expected at most n - 1 = 4"):
        knn_graph(points, n_neighbors=5)
    with pytest.raises(ddgjax.DDGInputError, match="radius"):
        epsilon_graph(points, radius=-1.0)
    with pytest.raises((ddgjax.DDGInputError, TypeCheckError), match="points"):  # as in test_laplacian_refuses_bad_shapes
        knn_graph(np.zeros(5))
    with pytest.raises(ddgjax.DDGInputError, match="points: the neighbour search"):
        jax.jit(lambda p: knn_graph(p, n_neighbors=2).edge_weights)(jnp.ones((5, 2)))


def test_gaussian_weights_gradient_in_points_is_the_closed_form():
    """With `sigma` given, `d w_ij / d p_i = -w_ij (p_i - p_j) / sigma^2` (and the opposite for `p_j`)."""
    points = np.random.default_rng(7).normal(size=(30, 3))
    edges, edge_weights = knn_graph(points, n_neighbors=4, sigma=0.7)
    probe = np.random.default_rng(8).normal(size=len(edges))
    np.testing.assert_allclose(gaussian_weights(points, edges, sigma=0.7), edge_weights, rtol=1e-14)
    grad = jax.jit(jax.grad(lambda p: gaussian_weights(p, edges, sigma=0.7) @ probe))(points)
    per_edge = -(probe * np.asarray(edge_weights))[:, None] * (points[edges[:, 0]] - points[edges[:, 1]]) / 0.7**2
    expected = np.zeros_like(points)
    np.add.at(expected, edges[:, 0], per_edge)
    np.add.at(expected, edges[:, 1], -per_edge)
    np.testing.assert_allclose(grad, expected, rtol=1e-12, atol=1e-14)


@pytest.mark.slow
def test_gaussian_weights_gradient_in_points_against_finite_differences():
    points = np.random.default_rng(7).normal(size=(30, 3))
    edges, _ = knn_graph(points, n_neighbors=4)
    probe = np.random.default_rng(8).normal(size=len(edges))
    # Default sigma (the mean edge length moves with the points) and a given, differentiated sigma.
    check_grads(jax.jit(lambda p: gaussian_weights(p, edges) @ probe), (points,), order=1, modes=("rev",), eps=1e-6)
    loss = jax.jit(lambda p, s: gaussian_weights(p, edges, sigma=s) @ probe)
    check_grads(loss, (points, 0.7), order=1, modes=("rev",), eps=1e-6)


def test_gaussian_weights_take_sigma_as_a_concrete_jax_scalar_and_refuse_a_bad_one():
    """A 0-d JAX array (what a user differentiating in sigma holds between steps) works eagerly as a float does."""
    points = np.random.default_rng(10).normal(size=(12, 2))
    edges, _ = knn_graph(points, n_neighbors=3)
    np.testing.assert_array_equal(
        gaussian_weights(points, edges, sigma=jnp.asarray(0.4)), gaussian_weights(points, edges, sigma=0.4)
    )
    for bad in (0.0, -1.0, jnp.asarray(jnp.nan), jnp.ones(2), True):
        with pytest.raises((ddgjax.DDGInputError, TypeCheckError), match="sigma"):
            gaussian_weights(points, edges, sigma=bad)


# ---------------------------------------------------------------------------------------------- learning


def test_harmonic_interpolation_on_a_weighted_path_is_the_series_resistor_formula():
    """On a path with ends at 0 and 1, `f_i` is the fraction of the resistance `sum 1 / w` before vertex i."""
    n = 12
    edges = np.stack([np.arange(n - 1), np.arange(1, n)], axis=1)
    edge_weights = np.random.default_rng(9).uniform(0.5, 2.0, n - 1)
    resistance = np.concatenate([[0.0], np.cumsum(1 / edge_weights)])
    expected = resistance / resistance[-1]
    f = harmonic_interpolation(
        edges, fixed_vertices=np.array([0, n - 1]), fixed_values=np.array([0.0, 1.0]), edge_weights=edge_weights, n_vertices=n
    )
    np.testing.assert_allclose(f, expected, rtol=0, atol=1e-14)
    # Two classes (one-hot) at once: the columns sum to 1.
    both = harmonic_interpolation(
        edges, fixed_vertices=np.array([0, n - 1]), fixed_values=np.eye(2), edge_weights=edge_weights, n_vertices=n
    )
    np.testing.assert_allclose(both, np.stack([1 - expected, expected], axis=1), rtol=0, atol=1e-14)


@pytest.mark.parametrize("solver", ["auto", pytest.param("cg", marks=pytest.mark.slow)])
def test_harmonic_interpolation_matches_spsolve_and_is_the_label_propagation_fixed_point(solver):
    edges, edge_weights, _ = _random_graph(60, seed=10)
    rng = np.random.default_rng(11)
    fixed = rng.choice(60, size=8, replace=False)
    values = rng.normal(size=(8, 3))
    f = np.asarray(
        harmonic_interpolation(
            edges, fixed_vertices=fixed, fixed_values=values, edge_weights=edge_weights, n_vertices=60, solver=solver
        )
    )
    L = _reference_laplacian(edges, edge_weights, 60)
    free = np.setdiff1d(np.arange(60), fixed)
    expected = np.zeros((60, 3))
    expected[fixed] = values
    expected[free] = spla.spsolve(L[free][:, free], -(L[free][:, fixed] @ values))
    # CG stops at a 1e-10 relative residual (linear_solve's rtol): its error is at most cond(L_ff) times that.
    atol = 1e-13 if solver == "auto" else np.linalg.cond(L[free][:, free].toarray()) * 1e-10 * np.abs(expected).max()
    np.testing.assert_allclose(f, expected, rtol=0, atol=atol)
    # Each free vertex is the weighted mean of its neighbours (a mean of errors <= atol, minus one); fixed ones kept.
    adjacency = sp.diags(L.diagonal()) - L
    mean = (adjacency @ f) / L.diagonal()[:, None]
    np.testing.assert_allclose(f[free], mean[free], rtol=0, atol=2 * atol)
    np.testing.assert_array_equal(f[fixed], values)


def test_harmonic_interpolation_component_without_fixed_vertex_is_zero():
    # Component A: path 0-1-2 (fixed ends); component B: triangle 3-4-5; vertex 6 isolated.
    edges = np.array([[0, 1], [1, 2], [3, 4], [4, 5], [3, 5]])
    solution = harmonic_interpolation(
        edges, fixed_vertices=np.array([0, 2]), fixed_values=np.array([1.0, 3.0]), n_vertices=7, throw=False
    )
    assert solution.result == ddgjax.RESULTS.successful
    np.testing.assert_allclose(solution.value, [1.0, 2.0, 3.0, 0.0, 0.0, 0.0, 0.0], atol=1e-14)
    assert float(solution.stats["residual"]) < 1e-12


def test_harmonic_interpolation_refuses_bad_fixed_data():
    edges = np.array([[0, 1], [1, 2]])
    with pytest.raises(ddgjax.DDGInputError, match="fixed_vertices: expected at least one"):
        harmonic_interpolation(edges, fixed_vertices=np.array([], dtype=int), fixed_values=np.zeros(0), n_vertices=3)
    with pytest.raises(ddgjax.DDGInputError, match="fixed_vertices: expected distinct"):
        harmonic_interpolation(edges, fixed_vertices=np.array([0, 0]), fixed_values=np.zeros(2), n_vertices=3)
    with pytest.raises((ddgjax.DDGInputError, TypeCheckError), match="fixed_values"):
        harmonic_interpolation(edges, fixed_vertices=np.array([0, 2]), fixed_values=np.zeros(3), n_vertices=3)
    with pytest.raises(ddgjax.DDGInputError, match="solver"):
        harmonic_interpolation(edges, fixed_vertices=np.array([0]), fixed_values=np.zeros(1), n_vertices=3, solver="lu")


@pytest.mark.slow
def test_harmonic_interpolation_gradients_against_finite_differences():
    edges, edge_weights, _ = _random_graph(25, seed=12)
    fixed = np.array([0, 7, 13, 20])
    values = np.random.default_rng(13).normal(size=(4, 2))
    probe = np.random.default_rng(14).normal(size=(25, 2))

    def loss(w, v):
        f = harmonic_interpolation(edges, fixed_vertices=fixed, fixed_values=v, edge_weights=w, n_vertices=25)
        return jnp.sum(probe * f**2)

    check_grads(jax.jit(loss), (edge_weights, values), order=1, modes=("rev",), eps=1e-6)


def test_tikhonov_smoothing_matches_spsolve():
    edges, edge_weights, _ = _random_graph(40, seed=15)
    signal = np.random.default_rng(16).normal(size=(40, 2))
    f = tikhonov_smoothing(edges, signal, edge_weights=edge_weights, n_vertices=40, alpha=0.7)
    L = _reference_laplacian(edges, edge_weights, 40)
    expected = spla.spsolve((sp.identity(40) + 0.7 * L).tocsc(), signal)
    np.testing.assert_allclose(f, expected, rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.sum(f, axis=0), signal.sum(axis=0), rtol=1e-12)  # L 1 = 0 keeps the mean
    with pytest.raises(ddgjax.DDGInputError, match="alpha: expected a finite number >= 0"):
        tikhonov_smoothing(edges, signal, n_vertices=40, alpha=-1.0)
    with pytest.raises(ddgjax.DDGInputError, match=r"signal: expected shape \(40,\)"):
        tikhonov_smoothing(edges, signal[:5], n_vertices=40, alpha=1.0)


@pytest.mark.slow
def test_tikhonov_smoothing_gradients_against_finite_differences():
    edges, edge_weights, _ = _random_graph(40, seed=15)
    signal = np.random.default_rng(16).normal(size=(40, 2))
    probe = np.random.default_rng(17).normal(size=(40, 2))

    def loss(w, y, alpha):
        return jnp.sum(probe * tikhonov_smoothing(edges, y, edge_weights=w, n_vertices=40, alpha=alpha) ** 2)

    check_grads(jax.jit(loss), (edge_weights, signal, 0.7), order=1, modes=("rev",), eps=1e-6)


# ---------------------------------------------------------------------------------------------- drawing


def _span_residual(x, y):
    """`min over 2x2 A of |x A - y| / |y|` (both centred): `y` is `x` up to a linear map of the plane.

    networkx's dense path takes the eigenvectors of a repeated eigenvalue from the non-symmetric
    `numpy.linalg.eig`, any (not orthonormal) basis of the eigenspace, and rescales them: a linear image
    of the same drawing, so the column spans are what agree.
    """
    x = x - x.mean(axis=0)
    y = y - y.mean(axis=0)
    fit = np.linalg.lstsq(x, y, rcond=None)[0]
    return np.linalg.norm(x @ fit - y) / np.linalg.norm(y)


def test_spectral_layout_of_a_cycle_is_a_regular_polygon_as_networkx():
    n = 16
    graph = nx.cycle_graph(n)
    edges = np.array(graph.edges)
    x = np.asarray(spectral_layout(edges, n_vertices=n))
    # Closed form: D = 2 I, the second eigenspace is {cos, sin}(2 pi i / n); D-normalised, radius 1 / sqrt(n).
    np.testing.assert_allclose(np.linalg.norm(x, axis=1), 1 / np.sqrt(n), rtol=1e-10)
    turns = np.angle(np.exp(1j * np.diff(np.unwrap(np.arctan2(x[:, 1], x[:, 0])))))
    np.testing.assert_allclose(np.abs(turns), 2 * np.pi / n, rtol=1e-10)
    assert len(set(np.sign(turns))) == 1
    # A regular graph: networkx's plain Laplacian has the same eigenspace (up to a linear map).
    reference = nx.spectral_layout(graph)
    assert _span_residual(x, np.array([reference[i] for i in range(n)])) < 1e-10


def test_spectral_layout_matches_the_dense_generalized_eigenproblem():
    graph = nx.grid_2d_graph(5, 6)
    graph = nx.convert_node_labels_to_integers(graph)
    edges = np.array(graph.edges)
    edge_weights = np.random.default_rng(18).uniform(0.5, 2.0, len(edges))  # distinct eigenvalues
    L = _reference_laplacian(edges, edge_weights, 30).toarray()
    values, vectors = scipy.linalg.eigh(L, np.diag(np.diag(L)))
    x = np.asarray(spectral_layout(edges, edge_weights=edge_weights, n_vertices=30, dim=3))
    signs = np.sign(np.sum(x * vectors[:, 1:4], axis=0))
    np.testing.assert_allclose(x, vectors[:, 1:4] * signs, rtol=0, atol=1e-10)
    assert values[1] < values[2] < values[3] < values[4]
    np.testing.assert_allclose(x.T @ np.diag(np.diag(L)) @ x, np.eye(3), atol=1e-12)  # Koren's normalisation
    with pytest.raises(ddgjax.DDGInputError, match="edges: the graph has 2 connected components"):
        spectral_layout(np.array([[0, 1], [1, 2], [3, 4], [4, 5]]), n_vertices=6)


@pytest.mark.slow
def test_spectral_layout_gradient_in_weights_against_finite_differences():
    graph = nx.convert_node_labels_to_integers(nx.grid_2d_graph(4, 5))
    edges = np.array(graph.edges)
    edge_weights = np.random.default_rng(19).uniform(0.5, 2.0, len(edges))
    probe = np.random.default_rng(20).normal(size=(20, 2))

    def loss(w):  # invariant to the sign of each axis
        return jnp.sum(probe * spectral_layout(edges, edge_weights=w, n_vertices=20) ** 2)

    check_grads(jax.jit(loss), (edge_weights,), order=1, modes=("rev",), eps=1e-6)


def _crossing_pairs(positions, edges):
    """Pairs of edges without a common vertex whose segments cross (strictly)."""
    a, b = positions[edges[:, 0]], positions[edges[:, 1]]

    def orient(p, q, r):
        return (q[..., 0] - p[..., 0]) * (r[..., 1] - p[..., 1]) - (q[..., 1] - p[..., 1]) * (r[..., 0] - p[..., 0])

    i, j = np.triu_indices(len(edges), k=1)
    disjoint = ~((edges[i][:, :, None] == edges[j][:, None, :]).any(axis=(1, 2)))
    i, j = i[disjoint], j[disjoint]
    crosses = (orient(a[i], b[i], a[j]) * orient(a[i], b[i], b[j]) < 0) & (
        orient(a[j], b[j], a[i]) * orient(a[j], b[j], b[i]) < 0
    )
    return np.count_nonzero(crosses)


def _signed_areas(x, faces):
    a, b = x[faces[:, 1]] - x[faces[:, 0]], x[faces[:, 2]] - x[faces[:, 0]]
    return a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]


def test_tutte_layout_of_a_disk_is_planar_and_barycentric():
    mesh = ddgjax.mesh.disk(4)
    edges = np.asarray(mesh.topology.edges)
    loop = np.asarray(mesh.topology.boundary_loops[0])
    n = mesh.n_vertices
    x = np.asarray(tutte_layout(edges, fixed_vertices=loop, n_vertices=n))
    angles = 2 * np.pi * np.arange(loop.size) / loop.size
    circle = np.stack([np.cos(angles), np.sin(angles)], axis=1)
    np.testing.assert_allclose(x[loop], circle, atol=1e-15)
    adjacency = sp.coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n, n)).tocsr()
    adjacency = adjacency + adjacency.T
    interior = np.setdiff1d(np.arange(n), loop)
    mean = (adjacency @ x) / np.asarray(adjacency.sum(axis=1))
    np.testing.assert_allclose(x[interior], mean[interior], rtol=0, atol=1e-12)
    assert _crossing_pairs(x, edges) == 0
    faces = np.asarray(mesh.faces)
    assert (_signed_areas(x, faces) > 0).all()  # every triangle keeps its orientation: an embedding


@pytest.mark.slow
def test_tutte_layout_with_random_weights_is_planar_and_equals_tutte_embedding():
    mesh = ddgjax.mesh.disk(4)
    edges = np.asarray(mesh.topology.edges)
    loop = np.asarray(mesh.topology.boundary_loops[0])
    n, faces = mesh.n_vertices, np.asarray(mesh.faces)
    angles = 2 * np.pi * np.arange(loop.size) / loop.size
    circle = np.stack([np.cos(angles), np.sin(angles)], axis=1)
    x = tutte_layout(edges, fixed_vertices=loop, fixed_values=circle, n_vertices=n)
    np.testing.assert_allclose(x, ddgjax.param.tutte_embedding(mesh, shape=circle), rtol=0, atol=1e-12)
    # Positive random edge_weights (Floater 1997) keep the drawing planar.
    edge_weights = np.random.default_rng(21).uniform(0.1, 10.0, len(edges))
    y = np.asarray(tutte_layout(edges, fixed_vertices=loop, edge_weights=edge_weights, n_vertices=n))
    assert _crossing_pairs(y, edges) == 0
    assert (_signed_areas(y, faces) > 0).all()


def test_tutte_layout_refuses_a_boundary_that_is_not_a_cycle():
    edges = np.array([[0, 1], [1, 2], [2, 3], [3, 0], [0, 2]])
    with pytest.raises(ddgjax.DDGInputError, match="fixed_vertices: consecutive boundary vertices"):
        tutte_layout(edges, fixed_vertices=np.array([0, 2, 1, 3]), n_vertices=4)  # 1-3 is no edge
    with pytest.raises((ddgjax.DDGInputError, TypeCheckError), match="fixed_values"):
        tutte_layout(edges, fixed_vertices=np.array([0, 1, 2]), fixed_values=np.zeros((4, 2)), n_vertices=4)


# ---------------------------------------------------------------------------------------------- networkx


def test_networkx_round_trip_with_named_nodes():
    graph = nx.Graph()
    graph.add_edge("a", "b", weight=2.0)
    graph.add_edge("b", "c", weight=0.5)
    graph.add_edge("c", "a")  # no weight attribute: 1, as networkx
    graph.add_node("lonely")
    edges, edge_weights, n_vertices, nodes = from_networkx(graph)
    assert nodes == ["a", "b", "c", "lonely"] and n_vertices == 4
    L = graph_laplacian(edges, edge_weights=edge_weights, n_vertices=n_vertices)
    np.testing.assert_allclose(L.todense(), nx.laplacian_matrix(graph, nodelist=nodes).toarray(), atol=1e-15)
    back = to_networkx(edges, edge_weights=edge_weights, n_vertices=n_vertices)
    relabelled = nx.relabel_nodes(back, dict(enumerate(nodes)))
    assert nx.utils.graphs_equal(relabelled, graph) is False  # "c"-"a" gained an explicit weight attribute
    np.testing.assert_allclose(
        nx.laplacian_matrix(relabelled, nodelist=nodes).toarray(), nx.laplacian_matrix(graph, nodelist=nodes).toarray()
    )
    _, ones, _, _ = from_networkx(graph, weight=None)
    np.testing.assert_array_equal(ones, 1.0)
    # A duplicated edge comes back once with the summed weight.
    merged = to_networkx(np.array([[0, 1], [1, 0]]), edge_weights=np.array([1.0, 2.5]), n_vertices=2)
    assert merged[0][1]["weight"] == 3.5


def test_networkx_refusals_and_missing_networkx(monkeypatch):
    with pytest.raises(ddgjax.DDGInputError, match="graph: expected an undirected graph"):
        from_networkx(nx.DiGraph([(0, 1)]))
    with pytest.raises(ddgjax.DDGInputError, match="graph: 1 self-loop"):
        from_networkx(nx.Graph([(0, 1), (1, 1)]))
    with pytest.raises(ddgjax.DDGInputError, match="graph: expected a networkx Graph"):
        from_networkx([(0, 1)])
    monkeypatch.setitem(sys.modules, "networkx", None)
    with pytest.raises(ImportError, match="pip install 'networkx>=3'"):
        to_networkx(np.array([[0, 1]]), n_vertices=2)
