"""The problem layer on meshes with unreferenced vertices or NaN positions set past the checks (issue 41: name the
actual cause, or give the correct value)."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

from ddgjax import MeshDataError
from ddgjax.geodesics import heat_distance
from ddgjax.mesh import Mesh, grid
from ddgjax.pde import solve_poisson
from ddgjax.spectral import eigenpairs
from ddgjax.volume import TetMesh, tet_ball


def _with_a_stray_vertex(domain):
    """`domain` with one more vertex, used by no face (tet), appended last."""
    vertices = np.vstack([np.asarray(domain.vertices), [[5.0, 5.0, 5.0]]])
    if isinstance(domain, TetMesh):
        return TetMesh.from_arrays(vertices, domain.tets)
    return Mesh.from_arrays(vertices, np.asarray(domain.faces))


@pytest.mark.parametrize("boundary", ["neumann", "dirichlet"])
@pytest.mark.parametrize("kind", ["surface", "solid"])
def test_eigenpairs_hold_unreferenced_vertices_at_zero(kind, boundary, icosphere2):
    """An unreferenced vertex has zero rows in L and M (no eigenvalue is its own): the pairs are those of the mesh
    without it, and the vertex's entries are 0, where the eigensolver used to fail with a message about areas."""
    surface = grid(8, 8) if boundary == "dirichlet" else icosphere2
    domain = surface if kind == "surface" else tet_ball(2)
    clean = eigenpairs(domain, k=6, boundary=boundary)
    stray = eigenpairs(_with_a_stray_vertex(domain), k=6, boundary=boundary)
    # The same reduced problem either way (the stray vertex only adds a zero row): round-off apart.
    np.testing.assert_allclose(np.asarray(stray.values), np.asarray(clean.values), rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(
        np.asarray(stray.vectors[:-1]), np.asarray(clean.vectors), atol=1e-8
    )  # eigenvector round-off ~ 1e-10 / gap
    np.testing.assert_array_equal(np.asarray(stray.vectors[-1]), 0.0)


@pytest.mark.parametrize("kind", ["surface", "solid"])
def test_nan_positions_set_past_the_checks_are_named(kind, icosphere2):
    """NaN coordinates placed with `eqx.tree_at` (which skips `with_vertices`' check) are named as such by every
    problem, not blamed on an eigensolver's convergence or a SciPy error."""
    domain = icosphere2 if kind == "surface" else tet_ball(2)
    broken = eqx.tree_at(lambda d: d.vertices, domain, jnp.asarray(domain.vertices).at[3].set(jnp.nan))
    for run in (
        lambda: eigenpairs(broken, k=4),
        lambda: solve_poisson(broken, np.ones(broken.n_vertices)),
        lambda: heat_distance(broken, [0]),
    ):
        with pytest.raises(MeshDataError, match=r"1 of its \d+ vertices have NaN or inf coordinates \(vertices \[3\]"):
            run()


def test_host_checks_leave_the_pytree_structure_alone(icosphere2):
    """The facts measured on the host once per mesh (degenerate faces, unusable tets) are kept beside the object,
    not on it: equinox flattens extra attributes into the treedef, so a mesh that had been checked used to make a
    user's `jit` compile a second program for the same connectivity."""
    import jax

    from ddgjax.mesh import check_mesh
    from ddgjax.pde import dirichlet_energy

    mesh = Mesh.from_arrays(np.asarray(icosphere2.vertices), np.asarray(icosphere2.faces))
    structure = jax.tree_util.tree_structure(mesh)
    check_mesh(mesh)
    heat_distance(mesh, [0])
    assert jax.tree_util.tree_structure(mesh) == structure
    energy = jax.jit(lambda m: dirichlet_energy(m, m.vertices))
    energy(mesh)
    energy(Mesh.from_arrays(2 * np.asarray(mesh.vertices), np.asarray(mesh.faces)))
    assert energy._cache_size() == 1
    solid = tet_ball(2)
    solid_structure = jax.tree_util.tree_structure(solid)
    solve_poisson(solid, np.ones(solid.n_vertices))
    assert jax.tree_util.tree_structure(solid) == solid_structure
