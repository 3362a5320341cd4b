"""ddgjax.learn's DiffusionNet: the block against its definition, batches of meshes of different sizes,
invariance to rigid motions, and a jitted training step that learns."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest
from scipy.spatial.transform import Rotation

from ddgjax import DDGInputError
from ddgjax.batch import MeshBatch, pad_vertex_values, unpad
from ddgjax.learn import (
    MIN_TIME,
    DiffusionNet,
    DiffusionNetBlock,
    diffusion_operators,
    spatial_gradient_features,
    spatial_gradients,
    spectral_diffusion,
    stack_diffusion_operators,
)
from ddgjax.mesh import disk, icosphere, torus, vertex_pointwise_mean_curvatures


def _bumpy(mesh, seed: int, amplitude: float = 0.05):
    """`mesh` with each vertex moved along its position at random: no symmetry, distinct eigenvalues."""
    V = np.asarray(mesh.vertices)
    return mesh.with_vertices(jnp.asarray(V * (1 + amplitude * np.random.default_rng(seed).standard_normal((len(V), 1)))))


@pytest.fixture(scope="module")
def meshes_and_operators(icosphere2):
    meshes = [_bumpy(icosphere2, 0), _bumpy(torus(n_major=20, n_minor=8), 1), _bumpy(disk(5), 2)]
    return meshes, [diffusion_operators(mesh, 12) for mesh in meshes]


@pytest.mark.slow
def test_a_block_is_its_definition(meshes_and_operators):
    """`x + MLP([x, h, tanh Re(conj(grad h) A grad h)])`, `h` the diffusion for the clamped learned times."""
    (mesh, *_), (operators, *_) = meshes_and_operators
    block = DiffusionNetBlock(6, key=jax.random.PRNGKey(0))
    block = eqx.tree_at(lambda b: b.times, block, jnp.array([0.0, -1.0, 0.01, 0.1, 0.5, 2.0]))
    x = jnp.asarray(np.random.default_rng(0).standard_normal((mesh.n_vertices, 6)))
    diffused = spectral_diffusion(x, operators, jnp.maximum(block.times, MIN_TIME))
    features = spatial_gradient_features(spatial_gradients(diffused, operators), block.gradient_real, block.gradient_imag)
    hidden = np.concatenate([x, diffused, features], axis=1)
    for layer in block.mlp.layers[:-1]:  # by hand: ReLU between the MLP's affine layers, none after the last
        hidden = np.maximum(hidden @ np.asarray(layer.weight).T + np.asarray(layer.bias), 0.0)
    last = block.mlp.layers[-1]
    expected = np.asarray(x) + hidden @ np.asarray(last.weight).T + np.asarray(last.bias)
    np.testing.assert_allclose(block(x, operators), expected, atol=1e-12)
    # The learned times start at 0 and are used clamped at MIN_TIME, so diffusion starts as (almost) the identity on the basis.
    fresh = DiffusionNetBlock(6, key=jax.random.PRNGKey(1))
    assert np.all(np.asarray(fresh.times) == 0.0)
    # ... and they learn from there: the clamp passes the derivative (DiffusionNet clamps the parameter itself).
    d_times = eqx.filter_grad(lambda b: jnp.sum(b(x, operators) ** 2))(fresh).times
    assert np.all(np.abs(np.asarray(d_times)) > 0), d_times


@pytest.mark.slow
def test_a_padded_batch_of_meshes_of_different_sizes_equals_each_mesh_alone(meshes_and_operators):
    meshes, operators = meshes_and_operators
    model = DiffusionNet(3, 2, width=8, n_blocks=2, key=jax.random.PRNGKey(0))
    batch = MeshBatch.from_meshes(meshes)
    stacked = stack_diffusion_operators(operators, n_vertices=batch.n_padded_vertices)
    outputs = jax.jit(jax.vmap(model))(batch.vertices, stacked)
    for got, mesh, ops in zip(unpad(batch, outputs), meshes, operators):
        np.testing.assert_allclose(got, model(mesh.vertices, ops), atol=1e-12)


def test_outputs_of_invariant_features_do_not_change_under_a_rigid_motion(meshes_and_operators):
    """Operators, gradient features and MLP are intrinsic: a rotated and moved mesh gives the same outputs
    (the frames turn with the mesh; the gradient features do not depend on them)."""
    (mesh, *_), (operators, *_) = meshes_and_operators
    rotation = Rotation.random(random_state=0).as_matrix()
    moved = mesh.with_vertices(mesh.vertices @ rotation.T + jnp.array([0.3, -1.0, 2.0]))
    moved_operators = diffusion_operators(moved, 12)
    model = DiffusionNet(2, 3, width=8, n_blocks=2, key=jax.random.PRNGKey(1))
    # Invariant inputs: the vertex areas and the squared distance to the centroid.
    features = lambda m, ops: jnp.stack([ops.mass, jnp.sum((m.vertices - m.vertices.mean(0)) ** 2, axis=1)], axis=1)
    expected = model(features(mesh, operators), operators)
    # 1e-9: eigenvectors of distinct eigenvalues come back to round-off times the inverse spectral gap.
    np.testing.assert_allclose(model(features(moved, moved_operators), moved_operators), expected, atol=1e-9)


@pytest.mark.slow
def test_a_jitted_training_step_on_a_batch_learns_curvature():
    """Predicting the pointwise mean curvature from positions on spheres of different radii and sizes:
    a few hundred Adam steps of the whole-batch step, jitted end to end, cut the masked loss tenfold."""
    meshes = [icosphere(s, radius=r) for s, r in [(2, 0.5), (2, 1.0), (3, 0.7), (3, 1.5), (2, 2.0)]]
    batch = MeshBatch.from_meshes(meshes)
    stacked = stack_diffusion_operators([diffusion_operators(m, 16) for m in meshes], n_vertices=batch.n_padded_vertices)
    target = pad_vertex_values([vertex_pointwise_mean_curvatures(m)[:, None] for m in meshes])
    mask = batch.vertex_mask[..., None]
    model = DiffusionNet(3, 1, width=16, n_blocks=2, key=jax.random.PRNGKey(0))
    optimiser = optax.adam(3e-3)

    def loss(model, vertices):
        predicted = jax.vmap(model)(vertices, stacked)
        return jnp.sum(jnp.where(mask, (predicted - target) ** 2, 0.0)) / jnp.sum(mask)

    @eqx.filter_jit
    def step(model, state, key):
        rotations = jax.vmap(lambda k: jax.random.orthogonal(k, 3))(jax.random.split(key, len(meshes)))
        value, grads = eqx.filter_value_and_grad(loss)(model, jnp.einsum("bij,bvj->bvi", rotations, batch.vertices))
        updates, state = optimiser.update(grads, state, model)
        return eqx.apply_updates(model, updates), state, value

    state = optimiser.init(eqx.filter(model, eqx.is_array))
    first = float(loss(model, batch.vertices))
    key = jax.random.PRNGKey(1)
    for _ in range(300):
        key, subkey = jax.random.split(key)
        model, state, value = step(model, state, subkey)
    assert step._cached._cache_size() == 1  # one program for the whole loop
    assert float(loss(model, batch.vertices)) < 0.1 * first, (first, float(value))


def test_bad_sizes_are_refused():
    with pytest.raises(DDGInputError, match="width"):
        DiffusionNetBlock(0, key=jax.random.PRNGKey(0))
    with pytest.raises(DDGInputError, match="n_blocks"):
        DiffusionNet(3, 1, n_blocks=0, key=jax.random.PRNGKey(0))
    with pytest.raises(DDGInputError, match="in_channels"):
        DiffusionNet(0, 1, key=jax.random.PRNGKey(0))
