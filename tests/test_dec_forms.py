"""The de Rham map (Stokes' theorem, quadrature exactness) and flat / sharp (Whitney) identities."""

from __future__ import annotations

import functools
import math

import igl
import jax
import jax.numpy as jnp
import jax.test_util
import numpy as np
import pytest

import ddgjax.dec as dec
from ddgjax import DDGInputError
from ddgjax.mesh import Mesh, face_normals, grid

from conftest import data_path


@functools.cache
def load(name: str) -> Mesh:
    V, F = igl.read_triangle_mesh(str(data_path("meshes", name)))
    return Mesh.from_arrays(V, F)


def potential(p):
    """A cubic 0-form."""
    x, y, z = p
    return x**3 - 2 * x * y * z + y**2 + 0.5 * z


def vector_potential(p):
    """A cubic covector field A; its curl is quadratic."""
    x, y, z = p
    return jnp.stack([y * z**2, x**3 - z, x * y * z + y**2])


def curl_of_vector_potential(p):
    x, y, z = p
    # curl A = (d_y A_z - d_z A_y, d_z A_x - d_x A_z, d_x A_y - d_y A_x)
    return jnp.stack([x * z + 2 * y + 1, 2 * y * z - y * z, 3 * x**2 - z**2])


@pytest.mark.parametrize("name", ["sphere_small.ply", "small_disk.obj", "bob_small.ply"])
@pytest.mark.slow
def test_stokes_theorem_on_edges_and_faces(name):
    """d0 of the sampled 0-form = integrated gradient; d1 of the integrated 1-form = integrated curl."""
    mesh = load(name)

    @jax.jit
    def sides(mesh):
        return (
            dec.d0(mesh) @ dec.integrate_0form(mesh, potential),
            dec.integrate_1form(mesh, jax.grad(potential), degree=2),
            dec.d1(mesh) @ dec.integrate_1form(mesh, vector_potential, degree=3),
            dec.integrate_2form(mesh, curl_of_vector_potential, degree=2),
        )

    d_f, grad_f, d_a, curl_a = (np.asarray(x) for x in sides(mesh))
    np.testing.assert_allclose(d_f, grad_f, rtol=0, atol=1e-13 * np.abs(d_f).max())
    np.testing.assert_allclose(d_a, curl_a, rtol=0, atol=1e-13 * np.abs(d_a).max())


@pytest.mark.slow
def test_quadrature_is_exact_for_the_stated_degree():
    """Monomials on one triangle and its edges against closed forms; fewer nodes are not exact."""
    corners = np.array([[0.3, -0.2, 0.1], [1.4, 0.1, -0.3], [0.2, 1.1, 0.4]])
    mesh = Mesh.from_arrays(corners, np.array([[0, 1, 2]]))
    sides = corners[1:] - corners[0]
    normal = np.cross(sides[0], sides[1])  # twice the area times n
    # Affine coordinates (s, t) of p = c0 + s e1 + t e2, from the Gram system.
    to_st = jnp.asarray(np.linalg.solve(sides @ sides.T, sides))

    @functools.partial(jax.jit, static_argnums=0)
    def monomial_fluxes(degree, exponents):
        def one(ab):
            def flux(p):
                s, t = to_st @ (p - corners[0])
                return s ** ab[0] * t ** ab[1] * jnp.asarray(normal / np.dot(normal, normal))

            return dec.integrate_2form(mesh, flux, degree=degree)[0]

        return jax.vmap(one)(exponents)

    for degree in range(7):
        a = np.arange(degree + 1)
        # int over {s, t >= 0, s + t <= 1} of s^a t^b = a! b! / (a + b + 2)!
        exact = np.array([math.factorial(i) * math.factorial(degree - i) for i in a]) / math.factorial(degree + 2)
        exponents = jnp.asarray(np.stack([a, degree - a], axis=1), jnp.float64)
        np.testing.assert_allclose(monomial_fluxes(degree, exponents), exact, rtol=1e-12)
        if degree == 6:
            assert np.abs(np.asarray(monomial_fluxes(degree - 2, exponents)) - exact).max() > 1e-8
    # Edges: alpha = x^k e_x integrates to (x_h^{k+1} - x_t^{k+1}) / (k + 1), exactly from degree k on.
    edges = mesh.topology.edges
    for k in (2, 7):
        expected = (corners[edges[:, 1], 0] ** (k + 1) - corners[edges[:, 0], 0] ** (k + 1)) / (k + 1)
        value = jax.jit(lambda m, k=k: dec.integrate_1form(m, lambda p: p[0] ** k * jnp.eye(3)[0], degree=k))(mesh)
        np.testing.assert_allclose(np.asarray(value), expected, rtol=1e-13)


def test_integrate_2form_of_a_constant_field_is_the_area_vector_flux():
    mesh = load("small_disk.obj")
    direction = jnp.asarray([0.2, -0.3, 1.0])
    flux, areas, normals = jax.jit(
        lambda m: (
            dec.integrate_2form(m, lambda p: direction, degree=0),
            dec.hodge2(m, inverse=True).diagonal(),
            face_normals(m),
        )
    )(mesh)
    np.testing.assert_allclose(flux, areas * (normals @ direction), rtol=1e-13)


@pytest.fixture(scope="module")
def whitney():
    """flat / sharp of various fields on a curved genus-1 mesh with obtuse faces, in one compile."""
    mesh = load("bob_small.ply")
    rng = np.random.default_rng(0)
    u = jnp.asarray(rng.standard_normal(mesh.n_vertices))
    alpha = jnp.asarray(rng.standard_normal(mesh.n_edges))
    constant = jnp.asarray([0.3, -1.2, 0.7])
    affine = jnp.asarray(rng.standard_normal((3, 3)))

    @jax.jit
    def compute(mesh):
        n = mesh.n_faces
        field_at_vertices = mesh.vertices @ affine.T + constant
        return {
            "du": dec.d0(mesh) @ u,
            "grad u": dec.gradient(mesh, u),
            "sharp du": dec.sharp(mesh, dec.d0(mesh) @ u),
            "flat sharp du": dec.flat(mesh, dec.sharp(mesh, dec.d0(mesh) @ u)),
            "alpha": alpha,
            "flat sharp alpha": dec.flat(mesh, dec.sharp(mesh, alpha)),
            "d1 alpha": dec.d1(mesh) @ alpha,
            "sharp flat constant": dec.sharp(mesh, dec.flat(mesh, jnp.broadcast_to(constant, (n, 3)))),
            "normals": face_normals(mesh),
            "flat vertices": dec.flat(mesh, field_at_vertices, at="vertices"),
            "integrated affine": dec.integrate_1form(mesh, lambda p: affine @ p + constant, degree=1),
        }

    return mesh, jax.tree.map(np.asarray, compute(mesh))


def test_sharp_of_exact_forms_is_the_gradient(whitney):
    _, r = whitney
    scale = np.abs(r["grad u"]).max()
    np.testing.assert_allclose(r["sharp du"], r["grad u"], rtol=0, atol=1e-13 * scale)
    np.testing.assert_allclose(r["flat sharp du"], r["du"], rtol=0, atol=1e-13 * np.abs(r["du"]).max())


def test_flat_sharp_removes_a_third_of_the_circulation(whitney):
    """`flat(sharp(alpha))_e = alpha_e - mean over the faces of e of (signed circulation) / 3`."""
    mesh, r = whitney
    topology = mesh.topology
    signs = topology.face_edge_signs[topology.edge_faces, topology.edge_face_corners]
    circulation = r["d1 alpha"][topology.edge_faces] * signs
    expected = r["alpha"] - circulation.mean(axis=1) / 3.0  # bob is closed: two faces per edge
    np.testing.assert_allclose(r["flat sharp alpha"], expected, rtol=0, atol=1e-13)


def test_sharp_flat_of_a_constant_field_is_its_tangent_part(whitney):
    _, r = whitney
    constant = np.array([0.3, -1.2, 0.7])
    normals = r["normals"]
    tangent = constant - (normals @ constant)[:, None] * normals
    np.testing.assert_allclose(r["sharp flat constant"], tangent, rtol=0, atol=1e-12)


def test_flat_of_a_vertex_field_integrates_its_linear_interpolant(whitney):
    _, r = whitney
    np.testing.assert_allclose(r["flat vertices"], r["integrated affine"], rtol=1e-13, atol=1e-14)


def fitted_rate(h, errors) -> float:
    """Slope of log(error) against log(h) (least squares)."""
    return float(np.polyfit(np.log(h), np.log(errors), 1)[0])


@jax.jit
def vertex_round_trip(mesh, field):
    """`sharp(flat(X))` at the vertices."""
    return dec.sharp(mesh, dec.flat(mesh, field, at="vertices"), at="vertices")


def test_vertex_sharp_reproduces_constant_and_rotation_fields_on_flat_meshes():
    """On a flat mesh, Whitney forms reproduce `a + b J p` (constant plus infinitesimal rotation) exactly,
    so their corner values, and any average of them, are exact at every vertex, boundary included."""
    mesh = load("small_disk.obj")  # z = 0, irregular, obtuse faces, boundary
    V = np.asarray(mesh.vertices)
    rotation = np.array([[0.0, -0.8, 0.0], [0.8, 0.0, 0.0], [0.0, 0.0, 0.0]])
    constant = np.array([0.3, -1.2, 0.0])
    for field in (np.broadcast_to(constant, V.shape), V @ rotation.T + constant):
        got = np.asarray(vertex_round_trip(mesh, jnp.asarray(field)))
        np.testing.assert_allclose(got, field, rtol=0, atol=1e-14)


def test_vertex_sharp_reproduces_linear_fields_where_the_one_ring_is_symmetric():
    """A general linear field (symmetric part too) is exact at the interior vertices of a regular grid,
    whose one-rings are point-symmetric, so the corner errors of opposite faces cancel; at the boundary
    (one-sided rings) it is not."""
    mesh = grid(6, 5, size=2.0)
    V = np.asarray(mesh.vertices)
    A = np.zeros((3, 3))
    A[:2, :2] = [[0.7, -1.1], [0.4, 1.3]]
    field = V @ A.T + np.array([0.2, 0.5, 0.0])
    got = np.asarray(vertex_round_trip(mesh, jnp.asarray(field)))
    interior = np.ones(mesh.n_vertices, dtype=bool)
    interior[mesh.topology.boundary_vertices] = False
    np.testing.assert_allclose(got[interior], field[interior], rtol=0, atol=1e-14)
    assert np.abs(got[~interior] - field[~interior]).max() > 1e-3


def sphere_field(p):
    """A smooth tangent field on the unit sphere: a rotation plus the tangent part of a constant."""
    n = p / jnp.linalg.norm(p)
    c = jnp.asarray([1.0, 0.2, -0.4])
    return jnp.cross(jnp.asarray([0.3, -0.5, 0.8]), n) + c - jnp.dot(n, c) * n


@jax.jit
def sphere_sharp_errors(mesh):
    """Max error of the vertex and face sharps of the de Rham map of `sphere_field`."""
    alpha = dec.integrate_1form(mesh, sphere_field, degree=6)
    barycentres = jnp.mean(mesh.vertices[mesh.faces], axis=1)
    at_vertices = dec.sharp(mesh, alpha, at="vertices") - jax.vmap(sphere_field)(mesh.vertices)
    at_faces = dec.sharp(mesh, alpha) - jax.vmap(sphere_field)(barycentres)
    return jnp.max(jnp.abs(at_vertices)), jnp.max(jnp.abs(at_faces))


@pytest.mark.slow
def test_sharp_converges_on_the_sphere(icospheres):
    levels = [2, 3, 4]
    errors = np.array([[float(e) for e in sphere_sharp_errors(icospheres(level))] for level in levels])
    h = 2.0 ** -np.asarray(levels)
    # Measured rates 1.15 (vertices: errors 0.054, 0.023, 0.011) and 1.03 (faces: 0.039, 0.018,
    # 0.0093): first order, as a Whitney (lowest-order) interpolant of a non-constant field is.
    assert fitted_rate(h, errors[:, 0]) > 0.9, errors
    assert fitted_rate(h, errors[:, 1]) > 0.9, errors
    assert errors[-1, 0] < 0.02


def circumcentric_corner_areas(V, F):
    """Each corner's part of its face's circumcentric dual cell, from the circumcentres (acute faces)."""
    p = V[F]
    a, b = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    n = np.cross(a, b)
    centres = p[:, 0] + np.cross(np.sum(a * a, 1)[:, None] * b - np.sum(b * b, 1)[:, None] * a, n) / (
        2 * np.sum(n * n, 1)[:, None]
    )
    areas = np.zeros(F.shape)
    for i in range(3):
        for j in (1, 2):
            midpoint = 0.5 * (p[:, i] + p[:, (i + j) % 3])
            areas[:, i] += 0.5 * np.linalg.norm(np.cross(midpoint - p[:, i], centres - p[:, i]), axis=1)
    return areas, centres


def test_sharp_against_libigl_grad_and_hirani_weights():
    """Faces: `sharp(d0 u)` is libigl's gradient. Vertices: the Whitney corner values, built from libigl's
    hat-function gradients, averaged with circumcentric dual-cell areas computed from the circumcentres
    (Hirani's primal-primal sharp; on this acute mesh, equal to the mixed-area weights)."""
    mesh = load("sphere_small.ply")  # angles 54-71 degrees
    V, F = np.asarray(mesh.vertices), mesh.topology.faces
    rng = np.random.default_rng(3)
    u, alpha = rng.standard_normal(mesh.n_vertices), rng.standard_normal(mesh.n_edges)
    got = jax.tree.map(
        np.asarray,
        jax.jit(
            lambda m: {
                "face du": dec.sharp(m, dec.d0(m) @ u),
                "vertex du": dec.sharp(m, dec.d0(m) @ u, at="vertices"),
                "vertex alpha": dec.sharp(m, alpha, at="vertices"),
            }
        )(mesh),
    )
    G = igl.grad(V, F)  # (3 nf, nv), rows x-block, y-block, z-block
    face_gradients = (G @ u).reshape(3, -1).T
    np.testing.assert_allclose(got["face du"], face_gradients, rtol=0, atol=1e-12 * np.abs(face_gradients).max())

    weights, centres = circumcentric_corner_areas(V, F)
    # The circumcentres are equidistant from the three corners (checks the formula above).
    distances = np.linalg.norm(V[F] - centres[:, None, :], axis=2)
    np.testing.assert_allclose(distances, np.repeat(distances[:, :1], 3, axis=1), rtol=1e-12)
    hat = np.stack([G[k * F.shape[0] : (k + 1) * F.shape[0]].toarray() for k in range(3)], axis=2)  # (nf, nv, 3)
    edge_index = {tuple(e): k for k, e in enumerate(mesh.topology.edges.tolist())}

    def along(i, j):  # alpha integrated from vertex i to vertex j
        return alpha[edge_index[(min(i, j), max(i, j))]] * (1 if i < j else -1)

    for one_form, key in [(np.asarray(dec.d0(mesh).to_scipy() @ u), "vertex du"), (None, "vertex alpha")]:
        expected = np.zeros((mesh.n_vertices, 3))
        for f, face in enumerate(F.tolist()):
            for k, i in enumerate(face):
                others = [face[(k + 1) % 3], face[(k + 2) % 3]]
                value = sum((u[j] - u[i] if one_form is not None else along(i, j)) * hat[f, j] for j in others)
                expected[i] += weights[f, k] * value
        expected /= np.bincount(F.ravel(), weights=weights.ravel())[:, None]
        np.testing.assert_allclose(got[key], expected, rtol=0, atol=1e-12 * np.abs(expected).max(), err_msg=key)


def test_forms_bad_input():
    mesh = load("tet.obj")
    with pytest.raises(DDGInputError, match="at: expected one of 'faces', 'vertices', got 'edges'"):
        dec.flat(mesh, jnp.zeros((4, 3)), at="edges")
    with pytest.raises(DDGInputError, match="at: expected one of 'faces', 'vertices'"):
        dec.sharp(mesh, jnp.zeros(6), at="corners")
    with pytest.raises(DDGInputError, match="field: expected leading dimension nf"):
        dec.flat(mesh, jnp.zeros((5, 3)))
    with pytest.raises(DDGInputError, match="alpha: expected leading dimension ne = 6"):
        dec.sharp(mesh, jnp.zeros(5))
    with pytest.raises(DDGInputError, match="degree: expected an integer >= 0, got -1"):
        dec.integrate_1form(mesh, lambda p: p, degree=-1)
    with pytest.raises(DDGInputError, match=r"alpha: expected values of shape \(3,\)"):
        dec.integrate_1form(mesh, lambda p: p[0])


@pytest.mark.slow
def test_forms_are_differentiable_in_the_vertices():
    mesh = load("tet.obj")

    def energy(V):
        moved = mesh.with_vertices(V)
        flux = dec.integrate_2form(moved, curl_of_vector_potential, degree=2)
        alpha = dec.integrate_1form(moved, vector_potential, degree=3)
        sharps = jnp.sum(dec.sharp(moved, alpha) ** 2) + jnp.sum(dec.sharp(moved, alpha, at="vertices") ** 2)
        return jnp.sum(flux**2) + sharps

    V = mesh.vertices + 0.05 * jnp.sqrt(jnp.arange(12.0).reshape(4, 3))
    # check_grads' float64 defaults (central differences with eps=1e-4, atol = rtol = 1e-5): the
    # truncation error of the finite difference is O(eps^2) ~ 1e-8 relative, so no finite-difference
    # check can confirm a gradient to 1e-10; 1e-5 still catches any wrong term.
    jax.test_util.check_grads(jax.jit(energy), (V,), order=1, modes=("rev",))
