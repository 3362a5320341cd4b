"""Gradient, divergence, curl, codifferential and Hodge Laplacians: libigl / gpytoolbox, the DDG heat
reference, exact identities and analytic fields."""

from __future__ import annotations

import functools

import gpytoolbox
import igl
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import ddgjax.dec as dec
from ddgjax import DDGInputError
from ddgjax.mesh import Mesh, face_areas, face_normals, face_vertex_positions

from conftest import data_path


@functools.cache
def load(name: str) -> Mesh:
    V, F = igl.read_triangle_mesh(str(data_path("meshes", name)))
    return Mesh.from_arrays(V, F)


@functools.cache
def fields(name: str) -> dict:
    """Vector calculus of fixed random data on `name`'s mesh, as host arrays, from one compile."""
    mesh = load(name)
    rng = np.random.default_rng(0)
    u = jnp.asarray(rng.standard_normal(mesh.n_vertices))
    X = jnp.asarray(rng.standard_normal((mesh.n_faces, 3)))

    @jax.jit
    def compute(mesh):
        normals = face_normals(mesh)
        grad_u = dec.gradient(mesh, u)
        tangent = X - jnp.sum(X * normals, axis=1, keepdims=True) * normals
        barycentres = jnp.mean(face_vertex_positions(mesh), axis=1)
        return {
            "u": u,
            "X": X,
            "areas": face_areas(mesh),
            "grad u": grad_u,
            "div grad u": dec.divergence(mesh, grad_u),
            "div X": dec.divergence(mesh, X),
            "curl X": dec.curl(mesh, tangent),
            "div rotated X": dec.divergence(mesh, jnp.cross(normals, tangent)),
            "curl grad u": dec.curl(mesh, grad_u),
            "div rotated grad u": dec.divergence(mesh, jnp.cross(normals, grad_u)),
            "curl rotation": dec.curl(mesh, jnp.cross(normals, barycentres)),
            "div source": dec.divergence(mesh, barycentres),
            "bary areas": dec.hodge0(mesh, dual="barycentric").diagonal(),
            "delta d u": dec.codifferential(mesh, dec.d0(mesh) @ u, degree=1),
            "laplacian0": dec.hodge_laplacian0(mesh, u),
            "laplacian0 weak": dec.hodge_laplacian0(mesh, u, weak=True),
            "star0": dec.hodge0(mesh).diagonal(),
        }

    return jax.tree.map(np.asarray, compute(mesh))


def libigl_laplacian(mesh):
    return -igl.cotmatrix(np.asarray(mesh.vertices), mesh.topology.faces)


@pytest.mark.parametrize("name", ["bob_small.ply", "small_disk.obj", "hourglass_ico.obj"])
@pytest.mark.slow
def test_gradient_and_divergence_against_libigl_and_gpytoolbox(name):
    mesh, r = load(name), fields(name)
    V, F = np.asarray(mesh.vertices), mesh.topology.faces
    G = igl.grad(V, F)
    scale = np.abs(r["grad u"]).max()
    np.testing.assert_allclose(r["grad u"], (G @ r["u"]).reshape(3, -1).T, rtol=0, atol=1e-12 * scale)
    np.testing.assert_allclose(r["grad u"], (gpytoolbox.grad(V, F) @ r["u"]).reshape(3, -1).T, rtol=0, atol=1e-12 * scale)
    # The weak divergence -sum_f A_f grad phi_i . X_f, normal components of X included (and ignored).
    expected = -G.T @ (np.tile(r["areas"], 3) * r["X"].T.ravel())
    np.testing.assert_allclose(r["div X"], expected, rtol=0, atol=1e-12 * np.abs(expected).max())
    L_u = libigl_laplacian(mesh) @ r["u"]
    np.testing.assert_allclose(r["div grad u"], -L_u, rtol=0, atol=1e-12 * np.abs(L_u).max())


def test_divergence_matches_the_ddg_heat_method_reference():
    """`test-heat-soln.txt` stores the negated integrated divergence of its face field X."""
    records: dict[str, list] = {}
    with open(data_path("ddg-exercises", "test-heat-soln.txt")) as handle:
        for line in handle:
            tag, *numbers = line.split()
            if tag in ("v", "f", "X", "div"):
                records.setdefault(tag, []).append(numbers)
    V, F = np.array(records["v"], float), np.array(records["f"], int) - 1
    X, div = np.array(records["X"], float), np.array(records["div"], float).ravel()
    mesh = Mesh.from_arrays(V, F)
    ours = np.asarray(jax.jit(dec.divergence)(mesh, jnp.asarray(X)))
    # Measured max difference 1.2e-9 (entries up to 0.07): the file's printed precision.
    np.testing.assert_allclose(ours, -div, rtol=0, atol=5e-9)


@pytest.mark.parametrize("name", ["bob_small.ply", "small_disk.obj"])
@pytest.mark.slow
def test_curl_identities(name):
    mesh, r = load(name), fields(name)
    interior = np.setdiff1d(np.arange(mesh.n_vertices), mesh.topology.boundary_vertices)
    # curl is the rotated divergence.
    np.testing.assert_allclose(r["curl X"], -r["div rotated X"], rtol=0, atol=1e-13 * np.abs(r["curl X"]).max())
    # Gradients are curl-free and rotated gradients divergence-free, at interior vertices.
    scale = np.abs(r["div grad u"]).max()
    np.testing.assert_allclose(r["curl grad u"][interior], 0.0, atol=1e-13 * scale)
    np.testing.assert_allclose(r["div rotated grad u"][interior], 0.0, atol=1e-13 * scale)
    # Weak forms against the hat functions (which sum to 1): the totals vanish on every mesh.
    for key in ("div X", "curl X", "div grad u"):
        assert abs(r[key].sum()) < 1e-12 * np.abs(r[key]).max(), key


def test_rotation_and_source_fields_on_a_flat_disk():
    """On a plane, X(p) = n x p (a counterclockwise rotation) has curl 2 and X(p) = p divergence 2:
    integrated, 2 x the barycentric dual area at every interior vertex, exactly (fields sampled at
    barycentres)."""
    mesh, r = load("small_disk.obj"), fields("small_disk.obj")
    interior = np.setdiff1d(np.arange(mesh.n_vertices), mesh.topology.boundary_vertices)
    assert interior.size > 5
    np.testing.assert_allclose(r["curl rotation"][interior], 2 * r["bary areas"][interior], rtol=1e-13)
    np.testing.assert_allclose(r["div source"][interior], 2 * r["bary areas"][interior], rtol=1e-13)


@pytest.mark.parametrize("name", ["bob_small.ply", "hourglass_ico.obj"])
def test_codifferential_and_hodge_laplacian0(name):
    mesh, r = load(name), fields(name)
    L_u = libigl_laplacian(mesh) @ r["u"]
    scale = np.abs(L_u).max()
    np.testing.assert_allclose(r["laplacian0 weak"], L_u, rtol=0, atol=1e-12 * scale)
    np.testing.assert_allclose(r["star0"] * r["delta d u"], L_u, rtol=0, atol=1e-12 * scale)
    np.testing.assert_array_equal(r["laplacian0"], r["delta d u"])


@pytest.fixture(scope="module")
def bob_hodge():
    """Dense weak Hodge Laplacians and codifferentials of bob (genus 1), barycentric stars (positive)."""
    mesh = load("bob_small.ply")
    rng = np.random.default_rng(1)
    forms = [jnp.asarray(rng.standard_normal((n, 2))) for n in (mesh.n_vertices, mesh.n_edges, mesh.n_faces)]

    @jax.jit
    def compute(mesh):
        def dense(apply, n):
            return apply(jnp.eye(n))

        stars = [dec.hodge_star_entries(mesh, degree=k, dual="barycentric") for k in range(3)]
        laplacians = [
            dense(lambda x: dec.hodge_laplacian0(mesh, x, dual="barycentric", weak=True), mesh.n_vertices),
            dense(lambda x: dec.hodge_laplacian1(mesh, x, dual="barycentric", weak=True), mesh.n_edges),
            dense(lambda x: dec.hodge_laplacian2(mesh, x, dual="barycentric", weak=True), mesh.n_faces),
        ]
        strong1 = dec.hodge_laplacian1(mesh, forms[1], dual="barycentric")
        d = [dec.d0(mesh) @ forms[0], dec.d1(mesh) @ forms[1]]
        deltas = [dec.codifferential(mesh, forms[k], degree=k, dual="barycentric") for k in (1, 2)]
        return stars, laplacians, strong1, d, deltas

    stars, laplacians, strong1, d, deltas = jax.tree.map(np.asarray, compute(mesh))
    return mesh, [np.asarray(f) for f in forms], stars, laplacians, strong1, d, deltas


def test_codifferential_is_the_adjoint_of_d(bob_hodge):
    """<d a, b>_{k+1} = <a, delta b>_k with <x, y>_k = x^T *_k y."""
    _, forms, stars, _, _, d, deltas = bob_hodge
    for k in (0, 1):
        left = np.einsum("ic,i,ic->c", d[k], stars[k + 1], forms[k + 1])
        right = np.einsum("ic,i,ic->c", forms[k], stars[k], deltas[k])
        np.testing.assert_allclose(left, right, rtol=1e-12)


@pytest.mark.slow
def test_hodge_laplacians_are_symmetric_psd_with_harmonic_kernels(bob_hodge):
    """Weak Delta_k symmetric PSD; kernels: constants (k = 0, 2) and 2 * genus harmonic 1-forms."""
    mesh, forms, stars, laplacians, strong1, _, _ = bob_hodge
    assert mesh.topology.genus == 1
    for k, matrix in enumerate(laplacians):
        np.testing.assert_allclose(matrix, matrix.T, rtol=0, atol=1e-12 * np.abs(matrix).max())
        eigenvalues = np.linalg.eigvalsh(matrix)
        # Zero eigenvalues come out at ~1e-14 x the largest; the smallest nonzero one is ~1e-3 x it.
        kernel = int(np.sum(eigenvalues < 1e-9 * eigenvalues[-1]))
        assert eigenvalues[0] > -1e-9 * eigenvalues[-1]
        assert kernel == (1, 2 * mesh.topology.genus, 1)[k], (k, eigenvalues[:4] / eigenvalues[-1])
    np.testing.assert_allclose(stars[1][:, None] * strong1, laplacians[1] @ forms[1], rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("name", ["bob_small.ply", "small_disk.obj"])
def test_hodge_laplacian2_matches_gpytoolbox(name):
    """`d1 *1^{-1} d1^T *2` from gpytoolbox's `dec_*` (its edge order and orientation cancel in the product)."""
    mesh = load(name)
    V, F = np.asarray(mesh.vertices), mesh.topology.faces
    omega = np.random.default_rng(4).standard_normal((mesh.n_faces, 2))
    got = jax.jit(lambda m: (dec.hodge_laplacian2(m, omega), dec.hodge_laplacian2(m, omega, weak=True)))(mesh)
    d1, star2 = gpytoolbox.dec_d1(F), gpytoolbox.dec_h2inv(V, F)
    strong = d1 @ (gpytoolbox.dec_h1inv(V, F) @ (d1.T @ (star2 @ omega)))
    # Relative to the largest entry: entries near zero carry the cancellation of the sums.
    for value, expected in zip(got, (strong, star2 @ strong)):
        np.testing.assert_allclose(np.asarray(value), expected, rtol=0, atol=1e-12 * np.abs(expected).max())


def test_vector_calculus_bad_input():
    mesh = load("tet.obj")
    with pytest.raises(DDGInputError, match="u: expected leading dimension nv = 4"):
        dec.gradient(mesh, jnp.zeros(5))
    with pytest.raises(DDGInputError, match="field: expected leading dimension nf = 4"):
        dec.divergence(mesh, jnp.zeros((3, 3)))
    with pytest.raises(DDGInputError, match="degree: expected one of 1, 2, got 0"):
        dec.codifferential(mesh, jnp.zeros(4), degree=0)
    with pytest.raises(DDGInputError, match="alpha: expected leading dimension ne = 6"):
        dec.hodge_laplacian1(mesh, jnp.zeros(4))
    # NumPy input is accepted (converted), like every JAX function.
    assert dec.gradient(mesh, np.zeros(4)).shape == (4, 3)


@pytest.mark.slow
def test_degenerate_faces_and_derivatives():
    """Zero-area and needle faces: finite values and gradients; vmap over vertex positions."""
    V = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0], [1, 1, 0], [1, 1e-9, 0]])
    degenerate = Mesh.from_arrays(V, np.array([[0, 1, 3], [1, 2, 3], [0, 2, 1], [0, 4, 2]]))
    u = jnp.asarray([0.3, -1.0, 2.0, 0.5, 0.1])

    def energy(V):
        moved = degenerate.with_vertices(V)
        grad_u = dec.gradient(moved, u)
        alpha = dec.d0(moved) @ u
        return (
            jnp.sum(jnp.tanh(dec.divergence(moved, grad_u)))
            + jnp.sum(jnp.tanh(dec.curl(moved, dec.sharp(moved, alpha))))
            + jnp.sum(jnp.tanh(dec.sharp(moved, alpha, at="vertices")))
            + jnp.sum(jnp.tanh(dec.hodge_laplacian1(moved, alpha, dual="barycentric")))
        )

    value, gradient = jax.jit(jax.value_and_grad(energy))(degenerate.vertices)
    assert np.isfinite(float(value)) and np.all(np.isfinite(np.asarray(gradient)))
    tet = load("tet.obj")
    batch = jnp.stack([tet.vertices, 2.0 * tet.vertices])
    batched = jax.jit(jax.vmap(lambda V: dec.gradient(tet.with_vertices(V), u[:4])))(batch)
    np.testing.assert_allclose(batched[1], 0.5 * batched[0], rtol=1e-14)


def test_gradient_matrix_is_libigls_grad_eagerly_and_under_jit_one_program_per_size(icosphere2):
    from ddgjax.dec._gradient_matrix import _gradient_values

    mesh = icosphere2
    V, F = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    nf = mesh.n_faces
    # igl.grad stacks all x rows, then y, then z: our row 3 f + c is its row c nf + f.
    rows = (np.arange(3)[None, :] * nf + np.arange(nf)[:, None]).ravel()
    expected = igl.grad(V, F).toarray()[rows]
    np.testing.assert_allclose(dec.gradient_matrix(mesh).to_scipy().toarray(), expected, atol=1e-12)
    jitted = jax.jit(lambda m: dec.gradient_matrix(m))(mesh)
    np.testing.assert_allclose(jitted.to_scipy().toarray(), expected, atol=1e-12)
    # Another connectivity of the same size: its own pattern (host, cached), the same compiled program.
    permutation = np.random.default_rng(0).permutation(V.shape[0])
    V2, F2 = V[permutation], np.argsort(permutation)[F]
    programs = _gradient_values._cache_size()
    ours = dec.gradient_matrix(Mesh.from_arrays(V2, F2)).to_scipy().toarray()
    np.testing.assert_allclose(ours, igl.grad(V2, F2).toarray()[rows], atol=1e-12)
    assert _gradient_values._cache_size() == programs
