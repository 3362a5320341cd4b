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
from conftest import shared_path

import ddgjax.dec as dec
from ddgjax._errors import DDGInputError
from ddgjax.mesh._geometry import face_normals
from ddgjax.mesh._mesh import Mesh


@functools.cache
def load(name: str) -> Mesh:
    V, F = igl.read_triangle_mesh(str(shared_path("meshes", name)))
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


def test_forms_bad_input():
    mesh = load("tet.obj")
    with pytest.raises(DDGInputError, match="at: expected 'faces' or 'vertices'"):
        dec.flat(mesh, jnp.zeros((4, 3)), at="edges")
    with pytest.raises(DDGInputError, match="field: expected leading dimension nf"):
        dec.flat(mesh, jnp.zeros((5, 3)))
    with pytest.raises(DDGInputError, match="alpha: expected leading dimension ne = 6"):
        dec.sharp(mesh, jnp.zeros(5))
    with pytest.raises(DDGInputError, match="degree: expected a nonnegative int"):
        dec.integrate_1form(mesh, lambda p: p, degree=-1)
    with pytest.raises(DDGInputError, match=r"alpha: expected values of shape \(3,\)"):
        dec.integrate_1form(mesh, lambda p: p[0])


def test_forms_are_differentiable_in_the_vertices():
    mesh = load("tet.obj")

    def energy(V):
        moved = mesh.with_vertices(V)
        flux = dec.integrate_2form(moved, curl_of_vector_potential, degree=2)
        return jnp.sum(flux**2) + jnp.sum(dec.sharp(moved, dec.integrate_1form(moved, vector_potential, degree=3)) ** 2)

    V = mesh.vertices + 0.05 * jnp.sqrt(jnp.arange(12.0).reshape(4, 3))
    jax.test_util.check_grads(jax.jit(energy), (V,), order=1, modes=("rev",))
