"""ddgjax.fluids: spectral Euler flow on the unit sphere against closed forms (Haurwitz 1940), invariants, gradients."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import ddgjax
from ddgjax import RESULTS, DDGInputError
from ddgjax.fluids import EulerFlowResult, FluidBasis, euler_flow, fluid_basis, stream_function_velocity
from ddgjax.mesh import Mesh, disk, icosphere


@pytest.fixture(scope="module")
def sphere():
    """icosphere(3) (642 vertices) and its basis of 36 = 6^2 eigenfunctions: degrees l <= 5."""
    mesh = icosphere(3)
    return mesh, fluid_basis(mesh, 36)


@pytest.fixture(scope="module")
def fine_sphere():
    """icosphere(4) (2,562 vertices) and 36 eigenfunctions."""
    mesh = icosphere(4)
    return mesh, fluid_basis(mesh, 36)


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
    np.testing.assert_allclose(np.asarray(basis.function(basis.coriolis)), 2 * z, atol=2e-3)  # z lies in the l = 1 modes


@pytest.mark.slow
def test_single_harmonic_is_steady(sphere):
    mesh, basis = sphere
    x, y, z = _xyz(mesh)
    w0 = 6.0 * x * z  # Y_2^1, stream function -x z: speed up to 1, turnover time 2 pi
    flow = euler_flow(mesh, w0, tau=0.1, steps=200, save_every=20, basis=basis)
    final = np.asarray(flow.value)
    assert isinstance(flow, EulerFlowResult) and flow.vorticity.shape == (11, mesh.n_vertices)
    assert float(flow.times[-1]) == pytest.approx(20.0)  # about 3 turnover times
    correlation = np.corrcoef(final, w0)[0, 1]
    amplitude = _inner(basis, final, w0) / _inner(basis, w0, w0)
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
        assert np.max(np.abs(invariant / invariant[0] - 1)) < 1e-13  # measured ~ 2e-15: Newton at round-off
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
    assert np.linalg.norm(turning.dye[-1]) == pytest.approx(np.linalg.norm(turning.dye[0]), rel=1e-3)


def test_stream_function_velocity(sphere):
    mesh, _ = sphere
    velocity = np.asarray(stream_function_velocity(mesh, -mesh.vertices[:, 2]))
    corners = np.asarray(mesh.vertices)[np.asarray(mesh.faces)]
    expected = np.cross([0.0, 0.0, 1.0], corners.mean(axis=1))  # the solid rotation e_z x p
    assert np.max(np.linalg.norm(velocity - expected, axis=1)) < 2e-2  # first order in h ~ 0.1
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    np.testing.assert_allclose(np.sum(velocity * normals, axis=1), 0.0, atol=1e-15)


@pytest.mark.slow
def test_gradient_initial_vorticity():
    mesh = icosphere(2)
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
    fd = (loss(w0 + eps * direction) - loss(w0 - eps * direction)) / (2 * eps)
    assert float(gradient @ direction) == pytest.approx(float(fd), rel=1e-7)  # measured 5e-11


@pytest.mark.slow
def test_gradient_vertex_positions():
    # A perturbed sphere: simple eigenvalues (on the icosphere degrees form exact clusters).
    mesh = icosphere(2)
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
    fd = (loss(vertices + eps * direction) - loss(vertices - eps * direction)) / (2 * eps)
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


def test_bad_input(sphere, without_type_checker):
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
    ]
    for change, name in bad:
        arguments = {"vorticity": x, **good, **change}
        with pytest.raises(DDGInputError, match=name):
            euler_flow(mesh, arguments.pop("vorticity"), **arguments)
    with pytest.raises(DDGInputError, match="basis"):
        euler_flow(icosphere(2), _xyz(icosphere(2))[0], tau=0.1, steps=1, basis=basis)
    with pytest.raises(DDGInputError, match="closed"):
        fluid_basis(disk(4), 8)
    with pytest.raises(DDGInputError, match="mass"):
        fluid_basis(mesh, 8, mass="galerkin")
    with pytest.raises(DDGInputError, match="stream_function"):
        stream_function_velocity(mesh, x[:3])


@pytest.mark.slow
def test_zero_area_face_refused_plainly_and_finite_with_robust():
    """A vertex moved onto its opposite edge (a face of zero area): the mesh's own basis is refused with
    `MeshDataError` naming `robust=True`; the intrinsic Delaunay basis keeps the flow and its gradient finite."""
    mesh = icosphere(2)
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
