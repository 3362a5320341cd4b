"""Tests for ddgjax.mesh._compiled: mesh kernels compiled once per mesh size, never per mesh object."""

from __future__ import annotations

import igl
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ddgjax._errors import MeshDataError
from ddgjax.laplacian import cotan_laplacian, dirichlet_energy, laplacian_apply, mass_matrix
from ddgjax.laplacian._cotan import _fem_values
from ddgjax.mesh import Mesh, icosphere, total_mean_curvature, vertex_mean_curvatures, vertex_principal_curvatures
from ddgjax.mesh._compiled import ElementCounts, compiled_kernel, counts_only


def _relabelled(mesh: Mesh, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """The same surface with its vertices renumbered: equal counts and pattern width, other connectivity."""
    V, F = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    permutation = np.random.default_rng(seed).permutation(V.shape[0])
    inverse = np.argsort(permutation)
    return V[permutation] * 1.3, inverse[F]


def test_meshes_of_one_size_share_one_program_and_keep_their_own_connectivity():
    first = icosphere(2)
    V, F = _relabelled(first, seed=0)
    second = Mesh.from_arrays(V, F)
    assert second.topology is not first.topology and second.vertex_pattern.width == first.vertex_pattern.width
    first_L = cotan_laplacian(first)
    programs = _fem_values.compiled._cache_size()
    L = cotan_laplacian(second)
    assert _fem_values.compiled._cache_size() == programs  # the second mesh compiled nothing
    # Each mesh's own faces and pattern reach the shared program (nothing of the first is baked in).
    assert abs(L.to_scipy() + igl.cotmatrix(V, F)).max() < 1e-12
    assert abs(first_L.to_scipy() + igl.cotmatrix(np.asarray(first.vertices), np.asarray(first.faces))).max() < 1e-12
    u = jnp.asarray(np.random.default_rng(1).random(V.shape[0]))
    np.testing.assert_allclose(laplacian_apply(second, u), L @ u, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(dirichlet_energy(second, u), 0.5 * u @ (L @ u), rtol=1e-12)
    masses = igl.massmatrix(V, F, igl.MASSMATRIX_TYPE_VORONOI).diagonal()
    np.testing.assert_allclose(mass_matrix(second).diagonal(), masses, rtol=1e-12)
    galerkin = igl.massmatrix(V, F, igl.MASSMATRIX_TYPE_FULL)
    assert abs(mass_matrix(second, kind="galerkin").to_scipy() - galerkin).max() < 1e-12


def test_kernels_cache_by_shape_not_by_topology_object():
    mesh = icosphere(1)
    calls = []

    @compiled_kernel
    def kernel(m):
        calls.append(1)  # runs once per trace
        return jnp.sum(m.vertices)

    again = Mesh.from_arrays(np.asarray(mesh.vertices), np.asarray(mesh.faces))
    kernel(mesh), kernel(again), kernel(mesh.with_vertices(2 * mesh.vertices))
    assert len(calls) == 1
    kernel(icosphere(2))  # another size: another program
    assert len(calls) == 2


def test_element_counts_refuse_anything_but_the_counts():
    mesh = icosphere(1)
    stand_in = counts_only(mesh).topology
    assert isinstance(stand_in, ElementCounts)
    assert (stand_in.n_vertices, stand_in.n_faces, stand_in.n_edges) == (mesh.n_vertices, mesh.n_faces, mesh.n_edges)
    assert stand_in == ElementCounts(mesh.n_vertices, mesh.n_faces, mesh.n_edges)
    assert stand_in != mesh.topology and hash(stand_in) == hash(ElementCounts(*stand_in._counts))
    with pytest.raises(AttributeError, match="boundary_edges: a compiled mesh kernel sees only the element counts"):
        stand_in.boundary_edges  # noqa: B018
    with pytest.raises(AttributeError, match="compiled mesh kernel"):
        stand_in.is_oriented  # noqa: B018

    @compiled_kernel
    def reads_topology(m):
        return jnp.asarray(m.topology.boundary_vertices)

    with pytest.raises(AttributeError, match="boundary_vertices"):
        reads_topology(mesh)


def test_compiled_kernels_inside_jit_grad_and_vmap():
    mesh = icosphere(1)
    u = jnp.asarray(np.random.default_rng(2).random(mesh.n_vertices))
    V = mesh.vertices

    def energy(W):
        return dirichlet_energy(mesh.with_vertices(W), u)

    gradient = jax.grad(energy)(V)
    np.testing.assert_allclose(jax.jit(jax.grad(energy))(V), gradient, rtol=1e-12)
    np.testing.assert_allclose(jax.jit(lambda m, W: dirichlet_energy(m.with_vertices(W), u))(mesh, V), energy(V), rtol=1e-13)
    batched = jax.vmap(lambda s: cotan_laplacian(mesh.with_vertices(s * V)).values)(jnp.asarray([1.0, 2.0]))
    np.testing.assert_allclose(batched[1], batched[0], rtol=1e-12)  # the cotan Laplacian is scale invariant


def test_orientation_is_checked_on_every_mesh_not_served_from_the_cache():
    oriented = icosphere(1)
    V, F = np.asarray(oriented.vertices), np.asarray(oriented.faces).copy()
    F[0] = F[0, ::-1]  # one face flipped: same sizes, inconsistent orientation
    flipped = Mesh.from_arrays(V, F)
    assert total_mean_curvature(oriented) > 0
    vertex_principal_curvatures(oriented)  # nested kernels reuse the outer check
    for function in (total_mean_curvature, vertex_mean_curvatures, vertex_principal_curvatures):
        with pytest.raises(MeshDataError, match="consistently oriented"):
            function(flipped)
    # A stand-in whose caller did not check the orientation refuses rather than guess.
    with pytest.raises(AttributeError, match="cannot check the orientation"):
        counts_only(oriented).topology.require_oriented("an operation")
    counts_only(oriented, oriented=True).topology.require_oriented("an operation")


@pytest.mark.skipif(jax.default_backend() != "cpu", reason="the tuned programs are compiled for CPU only")
def test_eager_kernels_compile_without_ynnpack_fusions():
    """Eager mesh kernels run the program `ddgjax._compile.tuned_jit` compiles: XLA:CPU's YNNPACK
    fusions off (several times slower for geometry's short reductions; benchmarks/README.md)."""
    from ddgjax.mesh import face_edge_lengths_sq

    mesh = icosphere(5)  # 61k face corners: past the size where XLA:CPU hands reductions to YNNPACK
    np.testing.assert_allclose(
        face_edge_lengths_sq(mesh), igl.squared_edge_lengths(np.asarray(mesh.vertices), np.asarray(mesh.faces)), rtol=1e-12
    )
    compiled = face_edge_lengths_sq.compiled
    (tuned,) = compiled.tuned_versions.values()
    stand_in = counts_only(mesh)
    assert "__ynn_fusion" not in tuned.lower(stand_in).compile().as_text()
