"""Tests for ddgjax.batch: padded batches of meshes of different sizes and their batched operators.

Every batched operator is checked against its single-mesh namesake on each mesh of a batch of four
(closed sphere and torus, a disk and a grid with boundaries), gradients against the per-mesh
gradients (zero on padding), one compiled program per bucket, the packed view, bad input, and the
batch sharded over two host devices (a subprocess: the device count is fixed when JAX starts).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ddgjax import DDGInputError, Mesh, dec
from ddgjax import batch as db
from ddgjax import laplacian as dl
from ddgjax import mesh as dm

from conftest import REPO, unit_icosphere

MESHES = (unit_icosphere(2), dm.torus(n_major=12, n_minor=6), dm.disk(4), dm.grid(5, 7))


def _jittered(mesh: Mesh, seed: int) -> Mesh:
    rng = np.random.default_rng(seed)
    return mesh.with_vertices(np.asarray(mesh.vertices) + 0.02 * rng.standard_normal((mesh.n_vertices, 3)))


@pytest.fixture(scope="module")
def meshes():
    return [_jittered(mesh, i) for i, mesh in enumerate(MESHES)]


@pytest.fixture(scope="module")
def batch(meshes):
    return db.MeshBatch.from_meshes(meshes)


@pytest.fixture(scope="module")
def values(meshes):
    rng = np.random.default_rng(7)
    return [rng.standard_normal(mesh.n_vertices) for mesh in meshes]


def _close(batched, singles, tol=1e-12):
    for got, want in zip(batched, singles, strict=True):
        np.testing.assert_allclose(got, np.asarray(want), rtol=0, atol=tol)


def test_padded_shapes_masks_and_counts(batch, meshes):
    nv = [m.n_vertices for m in meshes]
    nf = [m.n_faces for m in meshes]
    assert batch.vertices.shape == (4, db.bucket(max(nv)), 3)
    assert batch.faces.shape == (4, db.bucket(max(nf)), 3)
    assert batch.faces.dtype == jnp.int32
    np.testing.assert_array_equal(batch.n_vertices, nv)
    np.testing.assert_array_equal(batch.vertex_mask.sum(axis=1), nv)
    np.testing.assert_array_equal(batch.face_mask.sum(axis=1), nf)
    assert all(leaf.shape[0] == 4 for leaf in jax.tree_util.tree_leaves(batch))


def test_bucket_ladder():
    assert [db.bucket(n) for n in (0, 1, 64, 65, 100, 1000, 1025)] == [64, 64, 64, 80, 112, 1024, 1280]
    sizes = np.arange(64, 100_000, 37)
    padded = np.array([db.bucket(int(n)) for n in sizes])
    assert np.all(padded >= sizes) and np.all(padded < 1.25 * sizes + 1)


@pytest.mark.parametrize("columns", [None, 2])
def test_laplacian_apply_and_energy_equal_single_mesh(batch, meshes, values, columns):
    if columns:
        values = [np.stack([v, v**2], axis=1) for v in values]
    u = db.pad_vertex_values(values, n_vertices=batch.n_padded_vertices)
    applied = db.laplacian_apply(batch, u)
    assert np.all(np.asarray(applied)[~np.asarray(batch.vertex_mask)] == 0.0)
    _close(db.unpad(batch, applied), [dl.laplacian_apply(m, jnp.asarray(v)) for m, v in zip(meshes, values)])
    energies = db.dirichlet_energy(batch, u)
    assert energies.shape == (4,)
    _close(energies, [dl.dirichlet_energy(m, jnp.asarray(v)) for m, v in zip(meshes, values)])


def test_laplacian_equals_libigl(batch, meshes, values):
    igl = pytest.importorskip("igl")
    u = db.pad_vertex_values(values, n_vertices=batch.n_padded_vertices)
    references = [-igl.cotmatrix(np.asarray(m.vertices), np.asarray(m.faces)) @ v for m, v in zip(meshes, values)]
    _close(db.unpad(batch, db.laplacian_apply(batch, u)), references)


@pytest.mark.parametrize("mass", ["voronoi", "barycentric", "galerkin"])
def test_mass_equals_single_mesh(batch, meshes, values, mass):
    u = db.pad_vertex_values(values, n_vertices=batch.n_padded_vertices)
    singles = [dl.mass_matrix(m, mass=mass) for m in meshes]
    _close(db.unpad(batch, db.mass_apply(batch, u, mass=mass)), [M @ jnp.asarray(v) for M, v in zip(singles, values)])
    if mass == "galerkin":
        with pytest.raises(DDGInputError, match="mass"):
            db.lumped_mass(batch, mass=mass)
    else:
        _close(db.unpad(batch, db.lumped_mass(batch, mass=mass)), [M.diagonal() for M in singles])


def test_face_quantities_and_gradient_equal_single_mesh(batch, meshes, values):
    u = db.pad_vertex_values(values, n_vertices=batch.n_padded_vertices)
    for batched, single in ((db.face_areas, dm.face_areas), (db.face_normals, dm.face_normals)):
        result = batched(batch)
        assert np.all(np.asarray(result)[~np.asarray(batch.face_mask)] == 0.0)
        _close(db.unpad(batch, result, at="faces"), [single(m) for m in meshes])
    gradients = db.unpad(batch, db.gradient(batch, u), at="faces")
    _close(gradients, [dec.gradient(m, jnp.asarray(v)) for m, v in zip(meshes, values)])


@pytest.mark.parametrize(("weighting", "normalize"), [("area", True), ("angle", True), ("uniform", False)])
def test_vertex_normals_equal_single_mesh(batch, meshes, weighting, normalize):
    result = db.vertex_normals(batch, weighting=weighting, normalize=normalize)
    _close(db.unpad(batch, result), [dm.vertex_normals(m, weighting=weighting, normalize=normalize) for m in meshes])


@pytest.mark.slow  # ~7 s: compiles the reverse pass of three batched and three single-mesh operators
def test_gradients_equal_per_mesh_and_vanish_on_padding(batch, meshes, values):
    u = db.pad_vertex_values(values, n_vertices=batch.n_padded_vertices)

    def loss(V, u):
        moved = batch.with_vertices(V)
        applied = db.laplacian_apply(moved, u)
        return jnp.sum(db.dirichlet_energy(moved, u)) + jnp.sum(db.face_areas(moved) ** 2) + 0.1 * jnp.sum(applied**2)

    grad_V, grad_u = jax.jit(jax.grad(loss, argnums=(0, 1)))(batch.vertices, u)
    padding = ~np.asarray(batch.vertex_mask)
    assert np.all(np.isfinite(grad_V)) and np.all(np.asarray(grad_V)[padding] == 0.0)
    assert np.all(np.asarray(grad_u)[padding] == 0.0)

    def single(V, mesh, v):
        mesh = mesh.with_vertices(V)
        applied = dl.laplacian_apply(mesh, v)
        return dl.dirichlet_energy(mesh, v) + jnp.sum(dm.face_areas(mesh) ** 2) + 0.1 * jnp.sum(applied**2)

    singles = [jax.grad(single, argnums=(0, 2))(m.vertices, m, jnp.asarray(v)) for m, v in zip(meshes, values)]
    _close(db.unpad(batch, grad_V), [g[0] for g in singles])
    _close(db.unpad(batch, grad_u), [g[1] for g in singles])


def test_operators_work_inside_a_callers_jit_and_vmap(batch, values):
    u = db.pad_vertex_values(values, n_vertices=batch.n_padded_vertices)
    eager = db.laplacian_apply(batch, u)
    np.testing.assert_allclose(jax.jit(db.laplacian_apply)(batch, u), eager, rtol=0, atol=1e-13)
    # vmap over a stack of two batches of one bucket (the leading axis of every leaf).
    stacked = jax.tree_util.tree_map(lambda x: jnp.stack([x, x]), batch)
    twice = jax.vmap(db.laplacian_apply)(stacked, jnp.stack([u, 2 * u]))
    np.testing.assert_allclose(twice[1], 2 * eager, rtol=0, atol=1e-12)


def test_one_program_per_bucket(meshes, icosphere1):
    first = db.MeshBatch.from_meshes(meshes)
    second = db.MeshBatch.from_meshes([_jittered(m, 10 + i) for i, m in enumerate(MESHES[::-1])][:3] + [icosphere1])
    assert jax.tree_util.tree_structure(first) == jax.tree_util.tree_structure(second)
    kernel = db._operators._laplacian
    before = kernel._cache_size()
    for b in (first, second, first):
        db.laplacian_apply(b, jnp.ones(b.vertex_mask.shape))
    assert kernel._cache_size() - before <= 1


def test_packed_view_and_round_trips(batch, meshes, values):
    packed = batch.packed()
    np.testing.assert_array_equal(packed.vertices, np.concatenate([np.asarray(m.vertices) for m in meshes]))
    offsets = np.cumsum([0] + [m.n_vertices for m in meshes[:-1]])
    np.testing.assert_array_equal(packed.faces, np.concatenate([np.asarray(m.faces) + o for m, o in zip(meshes, offsets)]))
    np.testing.assert_array_equal(np.bincount(packed.vertex_meshes), [m.n_vertices for m in meshes])
    np.testing.assert_array_equal(np.bincount(packed.face_meshes), [m.n_faces for m in meshes])
    for rebuilt, mesh in zip(batch.meshes(), meshes):
        np.testing.assert_array_equal(rebuilt.vertices, mesh.vertices)
        np.testing.assert_array_equal(rebuilt.faces, mesh.faces)
    for got, want in zip(batch.unpad(db.pad_vertex_values(values, n_vertices=batch.n_padded_vertices)), values):
        np.testing.assert_array_equal(got, want)
    pairs = db.MeshBatch.from_meshes([(np.asarray(m.vertices), np.asarray(m.faces)) for m in meshes])
    np.testing.assert_array_equal(pairs.vertex_corners, batch.vertex_corners)


def test_bad_input_is_refused_naming_the_argument(batch, meshes):
    with pytest.raises(DDGInputError, match="meshes"):
        db.MeshBatch.from_meshes([])
    with pytest.raises(DDGInputError, match=r"meshes\[1\]"):
        db.MeshBatch.from_meshes([meshes[0], np.zeros((3, 3))])
    with pytest.raises(DDGInputError, match="n_vertices"):
        db.MeshBatch.from_meshes(meshes, n_vertices=10)
    with pytest.raises(DDGInputError, match="n_faces"):
        db.MeshBatch.from_meshes(meshes, n_faces=10)
    with pytest.raises(DDGInputError, match="values"):
        db.pad_vertex_values([np.zeros((3, 2)), np.zeros((4, 3))])
    with pytest.raises(DDGInputError, match="values"):
        db.pad_vertex_values([])
    with pytest.raises(DDGInputError, match="n_vertices"):
        db.pad_vertex_values([np.zeros(100)], n_vertices=64)
    with pytest.raises(DDGInputError, match="u"):
        db.laplacian_apply(batch, jnp.zeros((4, 7)))
    with pytest.raises(DDGInputError, match="batch"):
        db.laplacian_apply(meshes[0], jnp.zeros((1, meshes[0].n_vertices)))
    with pytest.raises(DDGInputError, match="values"):
        db.unpad(batch, np.zeros((4, 3)))
    with pytest.raises(DDGInputError, match="vertices"):
        batch.with_vertices(np.zeros((4, 3, 3)))


_SHARDED = textwrap.dedent(
    """
    import json
    import jax
    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp
    import numpy as np
    from ddgjax import batch as db
    from ddgjax import mesh as dm
    from ddgjax.sharding import shard_batch

    batch = db.MeshBatch.from_meshes([dm.icosphere(2), dm.torus(n_major=12, n_minor=6), dm.disk(4), dm.grid(5, 7)])
    u = db.pad_vertex_values([np.cos(np.asarray(m.vertices)[:, 0]) for m in batch.meshes()], n_vertices=batch.n_padded_vertices)
    sharded, sharded_u = shard_batch((batch, u))
    applied = jax.jit(db.laplacian_apply)(sharded, sharded_u)
    energy = jax.jit(jax.grad(lambda V, b, u: jnp.sum(db.dirichlet_energy(b.with_vertices(V), u))))(sharded.vertices, sharded, sharded_u)
    print(json.dumps({
        "devices": len(jax.devices()),
        "shards": len(sharded.vertices.addressable_shards),
        "apply": float(np.max(np.abs(np.asarray(applied) - np.asarray(db.laplacian_apply(batch, u))))),
        "gradient": float(np.max(np.abs(np.asarray(energy) - np.asarray(jax.grad(
            lambda V: jnp.sum(db.dirichlet_energy(batch.with_vertices(V), u)))(batch.vertices))))),
    }))
    """
)


@pytest.mark.slow  # ~5 s: a fresh interpreter with two host devices imports and compiles
def test_a_batch_sharded_over_two_devices_gives_the_same_answer():
    env = dict(os.environ)
    env["XLA_FLAGS"] = (env.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=2").strip()
    completed = subprocess.run([sys.executable, "-c", _SHARDED], env=env, capture_output=True, text=True, timeout=300, cwd=REPO)
    assert completed.returncode == 0, completed.stderr[-4000:]
    report = json.loads(completed.stdout.strip().splitlines()[-1])
    assert report["devices"] == 2 and report["shards"] == 2
    # The same per-mesh program, partitioned along the batch: agreement to round-off, not bitwise.
    assert report["apply"] < 1e-12
    assert report["gradient"] < 1e-12


@pytest.mark.slow
def test_zero_area_faces_give_zero_and_finite_gradients(meshes):
    # Face 0 is collinear (zero area): it adds nothing, and every derivative stays finite (DESIGN.md, Numerics).
    degenerate = Mesh.from_arrays(np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 1, 0]]), np.array([[0, 1, 2], [0, 1, 3]]))
    batch = db.MeshBatch.from_meshes([degenerate, meshes[2]])
    u = db.pad_vertex_values([np.arange(4.0), np.ones(meshes[2].n_vertices)], n_vertices=batch.n_padded_vertices)

    def loss(V):
        moved = batch.with_vertices(V)
        return jnp.sum(db.dirichlet_energy(moved, u)) + jnp.sum(db.face_normals(moved)) + jnp.sum(db.gradient(moved, u))

    gradient = jax.jit(jax.grad(loss))(batch.vertices)
    assert np.all(np.isfinite(gradient)) and np.all(gradient[~batch.vertex_mask] == 0.0)
    assert db.face_areas(batch)[0, 0] == 0.0 and np.all(db.face_normals(batch)[0, 0] == 0.0)


# ---- shapes that do not depend on the meshes' local structure ----

#: One bucket for every batch below, so that only the meshes' structure differs between them.
PADDED = {"n_vertices": 192, "n_faces": 384}


def _double_cone(ring: int) -> Mesh:
    """A closed double cone: two apexes of valence `ring` (degree `ring`) over a ring of `ring` vertices."""
    angles = 2 * np.pi * np.arange(ring) / ring
    vertices = np.concatenate([np.stack([np.cos(angles), np.sin(angles), 0 * angles], 1), [[0, 0, 1.0], [0, 0, -1.0]]])
    i = np.arange(ring)
    faces = np.concatenate(
        [np.stack([np.full(ring, ring), i, (i + 1) % ring], 1), np.stack([np.full(ring, ring + 1), (i + 1) % ring, i], 1)]
    )
    return Mesh.from_arrays(vertices, faces)


def _with_fins(mesh: Mesh, n_fins: int) -> Mesh:
    """`mesh` with `n_fins` extra triangles on its first edge (`2 + n_fins` faces there: non-manifold)."""
    tail, head = np.asarray(mesh.edges[0])
    V = np.asarray(mesh.vertices)
    apexes = (V[tail] + V[head]) / 2 + 0.3 * np.random.default_rng(3).standard_normal((n_fins, 3))
    new = mesh.n_vertices + np.arange(n_fins)
    faces = np.concatenate([np.asarray(mesh.faces), np.stack([np.full(n_fins, tail), np.full(n_fins, head), new], 1)])
    return Mesh.from_arrays(np.concatenate([V, apexes]), faces)


@pytest.fixture(scope="module")
def structures():
    """A regular icosphere, one with three and one with four faces on an edge, a double cone of valence 24."""
    sphere = _jittered(unit_icosphere(2), 20)
    return {
        "regular": sphere,
        "three faces on an edge": _with_fins(sphere, 1),
        "four faces on an edge": _with_fins(sphere, 2),
        "valence 24": _jittered(_double_cone(24), 21),
    }


def test_batches_of_one_bucket_share_shapes_and_one_program_whatever_the_structure(structures):
    regular = structures["regular"]
    batches = [db.MeshBatch.from_meshes([regular, mesh], **PADDED) for mesh in structures.values()]
    shapes = [jax.tree.map(jnp.shape, b) for b in batches]
    assert all(jax.tree_util.tree_structure(b) == jax.tree_util.tree_structure(batches[0]) for b in batches)
    assert all(s == shapes[0] for s in shapes), shapes
    user_jit = jax.jit(lambda b, u: db.laplacian_apply(b, u))  # a new function: a cache of its own
    kernel = db._operators._laplacian
    before = kernel._cache_size()
    for b in batches:
        u = b.vertices[..., 0]
        np.testing.assert_array_equal(user_jit(b, u), db.laplacian_apply(b, u))
    assert user_jit._cache_size() == 1
    assert kernel._cache_size() - before <= 1


def test_operators_equal_single_mesh_on_non_manifold_and_high_valence_meshes(structures):
    meshes = [structures["three faces on an edge"], structures["valence 24"]]
    batch = db.MeshBatch.from_meshes(meshes, **PADDED)
    rng = np.random.default_rng(8)
    values = [rng.standard_normal((m.n_vertices, 2)) for m in meshes]
    u = db.pad_vertex_values(values, n_vertices=batch.n_padded_vertices)
    _close(
        db.unpad(batch, db.laplacian_apply(batch, u)), [dl.cotan_laplacian(m) @ jnp.asarray(v) for m, v in zip(meshes, values)]
    )
    _close(db.unpad(batch, db.laplacian_apply(batch, u)), [dl.laplacian_apply(m, jnp.asarray(v)) for m, v in zip(meshes, values)])
    _close(db.dirichlet_energy(batch, u), [dl.dirichlet_energy(m, jnp.asarray(v)) for m, v in zip(meshes, values)])
    for mass in ("voronoi", "galerkin"):
        singles = [dl.mass_matrix(m, mass=mass) for m in meshes]
        _close(db.unpad(batch, db.mass_apply(batch, u, mass=mass)), [M @ jnp.asarray(v) for M, v in zip(singles, values)])
    _close(db.unpad(batch, db.lumped_mass(batch)), [dl.mass_matrix(m).diagonal() for m in meshes])


@pytest.mark.slow  # ~10 s: compiles the reverse pass, batched and for each mesh
def test_gradients_through_overflow_rows_and_edges_equal_single_mesh(structures):
    meshes = [structures["three faces on an edge"], structures["valence 24"]]
    batch = db.MeshBatch.from_meshes(meshes, **PADDED)
    rng = np.random.default_rng(8)
    values = [rng.standard_normal((m.n_vertices, 2)) for m in meshes]
    u = db.pad_vertex_values(values, n_vertices=batch.n_padded_vertices)
    weights = db.pad_vertex_values([v[:, 0] for v in values], n_vertices=batch.n_padded_vertices)

    def loss(V):
        moved = batch.with_vertices(V)
        return jnp.sum(weights * db.lumped_mass(moved)) + jnp.sum(db.laplacian_apply(moved, u) ** 2)

    def single(V, mesh, w, v):
        moved = mesh.with_vertices(V)
        return jnp.sum(w * dl.mass_matrix(moved).diagonal()) + jnp.sum(dl.laplacian_apply(moved, v) ** 2)

    grads = db.unpad(batch, jax.grad(loss)(batch.vertices))
    singles = [jax.grad(single)(m.vertices, m, jnp.asarray(v[:, 0]), jnp.asarray(v)) for m, v in zip(meshes, values)]
    # Entries reach ~6e3 on the cone (measured difference 1.8e-12, 3e-16 relative): relative 1e-12.
    _close(grads, singles, tol=1e-12 * max(float(np.max(np.abs(g))) for g in singles))


def test_a_batch_beyond_the_overflow_default_gets_a_larger_bucket_and_the_same_answers():
    # Degree 90 at both apexes: 2 x 84 overflow edges against the default max(16, 3 * 192 // 8) = 72.
    cone = _jittered(_double_cone(90), 22)
    batch = db.MeshBatch.from_meshes([cone], n_vertices=128, n_faces=192)
    assert batch.overflow_edges.shape[1] == db.bucket(2 * 84)
    u = db.pad_vertex_values([np.asarray(cone.vertices)], n_vertices=128)
    _close(db.unpad(batch, db.laplacian_apply(batch, u)), [dl.laplacian_apply(cone, cone.vertices)])
    _close(db.unpad(batch, db.lumped_mass(batch)), [dl.mass_matrix(cone).diagonal()])
