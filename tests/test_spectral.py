"""Tests for ddgjax.spectral: Laplacian eigenpairs against analytic spectra (sphere, hemisphere, disk,
square) with fitted convergence rates and against SciPy's eigsh on a real mesh; gradients (eigenvalues,
eigenvectors, cluster-invariant functions) against finite differences; the spectral tools."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.sparse.linalg as spla
from scipy.special import jn_zeros

from ddgjax import DDGInputError
from ddgjax.laplacian import cotan_laplacian, mass_matrix
from ddgjax.mesh import disk, edge_lengths, grid
from ddgjax.solve import amg_hierarchy
from ddgjax.spectral import (
    eigenpairs,
    heat_kernel,
    heat_kernel_signature,
    smallest_eigenpairs,
    spectral_coefficients,
    spectral_filter,
    spectral_reconstruction,
)

from finite_differences import central_difference, random_direction

# The unit sphere: l (l + 1) with multiplicity 2 l + 1, l = 0..3.
SPHERE_SPECTRUM = np.repeat([0.0, 2.0, 6.0, 12.0], [1, 3, 5, 7])


def _hemisphere(n_rings):
    """The unit upper hemisphere, from the unit disk: radius r to polar angle r pi / 2."""
    flat = disk(n_rings)
    xy = np.asarray(flat.vertices)[:, :2]
    r = np.linalg.norm(xy, axis=1)
    theta = r * np.pi / 2
    direction = xy / np.where(r > 0, r, 1.0)[:, None]
    vertices = np.column_stack([np.sin(theta)[:, None] * direction, np.cos(theta)])
    return flat.with_vertices(jnp.asarray(vertices))


@pytest.mark.slow
def test_unit_sphere_converges_to_l_l_plus_1_at_second_order(icospheres):
    errors, sizes = [], []
    for subdivisions in (2, 3, 4):
        mesh = icospheres(subdivisions)
        values, vectors = eigenpairs(mesh, 16)
        M = mass_matrix(mesh)
        np.testing.assert_allclose(vectors.T @ (M @ vectors), np.eye(16), atol=1e-10)
        errors.append(np.abs(np.asarray(values) - SPHERE_SPECTRUM).max())
        sizes.append(float(jnp.mean(edge_lengths(mesh))))
    rate = np.polyfit(np.log(sizes), np.log(errors), 1)[0]
    # The cotan FEM eigenvalues converge at O(h^2): fitted rate measured 2.0, and the O(h^2) discretisation
    # error is 0.05 at 2562 vertices (largest at l = 3).
    assert 1.8 < rate < 2.3, (errors, rate)
    assert errors[-1] < 0.06


@pytest.mark.slow
def test_agrees_with_scipy_eigsh_on_camelhead_neumann_and_dirichlet(data_mesh):
    mesh = data_mesh("camelhead.off")
    L, M = cotan_laplacian(mesh), mass_matrix(mesh)
    interior = np.setdiff1d(np.arange(mesh.n_vertices), mesh.topology.boundary_vertices)
    for boundary, rows in (("neumann", np.arange(mesh.n_vertices)), ("dirichlet", interior)):
        values, vectors = eigenpairs(mesh, 10, boundary=boundary)
        A, B = L.to_scipy()[rows][:, rows], M.to_scipy()[rows][:, rows]
        expected, reference = spla.eigsh(A.tocsc(), k=10, M=B.tocsc(), sigma=-1e-6, which="LM")
        # Two shift-invert Lanczos runs (different shifts, start vectors, SuperLU factors): round-off of the
        # factored solves of an ill-conditioned L - sigma M.
        np.testing.assert_allclose(values, expected, rtol=1e-8, atol=1e-10)
        # Same eigenvectors up to sign (the spectrum here has no clusters): |phi_i^T M psi_i| = 1, to
        # round-off divided by the relative gap between neighbouring eigenvalues.
        overlaps = np.asarray(vectors)[rows].T @ (B @ reference)
        np.testing.assert_allclose(np.abs(np.diag(overlaps)), 1.0, atol=1e-8)  # round-off over the gap
        if boundary == "dirichlet":
            assert np.all(np.asarray(vectors)[mesh.topology.boundary_vertices] == 0)
        largest = np.abs(np.asarray(vectors)).argmax(axis=0)
        assert np.all(np.asarray(vectors)[largest, np.arange(10)] > 0)  # the sign convention


@pytest.mark.parametrize(
    ("boundary", "expected"),
    # Spherical harmonics Y_l^m odd about the equator (l + m odd) vanish there; even ones (l + m even)
    # have zero normal derivative.
    [("dirichlet", [2.0, 6.0, 6.0, 12.0, 12.0, 12.0]), ("neumann", [0.0, 2.0, 2.0, 6.0, 6.0, 6.0])],
)
@pytest.mark.slow
def test_hemisphere_spectrum(boundary, expected):
    values, _ = eigenpairs(_hemisphere(16), 6, boundary=boundary)
    # O(h^2) discretisation error of a 16-ring mesh (mapped from the disk: uneven triangles near the pole).
    np.testing.assert_allclose(values, expected, rtol=0.02, atol=0.02)


@pytest.mark.slow
def test_unit_disk_dirichlet_spectrum_is_the_squared_bessel_zeros():
    j0, j1, j2 = jn_zeros(0, 2), jn_zeros(1, 1), jn_zeros(2, 1)
    expected = np.sort(np.concatenate([j0**2, np.repeat(j1**2, 2), np.repeat(j2**2, 2)]))
    values, _ = eigenpairs(disk(16), 6, boundary="dirichlet")
    # O(h^2) discretisation error of a 16-ring disk (and of its polygonal boundary).
    np.testing.assert_allclose(values, expected, rtol=0.01)


@pytest.mark.slow
def test_unit_square_spectrum():
    square = grid(24, 24, size=1.0)
    dirichlet, _ = eigenpairs(square, 4, boundary="dirichlet")
    neumann, _ = eigenpairs(square, 4)
    # O(h^2) discretisation error at h = 1/24 (measured 0.14 % for Neumann); the zero eigenvalue to round-off.
    np.testing.assert_allclose(dirichlet, np.pi**2 * np.array([2.0, 5.0, 5.0, 8.0]), rtol=0.01)
    np.testing.assert_allclose(neumann, np.pi**2 * np.array([0.0, 1.0, 1.0, 2.0]), rtol=0.01, atol=1e-10)  # measured 0.14 %


@pytest.mark.slow
def test_gradients_of_eigenvalues_eigenvectors_and_cluster_invariant_functions(icosphere2):
    mesh = icosphere2

    def spectrum(V, k):
        moved = mesh.with_vertices(V)
        return smallest_eigenpairs(cotan_laplacian(moved), mass_matrix(moved), k)

    # A generic shape (no clusters): eigenvalues and a function of the eigenvectors.
    rng = np.random.default_rng(1)
    V = mesh.vertices * jnp.asarray([1.0, 1.2, 1.5]) + 0.02 * rng.standard_normal(mesh.vertices.shape)
    weights = jnp.linspace(0.0, 1.0, mesh.n_vertices)[:, None]

    def generic(V):
        values, vectors = spectrum(V, 6)
        return jnp.sum(values[1:] ** 1.5) + jnp.sum(jnp.sin(3.0 * vectors[:, 1:]) * weights)

    # The round sphere (clusters of 3 and 5): functions invariant within each cluster.
    def invariant(V):
        values, vectors = spectrum(V, 9)
        return (
            jnp.sum(values[1:4])
            + jnp.sum(values[4:9] ** 2)
            + jnp.sum(heat_kernel_signature(values, vectors, t=0.1) * weights[:, 0])
        )

    for f, point in ((generic, V), (invariant, mesh.vertices)):
        gradient = jax.jit(jax.grad(f))(point)
        assert np.all(np.isfinite(gradient))
        direction = random_direction(point.shape)
        finite = central_difference(jax.jit(f), point, direction)
        # Central differences with step 1e-6: truncation ~1e-12, rounding ~1e-10 relative, plus the
        # eigensolves' round-off (amplified by 1 / gap in the eigenvector terms) divided by the step 2e-6.
        np.testing.assert_allclose(jnp.vdot(gradient, direction), finite, rtol=1e-6)


@pytest.mark.slow
def test_jit_and_vmap_equal_eager(icosphere2):
    mesh = icosphere2
    eager = eigenpairs(mesh, 5, boundary="neumann")
    jitted = jax.jit(lambda V: eigenpairs(mesh.with_vertices(V), 5))(mesh.vertices)
    for a, b in zip(eager, jitted):
        np.testing.assert_allclose(a, b, atol=1e-10)
    scales = jnp.asarray([1.0, 2.0])
    batched = jax.vmap(lambda s: eigenpairs(mesh.with_vertices(s * mesh.vertices), 5)[0])(scales)
    # lambda scales as 1 / s^2: exactly on the host's ARPACK path (s = 2 scales in binary: measured 0); the
    # subspace iteration an accelerator defaults to stops at a relative residual of 1e-10.
    np.testing.assert_allclose(batched[1], batched[0] / 4, rtol=1e-8, atol=1e-10)


def test_a_second_eager_call_compiles_nothing(icosphere2):
    """The host eigensolver's callback runs inside one program cached per size: called op by op, a
    callback made anew on each call was compiled again on each call."""
    compiles = []

    def listen(event, duration, **kwargs):
        if event.endswith("backend_compile_duration"):
            compiles.append(event)

    mesh = icosphere2
    first = eigenpairs(mesh, 5)
    moved = mesh.with_vertices(1.5 * mesh.vertices)
    jax.monitoring.register_event_duration_secs_listener(listen)
    try:
        second = eigenpairs(moved, 5, throw=False)
    finally:
        jax.monitoring.unregister_event_duration_listener(listen)
    # ARPACK on the host agrees to round-off (measured 1.5e-15); the subspace iteration an accelerator
    # defaults to stops at a relative residual of 1e-10.
    np.testing.assert_allclose(second.value.values, first.values / 1.5**2, rtol=1e-9, atol=1e-12)
    assert compiles == []


@pytest.mark.slow  # the fast tier's time limit (its checks run in the full suite)
def test_spectral_tools(icosphere2):
    mesh = icosphere2
    M = mass_matrix(mesh)
    values, vectors = eigenpairs(mesh, 16)
    # A function in the span is reconstructed exactly; the coefficients are its coordinates, up to the
    # eigenvectors' M-orthonormality round-off times coefficients as large as 15 (measured 2e-14).
    coefficients = jnp.arange(16.0)
    f = vectors @ coefficients
    np.testing.assert_allclose(spectral_coefficients(vectors, M, f), coefficients, atol=1e-12)
    np.testing.assert_allclose(spectral_reconstruction(vectors, spectral_coefficients(vectors, M, f)), f, atol=1e-12)
    # Filtering: an all-pass response projects; a low-pass one keeps the first four coordinates.
    kept = spectral_filter(values, vectors, M, f, response=lambda lam: lam < 3.0)
    np.testing.assert_allclose(
        spectral_coefficients(vectors, M, kept), jnp.where(jnp.arange(16) < 4, coefficients, 0.0), atol=1e-12
    )
    # The heat kernel: symmetric, its diagonal is the signature, and it integrates to exp(0) = 1 (the
    # constant eigenfunction carries all the mass).
    kernel = heat_kernel(values, vectors, np.arange(mesh.n_vertices), t=0.5)
    np.testing.assert_allclose(kernel, kernel.T, atol=1e-12)
    np.testing.assert_allclose(jnp.diagonal(kernel), heat_kernel_signature(values, vectors, t=0.5)[:, 0], atol=1e-12)
    np.testing.assert_allclose(jnp.sum(M @ kernel[:, 7]), 1.0, rtol=1e-12)  # measured 2.7e-15


def test_bad_input(without_type_checker, icosphere1):
    mesh = icosphere1
    cases = [
        (lambda: eigenpairs(mesh, 0), "k: expected an integer >= 1"),
        (lambda: eigenpairs(mesh, mesh.n_vertices), "k: expected fewer eigenpairs than unknowns"),
        (lambda: eigenpairs(mesh, 3, boundary="robin"), "boundary: expected one of"),
        (lambda: eigenpairs(mesh, 3, boundary="dirichlet"), "boundary: 'dirichlet' needs a mesh with a boundary"),
        (lambda: eigenpairs(mesh, 3, mass="cubic"), "mass: expected one of"),
        (
            lambda: smallest_eigenpairs(cotan_laplacian(mesh).to_scipy(), mass_matrix(mesh), 3),
            "L: expected a ddgjax SparseMatrix",
        ),
        (lambda: heat_kernel(jnp.ones(3), jnp.ones((42, 3)), [42], t=1.0), "sources: vertex indices must lie in"),
        (lambda: spectral_coefficients(jnp.ones((41, 3)), mass_matrix(mesh), jnp.ones(42)), r"vectors: expected shape \(42, k\)"),
    ]
    for call, message in cases:
        with pytest.raises(DDGInputError, match=message):
            call()


@pytest.mark.slow
def test_pure_jax_subspace_iteration_agrees_with_arpack(icosphere2):
    # k closes the clusters: 1 + 3 + 5 on the sphere; j01, j11 (2), j21 (2), j02, j31 (2) on the disk.
    for mesh, boundary, k in ((icosphere2, "neumann", 9), (disk(6), "dirichlet", 8)):
        expected = eigenpairs(mesh, k, boundary=boundary, method="arpack")
        M = mass_matrix(mesh)
        # Under jit with the default backend; eagerly with CG preconditioned by an AMG hierarchy of
        # L - sigma M built from the concrete values (CG under jit: the next test).
        solutions = [
            jax.jit(functools.partial(_subspace_eigenpairs, mesh, k=k, boundary=boundary, solver="auto"))(mesh.vertices),
            eigenpairs(mesh, k, boundary=boundary, method="subspace", solver="cg"),
        ]
        for values, vectors in solutions:
            # The subspace iteration stops at a relative residual of 1e-10 (`_SUBSPACE_TOLERANCE`).
            np.testing.assert_allclose(values, expected[0], rtol=1e-9, atol=1e-9)
            # Eigenvectors up to the basis inside clusters: both span the same subspace, M-orthonormally
            # (residual 1e-10 divided by the relative gap to the next cluster).
            overlap = np.asarray(expected[1]).T @ np.asarray(M @ vectors)
            np.testing.assert_allclose(np.linalg.svd(overlap, compute_uv=False), 1.0, atol=1e-8)  # residual over the gap


def _subspace_eigenpairs(mesh, V, *, k, boundary, solver):
    return eigenpairs(mesh.with_vertices(V), k, boundary=boundary, method="subspace", solver=solver)


@pytest.mark.slow
def test_subspace_iteration_with_a_multigrid_hierarchy_passed_into_jit_differentiates(icosphere1):
    """A hierarchy of L built outside jit preconditions the forward and the adjoint solves inside it; the
    gradient of the eigenvalue sum (invariant within clusters) equals ARPACK's path."""
    mesh = icosphere1.with_vertices(np.asarray(icosphere1.vertices) * np.array([1.0, 0.9, 1.2]))
    hierarchy = amg_hierarchy(cotan_laplacian(mesh))

    def loss(V, **options):
        values, vectors = eigenpairs(mesh.with_vertices(V), 6, **options)
        return jnp.sum(values) + jnp.sum(vectors[:, 1] ** 4)

    ours = jax.jit(jax.value_and_grad(lambda V: loss(V, method="subspace", solver="cg", preconditioner=hierarchy)))(mesh.vertices)
    expected = jax.value_and_grad(lambda V: loss(V, method="arpack"))(mesh.vertices)
    # Subspace iteration to a relative residual of 1e-10 and the adjoint CG to 1e-10 (`_ADJOINT_RTOL`),
    # both amplified by 1 / gap in the eigenvector terms of the gradient.
    np.testing.assert_allclose(ours[0], expected[0], rtol=1e-9)
    np.testing.assert_allclose(ours[1], expected[1], rtol=0, atol=1e-7 * np.abs(expected[1]).max())  # 1e-10 solves over the gap
    with pytest.raises(DDGInputError, match="preconditioner"):
        eigenpairs(mesh, 6, method="arpack", preconditioner=hierarchy)
    with pytest.raises(DDGInputError, match="traced"):
        jax.jit(lambda V: eigenpairs(mesh.with_vertices(V), 6, method="subspace", solver="cg", preconditioner="amg"))(
            mesh.vertices
        )


@pytest.mark.slow
def test_robust_eigenpairs_are_those_of_robust_laplacian(data_mesh):
    import robust_laplacian

    from ddgjax.laplacian import intrinsic_delaunay

    mesh = data_mesh("camelhead.off")
    L, M = robust_laplacian.mesh_laplacian(np.asarray(mesh.vertices), np.asarray(mesh.faces), mollify_factor=0.0)
    expected = np.sort(spla.eigsh(L.tocsc(), k=6, M=M.tocsc(), sigma=-1e-6, which="LM")[0])
    # Two shift-invert Lanczos runs (different shifts and factors) on operators assembled by different code
    # (intrinsic Delaunay flips, cotangents from edge lengths): round-off of each.
    np.testing.assert_allclose(eigenpairs(mesh, 6, mass="barycentric", robust=True)[0], expected, rtol=1e-9, atol=1e-10)
    # Inside jit, with the triangulation made once on the host.
    triangulation = intrinsic_delaunay(mesh)
    jitted = jax.jit(lambda V: eigenpairs(mesh.with_vertices(V), 6, mass="barycentric", robust=triangulation)[0])
    np.testing.assert_allclose(jitted(mesh.vertices), expected, rtol=1e-9, atol=1e-10)  # round-off of each solver


@pytest.mark.slow
def test_a_degenerate_mesh_is_refused_or_reported_never_a_wrong_spectrum(icosphere2):
    """A face of relative area 1e-16 in an icosphere (a corner 1e-16 edge lengths off the midpoint of the
    opposite edge): its cotangents are ~1e16 and rounding leaves the plain problem's small eigenpairs
    noise (lambda_1 from -0.008 to 38 where 0 is right, depending on the method). `eigenpairs` refuses
    the mesh (naming the face and `robust=True`), `robust=True` gives robust_laplacian's (mollified)
    spectrum, and where the positions cannot be checked first (inside jit) or the matrices are passed
    in, the outcome is a failure, never the pairs as a success."""
    import robust_laplacian

    from ddgjax import RESULTS, MeshDataError

    mesh = icosphere2
    V, F = np.asarray(mesh.vertices).copy(), np.asarray(mesh.faces)
    a, b, c = V[F[0]]
    away = (c - (a + b) / 2) / np.linalg.norm(c - (a + b) / 2)
    V[F[0, 2]] = (a + b) / 2 + 2e-16 * np.linalg.norm(b - a) * away  # area = 1e-16 * |b - a|^2
    degenerate = mesh.with_vertices(V)
    with pytest.raises(MeshDataError, match=r"faces \[0\] \(1 in all\) have zero or near-zero area.*robust=True"):
        eigenpairs(degenerate, 5)
    L, M = robust_laplacian.mesh_laplacian(V, F.astype(np.int64))  # mollify_factor=1e-5
    expected = np.sort(spla.eigsh(L.tocsc(), k=5, M=M.tocsc(), sigma=-1e-6, which="LM")[0])
    values = eigenpairs(degenerate, 5, mass="barycentric", robust=True)[0]
    # Two shift-invert Lanczos runs on independently assembled operators: round-off of each.
    np.testing.assert_allclose(values, expected, rtol=1e-9, atol=1e-10)
    # One component: one zero eigenvalue; the next is the sphere's 2 less icosphere(2)'s O(h^2) error.
    assert values[0] > -1e-12 and values[1] > 1.9
    # The plain operators, assembled regardless: no method returns their pairs as a success.
    L, M = cotan_laplacian(degenerate), mass_matrix(degenerate)
    for method in ("arpack", "subspace"):
        for k in (1, 5):
            solution = smallest_eigenpairs(L, M, k, method=method, throw=False)
            assert solution.result in (RESULTS.not_positive_definite, RESULTS.eigensolver_failed), (method, k)
            with pytest.raises(Exception, match="positive definite|did not converge"):
                smallest_eigenpairs(L, M, k, method=method)
    # Inside jit (positions traced: not checked first) the outcome is the failure.
    jitted = jax.jit(lambda W: eigenpairs(mesh.with_vertices(W), 5, throw=False).result)(degenerate.vertices)
    assert jitted in (RESULTS.not_positive_definite, RESULTS.eigensolver_failed)


def test_hermitian_real_form_solves_the_complex_problem_on_the_host(icosphere2):
    """The real form of a complex Hermitian problem (a connection Laplacian, 162 complex unknowns: ARPACK's
    complex mode) gives the real-form solver's pairs: equal eigenvalues, the same invariant subspaces."""
    from ddgjax.fields import connection_laplacian, connection_mass_matrix
    from ddgjax.fields._connection import plan_of
    from ddgjax.fields._laplacian import real_form, real_form_diagonal

    mesh = icosphere2
    L = real_form(connection_laplacian(mesh, n=1), plan_of(mesh))
    M = real_form_diagonal(connection_mass_matrix(mesh).values)
    values, vectors = smallest_eigenpairs(L, M, 6, hermitian_real_form=True)
    expected_values, expected_vectors = smallest_eigenpairs(L, M, 6)
    np.testing.assert_allclose(values, expected_values, rtol=1e-10)
    np.testing.assert_allclose(values[::2], values[1::2], rtol=1e-12)  # pairs: u and i u
    np.testing.assert_allclose(np.asarray(vectors).T @ np.asarray(M @ vectors), np.eye(6), atol=1e-12)
    overlap = np.asarray(expected_vectors).T @ np.asarray(M @ vectors)
    # The same invariant subspaces from two eigensolvers: round-off divided by the gap to the next pair.
    np.testing.assert_allclose(np.linalg.svd(overlap, compute_uv=False), 1.0, atol=1e-8)
    with pytest.raises(DDGInputError, match="even k"):
        smallest_eigenpairs(L, M, 3, hermitian_real_form=True)


@pytest.mark.slow
def test_named_pairs_and_outcomes_without_throw(monkeypatch, icosphere2):
    """`Eigenpairs` unpacks and names its fields; `throw=False` returns a `Solution` whose result is the
    eigensolver's: successful, or `eigensolver_failed` for a subspace iteration out of steps and for ARPACK's
    non-convergence on the host (both forced here), which raise with `throw=True`."""
    import scipy.sparse.linalg

    import ddgjax.spectral._generalized as generalized
    from ddgjax import RESULTS, Solution
    from ddgjax.spectral import Eigenpairs

    mesh = icosphere2  # 162 unknowns > 2 k + 64: the host path is ARPACK's, not the dense one
    pairs = eigenpairs(mesh, 4)
    assert isinstance(pairs, Eigenpairs)
    values, vectors = pairs
    assert values is pairs.values and vectors is pairs.vectors
    solution = eigenpairs(mesh, 4, throw=False)
    assert isinstance(solution, Solution) and solution.result == RESULTS.successful
    np.testing.assert_array_equal(solution.value.values, values)
    assert float(solution.stats["residual"]) < 1e-10
    dirichlet = eigenpairs(disk(5), 4, boundary="dirichlet", method="subspace", throw=False)
    assert dirichlet.result == RESULTS.successful and dirichlet.value.vectors.shape == (disk(5).n_vertices, 4)

    monkeypatch.setattr(generalized, "_SUBSPACE_MAX_STEPS", 1)
    failed = eigenpairs(mesh, 4, method="subspace", throw=False)
    assert failed.result == RESULTS.eigensolver_failed and float(failed.stats["residual"]) > 1e-10
    with pytest.raises(Exception, match="The eigensolver did not converge"):
        eigenpairs(mesh, 4, method="subspace")

    def no_convergence(*args, **kwargs):
        raise scipy.sparse.linalg.ArpackNoConvergence("forced", np.zeros(0), np.zeros((mesh.n_vertices, 0)))

    monkeypatch.setattr(scipy.sparse.linalg, "eigsh", no_convergence)
    assert eigenpairs(mesh, 4, method="arpack", throw=False).result == RESULTS.eigensolver_failed
    L, M = cotan_laplacian(mesh), mass_matrix(mesh)
    assert smallest_eigenpairs(L, M, 4, throw=False).result == RESULTS.eigensolver_failed
    with pytest.raises(Exception, match="The eigensolver did not converge"):
        jax.jit(lambda V: eigenpairs(mesh.with_vertices(V), 4)[0])(mesh.vertices)
