"""Tests for ddgjax.pde.hodge_decomposition: the DDG exercises' reference (genus 2), the identities
of the decomposition, the dimension of the harmonic space on surfaces of several topologies, an
independent face-system solve, gradients against finite differences, jit / batching, bad input."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ddgjax import RESULTS, DDGInputError, MeshDataError, Solution
from ddgjax.dec import d0, d1, hodge_star_entries
from ddgjax.mesh import Mesh, torus
from ddgjax.pde import HodgeDecomposition, hodge_decomposition
from ddgjax.pde.internal import closed_cocycle_basis

from conftest import read_ddg_reference
from finite_differences import central_difference
from mesh_union import disjoint_union


def _ddg_edges(mesh: Mesh) -> tuple[np.ndarray, np.ndarray]:
    """For each DDG-exercises edge (numbered and oriented by its first half-edge, scanning faces and
    then f0->f1, f1->f2, f2->f0): the index of the same edge in `mesh.edges` and the sign relating
    the two orientations (+1 where the DDG edge also runs low -> high)."""
    faces, nv = np.asarray(mesh.topology.faces, np.int64), mesh.n_vertices
    half_edges = np.stack([faces, np.roll(faces, -1, axis=1)], axis=-1).reshape(-1, 2)
    low, high = half_edges.min(axis=1), half_edges.max(axis=1)
    _, first = np.unique(low * nv + high, return_index=True)
    first = np.sort(first)
    edges = np.asarray(mesh.topology.edges, np.int64)
    index = np.searchsorted(edges[:, 0] * nv + edges[:, 1], low[first] * nv + high[first])
    return index, np.where(half_edges[first, 0] < half_edges[first, 1], 1.0, -1.0)


@pytest.fixture(scope="module")
def reference():
    data = read_ddg_reference("test-decomp-soln.txt")
    mesh = Mesh.from_arrays(data["v"], data["f"].astype(np.int64) - 1)
    index, sign = _ddg_edges(mesh)
    omega = np.zeros(mesh.n_edges)
    omega[index] = sign * data["omega"][:, 0]
    # The reference form and four random ones, in one call (one compiled program for this mesh).
    block = np.column_stack([omega, np.random.default_rng(9).standard_normal((mesh.n_edges, 4))])
    return mesh, block, data, index, sign, hodge_decomposition(mesh, block)


def test_matches_the_ddg_exercises_reference(reference):
    """test-decomp-soln.txt (genus 2, 3070 vertices): the three parts to 1e-6. Its exact part solves
    (L + 1e-8 I) alpha = d0^T *1 omega, which moves d alpha by ~1.5e-7 (and gamma with it); its
    coexact part (no shift) agrees to ~1e-13."""
    mesh, _, data, index, sign, parts = reference
    assert mesh.topology.genus == 2
    # The reference's shift 1e-8 I moves its d alpha and gamma by ~1.5e-7 (docstring).
    for ours, tag in ((parts.exact, "dAlpha"), (parts.coexact, "deltaBeta"), (parts.harmonic, "gamma")):
        np.testing.assert_allclose(np.asarray(ours)[index, 0] * sign, data[tag][:, 0], rtol=0, atol=1e-6)  # the shift's 1.5e-7
    np.testing.assert_allclose(np.asarray(parts.coexact)[index, 0] * sign, data["deltaBeta"][:, 0], rtol=0, atol=1e-12)


def _check_identities(mesh: Mesh, omega, parts: HodgeDecomposition, dual: str = "voronoi"):
    exact, coexact, harmonic = (np.asarray(part) for part in parts)
    star = np.asarray(hodge_star_entries(mesh, degree=1, dual=dual))
    D0, D1 = d0(mesh).to_scipy(), d1(mesh).to_scipy()
    scale = np.abs(omega).max()
    np.testing.assert_allclose(exact + coexact + harmonic, omega, rtol=0, atol=1e-14 * scale)
    # Closed: d1 d alpha = 0 exactly (integer incidence), d1 gamma = 0 to the solves' round-off.
    np.testing.assert_allclose(D1 @ exact, 0, atol=1e-14 * scale)
    np.testing.assert_allclose(D1 @ harmonic, 0, atol=1e-10 * scale)
    # Co-closed: d0^T *1 of the co-exact and harmonic parts vanish (delta = *0^{-1} d0^T *1).
    np.testing.assert_allclose(D0.T @ (star * coexact), 0, atol=1e-10 * scale)
    np.testing.assert_allclose(D0.T @ (star * harmonic), 0, atol=1e-10 * scale)
    # Pairwise orthogonal in the *1 pairing (an inner product where *1 > 0, a pairing anyway).
    norm = omega @ (np.abs(star) * omega)
    for a, b in ((exact, coexact), (exact, harmonic), (coexact, harmonic)):
        assert abs(a @ (star * b)) < 1e-10 * norm


def test_parts_are_closed_coclosed_and_orthogonal_on_the_reference_mesh(reference):
    """The reference mesh has 1076 non-Delaunay edges (*1 < 0 there): the identities still hold, and the
    harmonic parts of five forms span 2 g = 4 dimensions."""
    mesh, omega, *_, parts = reference
    assert np.sum(np.asarray(hodge_star_entries(mesh, degree=1)) < 0) == 1076
    for k in range(omega.shape[1]):
        _check_identities(mesh, omega[:, k], HodgeDecomposition(*(part[:, k] for part in parts)))
    singular = np.linalg.svd(np.asarray(parts.harmonic), compute_uv=False)
    # A rank: the singular values of the missing directions are round-off (measured 7e-17 of |omega|), the
    # harmonic ones at least 0.14.
    assert np.sum(singular > 1e-8 * np.abs(omega).max()) == 4, singular


def _annulus(n_around: int = 24, n_rings: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """A flat annulus 1 <= r <= 2 in z = 0, counterclockwise faces (genus 0, two boundary loops)."""
    angle = 2 * np.pi * np.arange(n_around) / n_around
    radius = 1 + np.arange(n_rings) / (n_rings - 1)
    vertices = np.stack([np.outer(np.cos(angle), radius), np.outer(np.sin(angle), radius), np.zeros((n_around, n_rings))], -1)
    i, j = np.arange(n_around)[:, None], np.arange(n_rings - 1)[None, :]
    a, b, c, d = i * n_rings + j, ((i + 1) % n_around) * n_rings + j, ((i + 1) % n_around) * n_rings + j + 1, i * n_rings + j + 1
    faces = np.concatenate([np.stack([a, c, b], -1).reshape(-1, 3), np.stack([a, d, c], -1).reshape(-1, 3)])
    return vertices.reshape(-1, 3), faces


@pytest.fixture(scope="module")
def union(icosphere1):
    """Torus (b1 = 2) + sphere (0) + annulus with boundary (1) + torus (2), as one mesh, jittered: the
    built-in torus's quads are cyclic, so the cotan *1 of their diagonals is exactly 0 (module docstring)."""
    shapes = [torus(n_major=12, n_minor=6), icosphere1, torus(major_radius=2.0, minor_radius=0.7, n_major=10, n_minor=7)]
    parts = [(np.asarray(s.vertices), np.asarray(s.topology.faces)) for s in shapes]
    parts = parts[:2] + [_annulus()] + parts[2:]
    rng = np.random.default_rng(7)
    return disjoint_union([(V + 0.02 * rng.standard_normal(V.shape), F) for V, F in parts])


def test_cocycle_basis_is_closed_and_counts_the_first_betti_number(union, reference):
    mesh = union.mesh
    basis = closed_cocycle_basis(mesh.topology)
    assert basis.shape == (mesh.n_edges, 5)
    np.testing.assert_array_equal(d1(mesh).to_scipy() @ basis, 0)
    assert set(np.unique(basis)) <= {-1.0, 0.0, 1.0}
    assert closed_cocycle_basis(mesh.topology) is basis  # cached per connectivity
    owners = [set(union.edge_owner[np.flatnonzero(basis[:, k])]) for k in range(5)]
    assert sorted(len(owner) for owner in owners) == [1] * 5  # each generator stays in its component
    assert sorted(next(iter(owner)) for owner in owners) == [0, 0, 2, 3, 3]
    ref_mesh = reference[0]
    assert closed_cocycle_basis(ref_mesh.topology).shape == (ref_mesh.n_edges, 4)


@pytest.mark.slow
def test_harmonic_space_has_the_dimension_of_the_first_cohomology(union):
    """Harmonic parts of random forms span 2 g + b - 1 dimensions per component: 2, 0, 1, 2."""
    mesh = union.mesh
    omega = np.random.default_rng(0).standard_normal((mesh.n_edges, 3))
    parts = hodge_decomposition(mesh, omega)
    harmonic = np.asarray(parts.harmonic)
    for part, dimension in enumerate((2, 0, 1, 2)):
        values = harmonic[union.edges_of(part)]
        singular = np.linalg.svd(values, compute_uv=False)
        # A rank: round-off for the missing directions (measured <= 2.2e-16 of |omega|), >= 0.2 for the others.
        assert np.sum(singular > 1e-8 * np.abs(omega).max()) == dimension, (part, singular)
    np.testing.assert_array_equal(harmonic[union.edges_of(1)], 0)  # the sphere has no generator at all
    for k in range(omega.shape[1]):
        _check_identities(mesh, omega[:, k], HodgeDecomposition(*(part[:, k] for part in parts)))


def _face_system_coexact(mesh: Mesh, omega: np.ndarray, star: np.ndarray) -> np.ndarray:
    """delta beta by the DDG notes' route: (d1 *1^{-1} d1^T) beta~ = d1 omega, solved with SciPy's LU,
    one face pinned per closed component (the system is singular there, compatible by construction)."""
    D1 = d1(mesh).to_scipy().tocsr()
    B = (D1 @ sp.diags(1 / star) @ D1.T).tocsr()
    topology = mesh.topology
    closed = np.ones(topology.n_components, dtype=bool)
    closed[topology.face_components[topology.edge_faces[topology.boundary_edges, 0]]] = False
    pins = [int(np.flatnonzero(topology.face_components == c)[0]) for c in np.flatnonzero(closed)]
    free = np.setdiff1d(np.arange(mesh.n_faces), pins)
    beta = np.zeros((mesh.n_faces,) + omega.shape[1:])
    beta[free] = spla.spsolve(B[free][:, free].tocsc(), (D1 @ omega)[free])
    return (D1.T @ beta) / star.reshape((-1,) + (1,) * (omega.ndim - 1))


@pytest.mark.parametrize("dual", ["voronoi", "barycentric"])
@pytest.mark.slow
def test_coexact_part_matches_an_independent_face_system_solve(union, dual):
    mesh = union.mesh
    omega = np.random.default_rng(1).standard_normal((mesh.n_edges, 3))
    parts = hodge_decomposition(mesh, omega, dual=dual)
    star = np.asarray(hodge_star_entries(mesh, degree=1, dual=dual))
    expected = _face_system_coexact(mesh, omega, star)
    np.testing.assert_allclose(parts.coexact, expected, rtol=0, atol=1e-10 * np.abs(omega).max())
    _check_identities(mesh, omega[:, 0], HodgeDecomposition(*(part[:, 0] for part in parts)), dual)


@pytest.mark.slow  # the fast tier's time limit (its checks run in the full suite)
def test_pure_forms_are_their_own_part(union):
    mesh = union.mesh
    rng = np.random.default_rng(2)
    star = np.asarray(hodge_star_entries(mesh, degree=1))
    exact_form = d0(mesh).to_scipy() @ rng.standard_normal(mesh.n_vertices)
    coexact_form = (d1(mesh).to_scipy().T @ rng.standard_normal(mesh.n_faces)) / star
    exact, coexact, harmonic = hodge_decomposition(mesh, np.stack([exact_form, coexact_form, exact_form + coexact_form], 1))
    scale = np.abs(coexact_form).max() + np.abs(exact_form).max()
    np.testing.assert_allclose(exact, np.stack([exact_form, 0 * exact_form, exact_form], 1), rtol=0, atol=1e-10 * scale)
    np.testing.assert_allclose(coexact, np.stack([0 * exact_form, coexact_form, coexact_form], 1), rtol=0, atol=1e-10 * scale)
    np.testing.assert_allclose(harmonic, 0, atol=1e-10 * scale)


def _small_torus() -> Mesh:
    mesh = torus(n_major=8, n_minor=5)
    return mesh.with_vertices(mesh.vertices + 0.02 * np.random.default_rng(8).standard_normal(mesh.vertices.shape))


@pytest.mark.slow
def test_gradients_with_respect_to_omega_and_vertices():
    mesh = _small_torus()
    rng = np.random.default_rng(4)
    omega, V = jnp.asarray(rng.standard_normal(mesh.n_edges)), mesh.vertices
    weights = jnp.asarray(rng.standard_normal((3, mesh.n_edges)))

    def loss(omega, V):
        parts = hodge_decomposition(mesh.with_vertices(V), omega)
        return sum(jnp.sum(w * jnp.sin(part)) for w, part in zip(weights, parts))

    gradients = jax.jit(jax.grad(loss, argnums=(0, 1)))(omega, V)
    along = (lambda x: loss(x, V), lambda x: loss(omega, x))  # the loss in omega, in V
    for k, argument in enumerate((omega, V)):
        direction = jnp.asarray(rng.standard_normal(argument.shape))
        finite = central_difference(along[k], argument, direction)
        # Central differences with step 1e-6: truncation ~1e-12, rounding ~1e-10 relative (measured 2.6e-10,
        # 3e-11, with a CPU's direct solves); on an accelerator the solves are CG's, to a residual of 1e-10.
        np.testing.assert_allclose(jnp.vdot(gradients[k], direction), finite, rtol=1e-6)
    # Forward mode agrees with reverse mode (the solves differentiate implicitly in both).
    tangents = (jnp.asarray(rng.standard_normal(omega.shape)), jnp.asarray(rng.standard_normal(V.shape)))
    _, forward = jax.jvp(loss, (omega, V), tangents)
    reverse = sum(jnp.vdot(g, t) for g, t in zip(gradients, tangents))
    np.testing.assert_allclose(forward, reverse, rtol=1e-10)


def test_throw_false_returns_the_parts_with_the_first_failing_step():
    mesh = _small_torus()
    omega = jnp.asarray(np.random.default_rng(6).standard_normal(mesh.n_edges))
    solution = hodge_decomposition(mesh, omega, throw=False)
    assert isinstance(solution, Solution) and solution.result == RESULTS.successful
    assert isinstance(solution.value, HodgeDecomposition) and float(solution.stats["residual"]) < 1e-10
    for ours, plain in zip(solution.value, hodge_decomposition(mesh, omega)):
        np.testing.assert_array_equal(ours, plain)
    # A NaN fails the Laplacian solve (step 1) and so the projection after it (step 3): the first one is reported.
    failed = hodge_decomposition(mesh, omega.at[3].set(jnp.nan), throw=False)
    assert failed.result == RESULTS.nonfinite
    with pytest.raises(Exception, match="NaN or inf"):
        hodge_decomposition(mesh, omega.at[3].set(jnp.nan))


def test_jit_and_vmap_equal_eager():
    mesh = _small_torus()
    omega = jnp.asarray(np.random.default_rng(5).standard_normal((mesh.n_edges, 3)))
    eager = [hodge_decomposition(mesh, omega[:, k]) for k in range(3)]
    # Batched over the columns inside the caller's jit: one program (the kernel traced into it).
    mapped = jax.jit(lambda m, w: jax.vmap(lambda c: hodge_decomposition(m, c), in_axes=1, out_axes=1)(w))(mesh, omega)
    for k, parts in enumerate(eager):
        for ours, map_part in zip(parts, mapped):
            np.testing.assert_allclose(map_part[:, k], ours, rtol=0, atol=1e-13)


def test_bad_input(without_type_checker, icosphere1):
    mesh = icosphere1
    omega = np.zeros(mesh.n_edges)
    cases = [
        (lambda: hodge_decomposition(np.zeros((3, 3)), omega), DDGInputError, "mesh: expected a ddgjax Mesh"),
        (lambda: hodge_decomposition(mesh, omega[:-1]), DDGInputError, rf"omega: expected shape \({mesh.n_edges},\)"),
        (lambda: hodge_decomposition(mesh, np.zeros((mesh.n_edges, 2, 2))), DDGInputError, "omega: expected shape"),
        (lambda: hodge_decomposition(mesh, omega.astype(complex)), DDGInputError, "omega: expected a real"),
        (lambda: hodge_decomposition(mesh, omega, dual="dual"), DDGInputError, "dual: expected one of"),
        (lambda: hodge_decomposition(mesh, omega, solver="lu"), DDGInputError, "solver: expected one of"),
    ]
    faces = np.asarray(mesh.topology.faces).copy()
    faces[0] = faces[0, ::-1]
    flipped = Mesh.from_arrays(np.asarray(mesh.vertices), faces)
    cases.append((lambda: hodge_decomposition(flipped, omega), MeshDataError, "consistently oriented"))
    for call, error, message in cases:
        with pytest.raises(error, match=message):
            call()
