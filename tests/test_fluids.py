"""ddgjax.fluids: spectral Euler flow on the unit sphere against closed forms (Haurwitz 1940), invariants, gradients;
on a torus of revolution, the harmonic flow of the handle against its closed form."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import ddgjax
from ddgjax import RESULTS, DDGInputError, Solution
from ddgjax.fluids import EulerFlowResult, FluidBasis, euler_flow, fluid_basis, stream_function_velocity
from ddgjax.mesh import Mesh, disk, torus

from finite_differences import central_difference


@pytest.fixture(scope="module")
def sphere(icosphere3):
    """icosphere(3) (642 vertices) and its basis of 36 = 6^2 eigenfunctions: degrees l <= 5."""
    return icosphere3, fluid_basis(icosphere3, 36)


@pytest.fixture(scope="module")
def fine_sphere(icosphere4):
    """icosphere(4) (2,562 vertices) and 36 eigenfunctions."""
    return icosphere4, fluid_basis(icosphere4, 36)


def _xyz(mesh):
    return np.asarray(mesh.vertices).T


def _inner(basis, f, g):
    return float(np.sum(np.asarray(basis.mass) * f * g))


def test_basis_tensor_alternating_and_values(sphere):
    mesh, basis = sphere
    W = np.asarray(basis.advection)
    assert isinstance(basis, FluidBasis) and W.shape == (36, 36, 36)
    np.testing.assert_array_equal(W, -np.swapaxes(W, 1, 2))
    np.testing.assert_allclose(W, -np.swapaxes(W, 0, 2), atol=1e-15)
    np.testing.assert_allclose(W, -np.swapaxes(W, 0, 1), atol=1e-15)
    # Degrees 1 and 2 of the unit sphere: l (l + 1) = 2, 6 up to the discretisation (0.6 % on icosphere(3)).
    np.testing.assert_allclose(np.asarray(basis.values[1:9]), [2.0] * 3 + [6.0] * 5, rtol=7e-3)
    x, y, z = _xyz(mesh)
    # z lies in the l = 1 modes, up to the discretisation (the discrete eigenfunctions are z only to O(h^2)).
    np.testing.assert_allclose(np.asarray(basis.function(basis.coriolis)), 2 * z, atol=2e-3)


@pytest.mark.slow
def test_single_harmonic_is_steady(sphere):
    mesh, basis = sphere
    x, y, z = _xyz(mesh)
    w0 = 6.0 * x * z  # Y_2^1, stream function -x z: speed up to 1, turnover time 2 pi
    flow = euler_flow(mesh, w0, tau=0.1, steps=200, save_every=20, basis=basis)
    final = np.asarray(flow.value)
    assert isinstance(flow, EulerFlowResult) and flow.vorticity.shape == (11, mesh.n_vertices)
    assert float(flow.times[-1]) == pytest.approx(20.0, rel=1e-15)  # about 3 turnover times; 200 * 0.1 rounds to 20
    correlation = np.corrcoef(final, w0)[0, 1]
    amplitude = _inner(basis, final, w0) / _inner(basis, w0, w0)
    # Steady up to the discretisation: the projection of x z spills slightly out of l = 2, and that part moves.
    assert correlation > 0.99999  # measured 0.9999988
    assert abs(amplitude - 1) < 1e-5  # measured 1.5e-6 (the projection of x z spills slightly out of l = 2)


def _phase(basis, w, cosine, sine, m):
    """The angle about z by which the pattern `cosine` (with its quarter-turn `sine`) has turned in `w`."""
    return np.arctan2(_inner(basis, w, sine), _inner(basis, w, cosine)) / m


@pytest.mark.slow
@pytest.mark.parametrize(("degree", "order"), [(2, 1), (3, 2)])
def test_rossby_haurwitz_wave(fine_sphere, degree, order):
    mesh, basis = fine_sphere
    x, y, z = _xyz(mesh)
    # Re and Im of (x + i y)^m z: Y_2^1 (x z, y z) and Y_3^2 ((x^2 - y^2) z, 2 x y z).
    cosine, sine = {1: (x * z, y * z), 2: ((x**2 - y**2) * z, 2 * x * y * z)}[order]
    omega, time = 2.0, 3.0
    flow = euler_flow(mesh, cosine, tau=0.015, steps=200, basis=basis, rotation=omega)
    speed = _phase(basis, np.asarray(flow.value), cosine, sine, order) / time
    haurwitz = -2 * omega / (degree * (degree + 1))
    # Discretisation error, second order in h: measured 0.97 % / 1.8 % (l = 2 / 3) on icosphere(3),
    # 0.24 % / 0.46 % on icosphere(4) (the discrete eigenvalues lie below l (l + 1) alike).
    assert speed == pytest.approx(haurwitz, rel=6e-3)


def test_energy_and_enstrophy_conserved(sphere):
    mesh, basis = sphere
    rng = np.random.default_rng(0)
    coefficients = np.zeros(36)
    coefficients[1:16] = rng.normal(size=15)  # degrees 1 to 3
    w0 = np.asarray(basis.function(coefficients))
    flow = euler_flow(mesh, w0, tau=0.05, steps=200, save_every=20, basis=basis)
    assert np.corrcoef(flow.value, w0)[0, 1] < 0.9  # the flow did move
    for invariant in (flow.kinetic_energy, flow.enstrophy):
        invariant = np.asarray(invariant)
        assert np.max(np.abs(invariant / invariant[0] - 1)) < 1e-13  # measured ~ 2e-15: the midpoint solved to round-off
    rotating = euler_flow(mesh, w0, tau=0.05, steps=200, save_every=20, basis=basis, rotation=1.5)
    absolute = 0.5 * np.sum((np.asarray(rotating.coefficients) + 1.5 * np.asarray(basis.coriolis)) ** 2, axis=1)
    for invariant in (np.asarray(rotating.kinetic_energy), absolute):
        assert np.max(np.abs(invariant / invariant[0] - 1)) < 1e-13


def test_viscous_decay(sphere):
    mesh, basis = sphere
    x, y, z = _xyz(mesh)
    nu, time = 0.1, 2.0
    flow = euler_flow(mesh, x * z, tau=0.01, steps=200, save_every=20, basis=basis, viscosity=nu)
    ratio = _inner(basis, np.asarray(flow.value), x * z) / _inner(basis, np.asarray(flow.vorticity[0]), x * z)
    discrete = float(np.mean(np.asarray(basis.values[4:9])))
    assert ratio == pytest.approx(
        np.exp(-nu * discrete * time), rel=1e-5
    )  # Crank-Nicolson: 200 (nu lambda tau)^3 / 12 = 3.6e-6, measured 4.2e-6
    assert ratio == pytest.approx(np.exp(-nu * 6 * time), rel=1e-2)  # lambda 0.6 % below 6: measured 0.68 %


@pytest.mark.slow
def test_dye(fine_sphere):
    mesh, basis = fine_sphere
    x, y, z = _xyz(mesh)
    still = euler_flow(mesh, np.zeros_like(x), tau=0.01, steps=200, basis=basis, dye=x + x * z)
    np.testing.assert_allclose(np.asarray(still.dye[-1]), np.asarray(still.dye[0]), atol=1e-14)
    rate, time = 0.7, 2.0
    # Vorticity 2 rate z is the solid rotation rate e_z x p (stream function -rate z).
    turning = euler_flow(mesh, 2 * rate * z, tau=0.01, steps=200, basis=basis, dye=x)
    angle = _phase(basis, np.asarray(turning.dye[-1]), x, y, 1)
    # Discretisation error: measured 0.39 % on icosphere(3), 0.097 % on icosphere(4).
    assert angle / time == pytest.approx(rate, rel=2e-3)
    # The dye's L2 norm is kept to round-off (Cayley step: 2e-15); this unweighted vertex norm changes as the
    # pattern turns over the icosphere's unequal vertex areas: measured 2.1e-5.
    assert np.linalg.norm(turning.dye[-1]) == pytest.approx(np.linalg.norm(turning.dye[0]), rel=1e-4)


def test_stream_function_velocity(sphere, icospheres):
    mesh, _ = sphere
    velocity = np.asarray(stream_function_velocity(mesh, -mesh.vertices[:, 2]))
    corners = np.asarray(mesh.vertices)[np.asarray(mesh.faces)]
    expected = np.cross([0.0, 0.0, 1.0], corners.mean(axis=1))  # the solid rotation e_z x p
    assert np.max(np.linalg.norm(velocity - expected, axis=1)) < 2e-2  # first order in h ~ 0.1
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    np.testing.assert_allclose(np.sum(velocity * normals, axis=1), 0.0, atol=1e-15)
    # At the vertices: first order (measured 1.2e-2 on icosphere(3), 6.0e-3 on icosphere(4)), the error
    # mostly the area-weighted vertex normal's tilt from the radius, along which the mean is made tangent.
    errors = []
    for level in (3, 4):
        sphere_mesh = icospheres(level)
        points = np.asarray(sphere_mesh.vertices)
        at_vertices = np.asarray(stream_function_velocity(sphere_mesh, -points[:, 2], at="vertices"))
        errors.append(np.max(np.linalg.norm(at_vertices - np.cross([0.0, 0.0, 1.0], points), axis=1)))
    assert errors[1] < 0.007 and errors[1] < errors[0] / 1.8
    with pytest.raises(DDGInputError, match="at"):
        stream_function_velocity(mesh, -mesh.vertices[:, 2], at="edges")


@pytest.mark.slow
def test_gradient_initial_vorticity(icosphere2):
    mesh = icosphere2
    basis = fluid_basis(mesh, 16)
    x, y, z = _xyz(mesh)
    rng = np.random.default_rng(1)
    target = rng.normal(size=x.shape)

    def loss(w0):
        flow = euler_flow(mesh, w0, tau=0.05, steps=10, save_every=5, basis=basis, rotation=0.5, dye=w0 * w0)
        return jnp.sum(flow.value * target) + jnp.sum(flow.dye[-1] ** 2)

    w0 = 3 * x * z + 2 * y + x * y
    direction = rng.normal(size=x.shape)
    gradient = jax.jit(jax.grad(loss))(jnp.asarray(w0))
    eps = 1e-5
    fd = central_difference(loss, w0, direction, eps)
    # Finite differences: O(eps^2) = 1e-10 truncation times the loss's third derivative, plus round-off / eps.
    assert float(gradient @ direction) == pytest.approx(float(fd), rel=1e-7)  # measured 5e-11


@pytest.mark.slow
def test_gradient_vertex_positions(icosphere2):
    # A perturbed sphere: simple eigenvalues (on the icosphere degrees form exact clusters).
    mesh = icosphere2
    rng = np.random.default_rng(2)
    vertices = np.asarray(mesh.vertices) * (1 + 0.05 * rng.uniform(size=(mesh.n_vertices, 1)))
    x, y, z = vertices.T
    w0 = 3 * x * z + y

    def loss(V):
        moved = mesh.with_vertices(V)
        flow = euler_flow(moved, w0, tau=0.05, steps=10, basis=fluid_basis(moved, 16), rotation=0.5)
        return jnp.sum(flow.value * x)

    direction = rng.normal(size=vertices.shape)
    gradient = jax.grad(loss)(jnp.asarray(vertices))
    eps = 1e-6
    fd = central_difference(loss, vertices, direction, eps)
    # Finite differences: O(eps^2) truncation + round-off / eps, the eigensolves' round-off in the basis
    # (divided by 2 eps and by the eigenvalue gaps) on top.
    assert float(jnp.sum(gradient * direction)) == pytest.approx(float(fd), rel=1e-6)  # measured 3e-9


@pytest.mark.slow
def test_jit_with_kept_basis_and_progress(sphere):
    mesh, basis = sphere
    x, y, z = _xyz(mesh)

    @jax.jit
    def final(w0, basis):
        return euler_flow(mesh, w0, tau=0.05, steps=10, save_every=5, basis=basis, dye=w0).value

    eager = euler_flow(mesh, x * z + y, tau=0.05, steps=10, save_every=5, basis=basis, dye=x * z + y)
    np.testing.assert_allclose(np.asarray(final(jnp.asarray(x * z + y), basis)), np.asarray(eager.value), atol=1e-13)
    bar = euler_flow(mesh, x * z + y, tau=0.05, steps=10, save_every=5, basis=basis, dye=x * z + y, progress=True)
    np.testing.assert_allclose(np.asarray(bar.vorticity), np.asarray(eager.vorticity), atol=1e-13)
    np.testing.assert_array_equal(np.asarray(eager.steps), [0, 5, 10])


@pytest.mark.slow
def test_nonfinite_outcome(sphere):
    mesh, basis = sphere
    x = _xyz(mesh)[0]

    @jax.jit
    def run(w0):
        flow = euler_flow(mesh, w0, tau=0.05, steps=4, save_every=2, basis=basis, throw=False)
        return flow.result, flow.first_failure_step

    result, first = run(jnp.asarray(x).at[3].set(jnp.nan))
    assert result == RESULTS.nonfinite and int(first) == 0
    result, first = run(jnp.asarray(x))
    assert result == RESULTS.successful and int(first) == 5
    throwing = jax.jit(lambda w0: euler_flow(mesh, w0, tau=0.05, steps=4, save_every=2, basis=basis).value)
    with pytest.raises(jax.errors.JaxRuntimeError, match="NaN or inf"):
        jax.block_until_ready(throwing(jnp.asarray(x).at[3].set(jnp.nan)))


@pytest.fixture(scope="module")
def ring():
    """A torus of revolution about z (R = 1, r = 0.4; 768 vertices) and 36 eigenfunctions with its 2 harmonic fields."""
    mesh = torus(major_radius=1.0, minor_radius=0.4, n_major=32, n_minor=12)
    return mesh, fluid_basis(mesh, 36)


def _torus_fields(mesh):
    """The closed-form harmonic fields of a surface of revolution about z at the face centroids: `e_phi / rho`
    (round the hole) and `e_s / rho = n x e_phi / rho` (round the tube); `rho` the distance to the axis."""
    corners = np.asarray(mesh.vertices)[np.asarray(mesh.faces)]
    centre = corners.mean(axis=1)
    rho = np.hypot(centre[:, 0], centre[:, 1])
    around_hole = np.stack([-centre[:, 1], centre[:, 0], np.zeros_like(rho)], axis=1) / rho[:, None] ** 2
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return around_hole, np.cross(normals, around_hole)


@pytest.mark.slow
def test_torus_harmonic_fields_against_closed_form():
    # The span of the computed fields against the smooth harmonic fields: the relative L2 residual of each
    # closed-form field's projection, and its fall under refinement (measured 0.074, 0.035 -> 0.037, 0.018:
    # order 1, all that piecewise constant fields can do for a smooth one). The fields are orthonormal, L2-orthogonal to rotated gradients (no vorticity) and to
    # gradients (divergence free) of piecewise linear functions.
    residuals = []
    for n_major, n_minor in [(32, 12), (64, 24)]:
        mesh = torus(major_radius=1.0, minor_radius=0.4, n_major=n_major, n_minor=n_minor)
        basis = fluid_basis(mesh, 16)
        fields, areas = np.asarray(basis.harmonic), np.asarray(basis.areas)
        assert fields.shape == (mesh.n_faces, 2, 3)
        np.testing.assert_allclose(np.einsum("f,fmd,fnd->mn", areas, fields, fields), np.eye(2), atol=1e-12)
        rng = np.random.default_rng(0)
        psi = rng.normal(size=mesh.n_vertices)
        turned = np.asarray(stream_function_velocity(mesh, psi))  # n x grad psi
        normals = np.cross(*np.swapaxes(np.diff(np.asarray(mesh.vertices)[np.asarray(mesh.faces)], axis=1), 0, 1))
        gradient = np.cross(turned, normals / np.linalg.norm(normals, axis=1, keepdims=True))  # grad psi
        for other in (turned, gradient):
            overlap = np.einsum("f,fmd,fd->m", areas, fields, other)
            assert np.abs(overlap).max() < 1e-10 * np.sqrt(np.sum(areas[:, None] * other**2))
        for exact in _torus_fields(mesh):
            coefficients = np.asarray(basis.harmonic_coefficients(exact))
            residual = exact - np.einsum("m,fmd->fd", coefficients, fields)
            residuals.append(np.sqrt(np.sum(areas[:, None] * residual**2) / np.sum(areas[:, None] * exact**2)))
    # First order in h (measured above): piecewise constant fields against smooth ones.
    assert max(residuals[:2]) < 0.08 and max(residuals[2:]) < 0.04
    assert residuals[2] < residuals[0] / 1.8 and residuals[3] < residuals[1] / 1.8


@pytest.mark.slow
def test_torus_harmonic_flow_stays_and_carries_the_dye(ring):
    mesh, basis = ring
    around_hole, around_tube = _torus_fields(mesh)
    coefficients = basis.harmonic_coefficients(around_hole)
    x, y, z = _xyz(mesh)
    with pytest.raises(DDGInputError, match="harmonic"):
        euler_flow(mesh, np.zeros_like(x), tau=0.05, steps=1, harmonic=np.array([np.nan, 0.0]), basis=basis)
    with pytest.raises(DDGInputError, match="harmonic"):
        euler_flow(mesh, np.zeros_like(x), tau=0.05, steps=1, harmonic=np.ones(1), basis=basis)
    with pytest.raises(DDGInputError, match="velocity"):
        basis.harmonic_coefficients(around_hole[:10])
    # Without vorticity a harmonic flow is steady, also viscous (the harmonic fields do not diffuse).
    flow = euler_flow(
        mesh, np.zeros_like(x), tau=0.025, steps=20, save_every=10, harmonic=coefficients, basis=basis, viscosity=0.1, dye=x
    )
    np.testing.assert_array_equal(np.asarray(flow.harmonic), np.tile(np.asarray(coefficients), (3, 1)))
    assert np.abs(np.asarray(flow.vorticity)).max() == 0.0
    assert float(flow.kinetic_energy[0]) == pytest.approx(0.5 * float(coefficients @ coefficients), rel=1e-12)
    # On a frame turning about the axis the flow round the hole stays too (2 Omega z is constant along its
    # streamlines), up to the discrete field's small component round the tube, which crosses them (measured
    # change 3e-4 of the coefficients after t = 1).
    turning = euler_flow(mesh, np.zeros_like(x), tau=0.05, steps=20, harmonic=coefficients, basis=basis, rotation=0.7)
    change = np.abs(np.asarray(turning.harmonic[-1] - turning.harmonic[0])).max()
    assert change < 1e-3 * np.abs(np.asarray(coefficients)).max()
    # The dye x = rho cos(phi) turns at the angular speed 1 / rho^2 of e_phi / rho: x(t) = rho cos(phi - t / rho^2)
    # (the Galerkin solution against the projection of the closed form, relative to its largest value, at t = 0.5:
    # 2.0e-2 here; with k = 64, 1.1e-2 on 48 x 16 and 3.6e-3 on 96 x 32).
    rho, phi = np.hypot(x, y), np.arctan2(y, x)
    exact = rho * np.cos(phi - float(flow.times[-1]) / rho**2)
    projected = np.asarray(basis.function(basis.coefficients(exact)))
    assert np.abs(np.asarray(flow.dye[-1]) - projected).max() < 0.03 * np.abs(projected).max()


@pytest.mark.slow
def test_torus_harmonic_exchange_conserves_energy_and_follows_the_momentum_equation(ring):
    mesh, basis = ring
    x, y, z = _xyz(mesh)
    around_hole, around_tube = _torus_fields(mesh)
    coefficients = basis.harmonic_coefficients(around_hole + 0.5 * around_tube)
    # Two vortex blobs of opposite sign, unevenly placed (a symmetric vorticity would exchange little).
    blobs = 8 * np.exp(-((x - 1.3) ** 2 + y**2 + z**2) / 0.2) - 8 * np.exp(-(x**2 + (y - 0.7) ** 2 + (z - 0.3) ** 2) / 0.2)
    w0 = np.asarray(basis.function(basis.coefficients(blobs)))
    flow = euler_flow(mesh, w0, tau=0.02, steps=100, save_every=10, harmonic=coefficients, basis=basis, rotation=0.5)
    # The energy (harmonic part included) and the enstrophy of the absolute vorticity a + Omega * coriolis.
    absolute_enstrophy = np.sum((np.asarray(flow.coefficients) + 0.5 * np.asarray(basis.coriolis)) ** 2, axis=1)
    for invariant in (np.asarray(flow.kinetic_energy), absolute_enstrophy):
        assert np.abs(invariant / invariant[0] - 1).max() < 1e-12
    harmonic = np.asarray(flow.harmonic)
    assert np.abs(harmonic[-1] - harmonic[0]).max() > 1e-2  # the vorticity does exchange energy with the handle
    # dc_m/dt = -int (w + f) (n x u) . h_m dA (the momentum equation projected on h_m), evaluated from the
    # face velocities (`stream_function_velocity`, not the basis tensors) and face-mean vorticity, against a centred difference of the flow's own coefficients.
    short = euler_flow(mesh, w0, tau=1e-4, steps=2, save_every=1, harmonic=coefficients, basis=basis, rotation=0.5)
    rate = (np.asarray(short.harmonic[2]) - np.asarray(short.harmonic[0])) / 2e-4
    faces = np.asarray(mesh.faces)
    velocity = np.asarray(stream_function_velocity(mesh, short.stream_function[1]) + basis.harmonic_velocity(short.harmonic[1]))
    absolute = np.asarray(short.vorticity[1])[faces].mean(axis=1) + 0.5 * 2 * z[faces].mean(axis=1)
    normals = np.cross(*np.swapaxes(np.diff(np.asarray(mesh.vertices)[faces], axis=1), 0, 1))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    momentum = -np.einsum(
        "f,f,fd,fmd->m", np.asarray(basis.areas), absolute, np.cross(normals, velocity), np.asarray(basis.harmonic)
    )
    # Two quadratures of the same integral: measured 1.9e-2 relative here, 4.7e-3 on 64 x 24, 1.2e-3 on 128 x 48.
    np.testing.assert_allclose(rate, momentum, rtol=3e-2)


@pytest.mark.slow
def test_torus_gradient_through_the_harmonic_exchange(ring):
    mesh, basis = ring
    x, y, z = _xyz(mesh)
    w0 = np.asarray(basis.function(basis.coefficients(np.exp(-((x - 1.3) ** 2 + y**2 + z**2) / 0.2))))

    def loss(w, c):
        flow = euler_flow(mesh, w, tau=0.05, steps=10, save_every=5, harmonic=c, basis=basis, rotation=0.3, dye=x)
        return jnp.sum(flow.dye[-1] * y) + jnp.sum(flow.harmonic[-1] ** 3)

    c0 = jnp.asarray([0.7, -0.4])
    gradient_w, gradient_c = jax.jit(jax.grad(loss, argnums=(0, 1)))(jnp.asarray(w0), c0)
    rng = np.random.default_rng(3)
    dw, dc = rng.normal(size=w0.shape), rng.normal(size=2)
    fd = central_difference(loss, (w0, c0), (dw, dc), eps=1e-5)
    # Finite differences: O(eps^2) = 1e-10 truncation times the loss's third derivative, plus round-off / eps.
    assert float(gradient_w @ dw + gradient_c @ dc) == pytest.approx(float(fd), rel=1e-7)


@pytest.mark.slow
def test_torus_with_a_zero_area_face_keeps_the_harmonic_flow_finite():
    # The harmonic fields vanish on the degenerate face (a closed form's vector there is of size 1 / area);
    # with the intrinsic Delaunay basis the flow, its harmonic part and their gradient stay finite.
    ring = torus(major_radius=1.0, minor_radius=0.4, n_major=24, n_minor=10)
    V = np.array(ring.vertices)
    a, b, c = np.asarray(ring.faces)[0]
    V[a] = (V[b] + V[c]) / 2
    flat = Mesh.from_arrays(V, np.asarray(ring.faces))
    basis = fluid_basis(flat, 16, robust=True)
    assert all(np.all(np.isfinite(np.asarray(leaf))) for leaf in jax.tree.leaves(basis))
    np.testing.assert_array_equal(np.asarray(basis.harmonic[0]), 0.0)
    vorticity = V[:, 0] * V[:, 2]

    def final(harmonic):
        return euler_flow(flat, vorticity, tau=0.01, steps=10, basis=basis, harmonic=harmonic).harmonic[-1]

    flow = euler_flow(flat, vorticity, tau=0.01, steps=10, basis=basis, harmonic=jnp.array([1.0, 0.5]), throw=False)
    assert flow.result == ddgjax.RESULTS.successful
    energy = np.asarray(flow.kinetic_energy)
    assert abs(energy[-1] / energy[0] - 1) < 1e-12
    assert np.all(np.isfinite(np.asarray(jax.jacrev(final)(jnp.array([1.0, 0.5])))))


def test_bad_input(sphere, without_type_checker, icosphere2):
    mesh, basis = sphere
    x = _xyz(mesh)[0]
    good = {"tau": 0.1, "steps": 4, "basis": basis}
    bad = [
        ({"vorticity": x[:-1]}, "vorticity"),
        ({"vorticity": np.where(np.arange(x.size) == 2, np.nan, x)}, "vorticity"),
        ({"tau": 0.0}, "tau"),
        ({"tau": -1.0}, "tau"),
        ({"steps": 0}, "steps"),
        ({"save_every": 3}, "save_every"),
        ({"viscosity": -1.0}, "viscosity"),
        ({"rotation": np.inf}, "rotation"),
        ({"dye": x[:5]}, "dye"),
        ({"method": "semi-lagrangian"}, "method"),
        ({"basis": (basis.values, basis.vectors)}, "basis"),
        ({"basis": None, "k": mesh.n_vertices}, "k"),
        ({"harmonic": np.ones(2)}, "harmonic"),
    ]
    for change, name in bad:
        arguments = {"vorticity": x, **good, **change}
        with pytest.raises(DDGInputError, match=name):
            euler_flow(mesh, arguments.pop("vorticity"), **arguments)
    with pytest.raises(DDGInputError, match="basis"):
        euler_flow(icosphere2, _xyz(icosphere2)[0], tau=0.1, steps=1, basis=basis)
    with pytest.raises(DDGInputError, match="closed"):
        fluid_basis(disk(4), 8)
    with pytest.raises(DDGInputError, match="mass"):
        fluid_basis(mesh, 8, mass="galerkin")
    with pytest.raises(DDGInputError, match="stream_function"):
        stream_function_velocity(mesh, x[:3])


@pytest.mark.slow
def test_zero_area_face_refused_plainly_and_finite_with_robust(icosphere2):
    """A vertex moved onto its opposite edge (a face of zero area): the mesh's own basis is refused with
    `MeshDataError` naming `robust=True`; the intrinsic Delaunay basis keeps the flow and its gradient finite."""
    mesh = icosphere2
    V = np.array(mesh.vertices)
    F = np.asarray(mesh.faces)
    a, b, c = F[0]
    V[a] = (V[b] + V[c]) / 2
    cap = Mesh.from_arrays(V, F)
    vorticity = V[:, 0] * V[:, 2]
    with pytest.raises(ddgjax.MeshDataError, match="robust=True"):
        euler_flow(cap, vorticity, tau=0.01, steps=5, k=16)
    basis = fluid_basis(cap, 16, robust=True)
    solution = euler_flow(cap, vorticity, tau=0.01, steps=20, basis=basis, throw=False)
    assert solution.result == ddgjax.RESULTS.successful
    assert np.all(np.isfinite(np.asarray(solution.vorticity)))
    gradient = jax.grad(lambda w: euler_flow(cap, w, tau=0.01, steps=5, basis=basis).value.sum())(vorticity)
    assert np.all(np.isfinite(np.asarray(gradient)))


def test_fluid_basis_with_throw_false_reports_its_solves(ring):
    """`throw=False`: the basis in a `ddgjax.Solution` with the eigensolve's and the harmonic fields' Poisson
    solve's outcome and stats; the same basis as `throw=True` (the torus has 2 harmonic fields, so both run)."""
    mesh, basis = ring
    solution = fluid_basis(mesh, 36, throw=False)
    assert isinstance(solution, Solution) and solution.result == RESULTS.successful
    assert set(solution.stats) == {"eigenpairs", "poisson"} and float(solution.stats["poisson"]["residual"]) < 1e-10
    np.testing.assert_allclose(solution.value.values, basis.values, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(solution.value.harmonic, basis.harmonic, rtol=1e-10, atol=1e-12)
