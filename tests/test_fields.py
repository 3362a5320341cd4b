"""Tests for ddgjax.fields: the connection against potpourri3d's connection Laplacian (gauge-invariant
comparison) and exact identities (holonomy, Gauss-Bonnet, flat frames); smoothest fields (flat disk,
Poincare-Hopf on the sphere, torus and genus-2 meshes for n = 1, 2, 4, a cube's cross field);
alignment and interpolation; gradients against finite differences; jit / vmap; bad input."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.linalg as sla
import scipy.sparse as sp
from jax.test_util import check_grads

from ddgjax import DDGInputError, Mesh, MeshDataError
from ddgjax.fields import (
    connection_laplacian,
    connection_mass_matrix,
    edge_polar_angles,
    edge_transport_angles,
    face_holonomies,
    field_singularities,
    field_to_vectors,
    interpolate_field,
    principal_curvature_alignment,
    smoothest_field,
    tangent_bases,
)
from ddgjax.laplacian import cotan_laplacian
from ddgjax.mesh import disk, edge_cotan_weights

from finite_differences import central_difference


def _cube(k: int) -> Mesh:
    """The surface of `[-1, 1]^3`, each side a `k x k` grid of squares split into two triangles (alternating
    diagonals), vertices shared along the cube's edges, faces counterclockwise seen from outside."""
    points, faces, index = [], [], {}

    def vertex(p):
        key = tuple(np.round(p, 9))
        if key not in index:
            index[key] = len(points)
            points.append(p)
        return index[key]

    t = np.linspace(-1.0, 1.0, k + 1)
    for axis in range(3):
        u, v = [a for a in range(3) if a != axis]
        for sign in (-1.0, 1.0):
            grid = np.empty((k + 1, k + 1), dtype=int)
            for a in range(k + 1):
                for b in range(k + 1):
                    p = np.zeros(3)
                    p[axis], p[u], p[v] = sign, t[a], t[b]
                    grid[a, b] = vertex(p)
            for a in range(k):
                for b in range(k):
                    q = [grid[a, b], grid[a + 1, b], grid[a + 1, b + 1], grid[a, b + 1]]
                    split = [(0, 1, 2), (0, 2, 3)] if (a + b) % 2 == 0 else [(0, 1, 3), (1, 2, 3)]
                    for tri in split:
                        corners = [q[c] for c in tri]
                        P = np.array([points[c] for c in corners])
                        outward = np.cross(P[1] - P[0], P[2] - P[0])[axis] * sign > 0
                        faces.append(corners if outward else corners[::-1])
    return Mesh.from_arrays(np.array(points), np.array(faces))


def _cylinder(n_around: int, n_along: int) -> Mesh:
    """An open cylinder of radius 1 and height 2 along z, triangulated, faces outward."""
    angles = np.linspace(0.0, 2 * np.pi, n_around, endpoint=False)
    heights = np.linspace(-1.0, 1.0, n_along + 1)
    V = np.array([[np.cos(a), np.sin(a), z] for z in heights for a in angles])
    faces = []
    for r in range(n_along):
        for c in range(n_around):
            a, b = r * n_around + c, r * n_around + (c + 1) % n_around
            faces += [[a, b, b + n_around], [a, b + n_around, a + n_around]]
    return Mesh.from_arrays(V, np.array(faces))


def _ellipsoid(sphere: Mesh) -> Mesh:
    """`sphere` (the unit icosphere(2)) made a slightly jittered ellipsoid: no symmetry, so the smallest eigenvalue
    of the connection Laplacian is simple."""
    rng = np.random.default_rng(3)
    V = np.asarray(sphere.vertices) * np.array([1.0, 1.3, 0.8]) + 0.01 * rng.standard_normal((sphere.n_vertices, 3))
    return sphere.with_vertices(jnp.asarray(V))


def _dense(matrix) -> np.ndarray:
    return np.asarray(matrix.to_scipy().toarray())


# --- the connection -------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["disk(5)", "icosphere(2)", "small_disk.obj", "sphere_small.ply"])
@pytest.mark.slow
def test_connection_laplacian_equals_potpourri3d_up_to_a_change_of_tangent_bases(name, icosphere2, data_mesh):
    pp3d = pytest.importorskip("potpourri3d")
    mesh = {"disk(5)": lambda: disk(5), "icosphere(2)": lambda: icosphere2}.get(name, lambda: data_mesh(name))()
    A = _dense(connection_laplacian(mesh))
    V, F = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    reference = sp.csr_matrix(pp3d.MeshVectorHeatSolver(V, F, use_intrinsic_delaunay=False).get_connection_laplacian()).toarray()
    # Two choices of reference edges differ by a diagonal unitary D (A = D B D^H): the spectrum, the
    # moduli of the entries and the product around every face (the holonomy) do not see D.
    np.testing.assert_allclose(sla.eigvalsh(A), sla.eigvalsh(reference), atol=1e-12)
    np.testing.assert_allclose(np.abs(A), np.abs(reference), atol=1e-13)
    a, b, c = F.T
    np.testing.assert_allclose(A[a, b] * A[b, c] * A[c, a], reference[a, b] * reference[b, c] * reference[c, a], atol=1e-13)


@pytest.mark.parametrize("name", ["sphere.obj", "torus.obj", "double-torus.obj", "hemisphere.obj"])
@pytest.mark.slow
def test_holonomy_is_the_transport_around_each_face_and_sums_to_two_pi_chi(name, data_mesh):
    mesh = data_mesh(name)
    rho = np.asarray(edge_transport_angles(mesh))
    holonomy = np.asarray(face_holonomies(mesh))
    around = np.sum(np.asarray(mesh.face_edge_signs) * rho[np.asarray(mesh.face_edges)], axis=1)
    np.testing.assert_allclose(np.angle(np.exp(1j * (around - holonomy))), 0.0, atol=1e-12)
    # With the geodesic boundary Gauss-Bonnet holds on meshes with boundary too (the hemisphere, chi = 1).
    assert holonomy.sum() == pytest.approx(2 * np.pi * mesh.topology.euler_characteristic, abs=1e-11)
    assert np.all((rho >= -np.pi) & (rho < np.pi))


def test_polar_angles_are_the_edges_angles_in_the_tangent_frame_on_a_flat_disk():
    mesh = disk(5)
    theta = np.asarray(edge_polar_angles(mesh, boundary_scaling="unscaled"))
    e1, e2, normal = (np.asarray(x) for x in tangent_bases(mesh))
    V, E = np.asarray(mesh.vertices), np.asarray(mesh.edges)
    for column, (tail, head) in enumerate([(E[:, 0], E[:, 1]), (E[:, 1], E[:, 0])]):
        d = V[head] - V[tail]
        measured = np.mod(np.arctan2(np.sum(d * e2[tail], 1), np.sum(d * e1[tail], 1)), 2 * np.pi)
        np.testing.assert_allclose(np.angle(np.exp(1j * (measured - theta[:, column]))), 0.0, atol=1e-12)
    np.testing.assert_allclose(normal, np.tile([0.0, 0.0, 1.0], (mesh.n_vertices, 1)), atol=1e-15)
    assert np.all(np.asarray(face_holonomies(mesh, boundary_scaling="unscaled")) == pytest.approx(0.0, abs=1e-14))


@pytest.mark.slow
def test_tangent_frames_are_orthonormal_with_e1_along_the_reference_edge(data_mesh):
    mesh = data_mesh("spot.obj")
    e1, e2, normal = (np.asarray(x) for x in tangent_bases(mesh))
    frames = np.stack([e1, e2, normal], axis=1)
    np.testing.assert_allclose(frames @ frames.transpose(0, 2, 1), np.broadcast_to(np.eye(3), frames.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(frames), 1.0, atol=1e-12)
    # Every vertex has exactly one outgoing edge at polar angle 0, and e1 is its tangential part.
    theta, E, V = np.asarray(edge_polar_angles(mesh)), np.asarray(mesh.edges), np.asarray(mesh.vertices)
    tails = np.concatenate([E[:, 0], E[:, 1]])
    heads = np.concatenate([E[:, 1], E[:, 0]])
    zero = np.concatenate(theta.T) == 0
    np.testing.assert_array_equal(np.bincount(tails[zero], minlength=mesh.n_vertices), 1)
    d = V[heads[zero]] - V[tails[zero]]
    d -= np.sum(d * normal[tails[zero]], axis=1, keepdims=True) * normal[tails[zero]]
    np.testing.assert_allclose(d / np.linalg.norm(d, axis=1, keepdims=True), e1[tails[zero]], atol=1e-12)


@pytest.mark.parametrize("n", [1, 3])
def test_connection_laplacian_is_hermitian_psd_and_its_energy_is_the_transport_mismatch(n, data_mesh):
    mesh = data_mesh("sphere_small.ply")
    A = _dense(connection_laplacian(mesh, n=n))
    np.testing.assert_array_equal(A, A.conj().T)
    # PSD: every cotan weight of this mesh is positive (Delaunay), so A is a sum of squares.
    assert np.all(np.asarray(edge_cotan_weights(mesh)) > 0)
    assert sla.eigvalsh(A).min() > -1e-12
    rng = np.random.default_rng(0)
    u = rng.standard_normal(mesh.n_vertices) + 1j * rng.standard_normal(mesh.n_vertices)
    E, w, rho = np.asarray(mesh.edges), np.asarray(edge_cotan_weights(mesh)), np.asarray(edge_transport_angles(mesh))
    expected = np.sum(w * np.abs(u[E[:, 1]] - np.exp(1j * n * rho) * u[E[:, 0]]) ** 2)
    np.testing.assert_allclose(np.vdot(u, A @ u), expected, rtol=1e-12)


def test_flat_connection_laplacian_is_the_cotan_laplacian_in_other_bases():
    mesh = disk(5)
    for n in (1, 4):
        A = _dense(connection_laplacian(mesh, n=n, boundary_scaling="unscaled"))
        np.testing.assert_allclose(sla.eigvalsh(A), sla.eigvalsh(_dense(cotan_laplacian(mesh))), atol=1e-12)


# --- smoothest fields and singularities ----------------------------------------------------------


@pytest.mark.parametrize("n", [1, 4])
@pytest.mark.slow
def test_flat_disk_carries_a_constant_field_with_zero_energy_and_no_singularities(n):
    mesh = disk(5)
    result = smoothest_field(mesh, n=n, boundary_scaling="unscaled")
    assert abs(float(result.energy)) < 1e-12
    np.testing.assert_allclose(np.abs(result.field), 1.0, atol=1e-12)
    first = np.asarray(field_to_vectors(mesh, result.field, n=n, boundary_scaling="unscaled"))[0]
    for at in ("vertices", "faces"):
        arms = np.asarray(field_to_vectors(mesh, result.field, n=n, at=at, boundary_scaling="unscaled"))
        distances = np.linalg.norm(arms[:, :, None, :] - first[None, None, :, :], axis=-1).min(axis=-1)
        # The same n directions everywhere (each arm of every vertex or face is an arm of vertex 0's). The
        # eigensolver's accuracy: "auto" is ARPACK on a CPU (round-off, measured 2e-15) but the subspace
        # iteration elsewhere, which stops at a residual of 1e-10 of the largest Ritz value.
        assert distances.max() < 1e-8
    assert np.all(np.asarray(field_singularities(mesh, result.field, n=n, boundary_scaling="unscaled")) == 0)


@pytest.mark.parametrize("name", ["sphere.obj", "torus.obj", "double-torus.obj", "icosphere(2)"])
@pytest.mark.slow
def test_poincare_hopf_indices_are_multiples_of_one_over_n_and_sum_to_chi(name, icosphere2, data_mesh):
    mesh = icosphere2 if name == "icosphere(2)" else data_mesh(name)
    chi = mesh.topology.euler_characteristic
    for n in (1, 2, 4):
        result = smoothest_field(mesh, n=n)
        indices = np.asarray(field_singularities(mesh, result.field, n=n))
        np.testing.assert_array_equal(indices * n, np.round(indices * n))
        assert indices.sum() == pytest.approx(chi, abs=1e-12), (n, indices[indices != 0])
        if name == "sphere.obj":  # the sphere's smoothest fields: 2n singularities of index +1/n, none negative
            np.testing.assert_array_equal(np.sort(indices[indices != 0]), np.full(2 * n, 1.0 / n))
        if chi < 0 and n == 1:  # the genus-2 vector field: two saddles of index -1
            np.testing.assert_array_equal(np.sort(indices[indices != 0]), [-1.0, -1.0])


@pytest.mark.slow
def test_cube_cross_field_is_parallel_off_the_corners_with_a_quarter_singularity_at_each_corner():
    mesh = _cube(4)
    V = np.asarray(mesh.vertices)
    corner = np.all(np.isclose(np.abs(V), 1.0), axis=1)
    near_corner = np.min(np.linalg.norm(V[:, None] - V[corner][None], axis=2), axis=1) < 0.5
    inside_a_side = np.sum(np.isclose(np.abs(V), 1.0), axis=1) == 1
    chosen = np.flatnonzero(inside_a_side & ~near_corner)

    def side_angles(field):
        """Angle of the first cross direction from each chosen vertex's side axis, times 4 (cross symmetry)."""
        vectors = np.asarray(field_to_vectors(mesh, field, n=4))[chosen, 0]
        axis = np.argmax(np.abs(V[chosen]), axis=1)
        a = np.eye(3)[(axis + 1) % 3]
        b = np.cross(np.sign(V[chosen, axis])[:, None] * np.eye(3)[axis], a)
        return 4 * np.arctan2(np.sum(vectors * b, 1), np.sum(vectors * a, 1))

    smoothest = smoothest_field(mesh, n=4)
    # The cube minus its corners is flat with holonomy pi/2 around each corner (trivial for n = 4): the
    # smoothest cross field is parallel there, the same rotation of the sides' axes everywhere (the
    # rotation is the eigenvector's free phase).
    turned = np.exp(1j * side_angles(smoothest.field))
    # To the eigensolver's accuracy: ARPACK on a CPU (measured 5e-15), elsewhere the subspace iteration's
    # residual of 1e-10 of the largest Ritz value.
    assert np.abs(turned - turned[0]).max() < 1e-9
    aligned = smoothest_field(mesh, n=4, alignment=principal_curvature_alignment(mesh, n=4))
    # Along the edges; a linear solve ("auto": CG's relative residual 1e-10 on a GPU, direct on a CPU).
    np.testing.assert_allclose(np.angle(np.exp(1j * side_angles(aligned.field))), 0.0, atol=1e-9)
    for result in (smoothest, aligned):
        indices = np.asarray(field_singularities(mesh, result.field, n=4))
        singular = np.flatnonzero(indices)
        np.testing.assert_array_equal(indices[singular], np.full(8, 0.25))
        assert np.all(corner[np.asarray(mesh.faces)[singular]].any(axis=1))  # one face at each of the 8 corners
        assert np.unique(np.asarray(mesh.faces)[singular][corner[np.asarray(mesh.faces)[singular]]]).size == 8


@pytest.mark.slow
def test_phase_is_deterministic_and_the_field_is_an_eigenvector(icosphere2):
    mesh = _ellipsoid(icosphere2)
    result = smoothest_field(mesh, n=2)
    A, M = _dense(connection_laplacian(mesh, n=2)), np.asarray(connection_mass_matrix(mesh).values)
    u = np.asarray(result.solution)
    np.testing.assert_allclose(np.vdot(u, M * u).real, 1.0, atol=1e-10)
    smallest = sla.eigh(A, np.diag(M), eigvals_only=True, subset_by_index=(0, 0))[0]
    # The eigensolver's residual: round-off with ARPACK (a CPU's "auto"; measured 1e-15 and 0 in the
    # eigenvalue), up to 1e-10 of the largest Ritz value with the subspace iteration (elsewhere).
    np.testing.assert_allclose(A @ u, float(result.energy) * M * u, atol=1e-8)
    assert float(result.energy) == pytest.approx(smallest, rel=1e-9)  # ARPACK's round-off or 1e-10 residual
    largest = np.argmax(np.abs(u))
    assert abs(u[largest].imag) <= 1e-15 * abs(u[largest]) and u[largest].real > 0  # rotated by its own phase: round-off


@pytest.mark.slow
def test_principal_curvature_alignment_points_around_a_cylinder():
    mesh = _cylinder(24, 8)
    V = np.asarray(mesh.vertices)
    interior = np.abs(V[:, 2]) < 0.99
    line = np.asarray(field_to_vectors(mesh, principal_curvature_alignment(mesh, n=2), n=2))[interior, 0]
    # Max curvature: around, not along the axis; up to 0.3 degrees, the gap between the polar angles (unfolded,
    # intrinsic) and the edges' directions projected to the tangent plane (chords of the circle).
    np.testing.assert_allclose(line[:, 2], 0.0, atol=5e-3)
    cross = smoothest_field(mesh, n=4, alignment=principal_curvature_alignment(mesh, n=4), alignment_weight=10.0)
    vectors = np.asarray(field_to_vectors(mesh, cross.field, n=4))[interior]
    # Each cross has one arm along the axis (up to the discretisation of the polar angles).
    assert np.abs(np.abs(vectors[..., 2]).max(axis=1) - 1.0).max() < 1e-3


@pytest.mark.slow
def test_alignment_weight_trades_smoothness_for_alignment(icosphere2):
    mesh = _ellipsoid(icosphere2)
    q = principal_curvature_alignment(mesh, n=4)
    energies, distances = [], []
    for weight in (0.01, 1.0, 100.0):
        result = smoothest_field(mesh, n=4, alignment=q, alignment_weight=weight)
        energies.append(float(result.energy))
        distances.append(float(jnp.mean(jnp.abs(result.field - q / jnp.abs(q)))))
    assert energies[0] < energies[1] < energies[2] and distances[0] > distances[1] > distances[2]
    assert float(smoothest_field(mesh, n=4).energy) < energies[0]  # the eigenvector is the smoothest


# --- interpolation --------------------------------------------------------------------------------


@pytest.mark.slow
def test_interpolation_from_one_vertex_of_a_flat_disk_is_the_constant_field():
    mesh = disk(5)
    u = interpolate_field(mesh, fixed_vertices=np.array([0]), fixed_values=jnp.array([0.6 - 0.8j]), boundary_scaling="unscaled")
    assert complex(u[0]) == 0.6 - 0.8j
    vectors = np.asarray(field_to_vectors(mesh, u, n=1, boundary_scaling="unscaled"))[:, 0]
    np.testing.assert_allclose(vectors, np.broadcast_to(vectors[0], vectors.shape), atol=1e-10)


@pytest.mark.slow
def test_interpolation_solves_the_dirichlet_problem_of_the_connection_laplacian(data_mesh):
    mesh = data_mesh("sphere_small.ply")
    fixed, values = np.array([0, 7, 20]), jnp.array([1.0 + 0j, 1j, -0.5 + 0.5j])
    u = np.asarray(interpolate_field(mesh, fixed_vertices=fixed, fixed_values=values, n=2))
    A = _dense(connection_laplacian(mesh, n=2))
    free = np.setdiff1d(np.arange(mesh.n_vertices), fixed)
    expected = np.linalg.solve(A[np.ix_(free, free)], -A[np.ix_(free, fixed)] @ np.asarray(values))
    np.testing.assert_allclose(u[free], expected, atol=1e-10)
    np.testing.assert_array_equal(u[fixed], values)
    # Under jit with traced values, and eagerly again with new values: one program, the block plan kept.
    from ddgjax.fields._interpolation import _interpolate

    jitted = jax.jit(lambda V, x: interpolate_field(mesh.with_vertices(V), fixed_vertices=fixed, fixed_values=x, n=2))
    np.testing.assert_allclose(np.asarray(jitted(mesh.vertices, values))[free], expected, atol=1e-10)
    programs = _interpolate._cache_size()
    again = np.asarray(interpolate_field(mesh, fixed_vertices=fixed, fixed_values=2 * values, n=2))
    np.testing.assert_allclose(again[free], 2 * expected, atol=1e-10)
    assert _interpolate._cache_size() == programs


@pytest.mark.slow
def test_interpolated_transport_agrees_with_potpourri3d_vector_heat_near_the_source(icosphere3):
    pp3d = pytest.importorskip("potpourri3d")
    mesh = icosphere3
    V, F = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    solver = pp3d.MeshVectorHeatSolver(V, F, use_intrinsic_delaunay=False)
    basis_x, basis_y, _ = solver.get_tangent_frames()
    source, direction = 0, basis_x[0]
    theirs = solver.transport_tangent_vector(source, [1.0, 0.0])
    their_vectors = theirs[:, :1] * basis_x + theirs[:, 1:] * basis_y
    e1, e2, _ = (np.asarray(x) for x in tangent_bases(mesh))
    ours = interpolate_field(
        mesh, fixed_vertices=np.array([source]), fixed_values=jnp.array([direction @ e1[source] + 1j * direction @ e2[source]])
    )
    our_vectors = np.asarray(field_to_vectors(mesh, ours, n=1))[:, 0]
    near = np.linalg.norm(V - V[source], axis=1) < 0.5
    cosines = np.sum(our_vectors[near] * their_vectors[near], 1) / np.linalg.norm(their_vectors[near], axis=1)
    # Two discretisations of parallel transport from one point (harmonic extension vs the vector heat
    # method's diffusion): they agree to within a few degrees near the source.
    assert cosines.min() > np.cos(np.radians(3.0)), np.degrees(np.arccos(cosines.min()))


# --- derivatives, jit, vmap -----------------------------------------------------------------------


@pytest.mark.slow
def test_energy_and_phase_fixed_field_gradients_match_finite_differences(icosphere2):
    mesh = _ellipsoid(icosphere2)
    V = mesh.vertices
    direction = jnp.asarray(np.random.default_rng(1).standard_normal(V.shape))
    weights = jnp.linspace(0.0, 1.0, mesh.n_vertices)

    def energy(V):
        return smoothest_field(mesh.with_vertices(V), n=1).energy

    def field_loss(V):  # depends on the phase too: the phase rule makes it a function of V
        return jnp.sum(weights * smoothest_field(mesh.with_vertices(V), n=1).field.real)

    def aligned_loss(V):
        moved = mesh.with_vertices(V)
        result = smoothest_field(moved, n=4, alignment=principal_curvature_alignment(moved, n=4))
        return result.energy + jnp.sum(weights * jnp.abs(result.solution) ** 2)

    for loss in (energy, field_loss, aligned_loss):
        gradient = jax.jit(jax.grad(loss))(V)
        loss = jax.jit(loss)
        # Central differences with h = 1e-6: truncation error ~1e-7 relative (measured: 7e-10, 7e-9, 2e-7;
        # they fall as h^2 down to 1e-6, so the gradients are right).
        expected = central_difference(loss, V, direction, eps=1e-6)
        assert float(jnp.sum(gradient * direction)) == pytest.approx(float(expected), rel=1e-6)  # measured <= 2e-7 (above)


@pytest.mark.slow
def test_connection_laplacian_values_pass_check_grads(data_mesh):
    mesh = data_mesh("sphere_small.ply")
    rng = np.random.default_rng(2)
    u = jnp.asarray(rng.standard_normal(mesh.n_vertices) + 1j * rng.standard_normal(mesh.n_vertices))

    def energy(V):
        A = connection_laplacian(mesh.with_vertices(V), n=2)
        return jnp.real(jnp.vdot(u, A @ u))

    check_grads(energy, (mesh.vertices,), order=1, modes=["rev", "fwd"], eps=1e-6)


@pytest.mark.slow
def test_jit_and_vmap_equal_eager(data_mesh):
    mesh = data_mesh("sphere_small.ply")
    V = mesh.vertices
    eager = smoothest_field(mesh, n=2)
    jitted = jax.jit(lambda V: smoothest_field(mesh.with_vertices(V), n=2))(V)
    np.testing.assert_allclose(jitted.field, eager.field, atol=1e-10)
    # The field is the solution's unit field: one complex number per vertex; the result unpacks.
    field, solution, energy = eager
    assert field.shape == (mesh.n_vertices,) and jnp.iscomplexobj(field)
    np.testing.assert_allclose(field, solution / jnp.abs(solution), atol=1e-15)
    assert energy.shape == ()
    np.testing.assert_array_equal(
        jax.jit(lambda V, u: field_singularities(mesh.with_vertices(V), u, n=2))(V, eager.field),
        field_singularities(mesh, eager.field, n=2),
    )
    batch = jnp.stack([V, 1.5 * V + 0.1])
    values = jax.vmap(lambda V: connection_laplacian(mesh.with_vertices(V), n=2).values)(batch)
    for k in range(2):
        np.testing.assert_allclose(values[k], connection_laplacian(mesh.with_vertices(batch[k]), n=2).values, atol=1e-14)
    energies = jax.vmap(lambda V: smoothest_field(mesh.with_vertices(V), n=2).energy)(batch)
    # Scaling by 1.5 divides the (weak / mass-normalised) eigenvalue by 1.5^2. Two eigensolves: round-off with
    # ARPACK (a CPU's "auto"; measured 2e-16), the subspace iteration's 1e-10 residual elsewhere.
    np.testing.assert_allclose(energies, [eager.energy, eager.energy / 2.25], rtol=1e-9)


# --- bad input ------------------------------------------------------------------------------------


def test_bad_input_is_refused_with_clear_errors(without_type_checker, icosphere1):
    mesh = icosphere1
    for bad in (0, -1, 1.5, True, "4"):
        with pytest.raises(DDGInputError, match="n: expected the number of directions"):
            connection_laplacian(mesh, n=bad)
    with pytest.raises(DDGInputError, match="boundary_scaling: expected one of"):
        smoothest_field(mesh, boundary_scaling="free")
    with pytest.raises(DDGInputError, match="mass: expected one of 'voronoi', 'barycentric', got 'galerkin'"):
        smoothest_field(mesh, mass="galerkin")
    with pytest.raises(DDGInputError, match="mass: expected one of 'voronoi', 'barycentric'"):
        connection_mass_matrix(mesh, mass="galerkin")
    with pytest.raises(DDGInputError, match="solver: expected one of"):
        smoothest_field(mesh, solver="lu")
    with pytest.raises(DDGInputError, match="method: expected one of"):
        smoothest_field(mesh, method="lobpcg")
    with pytest.raises(DDGInputError, match=r"field: expected shape \(42,\)"):
        field_singularities(mesh, jnp.ones(41, complex), n=1)
    with pytest.raises(DDGInputError, match=r"alignment: expected shape \(42,\)"):
        smoothest_field(mesh, n=4, alignment=jnp.ones((42, 2)))
    with pytest.raises(DDGInputError, match="alignment_weight"):
        smoothest_field(mesh, n=4, alignment=jnp.ones(42, complex), alignment_weight=-1.0)
    with pytest.raises(DDGInputError, match="at"):
        field_to_vectors(mesh, jnp.ones(42, complex), n=1, at="edges")
    with pytest.raises(DDGInputError, match="even n"):
        principal_curvature_alignment(mesh, n=3)
    with pytest.raises(DDGInputError, match="fixed_vertices: expected distinct"):
        interpolate_field(mesh, fixed_vertices=np.array([1, 1]), fixed_values=jnp.ones(2, complex))
    with pytest.raises(DDGInputError, match="fixed_vertices: vertex indices must lie in"):
        interpolate_field(mesh, fixed_vertices=np.array([42]), fixed_values=jnp.ones(1, complex))
    with pytest.raises(DDGInputError, match=r"fixed_values: expected shape \(2,\)"):
        interpolate_field(mesh, fixed_vertices=np.array([1, 2]), fixed_values=jnp.ones(3, complex))
    with pytest.raises(DDGInputError, match="Mesh.from_arrays"):
        smoothest_field((mesh.vertices, mesh.faces))


def test_meshes_without_a_consistent_orientation_are_refused():
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [0, -1, 0.5]], float)
    nonmanifold = Mesh.from_arrays(V, np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]]))
    with pytest.raises(MeshDataError, match="edge-manifold"):
        connection_laplacian(nonmanifold)
    flipped = Mesh.from_arrays(V[:4], np.array([[0, 1, 2], [0, 1, 3]]))
    with pytest.raises(MeshDataError, match="consistently oriented"):
        smoothest_field(flipped)
    unreferenced = Mesh.from_arrays(V, np.array([[0, 1, 2], [1, 0, 3]]))
    with pytest.raises(MeshDataError, match="unreferenced"):
        smoothest_field(unreferenced)


@pytest.mark.slow
def test_outcomes_without_throw(monkeypatch, icosphere2):
    """`throw=False` returns a `Solution` holding the same answer and the eigensolver's or the solve's outcome;
    a subspace eigensolve forced out of steps reports `eigensolver_failed` (and raises with `throw=True`)."""
    import ddgjax.spectral._generalized as generalized
    from ddgjax import RESULTS, Solution

    mesh = icosphere2
    solution = smoothest_field(mesh, n=2, throw=False)
    assert isinstance(solution, Solution) and solution.result == RESULTS.successful
    np.testing.assert_array_equal(solution.value.field, smoothest_field(mesh, n=2).field)
    aligned = smoothest_field(mesh, n=4, alignment=principal_curvature_alignment(mesh, n=4), solver="cg", throw=False)
    assert aligned.result == RESULTS.successful and int(aligned.stats["num_steps"]) > 0
    interpolated = interpolate_field(mesh, fixed_vertices=np.array([0]), fixed_values=jnp.array([1.0 + 0j]), throw=False)
    assert interpolated.result == RESULTS.successful and float(interpolated.stats["residual"]) < 1e-10
    monkeypatch.setattr(generalized, "_SUBSPACE_MAX_STEPS", 1)
    assert smoothest_field(mesh, n=2, method="subspace", throw=False).result == RESULTS.eigensolver_failed
    with pytest.raises(Exception, match="The eigensolver did not converge"):
        smoothest_field(mesh, n=2, method="subspace")


def test_tangent_bases_is_a_named_triple(icosphere1):
    from ddgjax.fields import TangentBases

    mesh = icosphere1
    bases = tangent_bases(mesh)
    assert isinstance(bases, TangentBases)
    e1, e2, normal = bases
    np.testing.assert_array_equal(bases.e2, e2)
    np.testing.assert_allclose(np.cross(np.asarray(normal), np.asarray(e1)), e2, atol=1e-15)
