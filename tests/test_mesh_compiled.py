"""Tests for the Mesh's compilation semantics: ddgjax kernels compile once per mesh size, a user's jit once per
connectivity; operator plans are built on first use; misuse gets a clear error."""

from __future__ import annotations

import igl
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ddgjax import DDGInputError, MeshDataError
from ddgjax._compile import kernel
from ddgjax.io import save_mesh
from ddgjax.laplacian import cotan_laplacian, dirichlet_energy, laplacian_apply, mass_matrix
from ddgjax.laplacian._cotan import _values as laplacian_values
from ddgjax.laplacian._plan import _VERTEX_PLANS, vertex_plan
from ddgjax.mesh import (
    Mesh,
    check_mesh,
    face_areas,
    icosphere,
    total_mean_curvature,
    vertex_mean_curvatures,
    vertex_pointwise_gaussian_curvatures,
    vertex_principal_curvatures,
)


def _relabelled(mesh: Mesh, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """The same surface with its vertices renumbered: equal counts and pattern width, other connectivity."""
    V, F = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    permutation = np.random.default_rng(seed).permutation(V.shape[0])
    inverse = np.argsort(permutation)
    return V[permutation] * 1.3, inverse[F]


def test_meshes_of_one_size_share_one_program_and_keep_their_own_connectivity(icosphere2):
    first = icosphere2
    V, F = _relabelled(first, seed=0)
    second = Mesh.from_arrays(V, F)
    assert second.topology != first.topology and vertex_plan(second).pattern.width == vertex_plan(first).pattern.width
    first_L = cotan_laplacian(first)
    programs = laplacian_values._cache_size()
    L = cotan_laplacian(second)
    assert laplacian_values._cache_size() == programs  # the second mesh compiled nothing
    # Each mesh's own faces and pattern reach the shared program (nothing of the first is baked in).
    assert abs(L.to_scipy() + igl.cotmatrix(V, F)).max() < 1e-12
    assert abs(first_L.to_scipy() + igl.cotmatrix(np.asarray(first.vertices), np.asarray(first.faces))).max() < 1e-12
    u = jnp.asarray(np.random.default_rng(1).random(V.shape[0]))
    np.testing.assert_allclose(laplacian_apply(second, u), L @ u, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(dirichlet_energy(second, u), 0.5 * u @ (L @ u), rtol=1e-12)
    masses = igl.massmatrix(V, F, igl.MASSMATRIX_TYPE_VORONOI).diagonal()
    np.testing.assert_allclose(mass_matrix(second).diagonal(), masses, rtol=1e-12)
    galerkin = igl.massmatrix(V, F, igl.MASSMATRIX_TYPE_FULL)
    assert abs(mass_matrix(second, mass="galerkin").to_scipy() - galerkin).max() < 1e-12


def test_kernels_cache_by_shape_not_by_topology_object(icosphere1, icosphere2):
    mesh = icosphere1
    calls = []

    @kernel
    def total(m):
        calls.append(1)  # runs once per trace
        return jnp.sum(m.vertices)

    again = Mesh.from_arrays(np.asarray(mesh.vertices), np.asarray(mesh.faces))
    total(mesh), total(again), total(mesh.with_vertices(2 * mesh.vertices))
    assert len(calls) == 1
    total(icosphere2)  # another size: another program
    assert len(calls) == 2


def test_kernels_see_arrays_only(icosphere1):
    seen = []

    @kernel
    def total(m):
        seen.append(m.topology)
        return jnp.sum(m.vertices) + m.n_faces + m.n_edges

    mesh = icosphere1
    assert total(mesh) == pytest.approx(float(jnp.sum(mesh.vertices)) + mesh.n_faces + mesh.n_edges, rel=1e-12)
    assert seen == [None]  # host connectivity is read before the kernel, never baked into the program


def test_a_user_jit_compiles_once_per_connectivity():
    # A mesh of its own, not the shared `icosphere2`: an eager operator leaves the host cache of
    # `degenerate_faces` on a mesh object, and that cache now changes the pytree structure a jit keys on.
    mesh = icosphere(2)
    V, F = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    energy = jax.jit(lambda m: dirichlet_energy(m, m.vertices))
    energy(mesh)
    energy(Mesh.from_arrays(V, F))  # the same arrays again: equal topology, the same program
    energy(Mesh.from_arrays(2 * V, F.copy()))
    assert energy._cache_size() == 1
    assert Mesh.from_arrays(V, F).topology == mesh.topology
    assert hash(Mesh.from_arrays(V, F).topology) == hash(mesh.topology)
    V2, F2 = _relabelled(mesh, seed=3)  # same sizes, other connectivity: its own program and its own answer
    other = Mesh.from_arrays(V2, F2)
    assert other.topology != mesh.topology
    expected = 0.5 * np.sum(V2 * (-igl.cotmatrix(V2, F2) @ V2))
    np.testing.assert_allclose(energy(other), expected, rtol=1e-12)
    assert energy._cache_size() == 2


def test_operator_plans_are_built_on_first_use_and_shared_per_connectivity(icosphere2):
    mesh = Mesh.from_arrays(*_relabelled(icosphere2, seed=7))  # a connectivity no other test has used
    face_areas(mesh)
    vertex_pointwise_gaussian_curvatures(mesh)
    assert mesh.topology not in _VERTEX_PLANS  # areas and curvature need no Laplacian plan
    L = cotan_laplacian(mesh)
    again = Mesh.from_arrays(np.asarray(mesh.vertices), np.asarray(mesh.faces))
    assert vertex_plan(again) is vertex_plan(mesh) and cotan_laplacian(again).pattern is L.pattern
    assert (mass_matrix(mesh, mass="galerkin") + L).pattern is L.pattern  # one pattern for both operators


@pytest.mark.parametrize(
    "function",
    [
        face_areas,
        vertex_pointwise_gaussian_curvatures,
        cotan_laplacian,
        mass_matrix,
        vertex_plan,
        lambda m: laplacian_apply(m, np.zeros(3)),
        lambda m: dirichlet_energy(m, np.zeros(3)),
        check_mesh,
        lambda m: save_mesh("never_written.obj", m),
    ],
)
@pytest.mark.parametrize("wrong", [np.zeros((3, 3)), (np.zeros((3, 3)), np.array([[0, 1, 2]])), "mesh.obj"])
def test_anything_but_a_mesh_is_refused_with_what_to_call(function, wrong, without_type_checker):
    with pytest.raises(DDGInputError, match=r"mesh: expected a ddgjax Mesh.*Mesh\.from_arrays"):
        function(wrong)


def test_calling_the_constructor_directly_points_to_from_arrays(without_type_checker, icosphere0):
    mesh = icosphere0
    with pytest.raises(DDGInputError, match=r"Mesh\.from_arrays"):
        Mesh(mesh.vertices, mesh.faces)


def test_wrong_shapes_under_jit_get_the_same_message_as_outside(icosphere1):
    mesh = icosphere1
    wrong = jnp.zeros(mesh.n_vertices + 1)
    for function in (laplacian_apply, dirichlet_energy):
        with pytest.raises(DDGInputError, match=r"u: expected shape \(42,\) or \(42, k\), got \(43,\)"):
            function(mesh, wrong)
        with pytest.raises(DDGInputError, match=r"u: expected shape \(42,\) or \(42, k\), got \(43,\)"):
            jax.jit(function)(mesh, wrong)
    for move in (mesh.with_vertices, jax.jit(lambda W: mesh.with_vertices(W).vertices)):
        with pytest.raises(DDGInputError, match=r"vertices: expected shape \(42, 3\), got \(43, 3\)"):
            move(jnp.zeros((43, 3)))


def test_compiled_kernels_inside_jit_grad_and_vmap(icosphere1):
    mesh = icosphere1
    u = jnp.asarray(np.random.default_rng(2).random(mesh.n_vertices))
    V = mesh.vertices

    def energy(W):
        return dirichlet_energy(mesh.with_vertices(W), u)

    gradient = jax.grad(energy)(V)
    np.testing.assert_allclose(jax.jit(jax.grad(energy))(V), gradient, rtol=1e-12)
    np.testing.assert_allclose(jax.jit(lambda m, W: dirichlet_energy(m.with_vertices(W), u))(mesh, V), energy(V), rtol=1e-13)
    batched = jax.vmap(lambda s: cotan_laplacian(mesh.with_vertices(s * V)).values)(jnp.asarray([1.0, 2.0]))
    np.testing.assert_allclose(batched[1], batched[0], rtol=1e-12)  # the cotan Laplacian is scale invariant


def test_orientation_is_checked_on_every_mesh_not_served_from_the_cache(icosphere1):
    oriented = icosphere1
    V, F = np.asarray(oriented.vertices), np.asarray(oriented.faces).copy()
    F[0] = F[0, ::-1]  # one face flipped: same sizes, inconsistent orientation
    flipped = Mesh.from_arrays(V, F)
    assert total_mean_curvature(oriented) > 0
    vertex_principal_curvatures(oriented)  # nested kernels reuse the outer check
    for function in (total_mean_curvature, vertex_mean_curvatures, vertex_principal_curvatures):
        with pytest.raises(MeshDataError, match="consistently oriented"):
            function(flipped)


def test_an_eager_kernel_runs_one_program_per_size():
    """An eager call of a mesh kernel runs one compiled program (not op-by-op dispatch), shared by every
    mesh of that size, and gives the jitted answer. (That the program is compiled with ddgjax's XLA:CPU
    options, without YNNPACK fusions, is printed by benchmarks/laplacian.py with its timing.)"""
    from ddgjax.mesh import face_edge_lengths_sq

    mesh = icosphere(5)  # 61k face corners: past the size where XLA:CPU hands reductions to YNNPACK
    programs = face_edge_lengths_sq._cache_size()
    expected = igl.squared_edge_lengths(np.asarray(mesh.vertices), np.asarray(mesh.faces))
    np.testing.assert_allclose(face_edge_lengths_sq(mesh), expected, rtol=1e-12)
    np.testing.assert_allclose(face_edge_lengths_sq(mesh.with_vertices(2 * mesh.vertices)), 4 * expected, rtol=1e-12)
    np.testing.assert_allclose(face_edge_lengths_sq(Mesh.from_arrays(*_relabelled(mesh, seed=4))), 1.69 * expected, rtol=1e-12)
    assert face_edge_lengths_sq._cache_size() - programs <= 1  # (0 when another test compiled this size already)
    plain = jax.jit(face_edge_lengths_sq.__wrapped__)(mesh.without_topology())
    np.testing.assert_allclose(face_edge_lengths_sq(mesh), plain, rtol=1e-15)
