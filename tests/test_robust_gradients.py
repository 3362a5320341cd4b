"""`robust=` entry points on degenerate meshes: finite values, and gradients that agree with central differences of
the mollified problem (issue 41). Each runs on a sphere with a flat cap (a vertex moved onto the midpoint of the
opposite edge: a face of zero area, angles pi, 0, 0) and on one with a collapsed face (three vertices at one
point); at coincident vertices the mollified problem has a kink (|p_a - p_b| at 0), so there the directions keep
the coincident vertices together."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ddgjax import RESULTS
from ddgjax.geodesics import heat_distance, log_map, parallel_transport, signed_heat_distance
from ddgjax.laplacian import intrinsic_delaunay, laplacian_and_mass
from ddgjax.mesh import Mesh
from ddgjax.pde import solve_poisson
from ddgjax.spectral import eigenpairs

from conftest import unit_icosphere
from finite_differences import central_difference, random_direction


def _degenerate(kind: str) -> Mesh:
    sphere = unit_icosphere(2)
    vertices, faces = np.array(sphere.vertices), np.asarray(sphere.faces)
    a, b, c = faces[7]
    if kind == "cap":
        vertices[c] = 0.5 * (vertices[a] + vertices[b])
    else:
        vertices[b] = vertices[c] = vertices[a]
    return Mesh.from_arrays(vertices, faces)


def _direction(mesh: Mesh, seed: int, *, keep_cap: bool = False) -> np.ndarray:
    """A random direction that moves coincident vertices together (the mollified problem is smooth along it);
    with `keep_cap`, one that also keeps the cap's middle vertex on its edge's midpoint."""
    vertices = np.asarray(mesh.vertices)
    direction = random_direction(vertices.shape, seed)
    for i in range(vertices.shape[0]):
        same = np.flatnonzero(np.all(vertices == vertices[i], axis=1))
        direction[same] = direction[same[0]]
    if keep_cap:
        a, b, c = np.asarray(mesh.faces)[7]
        direction[c] = 0.5 * (direction[a] + direction[b])
    return direction


ENTRY_POINTS = {
    "heat_distance": lambda mesh, tri, w: jnp.sum(w * heat_distance(mesh, [0], robust=tri)),
    "solve_poisson": lambda mesh, tri, w: jnp.sum(w * solve_poisson(mesh, w - w.mean(), robust=tri)),
    "eigenpairs": lambda mesh, tri, w: jnp.sum(eigenpairs(mesh, k=5, robust=tri).values),
    "laplacian_and_mass": lambda mesh, tri, w: (lambda L, M: w @ (L @ w) + jnp.sum(M.diagonal() * w))(
        *laplacian_and_mass(mesh, robust=tri)
    ),
    "log_map": lambda mesh, tri, w: jnp.sum(w[:, None] * log_map(mesh, 0, robust=tri)),
    "signed_heat_distance": lambda mesh, tri, w: jnp.sum(w * signed_heat_distance(mesh, [np.array([0, 42, 12])], robust=tri)),
    "parallel_transport": lambda mesh, tri, w: jnp.sum(
        w[:, None] * parallel_transport(mesh, 0, np.array([1.0, 0, 0]), robust=tri)
    ),
}
# The vector heat method's frames and the signed heat method's field use the faces' normals, and a cap's is
# undefined: it is left out (a threshold on the area, `ddgjax.mesh.internal.nondegenerate_face_mask`), so these
# are checked along directions that keep the cap flat. (A collapsed face makes the vector heat queries report
# RESULTS.coincident_vertices: the test below.)
VECTOR_HEAT = ("log_map", "parallel_transport")
NORMALS = (*VECTOR_HEAT, "signed_heat_distance")


@pytest.mark.parametrize(
    ("entry", "kind"),
    [
        (entry, kind)
        for entry in sorted(ENTRY_POINTS)
        for kind in ("cap", "collapsed")
        if not (entry in VECTOR_HEAT and kind == "collapsed")
    ],
)
def test_robust_gradients_agree_with_finite_differences(entry, kind):
    mesh = _degenerate(kind)
    triangulation = intrinsic_delaunay(mesh)
    weights = np.random.default_rng(3).standard_normal(mesh.n_vertices)

    def f(vertices):
        return ENTRY_POINTS[entry](mesh.with_vertices(vertices), triangulation, weights)

    vertices = np.asarray(mesh.vertices)
    gradient = np.asarray(jax.grad(f)(jnp.asarray(vertices)))
    assert np.isfinite(gradient).all()
    for seed in range(2):
        direction = _direction(mesh, seed, keep_cap=entry in NORMALS)
        expected = float(central_difference(f, vertices, direction))
        # Central differences at eps = 1e-6 across features of the mollification's size (1e-5 of the mean
        # edge): O(eps^2 / delta^2) ~ 1e-2 relative at worst, measured <= 2e-4 (1e-12-sized gradients before).
        assert float(gradient.ravel() @ direction.ravel()) == pytest.approx(expected, rel=1e-3, abs=1e-6)


@pytest.mark.parametrize("query", ["transport", "log_map"])
def test_vector_heat_reports_coincident_vertices(query):
    """Two vertices at one point have no tangent direction between them: the vector heat queries say so through
    RESULTS (they used to rotate vectors by up to 169 degrees and report success), and raise by default."""
    mesh = _degenerate("collapsed")
    run = {
        "transport": lambda throw: parallel_transport(mesh, 0, np.array([1.0, 0.0, 0.0]), robust=True, throw=throw),
        "log_map": lambda throw: log_map(mesh, 0, robust=True, throw=throw),
    }[query]
    assert run(False).result == RESULTS.coincident_vertices
    with pytest.raises(Exception, match="edge of zero length"):
        run(True)
    near = np.array(mesh.vertices)
    a, b, c = np.asarray(mesh.faces)[7]
    near[b], near[c] = near[a] + [1e-9, 0.0, 0.0], near[a] + [0.0, 1e-9, 0.0]  # nearly coincident: directions defined
    moved = Mesh.from_arrays(near, np.asarray(mesh.faces))
    assert log_map(moved, 0, robust=True, throw=False).result == RESULTS.successful
