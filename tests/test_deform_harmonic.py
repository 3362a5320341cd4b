"""Tests for ddgjax.deform.biharmonic_deformation: libigl's `harmonic` (k = 1, 2, 3) on the displacement,
exact identities (handles, identity, translations, affine maps of a flat disk), gradients against finite
differences, jit / vmap, bad input and the results convention."""

from __future__ import annotations

import igl
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from jax.test_util import check_grads

from ddgjax import RESULTS, DDGInputError, Solution
from ddgjax.deform import biharmonic_deformation
from ddgjax.mesh import Mesh, disk

from conftest import unit_icosphere
from mesh_union import disjoint_union


def _curved_disk() -> tuple[Mesh, np.ndarray, np.ndarray]:
    """A paraboloid cap over the unit disk, its boundary held, the vertices near the centre lifted and pushed."""
    mesh = disk(5)
    V = np.asarray(mesh.vertices).copy()
    V[:, 2] = 0.4 * (V[:, 0] ** 2 + V[:, 1] ** 2)
    boundary = mesh.topology.boundary_vertices
    centre = np.flatnonzero(np.hypot(V[:, 0], V[:, 1]) < 0.25)
    b = np.concatenate([boundary, centre])
    bc = V[b].copy()
    bc[boundary.size :] += [0.1, 0.0, 0.5]
    return mesh.with_vertices(V), b, bc


def _sphere() -> tuple[Mesh, np.ndarray, np.ndarray]:
    """A closed mesh with two handle regions: the north cap pulled up and sideways, the south cap held."""
    mesh = unit_icosphere(2)
    V = np.asarray(mesh.vertices)
    north, south = np.flatnonzero(V[:, 2] > 0.7), np.flatnonzero(V[:, 2] < -0.7)
    b = np.concatenate([north, south])
    bc = V[b].copy()
    bc[: north.size] += [0.2, 0.0, 0.4]
    return mesh, b, bc


MESHES = {"curved_disk": _curved_disk, "sphere": _sphere}


# k = 3 (the widest operator, the longest compile) in the slow tier.
@pytest.mark.parametrize("k", [1, 2, pytest.param(3, marks=pytest.mark.slow)])
@pytest.mark.parametrize("name", sorted(MESHES))
def test_equals_libigl_harmonic_on_the_displacement(name, k):
    """libigl's tutorial 401 ("deformation field"): `V + igl.harmonic(V, F, b, bc - V[b], k)`."""
    mesh, b, bc = MESHES[name]()
    V, F = np.asarray(mesh.vertices), np.asarray(mesh.faces, dtype=np.int64)
    U = np.asarray(biharmonic_deformation(mesh, fixed_vertices=b, fixed_values=bc, order=k))
    expected = V + igl.harmonic(V, F, b, bc - V[b], k)
    # Q's condition number grows like h^(-2k); a direct solve on either side agrees to ~1e-13 here.
    np.testing.assert_allclose(U, expected, rtol=0, atol=1e-10)
    np.testing.assert_array_equal(U[b], bc)  # the handles land exactly


@pytest.mark.parametrize("k", [2, pytest.param(3, marks=pytest.mark.slow)])
def test_barycentric_mass_equals_libigls_operator_with_that_mass(k):
    """`mass="barycentric"`: libigl's `harmonic_integrated_from_laplacian_and_mass(L, M, k)` (its `Q`, built
    with the barycentric mass matrix) solved with SciPy on the free vertices."""
    mesh, b, bc = _sphere()
    V, F = np.asarray(mesh.vertices), np.asarray(mesh.faces, dtype=np.int64)
    L = sp.csc_matrix(igl.cotmatrix(V, F))
    M = sp.csc_matrix(igl.massmatrix(V, F, igl.MASSMATRIX_TYPE_BARYCENTRIC))
    Q = sp.csr_matrix(igl.harmonic_integrated_from_laplacian_and_mass(L, M, k))
    free = np.setdiff1d(np.arange(V.shape[0]), b)
    D = np.zeros_like(V)
    D[b] = bc - V[b]
    D[free] = spla.spsolve(sp.csc_matrix(Q[free][:, free]), -(Q[free][:, b] @ D[b]))
    U = biharmonic_deformation(mesh, fixed_vertices=b, fixed_values=bc, order=k, mass="barycentric")
    np.testing.assert_allclose(U, V + D, rtol=0, atol=1e-10)  # two direct solves of Q_ff (see above)


def test_flat_disk_k1_reproduces_affine_maps_and_the_positions_form():
    """On a flat disk with its boundary held, the coordinates are harmonic: an affine map of the boundary
    (a rotation, a shear, a translation) moves every vertex by it, and the displacement form equals libigl's
    `harmonic` on the positions (tutorial 401's other mode)."""
    mesh = disk(4)
    V, F = np.asarray(mesh.vertices), np.asarray(mesh.faces, dtype=np.int64)
    b = mesh.topology.boundary_vertices
    c, s = np.cos(0.3), np.sin(0.3)
    A = np.array([[c, -s, 0.0], [s, c, 0.0], [0.2, 0.1, 1.0]])  # rotation about z, then a shear into z
    affine = V @ A.T + [0.5, -1.0, 2.0]
    U = np.asarray(biharmonic_deformation(mesh, fixed_vertices=b, fixed_values=affine[b], order=1))
    np.testing.assert_allclose(U, affine, rtol=0, atol=1e-13)
    np.testing.assert_allclose(U, igl.harmonic(V, F, b, affine[b], 1), rtol=0, atol=1e-13)


@pytest.mark.parametrize("k", [1, 2, 3])
def test_identity_and_translation(k):
    """Handles left in place give the rest shape; a translation of every handle translates every vertex
    (constants are k-harmonic). A rotation of the handles is not reproduced exactly (module docstring)."""
    mesh, b, _ = _sphere()
    V = np.asarray(mesh.vertices)
    np.testing.assert_allclose(biharmonic_deformation(mesh, fixed_vertices=b, fixed_values=V[b], order=k), V, rtol=0, atol=1e-15)
    shift = np.array([0.3, -0.2, 1.5])
    U = biharmonic_deformation(mesh, fixed_vertices=b, fixed_values=V[b] + shift, order=k)
    np.testing.assert_allclose(U, V + shift, rtol=0, atol=1e-12)


@pytest.mark.slow  # compiling the forward- and reverse-mode programs takes ~8 s
@pytest.mark.parametrize("k", [2, 3])
def test_gradients_in_the_handles_and_the_rest_positions(k, icosphere1):
    """Forward and reverse mode against finite differences (the solve differentiates implicitly)."""
    mesh = icosphere1
    V = np.asarray(mesh.vertices)
    b = np.array([0, 5, 9])
    bc = V[b] + np.array([[0.1, 0.2, -0.1], [0.0, 0.3, 0.1], [-0.2, 0.0, 0.0]])
    weights = np.random.default_rng(0).normal(size=V.shape)

    @jax.jit
    def loss(values, positions):
        deformed = biharmonic_deformation(mesh.with_vertices(positions), fixed_vertices=b, fixed_values=values, order=k)
        return jnp.sum(weights * deformed)

    check_grads(loss, (jnp.asarray(bc), jnp.asarray(V)), order=1, modes=("fwd", "rev"))


@pytest.mark.slow
def test_jit_and_vmap_equal_eager():
    mesh, b, bc = _curved_disk()
    eager = biharmonic_deformation(mesh, fixed_vertices=b, fixed_values=bc)
    jitted = jax.jit(
        lambda values, positions: biharmonic_deformation(mesh.with_vertices(positions), fixed_vertices=b, fixed_values=values)
    )
    np.testing.assert_allclose(jitted(bc, mesh.vertices), eager, rtol=0, atol=1e-14)
    batch = np.stack([bc, bc + 0.1])
    batched = jax.jit(jax.vmap(lambda values: biharmonic_deformation(mesh, fixed_vertices=b, fixed_values=values)))(batch)
    np.testing.assert_allclose(
        batched[1], biharmonic_deformation(mesh, fixed_vertices=b, fixed_values=batch[1]), rtol=0, atol=1e-14
    )


def test_throw_false_returns_a_solution():
    mesh, b, bc = _sphere()
    solution = biharmonic_deformation(mesh, fixed_vertices=b, fixed_values=bc, throw=False)
    assert isinstance(solution, Solution)
    assert solution.result == RESULTS.successful
    assert float(solution.stats["residual"]) < 1e-10
    np.testing.assert_array_equal(solution.value, biharmonic_deformation(mesh, fixed_vertices=b, fixed_values=bc))


@pytest.mark.slow  # the fast tier's time limit (its checks run in the full suite)
def test_every_vertex_a_handle_and_unused_vertices(icosphere0):
    """All vertices fixed: the handles' values, nothing solved. A vertex used by no face stays where it is."""
    mesh = icosphere0
    V = np.asarray(mesh.vertices)
    everything = np.arange(V.shape[0])
    np.testing.assert_array_equal(biharmonic_deformation(mesh, fixed_vertices=everything, fixed_values=V + 1), V + 1)
    spare = Mesh.from_arrays(np.concatenate([V, [[5.0, 5.0, 5.0]]]), np.asarray(mesh.faces))
    U = np.asarray(biharmonic_deformation(spare, fixed_vertices=np.array([0]), fixed_values=V[:1] + 1))
    np.testing.assert_allclose(U, np.concatenate([V + 1, [[5.0, 5.0, 5.0]]]), rtol=0, atol=1e-13)


def test_bad_input_names_the_argument(without_type_checker):
    mesh, b, bc = _sphere()
    cases = [
        (dict(fixed_values=bc[:, :2]), "fixed_values: expected shape"),
        (dict(fixed_values=bc[:-1]), "fixed_values: expected shape"),
        (dict(fixed_values=None), "fixed_values: expected shape"),
        (
            dict(fixed_vertices=np.array([], dtype=np.int64), fixed_values=np.zeros((0, 3))),
            "fixed_vertices: expected at least one",
        ),
        (dict(fixed_vertices=np.concatenate([b[:-1], b[:1]])), "fixed_vertices: expected distinct"),
        (dict(fixed_vertices=np.concatenate([b[:-1], [mesh.n_vertices]])), "fixed_vertices: vertex indices must lie"),
        (dict(fixed_vertices=b[None, :], fixed_values=bc), "fixed_values: expected shape"),
        (dict(order=0), "order: expected an integer >= 1"),
        (dict(order=1.5), "order: expected an integer >= 1"),
        (dict(order=True), "order: expected an integer >= 1"),
        (dict(mass="galerkin"), "mass"),
        (dict(solver="lu"), "solver"),
    ]
    for change, message in cases:
        arguments = dict(fixed_vertices=b, fixed_values=bc) | change
        with pytest.raises(DDGInputError, match=message):
            biharmonic_deformation(mesh, **arguments)
    with pytest.raises(DDGInputError, match="mesh"):
        biharmonic_deformation(np.asarray(mesh.vertices), fixed_vertices=b, fixed_values=bc)
    two = disjoint_union([(np.asarray(mesh.vertices), np.asarray(mesh.faces))] * 2).mesh
    with pytest.raises(DDGInputError, match="fixed_vertices: every connected component needs a handle"):
        biharmonic_deformation(two, fixed_vertices=b, fixed_values=bc)


@pytest.mark.slow
@pytest.mark.parametrize("name", ["arap", "biharmonic_deformation"])
def test_degenerate_geometry_keeps_values_and_gradients_finite(name, icosphere2):
    """Two vertices at one point (zero-length edge, zero-area faces): answers and handle gradients stay finite."""
    import ddgjax.deform as deform

    function = getattr(deform, name)
    sphere = icosphere2
    collapsed = sphere.with_vertices(sphere.vertices.at[1].set(sphere.vertices[0]))
    fixed = jnp.array([10, 11, 12])
    values = collapsed.vertices[fixed] + 0.1
    assert jnp.all(jnp.isfinite(function(collapsed, fixed_vertices=fixed, fixed_values=values)))
    gradient = jax.grad(lambda x: function(collapsed, fixed_vertices=fixed, fixed_values=x).sum())(values)
    assert jnp.all(jnp.isfinite(gradient))
