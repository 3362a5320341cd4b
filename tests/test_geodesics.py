"""Tests for ddgjax.geodesics (heat method): every intermediate against the DDG reference, distances
against potpourri3d (geometry-central) and against great-circle distance on spheres with a fitted
rate, the kept solver, sources inside faces, boundaries, gradients against finite differences."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import potpourri3d as pp3d
import pytest

from ddgjax import DDGInputError
from ddgjax.geodesics import heat_distance, heat_distance_solver
from ddgjax.mesh import Mesh, disk, edge_lengths

from conftest import read_ddg_reference
from finite_differences import central_difference


@pytest.mark.slow
def test_every_step_matches_the_ddg_reference():
    data = read_ddg_reference("test-heat-soln.txt")
    mesh = Mesh.from_arrays(data["v"], data["f"].astype(np.int64) - 1)
    sources = np.flatnonzero(data["delta"][:, 0])
    steps = heat_distance_solver(mesh, mass="barycentric").steps(sources)
    # The reference uses the barycentric mass and adds 1e-8 I to L; the course accepts ~1e-5.
    np.testing.assert_allclose(steps.field, data["X"], rtol=0, atol=1e-5)
    np.testing.assert_allclose(-steps.divergence, data["div"][:, 0], rtol=0, atol=1e-5)  # the reference's shift
    distance = np.asarray(steps.distance)
    np.testing.assert_allclose(distance - distance.min(), data["phi"][:, 0], rtol=0, atol=1e-5)  # the reference's shift
    assert distance[sources[0]] == 0


@pytest.mark.parametrize("name", ["spot.obj", "camelhead.off"])
@pytest.mark.slow
def test_matches_potpourri3d(name, data_mesh):
    mesh = data_mesh(name)
    V, F = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    # geometry-central: lumped barycentric mass, Neumann heat flow; `use_robust=False` keeps the mesh's
    # own cotan Laplacian (its default is the intrinsic Delaunay one).
    expected = pp3d.MeshHeatMethodDistanceSolver(V, F, t_coef=1.0, use_robust=False).compute_distance(7)
    ours = heat_distance(mesh, [7], mass="barycentric", boundary="neumann")
    # Measured: 1.1e-4 (spot) and 3.4e-4 (camelhead) of the largest distance, a uniform scale of
    # 1 - 1.2e-4 between the two (a slightly different time t or regularisation in geometry-central).
    np.testing.assert_allclose(ours, expected, rtol=0, atol=1e-3 * expected.max())


@pytest.mark.slow
def test_sphere_great_circle_distance_error_falls_under_refinement(icospheres):
    errors, sizes = [], []
    for subdivisions in (2, 3, 4):
        mesh = icospheres(subdivisions)
        V = np.asarray(mesh.vertices)
        exact = np.arccos(np.clip(V @ V[0], -1.0, 1.0))
        errors.append(np.abs(np.asarray(heat_distance(mesh, [0])) - exact).mean())
        sizes.append(float(jnp.mean(edge_lengths(mesh))))
    rate = np.polyfit(np.log(sizes), np.log(errors), 1)[0]
    assert errors[-1] < 0.015 and 0.8 < rate < 2.2, (errors, rate)  # measured: 0.013, rate 0.9 (first order)


@pytest.mark.slow
def test_kept_solver_queries_jit_vmap_and_points_inside_faces(icosphere3):
    mesh = icosphere3
    solver = heat_distance_solver(mesh)
    single = solver.distance([5])
    np.testing.assert_allclose(single, heat_distance(mesh, [5]), atol=1e-12)
    jitted = jax.jit(lambda solver: solver.distance([5]))(solver)
    np.testing.assert_allclose(jitted, single, atol=1e-12)
    batch = jax.vmap(lambda v: solver.distance((np.array([0]), v[None, :])))(jnp.eye(3))
    corners = np.asarray(mesh.faces)[0]
    for k in range(3):  # a point at a face's corner is that vertex
        np.testing.assert_allclose(batch[k], solver.distance([corners[k]]), atol=1e-10)
    # A point inside a face: its corners at their straight-line distance from it on average (the shift
    # that puts the sources at 0, lower here than the minimum), positive everywhere.
    middle = solver.distance((np.array([0]), jnp.full((1, 3), 1 / 3)))
    V = np.asarray(mesh.vertices)[corners]
    straight = np.linalg.norm(V - V.mean(axis=0), axis=1)
    np.testing.assert_allclose(jnp.mean(middle[corners] - straight), 0.0, atol=1e-12)
    assert float(middle.min()) > 0 and float(middle.max()) > 3.0


@pytest.mark.slow
def test_disk_boundary_average_and_neumann():
    mesh = disk(16)
    r = np.linalg.norm(np.asarray(mesh.vertices)[:, :2], axis=1)
    centre = int(np.argmin(r))
    average = np.asarray(heat_distance(mesh, [centre]))
    neumann = np.asarray(heat_distance(mesh, [centre], boundary="neumann"))
    exact = np.linalg.norm(np.asarray(mesh.vertices) - np.asarray(mesh.vertices)[centre], axis=1)
    rim = mesh.topology.boundary_vertices
    errors = {name: np.abs(d - exact)[rim].mean() for name, d in (("average", average), ("neumann", neumann))}
    # The heat method's O(h) error, at the rim of disk(16): measured 0.0065 for both.
    assert errors["average"] < 0.02 and errors["neumann"] < 0.02, errors
    assert errors["average"] < errors["neumann"], errors  # the paper's point: less bias at the boundary


@pytest.mark.slow
def test_gradient_in_the_vertex_positions_matches_finite_differences(icosphere2):
    mesh = icosphere2
    V0 = mesh.vertices * jnp.asarray([1.0, 1.3, 0.8])
    weights = jnp.linspace(0.5, 1.5, mesh.n_vertices)

    @jax.jit
    def loss(V):
        return jnp.sum(weights * heat_distance(mesh.with_vertices(V), [0]) ** 2)

    _check_gradient_against_central_differences(loss, V0, seed=0)


def test_bad_input(without_type_checker, icosphere1):
    mesh = icosphere1
    cases = [
        (lambda: heat_distance(mesh, []), "sources: expected vertex indices"),
        (lambda: heat_distance(mesh, [42]), r"sources: vertex indices must lie in \[0, 42\)"),
        (lambda: heat_distance(mesh, [0.5]), "sources: expected vertex indices"),
        (lambda: heat_distance(mesh, (np.array([80]), np.ones((1, 3)) / 3)), r"sources: face indices must lie in \[0, 80\)"),
        (lambda: heat_distance(mesh, (np.array([0]), np.ones((1, 2)))), "sources: expected barycentric coordinates"),
        (lambda: heat_distance(mesh, [0], t_coef=0.0), "t_coef: expected a positive number"),
        (lambda: heat_distance(mesh, [0], boundary="robin"), "boundary: expected one of"),
        (lambda: heat_distance(mesh, [0], solver="lu"), "solver: expected one of"),
        (lambda: heat_distance(mesh, [0], mass="cubic"), "mass: expected one of"),
    ]
    for call, message in cases:
        with pytest.raises(DDGInputError, match=message):
            call()


@pytest.mark.slow
def test_robust_laplacian_brings_camelhead_distances_near_potpourri3d_robust_mode(data_mesh):
    mesh = data_mesh("camelhead.off")
    V, F = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    expected = pp3d.MeshHeatMethodDistanceSolver(V, F).compute_distance(7)  # potpourri3d's default: robust
    options = {"mass": "barycentric", "boundary": "neumann"}
    errors = {
        robust: np.abs(np.asarray(heat_distance(mesh, [7], robust=robust, **options)) - expected).max() / expected.max()
        for robust in (False, True)
    }
    # Measured: 7.7% with the plain cotan Laplacian (camelhead's obtuse triangles), 1.4% with the intrinsic
    # Delaunay one; potpourri3d's robust mode also mollifies the lengths and uses a tufted cover, hence not 0.
    assert errors[True] < 0.02 and errors[True] < errors[False] / 3, errors


@pytest.mark.slow
def test_outcomes_without_throw():
    """A successful query reports `RESULTS.successful` with the solves' residual; a conjugate gradient cut
    short in the heat flow reports `max_steps_reached` (the first failing solve), and raises with `throw=True`."""
    import equinox as eqx

    from ddgjax import RESULTS, Solution
    from ddgjax.solve import factorize

    mesh = disk(6)
    solution = heat_distance(mesh, [0], throw=False)
    assert isinstance(solution, Solution) and solution.result == RESULTS.successful
    np.testing.assert_array_equal(solution.value, heat_distance(mesh, [0]))
    assert float(solution.stats["residual"]) < 1e-10
    solver = heat_distance_solver(mesh, solver="cg")
    assert solver.distance([0], throw=False).result == RESULTS.successful
    cut = eqx.tree_at(lambda s: s.factors.heat, solver, factorize(solver.factors.heat.system, solver="cg", max_steps=2))
    failed = cut.distance([0], throw=False)
    assert failed.result == RESULTS.max_steps_reached and int(failed.stats["num_steps"]) >= 2
    assert cut.steps([0], throw=False).result == RESULTS.max_steps_reached
    with pytest.raises(Exception, match="did not reach its tolerance within `max_steps`"):
        cut.distance([0])


@pytest.mark.slow
def test_dirichlet_heat_flow_on_a_disk():
    """`boundary="dirichlet"` holds the heat at 0 on the rim; "average" is the mean of its heat and the Neumann one."""
    mesh = disk(8)
    steps = {b: heat_distance_solver(mesh, boundary=b).steps([0]) for b in ("average", "neumann", "dirichlet")}
    assert np.all(np.asarray(steps["dirichlet"].heat)[mesh.topology.boundary_vertices] == 0)
    np.testing.assert_allclose(steps["average"].heat, (steps["neumann"].heat + steps["dirichlet"].heat) / 2, atol=1e-14)


def _strip(n: int) -> tuple[np.ndarray, np.ndarray]:
    """One row of `2 n` right triangles (every vertex on the boundary)."""
    V = np.array([[i, j, 0.0] for i in range(n + 1) for j in (0, 1)])
    F = np.concatenate([[[2 * i, 2 * i + 2, 2 * i + 1], [2 * i + 1, 2 * i + 2, 2 * i + 3]] for i in range(n)])
    return V, F


def _obtuse_grid(n: int) -> tuple[np.ndarray, np.ndarray]:
    """A flat `n x n` grid with every other row shifted and the rows squashed: angles up to 139 degrees."""
    x, y = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    x = x + 0.35 / (n - 1) * (np.arange(n)[:, None] % 2)
    V = np.stack([x.ravel(), 0.3 * y.ravel(), np.zeros(n * n)], axis=1)
    a = (np.arange(n - 1)[:, None] * n + np.arange(n - 1)).ravel()
    F = np.concatenate([np.stack([a, a + 1, a + n + 1], 1), np.stack([a, a + n + 1, a + n], 1)])
    return V, F


VALID_MESHES = {
    "triangle": (np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.2, 0.9, 0.0]]), np.array([[0, 1, 2]])),
    "strip": _strip(6),
    "obtuse": _obtuse_grid(12),
}


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(VALID_MESHES))
def test_every_valid_mesh_matches_potpourri3d_shifted_to_minimum_zero(name):
    """A single triangle, a strip (no interior vertex) and a mesh of obtuse triangles: the distance is
    potpourri3d's (`use_robust=False`, same mass and heat flow) shifted so that its minimum is 0, so
    never negative (on the obtuse grid potpourri3d's own minimum is -0.06, away from the source)."""
    V, F = VALID_MESHES[name]
    mesh = Mesh.from_arrays(V, F)
    expected = pp3d.MeshHeatMethodDistanceSolver(V, F, t_coef=1.0, use_robust=False).compute_distance(0)
    expected = expected - expected.min()
    options = {"mass": "barycentric", "boundary": "neumann"}
    ours = np.asarray(heat_distance(mesh, [0], **options))
    assert ours.min() == 0
    # Measured: 9e-7 (triangle), 9e-6 (strip), 1.4e-5 (obtuse) of the largest distance (a slightly
    # different time or regularisation in geometry-central, as test_matches_potpourri3d).
    np.testing.assert_allclose(ours, expected, rtol=0, atol=1e-4 * expected.max())
    np.testing.assert_array_equal(heat_distance_solver(mesh, **options).distance([0]), ours)
    # The default, boundary="average": every vertex of the triangle and the strip is a boundary vertex, so
    # the Dirichlet heat is 0 and the Neumann flow alone is used; the solver route agrees.
    average = np.asarray(heat_distance(mesh, [0], mass="barycentric"))
    if name != "obtuse":
        np.testing.assert_array_equal(average, ours)
    assert average.min() == 0
    np.testing.assert_allclose(heat_distance_solver(mesh, mass="barycentric").distance([0]), average, rtol=0, atol=1e-14)


@pytest.mark.slow
def test_several_sources_are_never_negative():
    """potpourri3d shifts by the sources' mean, so with several sources some distances are negative; here
    the minimum is 0: the same field shifted."""
    mesh = disk(8)
    V, F = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    sources = [3, 40, 70]
    expected = pp3d.MeshHeatMethodDistanceSolver(V, F, use_robust=False).compute_distance_multisource(sources)
    assert expected.min() < -0.01  # measured: -0.016
    ours = np.asarray(heat_distance(mesh, sources, mass="barycentric", boundary="neumann"))
    # Measured: 1.3e-5 of the largest distance (as above).
    np.testing.assert_allclose(ours, expected - expected.min(), rtol=0, atol=1e-4 * expected.max())


@pytest.mark.slow
def test_unreachable_components_and_unreferenced_vertices_are_inf():
    """Two disks and a vertex of no face: a source on the first disk leaves the second and the lone vertex at
    `inf`, and the first disk's distances are those of the disk alone; sources on both disks reach both."""
    disk_mesh = disk(4)
    V, F = np.asarray(disk_mesh.vertices), np.asarray(disk_mesh.faces)
    n = V.shape[0]
    mesh = Mesh.from_arrays(np.vstack([V, V + [3.0, 0.0, 0.0], [[9.0, 9.0, 9.0]]]), np.vstack([F, F + n]))
    alone = np.asarray(heat_distance(disk_mesh, [0]))
    solver = heat_distance_solver(mesh)
    for distance in (heat_distance(mesh, [0]), solver.distance([0]), jax.jit(lambda s: s.distance([0]))(solver)):
        distance = np.asarray(distance)
        assert np.all(np.isinf(distance[n:])) and np.all(distance[n:] > 0)
        np.testing.assert_allclose(distance[:n], alone, rtol=0, atol=1e-12)
    both = np.asarray(solver.distance([0, n]))
    np.testing.assert_allclose(both[:n], alone, rtol=0, atol=1e-12)
    np.testing.assert_allclose(both[n:-1], alone, rtol=0, atol=1e-12)
    assert np.isinf(both[-1])
    # potpourri3d on the reached disk (it gives the other disk a finite constant).
    expected = pp3d.MeshHeatMethodDistanceSolver(V, F, use_robust=False).compute_distance(0)
    ours = np.asarray(heat_distance(mesh, [0], mass="barycentric", boundary="neumann"))[:n]
    # Measured: 1.4e-6 of the largest distance (geometry-central's time or regularisation, as above).
    np.testing.assert_allclose(ours, expected - expected.min(), rtol=0, atol=1e-5 * expected.max())


@pytest.mark.slow
def test_gradient_with_unreachable_vertices_matches_finite_differences():
    """Masking the `inf` of an unreachable component gives a finite gradient, equal to central differences
    (the other disk's vertices count too: they move the mean edge length, so the heat flow's time)."""
    disk_mesh = disk(4)
    V, F = np.asarray(disk_mesh.vertices), np.asarray(disk_mesh.faces)
    n = V.shape[0]
    mesh = Mesh.from_arrays(np.vstack([V * [1.0, 1.2, 1.0], V + [3.0, 0.0, 0.0]]), np.vstack([F, F + n]))

    @jax.jit
    def loss(V):
        distance = heat_distance(mesh.with_vertices(V), [0])
        return jnp.sum(jnp.where(jnp.isfinite(distance), distance, 0.0) ** 2)

    V0 = mesh.vertices
    _check_gradient_against_central_differences(loss, V0, seed=1)


@pytest.mark.slow
def test_messages_name_the_users_arguments():
    """No internal name (`fixed`) in a message: a Dirichlet heat flow on a mesh with no interior vertex,
    a source on the boundary under it, a source on an unreferenced vertex."""
    V, F = _strip(3)
    strip = Mesh.from_arrays(V, F)
    rim = int(disk(4).topology.boundary_vertices[0])
    lone = Mesh.from_arrays(np.vstack([V, [[0.0, 0.0, 5.0]]]), F)
    cases = [
        (lambda: heat_distance(strip, [0], boundary="dirichlet"), 'boundary: "dirichlet" holds the heat at 0 .* all 8 vertices'),
        (lambda: heat_distance_solver(strip, boundary="dirichlet"), 'use boundary="average"'),
        (
            lambda: heat_distance(disk(4), [rim], boundary="dirichlet"),
            r"sources: the sources at positions \[0\] .* lie on the boundary",
        ),
        (lambda: heat_distance_solver(disk(4), boundary="dirichlet").distance([0, rim]), r"positions \[1\]"),
        (lambda: heat_distance(lone, [8]), r"sources: vertices \[8\] belong to no face"),
    ]
    for call, message in cases:
        with pytest.raises(DDGInputError, match=message) as raised:
            call()
        assert "fixed" not in str(raised.value)


def _check_gradient_against_central_differences(loss, V0, *, seed: int):
    """`grad loss` finite, and its derivative along a random direction equal to central differences."""
    gradient = jax.grad(loss)(V0)
    assert np.all(np.isfinite(gradient))
    direction = np.random.default_rng(seed).standard_normal(V0.shape)
    finite = central_difference(loss, V0, direction, eps=1e-6)
    # Central differences with step 1e-6: truncation ~1e-9 relative; the loss's round-off (~1e-13 relative:
    # three solves, one with the pinned Laplacian) over the step leaves ~1e-7 (measured 1.3e-7, 6e-9). On an
    # accelerator the solves are CG's, to a relative residual of 1e-10.
    np.testing.assert_allclose(jnp.vdot(gradient, direction), finite, rtol=1e-6)
