"""Tests for ddgjax.volume's geometry core and operators: the cotan Laplacian and mass matrices of tet meshes
against libigl and exact rational arithmetic, dihedral angles, derivatives, degenerate tets."""

from __future__ import annotations

from fractions import Fraction

import igl
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.spatial
from jax.test_util import check_grads

from ddgjax import DDGInputError, volume

from tet_meshes import jittered_grid_tets

jax.config.update("jax_enable_x64", True)


@pytest.fixture(scope="module")
def tet_mesh() -> volume.TetMesh:
    return jittered_grid_tets()


def host(tet_mesh):
    return np.asarray(tet_mesh.vertices), np.asarray(tet_mesh.tets).astype(np.int64)


def test_cotan_laplacian_equals_libigl_negated_cotmatrix(tet_mesh):
    V, T = host(tet_mesh)
    L = volume.cotan_laplacian(tet_mesh)
    reference = -igl.cotmatrix(V, T)
    scale = abs(reference).max()
    # libigl computes the weights through face areas and arccos: ~1e-9 of the largest on this mesh's slivers.
    assert abs(L.to_scipy() - reference).max() < 1e-9 * scale
    assert np.abs(np.asarray(L @ jnp.ones(tet_mesh.n_vertices))).max() < 1e-12 * scale  # L 1 = 0
    assert np.linalg.eigvalsh(L.todense()).min() > -1e-10 * scale  # PSD


@pytest.mark.parametrize(("mass", "igl_type"), [("barycentric", "BARYCENTRIC"), ("galerkin", "FULL")])
def test_mass_matrices_equal_libigl(tet_mesh, mass, igl_type):
    V, T = host(tet_mesh)
    M = volume.mass_matrix(tet_mesh, mass=mass)
    reference = igl.massmatrix(V, T, getattr(igl, f"MASSMATRIX_TYPE_{igl_type}"))
    assert abs(M.to_scipy() - reference).max() < 1e-15
    assert float(jnp.sum(M.todense())) == pytest.approx(float(jnp.sum(volume.tet_volumes(tet_mesh))), rel=1e-13)


def test_cotan_weights_and_dihedral_angles_against_libigl(tet_mesh):
    V, T = host(tet_mesh)
    theta, _ = igl.dihedral_angles(V, T)
    assert np.abs(np.asarray(volume.tet_dihedral_angles(tet_mesh)) - theta).max() < 1e-9  # libigl's arccos route
    # libigl's cotmatrix_entries gives l_k cot(theta_k) / 6 per edge k: the weight of the opposite edge.
    entries = igl.cotmatrix_entries(V, T)
    weights = np.asarray(volume.tet_cotan_weights(tet_mesh))
    # libigl computes them through face areas and arccos: ~1e-9 of the largest on this mesh's slivers.
    assert np.abs(weights - np.roll(entries, 3, axis=1)).max() < 1e-8 * np.abs(entries).max()


def _exact_stiffness(points) -> list[Fraction]:
    """`-V grad phi_i . grad phi_j` per local edge in exact rational arithmetic (Cramer's rule on the edge vectors)."""
    p = [[Fraction(int(x)) for x in row] for row in points]
    e = [[p[a][c] - p[0][c] for c in range(3)] for a in (1, 2, 3)]

    def det(m):
        return (
            m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
            - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
        )

    d = det(e)
    # grad phi_a (a = 1..3) are the columns of e^{-1}: cofactors over the determinant.
    cofactor = [
        [
            (
                e[(r + 1) % 3][(c + 1) % 3] * e[(r + 2) % 3][(c + 2) % 3]
                - e[(r + 1) % 3][(c + 2) % 3] * e[(r + 2) % 3][(c + 1) % 3]
            )
            for c in range(3)
        ]
        for r in range(3)
    ]
    grads = [[cofactor[r][c] / d for c in range(3)] for r in range(3)]
    grads = [[-sum(g[c] for g in grads) for c in range(3)], *grads]
    volume_ = abs(d) / 6
    return [-volume_ * sum(grads[i][c] * grads[j][c] for c in range(3)) for i, j in volume.TET_EDGES]


def test_cotan_weights_exact_on_a_sliver():
    """A near-flat integer tet: the Gram-adjugate core keeps ~1e-15 relative (libigl's formula loses ~1e-8 here)."""
    points = np.array([[0, 0, 0], [1000, 0, 0], [0, 1000, 0], [499, 501, 1]], dtype=float)
    tet_mesh = volume.TetMesh.from_arrays(points, np.array([[0, 1, 2, 3]]))
    exact = np.array([float(w) for w in _exact_stiffness(np.asarray(tet_mesh.vertices)[np.asarray(tet_mesh.tets[0])])])
    weights = np.asarray(volume.tet_cotan_weights(tet_mesh))[0]
    assert np.abs(weights - exact).max() < 1e-12 * np.abs(exact).max()


def test_regular_tet_dihedral_angles_and_volume_from_lengths():
    lengths_sq = jnp.ones((1, 6))
    np.testing.assert_allclose(volume.tet_dihedral_angles_from_lengths_sq(lengths_sq), np.arccos(1 / 3), rtol=1e-14)
    assert float(volume.tet_volumes_from_lengths_sq(lengths_sq)[0]) == pytest.approx(1 / (6 * np.sqrt(2)), rel=1e-14)
    # Each weight l cot(arccos(1/3)) / 6 = 1 / (6 sqrt(8)).
    np.testing.assert_allclose(volume.tet_cotan_weights_from_lengths_sq(lengths_sq), 1 / (6 * np.sqrt(8)), rtol=1e-14)


def test_apply_energy_and_matrix_agree(tet_mesh):
    u = jnp.asarray(np.random.default_rng(1).normal(size=(tet_mesh.n_vertices, 2)))
    L = volume.cotan_laplacian(tet_mesh)
    np.testing.assert_allclose(volume.laplacian_apply(tet_mesh, u), L @ u, atol=1e-11)
    energy = volume.dirichlet_energy(tet_mesh, u)
    assert float(energy) == pytest.approx(0.5 * float(jnp.sum(u * (L @ u))), rel=1e-12)
    # The Dirichlet energy of a linear function is |grad|^2 volume / 2.
    linear = tet_mesh.vertices @ jnp.array([1.0, -2.0, 0.5])
    total = float(jnp.sum(volume.tet_volumes(tet_mesh)))
    assert float(volume.dirichlet_energy(tet_mesh, linear)) == pytest.approx(0.5 * 5.25 * total, rel=1e-12)


def test_derivatives_in_the_vertex_positions_match_finite_differences():
    # The five-tet split of a unit cube, moved a little: well-shaped tets, so central differences are accurate.
    cube = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], dtype=float)
    cube = cube + 0.05 * np.random.default_rng(2).uniform(-1, 1, size=cube.shape)
    tets = np.array([[0, 1, 2, 4], [3, 1, 2, 7], [5, 1, 4, 7], [6, 2, 4, 7], [1, 2, 4, 7]])
    small = volume.TetMesh.from_arrays(cube, tets)
    u = jnp.asarray(np.random.default_rng(3).normal(size=small.n_vertices))

    def energy(V):
        return volume.dirichlet_energy(small.with_vertices(V), u)

    def laplacian_values(V):
        return volume.cotan_laplacian(small.with_vertices(V)).values

    def dual(V):
        return volume.mass_matrix(small.with_vertices(V), mass="galerkin").values

    # Central differences of step 1e-5: O(eps^2) ~1e-10 truncation + round-off / eps ~1e-11 (all pass at 1e-9).
    differences = dict(order=1, eps=1e-5, atol=1e-8, rtol=1e-8)
    check_grads(energy, (small.vertices,), modes=("fwd", "rev"), **differences)
    check_grads(laplacian_values, (small.vertices,), modes=("fwd", "rev"), **differences)
    check_grads(dual, (small.vertices,), modes=("rev",), **differences)


@pytest.mark.slow
def test_flat_tets_keep_values_and_gradients_finite():
    points = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0.3, 0.3, 0.0], [0.2, 0.2, 1.0]])
    tet_mesh = volume.TetMesh.from_arrays(points, np.array([[0, 1, 2, 3], [0, 1, 2, 4]]))  # tet 0 is flat
    u = jnp.arange(5.0)
    L = volume.cotan_laplacian(tet_mesh).todense()
    assert np.isfinite(np.asarray(L)).all()
    np.testing.assert_array_equal(np.asarray(volume.tet_cotan_weights(tet_mesh))[0], 0.0)

    def everything(V):  # one gradient through every quantity (one compilation)
        moved = tet_mesh.with_vertices(V)
        return (
            volume.dirichlet_energy(moved, u)
            + jnp.sum(volume.tet_dihedral_angles(moved))
            + jnp.sum(volume.mass_matrix(moved, mass="galerkin").values)
            + jnp.sum(volume.tet_hat_gradients(moved) ** 2)
        )

    value, gradient = jax.value_and_grad(everything)(tet_mesh.vertices)
    assert np.isfinite(float(value)) and np.isfinite(np.asarray(gradient)).all()


@pytest.mark.slow
def test_second_derivatives_of_the_energy_match_finite_differences():
    cube = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], dtype=float)
    cube = cube + 0.05 * np.random.default_rng(2).uniform(-1, 1, size=cube.shape)
    small = volume.TetMesh.from_arrays(cube, np.array([[0, 1, 2, 4], [3, 1, 2, 7], [5, 1, 4, 7], [6, 2, 4, 7], [1, 2, 4, 7]]))
    u = jnp.asarray(np.random.default_rng(3).normal(size=small.n_vertices))
    # Second order: central differences of the first derivatives at step 1e-5, whose own round-off / eps adds
    # up (measured 2.3e-9 relative).
    check_grads(
        lambda V: volume.dirichlet_energy(small.with_vertices(V), u),
        (small.vertices,),
        order=2,
        modes=("fwd", "rev"),
        eps=1e-5,
        atol=1e-7,
        rtol=1e-7,
    )


def test_operators_compile_once_per_connectivity_and_vmap_over_positions(tet_mesh):
    def values(V):
        return volume.cotan_laplacian(tet_mesh.with_vertices(V)).values

    batch = tet_mesh.vertices[None] * jnp.array([1.0, 2.0])[:, None, None]
    stacked = jax.jit(jax.vmap(values))(batch)
    # Scaling lengths by s scales the 3-D cotan weights l cot / 6 by s.
    np.testing.assert_allclose(stacked[1], 2.0 * stacked[0], rtol=1e-12, atol=1e-12)


def test_bad_arguments_name_themselves(tet_mesh, without_type_checker, icosphere1):
    with pytest.raises(DDGInputError, match="tet_mesh"):
        volume.cotan_laplacian((tet_mesh.vertices, tet_mesh.tets))
    with pytest.raises(DDGInputError, match="u"):
        volume.laplacian_apply(tet_mesh, jnp.ones(3))
    with pytest.raises(DDGInputError, match="mass"):
        volume.mass_matrix(tet_mesh, mass="lumped")
    with pytest.raises(DDGInputError, match="triangle Mesh"):
        volume.cotan_laplacian(icosphere1)


def test_plane_section_restricts_a_linear_function_exactly(tet_mesh):
    """The cut of the jittered cube at z = 0.1: every section vertex on the plane, a linear function restricted
    exactly, the cut's area that of the (convex) Delaunay solid's convex section, one oriented sheet along the normal."""
    from ddgjax.mesh import check_mesh, face_normals, total_area

    coefficients = np.array([1.0, -2.0, 3.0])
    u = np.asarray(tet_mesh.vertices) @ coefficients
    section, values = volume.plane_section(tet_mesh, u, point=(0.0, 0.0, 0.1))
    points = np.asarray(section.vertices)
    np.testing.assert_allclose(points[:, 2], 0.1, atol=1e-15)
    np.testing.assert_allclose(values, points @ coefficients, atol=1e-13)
    # Delaunay tets fill the convex hull, whose section is the convex hull of the section's points.
    assert float(total_area(section)) == pytest.approx(scipy.spatial.ConvexHull(points[:, :2]).volume, rel=1e-12)
    report = check_mesh(section)
    assert report.inconsistent_edges.size == 0 and report.n_components == 1
    assert (np.asarray(face_normals(section))[:, 2] > 0).mean() > 0.99  # zero-area triangles have no normal
    with pytest.raises(DDGInputError, match="plane"):
        volume.plane_section(tet_mesh, u, point=(0.0, 0.0, 5.0))
    with pytest.raises(DDGInputError, match="normal"):
        volume.plane_section(tet_mesh, u, normal=(0.0, 0.0, 0.0))
