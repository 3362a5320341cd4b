"""Tests for ddgjax.pde._energies: Dirichlet, screened Dirichlet, Poisson and gradient-fitting energies."""

from __future__ import annotations

import gpytoolbox
import igl
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

import ddgjax.laplacian
from ddgjax import DDGInputError
from ddgjax.dec import divergence, gradient
from ddgjax.laplacian import cotan_laplacian, mass_matrix
from ddgjax.mesh import Mesh, disk, vertex_dual_areas
from ddgjax.pde._energies import (
    dirichlet_energy,
    gradient_fitting_energy,
    poisson_energy,
    screened_dirichlet_energy,
)

from conftest import read_ddg_reference
from finite_differences import central_difference
from mesh_union import disjoint_union

# Exact identities (autodiff gradient = the stated matrix formula) are checked to round-off: a
# relative 1e-12 of the largest term, since L, M and the libigl matrices sum the same per-face terms
# in different orders. Derivatives in the vertex positions are compared with central finite
# differences of step 1e-4, whose truncation error is ~1e-8 relative, with jax.test_util.check_grads's
# float64 default tolerance (1e-5).

MASS_TYPES = {
    "voronoi": igl.MASSMATRIX_TYPE_VORONOI,
    "barycentric": igl.MASSMATRIX_TYPE_BARYCENTRIC,
    "galerkin": igl.MASSMATRIX_TYPE_FULL,
}

# Each energy with its gradient in the unknowns, jitted once per mesh topology, shape and option
# (eager dispatch of every small op would dominate the test time): `(value, gradient)`.
_dirichlet = jax.jit(jax.value_and_grad(dirichlet_energy, argnums=1))
_poisson = jax.jit(jax.value_and_grad(poisson_energy, argnums=1), static_argnames="mass")
_screened = jax.jit(jax.value_and_grad(screened_dirichlet_energy, argnums=(1, 2)), static_argnames="mass")
_fitting = jax.jit(jax.value_and_grad(gradient_fitting_energy, argnums=1))
_divergence = jax.jit(divergence)
_gradient = jax.jit(gradient)


class Case:
    """A mesh with its libigl matrices and random data (fixed seed)."""

    def __init__(self, mesh: Mesh, seed: int = 0):
        self.mesh = mesh
        self.V = np.asarray(mesh.vertices)
        self.F = np.asarray(mesh.faces, dtype=np.int64)
        self.L = -igl.cotmatrix(self.V, self.F)
        self.M = {kind: igl.massmatrix(self.V, self.F, igl_type) for kind, igl_type in MASS_TYPES.items()}
        self.G = igl.grad(self.V, self.F)  # (3 nf, nv): all x components, then y, then z
        self.areas = igl.doublearea(self.V, self.F) / 2
        rng = np.random.default_rng(seed)
        self.phi = rng.standard_normal(mesh.n_vertices)
        self.rho = rng.standard_normal(mesh.n_vertices)
        self.columns = rng.standard_normal((mesh.n_vertices, 2))
        self.field = rng.standard_normal((mesh.n_faces, 3))

    def face_gradients(self, u):
        return (self.G @ u).reshape(3, -1).T


def _close(actual, expected, rtol=1e-12):
    actual, expected = np.asarray(actual), np.asarray(expected)
    np.testing.assert_allclose(actual, expected, rtol=0, atol=rtol * max(np.abs(expected).max(), 1.0))


def _union(*meshes: Mesh) -> Mesh:
    return disjoint_union([(np.asarray(m.vertices), np.asarray(m.faces)) for m in meshes]).mesh


@pytest.fixture(scope="module")
def case(icosphere2):
    """A closed surface and a flat mesh with boundary, as one disjoint union: the energies and the
    libigl matrices are sums over faces, so each identity below holds on both parts at once, and one
    compiled program per energy serves both."""
    return Case(_union(icosphere2, disk()))


def test_dirichlet_energy_is_the_laplacian_one(case):
    assert dirichlet_energy is ddgjax.laplacian.dirichlet_energy  # re-exported, not duplicated
    value, grad = _dirichlet(case.mesh, case.phi)
    _close(value, 0.5 * case.phi @ (case.L @ case.phi))
    _close(grad, case.L @ case.phi)
    _close(_dirichlet(case.mesh, case.columns)[1], case.L @ case.columns)


@pytest.mark.parametrize("mass", list(MASS_TYPES))
@pytest.mark.slow
def test_poisson_energy_gradient_is_L_phi_plus_M_rho(case, mass):
    L, M, phi, rho = case.L, case.M[mass], case.phi, case.rho
    value, grad = _poisson(case.mesh, phi, rho, mass=mass)
    _close(value, 0.5 * phi @ (L @ phi) + phi @ (M @ rho))
    _close(grad, L @ phi + M @ rho)
    # The same with ddgjax's own matrices, exported to SciPy.
    ours = cotan_laplacian(case.mesh).to_scipy(), mass_matrix(case.mesh, mass=mass).to_scipy()
    _close(grad, ours[0] @ phi + ours[1] @ rho)
    # The issue's `L phi - M rho` is the same energy for -Delta phi = rho: pass -rho.
    _close(_poisson(case.mesh, phi, -rho, mass=mass)[1], L @ phi - M @ rho)
    # Columns are independent problems, their energies summed.
    Phi, Rho = case.columns, case.columns[::-1]
    value, grad = _poisson(case.mesh, Phi, Rho, mass=mass)
    _close(value, sum(_poisson(case.mesh, Phi[:, j], Rho[:, j], mass=mass)[0] for j in range(2)))
    _close(grad, L @ Phi + M @ Rho)


@pytest.mark.parametrize("mass", list(MASS_TYPES))
@pytest.mark.slow
def test_screened_energy_gradient_is_L_plus_s_M_phi(case, mass):
    L, M, phi, s = case.L, case.M[mass], case.phi, 2.5
    value, (grad_phi, grad_s) = _screened(case.mesh, phi, s, mass=mass)
    _close(value, 0.5 * phi @ ((L + s * M) @ phi))
    _close(grad_phi, (L + s * M) @ phi)
    _close(grad_s, 0.5 * phi @ (M @ phi))
    _close(_screened(case.mesh, case.columns, s, mass=mass)[1][0], (L + s * M) @ case.columns)
    # s = 0 is the Dirichlet energy.
    _close(_screened(case.mesh, phi, 0.0, mass=mass)[0], _dirichlet(case.mesh, phi)[0])


def test_gradient_fitting_energy_against_libigl(case):
    phi, X, L = case.phi, case.field, case.L
    residual = case.face_gradients(phi) - X
    value, grad = _fitting(case.mesh, phi, X)
    _close(value, np.sum(case.areas[:, None] * residual**2))
    # grad_phi E_X = 2 (L phi - G^T A X): libigl's G, and ddgjax's integrated divergence (= -G^T A X).
    weak_divergence = case.G.T @ (np.tile(case.areas, 3) * X.T.reshape(-1))
    expected = 2 * (L @ phi - weak_divergence)
    _close(grad, expected)
    _close(grad, 2 * (L @ phi + np.asarray(_divergence(case.mesh, X))))
    # Columns with one field per column.
    fields = np.stack([X, X[::-1]], axis=-1)
    total = sum(_fitting(case.mesh, case.columns[:, j], fields[..., j])[0] for j in range(2))
    _close(_fitting(case.mesh, case.columns, fields)[0], total)


def test_gradient_fitting_energy_vanishes_on_gradients(case):
    phi = case.phi
    scale = float(_fitting(case.mesh, phi, np.zeros((case.mesh.n_faces, 3)))[0])  # int |grad phi|^2
    for X in (np.asarray(_gradient(case.mesh, phi)), case.face_gradients(phi)):
        value, grad = _fitting(case.mesh, phi, X)
        # libigl's G phi rounds differently: squares of ~1e-16 relative differences.
        assert float(value) <= 1e-24 * scale
        _close(grad, np.zeros(case.mesh.n_vertices), rtol=1e-12 * np.abs(case.L @ phi).max())
    np.testing.assert_allclose(scale, 2 * float(_dirichlet(case.mesh, phi)[0]), rtol=1e-12)  # E_0 = int |grad phi|^2


def test_half_gradient_fitting_is_poisson_with_rho_the_divergence(case):
    """The report's derivation, discretely: 1/2 E_X(phi) = poisson_energy(phi, rho) + 1/2 int |X|^2 when
    M rho = div X (lumped M), for every phi. This fixes the sign of the Poisson energy."""
    X = case.field
    areas = np.asarray(vertex_dual_areas(case.mesh))
    rho = np.asarray(_divergence(case.mesh, X)) / areas
    constant = 0.5 * np.sum(case.areas[:, None] * X**2)
    for phi in (case.phi, case.rho, np.zeros(case.mesh.n_vertices)):
        _close(0.5 * _fitting(case.mesh, phi, X)[0], _poisson(case.mesh, phi, rho, mass="voronoi")[0] + constant)


def _bordered_solve(L: sp.spmatrix, b: np.ndarray) -> np.ndarray:
    """Zero-mean solution of the singular L phi = b on a closed connected surface (1^T b = 0)."""
    n = L.shape[0]
    ones = sp.csr_matrix(np.ones((n, 1)))
    system = sp.bmat([[L, ones], [ones.T, None]], format="csc")
    return spla.spsolve(system, np.append(b, 0.0))[:n]


def test_minimiser_on_a_closed_sphere(icosphere3):
    case = Case(icosphere3)
    M = case.M["voronoi"]
    rho = case.rho - np.sum(M @ case.rho) / M.sum()  # compatible: zero mean for M
    b = M @ rho
    phi = _bordered_solve(case.L, -b)  # Delta phi = rho with Delta = -M^{-1} L
    scale = np.abs(b).max()
    energy, grad = _poisson(case.mesh, phi, rho, mass="voronoi")
    _close(grad, np.zeros_like(phi), rtol=1e-10 * scale)  # spsolve round-off
    # A minimum, not a saddle: every nearby phi has a higher energy (convex; constants leave it unchanged).
    rng = np.random.default_rng(1)
    for _ in range(3):
        assert float(_poisson(case.mesh, phi + 1e-3 * rng.standard_normal(phi.shape), rho, mass="voronoi")[0]) > float(energy)
    np.testing.assert_allclose(float(_poisson(case.mesh, phi + 5.0, rho, mass="voronoi")[0]), float(energy), rtol=1e-12)
    # The sign: L phi = M rho makes the gradient of poisson_energy(phi, -rho) vanish.
    phi_minus = _bordered_solve(case.L, b)
    _close(_poisson(case.mesh, phi_minus, -rho, mass="voronoi")[1], np.zeros_like(phi), rtol=1e-10 * scale)


def test_minimiser_with_dirichlet_boundary_is_libigl_and_gpytoolbox_min_quad_with_fixed():
    """poisson_energy is min_quad_with_fixed's objective 1/2 Z^T A Z + Z^T B with A = L, B = M rho."""
    case = Case(disk())
    boundary = igl.boundary_loop(case.F)
    interior = np.setdiff1d(np.arange(case.mesh.n_vertices), boundary)
    values = np.cos(3 * np.arctan2(case.V[boundary, 1], case.V[boundary, 0]))
    M = case.M["galerkin"]
    libigl = igl.min_quad_with_fixed(
        A=sp.csc_matrix(case.L), B=(M @ case.rho)[:, None], known=boundary.astype(np.int64), Y=values[:, None], pd=True
    )[:, 0]
    gpy = gpytoolbox.min_quad_with_fixed(sp.csr_matrix(case.L), c=M @ case.rho, k=boundary, y=values)
    scale = np.abs(M @ case.rho).max()
    for phi in (libigl, gpy):
        np.testing.assert_allclose(phi[boundary], values, rtol=1e-12)
        grad = np.asarray(_poisson(case.mesh, phi, case.rho, mass="galerkin")[1])
        np.testing.assert_allclose(grad[interior], 0, atol=1e-10 * scale)  # sparse direct solve round-off


def test_sign_matches_the_ddg_exercises_poisson_reference():
    """Crane's DDG exercises (test-spp-soln.txt) solve (L + 1e-8 I) phi = -M (rho - mean rho), M barycentric:
    the same Delta phi = rho, so the gradient of poisson_energy vanishes at their phi (up to -1e-8 phi)."""
    data = read_ddg_reference("test-spp-soln.txt")
    mesh = Mesh.from_arrays(data["v"], data["f"].astype(np.int64) - 1)
    mass, rho, phi = data["mass"][:, 0], data["rho"][:, 0], data["phi"][:, 0]
    # The reference's areas carry single-precision rounding (3.5e-8 relative here); its phi solves its
    # own system to 3e-10, so the gradient with our (float64) mass matrix is zero to the areas' rounding.
    _close(vertex_dual_areas(mesh, dual="barycentric"), mass, rtol=1e-7)
    rho = rho - np.sum(mass * rho) / np.sum(mass)
    scale = np.abs(mass * rho).max()
    grad = np.asarray(_poisson(mesh, phi, rho, mass="barycentric")[1])
    # -1e-8 phi: the reference's regularisation. The opposite sign would give 2 M rho instead. Zero up to
    # the reference's single-precision areas (3.5e-8 relative) and its own solve (3e-10).
    np.testing.assert_allclose(grad, -1e-8 * phi, atol=1e-7 * scale)
    assert np.abs(np.asarray(_poisson(mesh, phi, -rho, mass="barycentric")[1])).max() > scale


@pytest.mark.slow
def test_vertex_gradients_against_finite_differences(icosphere1):
    """Forward and reverse mode in the vertex positions against central differences (what
    jax.test_util.check_grads does at order 1), on a closed icosphere and a disk with boundary joined
    into one mesh: one compiled program for both."""
    mesh = _union(icosphere1, disk(n_rings=2))
    rng = np.random.default_rng(2)
    # Off the symmetric positions, so no corner sits on the right angle where the Voronoi area switches formula.
    V = mesh.vertices + 0.05 * jnp.asarray(rng.standard_normal(mesh.vertices.shape))
    phi, rho = (jnp.asarray(rng.standard_normal(mesh.n_vertices)) for _ in range(2))
    X = jnp.asarray(rng.standard_normal((mesh.n_faces, 3)))

    @jax.jit
    def energies(W):  # one program for all four
        moved = mesh.with_vertices(W)
        return jnp.stack(
            [
                poisson_energy(moved, phi, rho, mass="voronoi"),
                poisson_energy(moved, phi, rho, mass="galerkin"),
                screened_dirichlet_energy(moved, phi, 0.7, mass="barycentric"),
                gradient_fitting_energy(moved, phi, X),
            ]
        )

    @jax.jit
    def derivatives(W, tangent, cotangent):  # forward and reverse mode, one program
        _, pullback = jax.vjp(energies, W)
        return jax.jvp(energies, (W,), (tangent,))[1], pullback(cotangent)[0]

    tangent = jnp.asarray(rng.standard_normal(V.shape))
    cotangent = jnp.asarray(rng.standard_normal(4))
    forward, reverse = derivatives(V, tangent, cotangent)
    eps = 1e-4
    finite = central_difference(energies, V, tangent, eps)
    # Central differences of step 1e-4: O(eps^2) ~1e-8 relative truncation; check_grads' float64 tolerance.
    np.testing.assert_allclose(forward, finite, rtol=1e-5, atol=1e-5)
    # Reverse mode against the same differences: the same tolerance.
    np.testing.assert_allclose(jnp.vdot(reverse, tangent), jnp.vdot(cotangent, finite), rtol=1e-5, atol=1e-5)


def test_hessian_vector_products_in_the_unknowns(case):
    """Forward-over-reverse products (what a Newton step of optimistix / lineax uses) are the matrices."""
    mesh, L = case.mesh, case.L
    phi, rho, X, direction = (jnp.asarray(a) for a in (case.phi, case.rho, case.field, case.columns[:, 0]))
    M = case.M["galerkin"]
    energies = {  # energy of phi, its Hessian
        "poisson": (lambda p: poisson_energy(mesh, p, rho, mass="galerkin"), L),
        "screened": (lambda p: screened_dirichlet_energy(mesh, p, 0.7, mass="galerkin"), L + 0.7 * M),
        "fitting": (lambda p: gradient_fitting_energy(mesh, p, X), 2 * L),
    }
    hvps = jax.jit(lambda p, d: [jax.jvp(jax.grad(energy), (p,), (d,))[1] for energy, _ in energies.values()])
    for hvp, (_, matrix) in zip(hvps(phi, direction), energies.values()):
        _close(hvp, matrix @ np.asarray(direction))


@pytest.mark.slow
def test_jit_and_vmap_equal_eager(icosphere1):
    case = Case(icosphere1)
    mesh = case.mesh
    phi, rho, X = (jnp.asarray(a) for a in (case.phi, case.rho, case.field))

    def energies(W, p):  # dirichlet, poisson, screened, fitting
        m = mesh.with_vertices(W)
        return jnp.stack(
            [
                dirichlet_energy(m, p),
                poisson_energy(m, p, rho, mass="galerkin"),
                screened_dirichlet_energy(m, p, 1.5),
                gradient_fitting_energy(m, p, X),
            ]
        )

    rng = np.random.default_rng(3)
    phis = jnp.asarray(rng.standard_normal((3, mesh.n_vertices)))
    vertices = mesh.vertices[None] * (1 + 0.1 * jnp.asarray(rng.random((3, 1, 1))))

    @jax.jit  # one program: the energies, batched over phi, batched over the vertex positions
    def jitted(phis, vertices):
        batched = jax.vmap(lambda p: energies(mesh.vertices, p))(phis)
        return energies(mesh.vertices, phi), batched, jax.vmap(lambda W: energies(W, phi))(vertices)

    # Against op-by-op evaluation, one state at a time. Fused and op-by-op evaluation sum in different
    # orders: round-off.
    eager = (
        np.asarray(energies(mesh.vertices, phi)),
        np.stack([np.asarray(energies(mesh.vertices, p)) for p in phis]),
        np.stack([np.asarray(energies(W, phi)) for W in vertices]),
    )
    for ours, expected in zip(jitted(phis, vertices), eager):
        for k, name in enumerate(("dirichlet", "poisson", "screened", "fitting")):
            np.testing.assert_allclose(ours[..., k], expected[..., k], rtol=1e-13, err_msg=name)


@pytest.mark.slow
def test_degenerate_faces_give_finite_values_and_gradients():
    V = jnp.asarray([[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0], [1, 1, 0], [1, 0, 0.5]], dtype=float)
    mesh = Mesh.from_arrays(V, [[0, 1, 2], [1, 4, 2], [0, 3, 1], [1, 3, 4], [1, 5, 4]])  # face 2 has zero area
    phi = jnp.arange(6.0)
    X = jnp.ones((5, 3))

    def energies(W):
        moved = mesh.with_vertices(W)
        return jnp.stack(
            [
                poisson_energy(moved, phi, phi, mass="voronoi"),
                screened_dirichlet_energy(moved, phi, 2.0, mass="galerkin"),
                gradient_fitting_energy(moved, phi, X),
            ]
        )

    values_and_jacobian = jax.jit(lambda W: (energies(W), jax.jacrev(energies)(W)))  # one program
    for W in (V, V.at[5].set(V[1])):  # also a collapsed (zero-length) edge
        values, jacobian = values_and_jacobian(W)
        assert np.all(np.isfinite(values))
        assert np.all(np.isfinite(jacobian))


def test_bad_input(without_type_checker, icosphere0):
    mesh = icosphere0
    nv, nf = mesh.n_vertices, mesh.n_faces
    phi = jnp.zeros(nv)
    with pytest.raises(DDGInputError, match=r"phi: expected shape \(12,\) or \(12, k\), got \(11,\)"):
        poisson_energy(mesh, jnp.zeros(nv - 1), phi)
    with pytest.raises(DDGInputError, match=r"phi: expected shape"):
        screened_dirichlet_energy(mesh, jnp.zeros((nv, 2, 2)), 1.0)
    with pytest.raises(DDGInputError, match=r"rho: expected the shape of phi, \(12,\), got \(12, 2\)"):
        poisson_energy(mesh, phi, jnp.zeros((nv, 2)))
    with pytest.raises(DDGInputError, match=r"field: expected shape \(20, 3\)"):
        gradient_fitting_energy(mesh, phi, jnp.zeros((nf, 2)))
    with pytest.raises(DDGInputError, match=r"field: expected shape \(20, 3, 2\)"):
        gradient_fitting_energy(mesh, jnp.zeros((nv, 2)), jnp.zeros((nf, 3)))
    with pytest.raises(DDGInputError, match="mass: expected one of"):
        poisson_energy(mesh, phi, phi, mass="lumped")
    with pytest.raises(DDGInputError, match="screening: expected a real scalar"):
        screened_dirichlet_energy(mesh, phi, jnp.ones(2))
    with pytest.raises(DDGInputError, match="screening: expected a real scalar"):
        screened_dirichlet_energy(mesh, phi, 1j)
    with pytest.raises(DDGInputError, match="phi: expected a real floating-point array"):
        poisson_energy(mesh, phi.astype(complex), phi)
    with pytest.raises(DDGInputError, match="mesh: expected a ddgjax Mesh"):
        poisson_energy((mesh.vertices, mesh.faces), phi, phi)
    # Shapes are known under jit: the same message.
    with pytest.raises(DDGInputError, match=r"rho: expected the shape of phi"):
        jax.jit(lambda r: poisson_energy(mesh, phi, r))(jnp.zeros(nv + 1))
