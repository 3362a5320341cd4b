"""ddgjax.learn: DiffusionNet's per-shape operators, spectral diffusion, spatial gradients and their batches."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.linalg
import scipy.sparse.linalg as spla
from jax.test_util import check_grads

from ddgjax import LUMPED_MASS_MATRICES, RESULTS, DDGInputError, MeshDataError
from ddgjax.io import load_mesh, save_mesh
from ddgjax.laplacian import cotan_laplacian, mass_matrix
from ddgjax.learn import (
    DiffusionOperators,
    diffusion_operators,
    diffusion_operators_of_meshes,
    spatial_gradient_features,
    spatial_gradients,
    spectral_diffusion,
    stack_diffusion_operators,
)
from ddgjax.mesh import disk, grid

from conftest import unit_icosphere


def _bumpy_sphere(subdivisions: int = 2, seed: int = 0):
    """An icosphere with every vertex moved radially at random: no symmetry, so no repeated eigenvalues."""
    mesh = unit_icosphere(subdivisions)
    V = np.asarray(mesh.vertices)
    scale = 1 + 0.05 * np.random.default_rng(seed).standard_normal((V.shape[0], 1))
    return mesh.with_vertices(jnp.asarray(V * scale))


def _dense_heat(mesh, k, x, times):
    """`Phi diag(exp(-lambda t)) Phi^T M x` from SciPy's dense generalised eigendecomposition of the plain `L`, `M`."""
    L = cotan_laplacian(mesh).to_scipy().toarray()
    M = mass_matrix(mesh).to_scipy().toarray()
    values, vectors = scipy.linalg.eigh(L, M, subset_by_index=[0, k - 1])
    coefficients = vectors.T @ M @ x
    return vectors @ (np.exp(-values[:, None] * times[None, :]) * coefficients)


def test_spectral_diffusion_is_the_truncated_heat_semigroup():
    mesh, k = _bumpy_sphere(), 12
    ops = diffusion_operators(mesh, k, robust=False)
    x = np.random.default_rng(1).standard_normal((mesh.n_vertices, 3))
    times = np.array([0.0, 0.01, 0.3])
    np.testing.assert_allclose(
        spectral_diffusion(jnp.asarray(x), ops, jnp.asarray(times)), _dense_heat(mesh, k, x, times), atol=1e-11
    )
    # One channel as a vector with a scalar time; a negative (learned) time acts as time 0.
    np.testing.assert_allclose(
        spectral_diffusion(jnp.asarray(x[:, 1]), ops, 0.01), _dense_heat(mesh, k, x, times)[:, 1], atol=1e-11
    )
    np.testing.assert_allclose(
        spectral_diffusion(jnp.asarray(x), ops, jnp.asarray([-1.0, 0.01, 0.3])), _dense_heat(mesh, k, x, times), atol=1e-11
    )
    # The operators: M-orthonormal eigenvectors, the lumped mass.
    np.testing.assert_allclose(ops.vectors.T @ (ops.mass[:, None] * ops.vectors), np.eye(k), atol=1e-11)
    np.testing.assert_allclose(ops.mass, mass_matrix(mesh).diagonal(), atol=1e-15)


def _robust_laplacian_pairs(mesh, k):
    import robust_laplacian

    V, F = np.asarray(mesh.vertices), np.asarray(mesh.faces).astype(np.int64)
    L, M = robust_laplacian.mesh_laplacian(V, F, mollify_factor=1e-5)
    values, vectors = spla.eigsh(L.tocsc(), k, M.tocsc(), sigma=-1e-8)
    order = np.argsort(values)
    return values[order], vectors[:, order]


def _check_against_robust_laplacian(mesh, k):
    ops = diffusion_operators(mesh, k, mass="barycentric")  # robust_laplacian's mass is barycentric
    values, vectors = _robust_laplacian_pairs(mesh, k)
    # Both are ARPACK solves to machine precision (tol=0): measured 3.1e-14 relative on camelhead.
    np.testing.assert_allclose(ops.values[1:], values[1:], rtol=1e-10)
    assert abs(float(ops.values[0])) < 1e-10 and abs(values[0]) < 1e-10
    # Eigenspaces: the largest principal angle between the spans; ARPACK's eigenvectors are accurate to
    # ~ its residual (machine precision) over the gap to the next eigenvalue: measured 7e-14.
    angle = scipy.linalg.subspace_angles(np.asarray(ops.vectors), vectors).max()
    assert angle < 1e-10, angle


def test_eigenpairs_match_robust_laplacian_on_a_built_in_mesh():
    _check_against_robust_laplacian(_bumpy_sphere(), 10)


@pytest.mark.slow
def test_eigenpairs_match_robust_laplacian_on_a_mesh_with_slivers(data_mesh):
    _check_against_robust_laplacian(data_mesh("camelhead.off"), 16)  # near-degenerate triangles


@pytest.mark.slow
def test_derivatives_in_the_times_and_the_features_match_finite_differences():
    mesh = _bumpy_sphere(1)
    ops = diffusion_operators(mesh, 8)
    x = jnp.asarray(np.random.default_rng(2).standard_normal((mesh.n_vertices, 2)))
    times = jnp.asarray([0.05, 0.4])  # away from the clamp at 0, where the derivative jumps
    check_grads(lambda x, t: spectral_diffusion(x, ops, t), (x, times), order=1, modes=("fwd", "rev"))
    a = jnp.asarray(np.random.default_rng(3).standard_normal((2, 2, 2)))
    check_grads(lambda x, ar, ai: spatial_gradient_features(spatial_gradients(x, ops), ar, ai), (x, a[0], a[1]), order=1)
    # A learned time below 0 is clamped: no derivative pushes it further.
    assert jax.grad(lambda t: spectral_diffusion(x, ops, t).sum())(jnp.asarray([-0.1, 0.2]))[0] == 0


def _frame_gradient(ops, vector):
    """The constant 3D `vector` in each vertex's frame `(e1, e2)`."""
    return jnp.stack([ops.frames.e1 @ vector, ops.frames.e2 @ vector], axis=-1)


def test_spatial_gradient_is_exact_for_linear_functions_on_a_flat_mesh():
    mesh = grid(7, 6)
    V = np.asarray(mesh.vertices).copy()
    V[:, :2] += 0.03 * np.random.default_rng(4).standard_normal((V.shape[0], 2))  # irregular, still flat
    mesh = mesh.with_vertices(jnp.asarray(V))
    ops = diffusion_operators(mesh, 4)
    slope = np.array([0.7, -1.3, 0.0])
    g = spatial_gradients(jnp.asarray(V @ slope + 2.0), ops)
    # The fit's ridge (1e-12 of the one-ring's second moment) bounds the error, times the condition number.
    np.testing.assert_allclose(g, _frame_gradient(ops, slope), atol=1e-10)
    np.testing.assert_allclose(jnp.abs(ops.frames.normal[:, 2]), 1.0, atol=1e-14)


@pytest.mark.slow
def test_spatial_gradient_converges_on_a_sphere(icospheres):
    errors, spacings = [], []
    for level in (3, 4, 5):  # level 1 is too symmetric: its error is round-off
        mesh = icospheres(level)
        ops = diffusion_operators(mesh, 4)
        V = np.asarray(mesh.vertices)
        tangent = np.array([0.0, 0.0, 1.0]) - V[:, 2:3] * V  # grad of z on the unit sphere
        exact = jnp.stack([jnp.sum(ops.frames.e1 * tangent, -1), jnp.sum(ops.frames.e2 * tangent, -1)], -1)
        errors.append(float(jnp.max(jnp.linalg.norm(spatial_gradients(jnp.asarray(V[:, 2]), ops) - exact, axis=-1))))
        edges = np.asarray(mesh.topology.edges)
        spacings.append(float(np.mean(np.linalg.norm(V[edges[:, 0]] - V[edges[:, 1]], axis=1))))
    rate = np.polyfit(np.log(spacings), np.log(errors), 1)[0]
    assert rate > 0.95, (rate, errors)  # the largest error of a one-ring fit on a curved surface is O(h) (measured 0.99)


def test_gradient_features_do_not_depend_on_the_frames():
    rng = np.random.default_rng(5)
    g = jnp.asarray(rng.standard_normal((40, 3, 2)))
    a_real, a_imag = jnp.asarray(rng.standard_normal((3, 3))), jnp.asarray(rng.standard_normal((3, 3)))
    features = spatial_gradient_features(g, a_real, a_imag)
    z = np.asarray(g[..., 0] + 1j * g[..., 1])
    expected = np.tanh(np.real(np.conj(z) * (z @ (np.asarray(a_real) + 1j * np.asarray(a_imag)).T)))
    np.testing.assert_allclose(features, expected, atol=1e-14)
    for angles in (np.full(40, 0.7), rng.uniform(0, 2 * np.pi, 40)):  # one rotation for all frames, one per vertex
        turned = z * np.exp(1j * angles)[:, None]
        rotated = jnp.asarray(np.stack([turned.real, turned.imag], -1))
        np.testing.assert_allclose(spatial_gradient_features(rotated, a_real, a_imag), features, atol=1e-14)


@pytest.mark.slow
def test_the_cache_hits_recomputes_corrupt_files_and_separates_settings(tmp_path, monkeypatch, icosphere1):
    import ddgjax.learn._operators as module

    mesh = icosphere1
    first = diffusion_operators(mesh, 5, cache_dir=tmp_path)
    files = list(tmp_path.iterdir())
    assert len(files) == 1 and files[0].suffix == ".npz"

    def refuse(*args, **kwargs):
        raise AssertionError("computed although cached")

    with monkeypatch.context() as patch:
        patch.setattr(module, "_compute", refuse)
        hit = diffusion_operators(mesh, 5, cache_dir=tmp_path)
    for a, b in zip(jax.tree.leaves(first), jax.tree.leaves(hit)):
        np.testing.assert_array_equal(a, b)
    assert isinstance(hit.frames, type(first.frames))
    files[0].write_bytes(b"not an npz file")
    again = diffusion_operators(mesh, 5, cache_dir=tmp_path)
    np.testing.assert_array_equal(again.values, first.values)
    assert module._load(files[0]) is not None  # rewritten whole
    diffusion_operators(mesh, 6, cache_dir=tmp_path)
    diffusion_operators(mesh, 5, mass="barycentric", cache_dir=tmp_path)
    diffusion_operators(mesh.with_vertices(mesh.vertices * 2), 5, cache_dir=tmp_path)
    assert sorted(p.suffix for p in tmp_path.iterdir()) == [".npz"] * 4  # no temporary file left


@pytest.mark.slow
def test_stacked_operators_under_vmap_equal_each_mesh():
    meshes = [_bumpy_sphere(1), disk(4), _bumpy_sphere(1, seed=3)]
    ops = [diffusion_operators(mesh, 6) for mesh in meshes]
    batch = stack_diffusion_operators(ops)
    n = batch.mass.shape[1]
    assert n == 64 and batch.gradient_neighbors.shape[2] == 8 and batch.vectors.shape == (3, n, 6)
    rng = np.random.default_rng(6)
    x = jnp.asarray(rng.standard_normal((3, n, 4)))  # padded rows hold junk: they must not matter
    times = jnp.asarray([0.0, 0.1, 0.5, 2.0])
    diffused = jax.vmap(spectral_diffusion, in_axes=(0, 0, None))(x, batch, times)
    gradients = jax.vmap(spatial_gradients)(x, batch)
    for b, (mesh, op) in enumerate(zip(meshes, ops)):
        nv = mesh.n_vertices
        np.testing.assert_allclose(diffused[b, :nv], spectral_diffusion(x[b, :nv], op, times), atol=1e-12)
        np.testing.assert_allclose(gradients[b, :nv], spatial_gradients(x[b, :nv], op), atol=1e-12)
        np.testing.assert_array_equal(diffused[b, nv:], 0.0)
        np.testing.assert_array_equal(gradients[b, nv:], 0.0)
    with pytest.raises(DDGInputError, match="operators: expected one number of eigenpairs k"):
        stack_diffusion_operators([ops[0], diffusion_operators(meshes[0], 5)])
    with pytest.raises(DDGInputError, match="n_vertices: expected an integer >= 61"):
        stack_diffusion_operators(ops, n_vertices=50)


def test_bad_input_is_refused_naming_the_argument(icosphere1):
    mesh = icosphere1
    ops = diffusion_operators(mesh, 4)
    with pytest.raises(DDGInputError, match="k: expected fewer eigenpairs than the mesh's 42 vertices, got 42"):
        diffusion_operators(mesh, 42)
    with pytest.raises(DDGInputError, match=r"times: expected shape \(3,\)"):
        spectral_diffusion(mesh.vertices, ops, jnp.ones(2))
    with pytest.raises(DDGInputError, match=r"x: expected shape \(42,\) or \(42, C\)"):
        spectral_diffusion(jnp.ones((40, 3)), ops, jnp.ones(3))
    with pytest.raises(DDGInputError, match=r"x: expected shape"):
        spatial_gradients(jnp.ones((42, 3, 1)), ops)
    expected = ", ".join(map(repr, LUMPED_MASS_MATRICES))
    with pytest.raises(DDGInputError, match=f"mass: expected one of {expected}, got 'galerkin'"):
        diffusion_operators(mesh, 4, mass="galerkin")


@pytest.mark.slow
def test_a_folder_of_meshes_with_a_degenerate_one(tmp_path, capsys, icosphere1, icosphere2):
    mesh = icosphere2
    V = np.asarray(mesh.vertices).copy()
    f = np.asarray(mesh.faces)[0]
    V[f[2]] = 0.5 * (V[f[0]] + V[f[1]])  # face 0 collapses onto its edge
    degenerate = mesh.with_vertices(jnp.asarray(V))
    with pytest.raises(MeshDataError, match="robust=True"):
        diffusion_operators(degenerate, 4, robust=False)
    meshes = {"a.obj": icosphere1, "b.off": disk(4), "c.obj": degenerate}
    for name, shape in meshes.items():
        save_mesh(tmp_path / name, shape)
    operators = diffusion_operators_of_meshes((load_mesh(tmp_path / name) for name in sorted(meshes)), 5, progress=True)
    assert "diffusion operators" in capsys.readouterr().err  # the progress bar
    for ops, shape in zip(operators, meshes.values()):
        assert isinstance(ops, DiffusionOperators) and ops.vectors.shape == (shape.n_vertices, 5)
        assert all(bool(jnp.all(jnp.isfinite(leaf))) for leaf in jax.tree.leaves(ops))
    # The robust operators of the degenerate mesh are robust_laplacian's (its mass is barycentric).
    values = diffusion_operators(degenerate, 5, mass="barycentric").values
    # ARPACK to machine precision on both sides: measured 3.3e-15.
    np.testing.assert_allclose(values[1:], _robust_laplacian_pairs(degenerate, 5)[0][1:], rtol=1e-10)
    solution = diffusion_operators(degenerate, 5, throw=False)
    assert solution.result == RESULTS.successful and isinstance(solution.value, DiffusionOperators)


@pytest.mark.slow
def test_the_operators_are_differentiable_in_the_vertex_positions():
    from ddgjax.laplacian import intrinsic_delaunay

    mesh = _bumpy_sphere(1)
    triangulation = intrinsic_delaunay(mesh, mollify_factor=1e-5)  # the robust operators, at traced positions

    def summary(V):
        ops = diffusion_operators(mesh.with_vertices(V), 6, robust=triangulation)
        return ops.values[1:].sum() + jnp.sum(ops.gradient_weights**2) + ops.mass.sum() + ops.frames.e1[:, 0].sum()

    check_grads(summary, (mesh.vertices,), order=1, modes=("rev",))
    np.testing.assert_allclose(
        diffusion_operators(mesh, 6, robust=triangulation).values, diffusion_operators(mesh, 6).values, atol=1e-12
    )
    with pytest.raises(DDGInputError, match="intrinsic_delaunay flips edges on the host"):
        jax.grad(lambda V: diffusion_operators(mesh.with_vertices(V), 6).values.sum())(mesh.vertices)
