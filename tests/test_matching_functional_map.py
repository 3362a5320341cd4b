"""Wave kernel signature, matching descriptors and the least-squares functional map, against pyFM."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.sparse as sp
from pyFM.functional import FunctionalMapping
from pyFM.mesh import TriMesh
from pyFM.optimize import energy_func_std, grad_energy_std
from pyFM.optimize.weights import canonical_taus, resolvent_mask
from pyFM.signatures import WKS, auto_HKS, auto_WKS
from scipy.spatial import cKDTree

from ddgjax import RESULTS, DDGInputError, Mesh, Solution
from ddgjax.matching import descriptors, functional_map, spectral_shape
from ddgjax.spectral import wave_kernel_signature

from conftest import unit_icosphere
from finite_differences import central_difference


def _noisy_sphere(seed: int, *, mirror: bool = False) -> Mesh:
    """An icosphere with random vertex noise: no symmetry left, or (`mirror`) only the x -> -x reflection."""
    base = unit_icosphere(2)
    V, F = np.asarray(base.vertices), np.asarray(base.faces)
    noise = 0.08 * np.random.default_rng(seed).standard_normal(V.shape)
    if mirror:
        reflect = np.array([-1.0, 1.0, 1.0])
        partner = cKDTree(V).query(V * reflect)[1]
        noise = (noise + noise[partner] * reflect) / 2
    return Mesh.from_arrays(V + noise * np.linalg.norm(V, axis=1, keepdims=True), F)


def _stretched(mesh: Mesh, factors=(1.3, 1.0, 0.8)) -> Mesh:
    return Mesh.from_arrays(np.asarray(mesh.vertices) * np.asarray(factors), np.asarray(mesh.faces))


def _trimesh(shape) -> TriMesh:
    """pyFM's mesh of the same arrays, holding our mass and eigenpairs (so both see the same basis)."""
    mesh = TriMesh(np.asarray(shape.mesh.vertices), np.asarray(shape.mesh.faces))
    mesh.mass = sp.diags(np.asarray(shape.mass))
    mesh.eigenvalues = np.asarray(shape.values)
    mesh.eigenvectors = np.asarray(shape.vectors)
    return mesh


def _pyfm_energy_args(model, k, weights, reversing=False):
    """The arguments pyFM's `fit` hands `energy_func_std` (weights normalised, `canonical_taus`)."""
    total = sum(weights)
    w_d, w_l, w_c, w_o = (w / total for w in weights)
    model._set_k(k)
    A, B = model.mesh1.project(model.descr1, k=k), model.mesh2.project(model.descr2, k=k)
    descr_op = model._compute_descr_op() if w_c > 0 else []
    orient_op = model._compute_orientation_op(reversing=reversing) if w_o > 0 else []
    mask = resolvent_mask(model.mesh1.eigenvalues[:k], model.mesh2.eigenvalues[:k], gamma=0.5)
    t_d, t_l, t_c, t_o = canonical_taus(A, B, descr_op, orient_op, mask)
    return (w_d / t_d, w_l / t_l, w_c / t_c, w_o / t_o, A, B, descr_op, orient_op, mask)


@pytest.fixture(scope="module")
def pair():
    source = spectral_shape(_noisy_sphere(0), 30)
    target = spectral_shape(_stretched(source.mesh), 30)
    return source, target


@pytest.mark.slow  # the fast tier's time limit (its checks run in the full suite)
def test_wave_kernel_signature_matches_pyfm(pair):
    shape = pair[0]
    values, vectors = np.asarray(shape.values), np.asarray(shape.vectors)
    ours = wave_kernel_signature(shape.values, shape.vectors, n_energies=40)
    np.testing.assert_allclose(ours, auto_WKS(values, vectors, 40), rtol=0, atol=1e-10)
    energies = np.linspace(1.0, 4.0, 7)
    np.testing.assert_allclose(
        wave_kernel_signature(values, vectors, energies=energies, sigma=0.3),
        WKS(values, vectors, energies, 0.3, scaled=True),
        rtol=0,
        atol=1e-10,
    )
    np.testing.assert_allclose(
        jax.jit(lambda v, f: wave_kernel_signature(v, f, n_energies=40))(values, vectors), ours, atol=1e-14
    )


def test_wave_kernel_signature_gradient(pair):
    shape = pair[0]
    weights = np.random.default_rng(1).standard_normal((shape.vectors.shape[0], 10))

    @jax.jit
    def loss(values):
        return jnp.sum(weights * wave_kernel_signature(values, shape.vectors, n_energies=10))

    direction = np.random.default_rng(2).standard_normal(shape.k)
    direction[0] = 0.0  # the zero eigenvalue is dropped: its derivative is 0
    gradient = jax.grad(loss)(shape.values)
    assert np.all(np.isfinite(gradient))
    numeric = central_difference(loss, shape.values, direction, eps=1e-6)
    # Finite differences: rounding of a loss of ~4.6 over eps = 1e-6, against a derivative of only ~0.033,
    # is ~1e-8 relative (measured 2.7e-8).
    np.testing.assert_allclose(gradient @ direction, numeric, rtol=1e-6)


@pytest.mark.parametrize("kind", ["wks", "hks"])
def test_descriptors_match_pyfm(pair, kind):
    source, target = pair
    model = FunctionalMapping(_trimesh(source), _trimesh(target))
    landmarks = np.array([3, 40, 100])
    model.compute_spectral_descriptors(n_descr=25, descr_type=kind.upper(), k_descr=20, landmarks=landmarks)
    for shape, expected in ((source, model.descr1), (target, model.descr2)):
        ours = descriptors(shape, kind=kind, n_descriptors=25, landmarks=landmarks, k=20)
        assert ours.shape == (shape.vectors.shape[0], 25 * 4)
        np.testing.assert_allclose(ours, expected, rtol=0, atol=1e-10 * np.abs(expected).max())
    plain = descriptors(source, kind=kind, n_descriptors=25)
    raw = (auto_WKS if kind == "wks" else auto_HKS)(np.asarray(source.values), np.asarray(source.vectors), 25)
    raw = raw / np.sqrt(np.asarray(source.mass) @ raw**2)
    np.testing.assert_allclose(plain, raw, rtol=0, atol=1e-10 * np.abs(raw).max())


def test_descriptors_bad_input(pair):
    shape = pair[0]
    with pytest.raises(DDGInputError, match="kind"):
        descriptors(shape, kind="sihks")
    with pytest.raises(DDGInputError, match=r"^k: expected an integer in \[2, "):
        descriptors(shape, k=31)
    with pytest.raises(DDGInputError, match="landmarks"):
        descriptors(shape, landmarks=np.array([0, 10_000]))
    with pytest.raises(DDGInputError, match="n_descriptors"):
        descriptors(shape, n_descriptors=0)


def _pyfm_exact_minimiser(args, first_column, k):
    """The minimiser of pyFM's energy with pyFM's fixed first column, from the Hessian probed by its gradient."""
    b = grad_energy_std(np.zeros((k, k)), *args)
    hessian = np.stack([grad_energy_std(e.reshape(k, k), *args) - b for e in np.eye(k * k)], axis=1)
    free = np.arange(k * k) % k != 0
    C = np.zeros(k * k)
    C[~free] = first_column
    C[free] = np.linalg.solve(hessian[np.ix_(free, free)], -grad_energy_std(C.reshape(k, k), *args)[free])
    return C.reshape(k, k)


@pytest.mark.slow
@pytest.mark.parametrize("method", ["cholesky", "cg"])
@pytest.mark.parametrize("orientation_weight", [0.0, 1.0])
def test_functional_map_minimises_pyfm_energy(pair, orientation_weight, method):
    source, target = pair
    k = 20
    model = FunctionalMapping(_trimesh(source), _trimesh(target))
    model.compute_spectral_descriptors(n_descr=30, descr_type="WKS", k_descr=30)
    args = _pyfm_energy_args(model, k, (1e-1, 1e-3, 1.0, orientation_weight))
    model.fit(K=(k, k), w_orient=orientation_weight, factr=10.0, pgtol=1e-12)
    ours = functional_map(
        source,
        target,
        model.descr1,
        model.descr2,
        k_source=k,
        k_target=k,
        orientation_weight=orientation_weight,
        method=method,
    )
    assert ours.shape == (k, k)
    ours_energy, pyfm_energy = energy_func_std(np.asarray(ours), *args), energy_func_std(model.FM_12, *args)
    assert ours_energy <= pyfm_energy * (1 + 1e-10)
    # The reference's Hessian is probed by differences of pyFM's gradient and solved densely: their rounding
    # times the Hessian's condition (~1e4) leaves ~1e-10 (measured 1.3e-10).
    np.testing.assert_allclose(ours, _pyfm_exact_minimiser(args, model.FM_12[:, 0], k), rtol=0, atol=1e-9)
    # pyFM's L-BFGS stops short of the minimiser by about its tolerance times the Hessian's condition (~1e4).
    np.testing.assert_allclose(ours, model.FM_12, rtol=0, atol=1e-4)


@pytest.mark.slow
def test_functional_map_of_an_isometric_pair_is_its_true_map():
    mesh = _noisy_sphere(3)
    permutation = np.random.default_rng(4).permutation(mesh.vertices.shape[0])
    inverse = np.argsort(permutation)
    shuffled = Mesh.from_arrays(np.asarray(mesh.vertices)[permutation], inverse[np.asarray(mesh.faces)])
    source, target = spectral_shape(mesh, 20), spectral_shape(shuffled, 20)
    C = functional_map(
        source,
        target,
        descriptors(source, n_descriptors=40),
        descriptors(target, n_descriptors=40),
    )
    # Target vertex i is source vertex permutation[i]: C = Phi_t^T M_t Phi_s[permutation], diagonal +-1.
    truth = np.asarray(target.vectors).T @ (np.asarray(target.mass)[:, None] * np.asarray(source.vectors)[permutation])
    np.testing.assert_allclose(np.abs(np.diag(truth)), 1.0, atol=1e-10)  # measured 1.6e-15
    # Rounding of the Cholesky solve of the normal equations times their condition: measured 7.0e-11.
    np.testing.assert_allclose(C, truth, atol=1e-9)


@pytest.mark.slow
@pytest.mark.parametrize("orientation", ["preserving", "reversing"])
def test_orientation_term_separates_a_shape_from_its_mirror_image(orientation):
    mesh = _noisy_sphere(5, mirror=True)
    shape = spectral_shape(mesh, 15)
    V, Phi, mass = np.asarray(mesh.vertices), np.asarray(shape.vectors), np.asarray(shape.mass)
    mirror = cKDTree(V).query(V * np.array([-1.0, 1.0, 1.0]))[1]
    identity, mirrored = np.eye(15), Phi.T @ (mass[:, None] * Phi[mirror])
    assert np.abs(identity - mirrored).max() > 1.0  # the mirror map differs
    F = descriptors(shape, n_descriptors=30)
    C = functional_map(shape, shape, F, F, orientation_weight=1.0, orientation=orientation)
    expected, other = (identity, mirrored) if orientation == "preserving" else (mirrored, identity)
    # Rounding of the Cholesky solve times the condition of a nearly symmetric pair's normal equations: measured 5.4e-11.
    np.testing.assert_allclose(C, expected, atol=1e-9)
    assert np.abs(C - other).max() > 1.0


@pytest.mark.slow
@pytest.mark.parametrize("method", ["cholesky", "cg"])
def test_functional_map_gradient_in_the_descriptors(pair, method):
    source, target = pair
    F_s, F_t = descriptors(source, n_descriptors=6), descriptors(target, n_descriptors=6)
    weights = np.random.default_rng(6).standard_normal((8, 8))

    @jax.jit
    def loss(F_s, F_t):
        C = functional_map(source, target, F_s, F_t, k_source=8, k_target=8, orientation_weight=0.5, method=method, rtol=1e-13)
        return jnp.sum(weights * C)

    gradients = jax.grad(loss, argnums=(0, 1))(F_s, F_t)
    rng = np.random.default_rng(7)
    partials = ((lambda x: loss(x, F_t), F_s), (lambda x: loss(F_s, x), F_t))
    for gradient, (partial, at) in zip(gradients, partials):
        direction = rng.standard_normal(gradient.shape)
        numeric = central_difference(partial, np.asarray(at), direction, eps=1e-6)
        # Finite differences: the solve's rounding over eps = 1e-6 against a derivative of ~6-8: measured <= 1.4e-8.
        np.testing.assert_allclose(np.sum(gradient * direction), numeric, rtol=1e-7)


@pytest.mark.slow
@pytest.mark.parametrize("method", ["cholesky", "cg"])
def test_functional_map_jit_and_vmap(pair, method):
    source, target = pair
    F_s = jnp.stack([descriptors(source, n_descriptors=10), descriptors(source, kind="hks", n_descriptors=10)])
    F_t = jnp.stack([descriptors(target, n_descriptors=10), descriptors(target, kind="hks", n_descriptors=10)])

    @jax.jit
    def solve(F_s, F_t):
        return functional_map(source, target, F_s, F_t, k_source=12, k_target=10, orientation_weight=0.3, method=method)

    batched = jax.vmap(solve)(F_s, F_t)
    assert batched.shape == (2, 10, 12)
    for i in range(2):
        single = functional_map(source, target, F_s[i], F_t[i], k_source=12, k_target=10, orientation_weight=0.3, method=method)
        np.testing.assert_allclose(batched[i], single, atol=1e-10)
        np.testing.assert_allclose(solve(F_s[i], F_t[i]), single, atol=1e-10)


@pytest.mark.slow
def test_functional_map_outcome(pair):
    source, target = pair
    F_s, F_t = descriptors(source, n_descriptors=10), descriptors(target, n_descriptors=10)
    solution = functional_map(source, target, F_s, F_t, method="cg", max_steps=1, throw=False)
    assert isinstance(solution, Solution)
    assert solution.result == RESULTS.max_steps_reached
    with pytest.raises(Exception, match="max_steps"):
        functional_map(source, target, F_s, F_t, method="cg", max_steps=1)
    converged = functional_map(source, target, F_s, F_t, method="cg", throw=False)
    assert converged.result == RESULTS.successful and int(converged.stats["num_steps"]) > 1


def test_functional_map_bad_input(pair):
    source, target = pair
    F_s, F_t = descriptors(source, n_descriptors=5), descriptors(target, n_descriptors=5)
    with pytest.raises(DDGInputError, match="source_descriptors"):
        functional_map(source, target, F_s[:-1], F_t)
    with pytest.raises(DDGInputError, match="target_descriptors"):
        functional_map(source, target, F_s, F_t[:, :4])
    with pytest.raises(DDGInputError, match="k_source"):
        functional_map(source, target, F_s, F_t, k_source=31)
    with pytest.raises(DDGInputError, match="k_target"):
        functional_map(source, target, F_s, F_t, k_target=0)
    with pytest.raises(DDGInputError, match="orientation"):
        functional_map(source, target, F_s, F_t, orientation="mirror")
    with pytest.raises(DDGInputError, match="laplacian_weight"):
        functional_map(source, target, F_s, F_t, laplacian_weight=-1.0)
    with pytest.raises(DDGInputError, match="method"):
        functional_map(source, target, F_s, F_t, method="lbfgs")


@pytest.mark.slow
def test_a_flat_energy_still_gives_a_finite_map(icosphere2):
    """An ellipsoid matched to itself: its mirror symmetries leave the energy flat along the sign of
    every antisymmetric eigenfunction (no descriptor sees it), and the dense Hessian singular; the
    map stays finite and a minimiser (its descriptor term as small as CG's)."""
    from ddgjax.matching import descriptors, functional_map, spectral_shape

    mesh = icosphere2
    mesh = mesh.with_vertices(np.asarray(mesh.vertices) * np.array([1.0, 1.3, 0.8]))
    shape = spectral_shape(mesh, 10)
    d = descriptors(shape, n_descriptors=20)
    A = np.asarray(shape.vectors).T @ (np.asarray(shape.mass)[:, None] * np.asarray(d))
    residuals = []
    for method in ("cholesky", "cg"):
        solution = functional_map(shape, shape, d, d, method=method, throw=False)
        C = np.asarray(solution.value)
        assert np.all(np.isfinite(C)), method
        residuals.append(np.linalg.norm(C @ A - A) / np.linalg.norm(A))
    # The Hessian is singular: Cholesky's last pivots are rounding-sized, and their inverses amplify the
    # rounding of its answer (measured 2.9e-14 here, CG 8.9e-16; the bound allows for another platform's pivots).
    assert residuals[0] < 1e-6 and residuals[1] < 1e-6, residuals
