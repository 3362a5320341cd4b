"""`ddgjax.discretization.discretize`: a triangle or tet mesh as the problem layer solves on it.

Checked against libigl (`cotmatrix`, `massmatrix` on `(V, F)` and `(V, T)`), robust_laplacian (the
mollified intrinsic Delaunay pair), finite differences of the Dirichlet energy through it, and its refusals.
"""

from __future__ import annotations

import doctest

import igl
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import robust_laplacian

from ddgjax import DDGInputError, MeshDataError
from ddgjax.discretization import Discretization, discretize
from ddgjax.discretization import _discretization as discretization_module
from ddgjax.laplacian import intrinsic_delaunay
from ddgjax.mesh import Mesh
from ddgjax.volume import tet_ball

from conftest import unit_icosphere
from finite_differences import central_difference, random_direction

jax.config.update("jax_enable_x64", True)


def _jittered_sphere() -> Mesh:
    mesh = unit_icosphere(2)
    V = np.asarray(mesh.vertices) * (1.0 + 0.15 * random_direction((mesh.n_vertices, 1), seed=3))
    return mesh.with_vertices(V)


def _host(mesh):
    cells = mesh.tets if hasattr(mesh, "tets") else mesh.faces
    return np.array(mesh.vertices), np.asarray(cells).astype(np.int64)


@pytest.mark.parametrize(("mass", "igl_type"), [("voronoi", "VORONOI"), ("barycentric", "BARYCENTRIC")])
def test_a_surface_is_libigls_cotan_laplacian_and_mass(mass, igl_type):
    mesh = _jittered_sphere()
    V, F = _host(mesh)
    d = discretize(mesh, mass=mass)
    assert isinstance(d, Discretization) and d.domain is mesh and d.triangulation is None
    L_igl, M_igl = -igl.cotmatrix(V, F), igl.massmatrix(V, F, getattr(igl, f"MASSMATRIX_TYPE_{igl_type}"))
    assert abs(d.laplacian.to_scipy() - L_igl).max() < 1e-12 * abs(L_igl).max()
    assert abs(d.mass.to_scipy() - M_igl).max() < 1e-15
    np.testing.assert_array_equal(np.asarray(d.pattern.rows), np.asarray(d.laplacian.pattern.rows))


def test_a_solid_is_libigls_tet_cotan_laplacian_and_mass():
    solid = tet_ball(2)
    V, T = _host(solid)
    d = discretize(solid, mass="barycentric")
    L_igl, M_igl = -igl.cotmatrix(V, T), igl.massmatrix(V, T, igl.MASSMATRIX_TYPE_BARYCENTRIC)
    assert abs(d.laplacian.to_scipy() - L_igl).max() < 1e-9 * abs(L_igl).max()  # libigl's arccos route: ~1e-10
    assert abs(d.mass.to_scipy() - M_igl).max() < 1e-15


def test_robust_is_robust_laplacians_pair_on_a_degenerate_mesh():
    mesh = _jittered_sphere()
    V, F = _host(mesh)
    V[F[0, 2]] = 0.5 * (V[F[0, 0]] + V[F[0, 1]])  # face 0 collapses onto its edge
    degenerate = mesh.with_vertices(V)
    with pytest.raises(MeshDataError, match="robust=True"):
        discretize(degenerate)
    d = discretize(degenerate, mass="barycentric", robust=True)
    L_robust, M_robust = robust_laplacian.mesh_laplacian(V, F, mollify_factor=1e-5)
    assert d.triangulation is not None and np.all(np.isfinite(np.asarray(d.laplacian.values)))
    assert abs(d.laplacian.to_scipy() - L_robust).max() < 1e-10 * abs(L_robust).max()
    assert abs(d.mass.to_scipy() - M_robust).max() < 1e-12 * abs(M_robust).max()


def test_the_dirichlet_energy_through_it_matches_finite_differences_and_its_pattern_stays_concrete_under_jit():
    mesh = _jittered_sphere()
    u = jnp.cos(2.0 * mesh.vertices[:, 2])
    triangulation = intrinsic_delaunay(mesh)  # flipped on the host, closed over (concrete) by the traced function
    seen = []

    def energy(V):
        d = discretize(mesh.with_vertices(V), robust=triangulation)
        seen.append(isinstance(d.pattern.rows, jax.core.Tracer))
        return 0.5 * u @ (d.laplacian @ u) + jnp.sum(d.mass.diagonal())

    V = mesh.vertices
    direction = random_direction(V.shape, seed=1)
    gradient = jax.jit(jax.grad(energy))(V)
    assert seen == [False]  # the host plan's pattern, even while the Laplacian's values are traced
    expected = central_difference(energy, V, direction)
    # Central differences at step 1e-6: O(eps^2) truncation + round-off ~1e-16 / eps relative.
    np.testing.assert_allclose(float(jnp.vdot(gradient, direction)), float(expected), rtol=1e-7)


def test_bad_input_is_refused_naming_the_argument(without_type_checker, icosphere1):
    with pytest.raises(DDGInputError, match=r"^mesh: expected a ddgjax Mesh, got an array of shape \(4, 3\)"):
        discretize(np.zeros((4, 3)))
    with pytest.raises(DDGInputError, match="Mesh.from_arrays"):
        discretize((np.zeros((3, 3)), np.zeros((1, 3), int)))
    with pytest.raises(DDGInputError, match="mass"):
        discretize(icosphere1, mass="lumped")
    with pytest.raises(DDGInputError, match="robust"):
        discretize(icosphere1, robust="yes")
    with pytest.raises(DDGInputError, match="robust: .*TetMesh takes only robust=False"):
        discretize(tet_ball(1), robust=True)


def test_the_docstring_example_runs():
    failures, attempted = doctest.testmod(discretization_module, verbose=False)
    assert attempted > 0 and failures == 0
