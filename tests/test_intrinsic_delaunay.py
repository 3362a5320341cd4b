"""Tests for the intrinsic Delaunay Laplacian (ddgjax.laplacian._intrinsic) and the squared-length core (_lengths)."""

from __future__ import annotations

import functools

import igl
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import robust_laplacian
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ddgjax import DDGInputError, MeshDataError
from ddgjax.laplacian import (
    IntrinsicTriangulation,
    cotan_laplacian,
    cotan_laplacian_from_lengths_sq,
    intrinsic_delaunay,
    intrinsic_delaunay_laplacian,
    intrinsic_delaunay_mass_matrix,
    laplacian_and_mass,
    mass_matrix,
    mass_matrix_from_lengths_sq,
    triangulation_plan,
)
from ddgjax.mesh import Mesh, check_mesh
from ddgjax.mesh.internal import degenerate_faces
from ddgjax.pde import harmonic_interpolation, solve_poisson
from ddgjax.sparse import dirichlet_blocks
from ddgjax.spectral import eigenpairs

from conftest import load_data_mesh, unit_icosphere
from finite_differences import central_difference

REAL_MESHES = ["beetle.off", "camelhead.off", "nefertiti.obj"]
IGL_MASS = {
    "voronoi": igl.MASSMATRIX_TYPE_VORONOI,
    "barycentric": igl.MASSMATRIX_TYPE_BARYCENTRIC,
    "galerkin": igl.MASSMATRIX_TYPE_FULL,
}


def _relative(a, b) -> float:
    return abs(a - b).max() / abs(b).max()


def _off_diagonal(matrix: sp.spmatrix) -> sp.coo_matrix:
    """Strictly upper triangle (each edge once) of a symmetric matrix."""
    return sp.triu(matrix, k=1).tocoo()


def _n_negative_weights(L_psd: sp.spmatrix) -> int:
    """Edges with a negative cotan weight, i.e. a positive off-diagonal entry of the PSD Laplacian."""
    return int(np.sum(_off_diagonal(L_psd).data > 0))


@functools.cache
def _prepared(name: str):
    """`(mesh, triangulation, L)` of a shared mesh, built once for all the tests that use it."""
    mesh = load_data_mesh(name)
    triangulation = intrinsic_delaunay(mesh)
    return mesh, triangulation, intrinsic_delaunay_laplacian(mesh, triangulation=triangulation)


@pytest.fixture(scope="module", params=REAL_MESHES)
def real(request):
    mesh, triangulation, L = _prepared(request.param)
    return request.param, mesh, triangulation, L.to_scipy()


def _vertices_and_faces(mesh: Mesh) -> tuple[np.ndarray, np.ndarray]:
    return np.asarray(mesh.vertices), np.asarray(mesh.faces).astype(np.int64)


# Negative cotan weights (edges) of the plain cotan Laplacian -> intrinsic Delaunay, measured:
# beetle 10709 -> 124 (all on the boundary, which is never flipped; libigl keeps the same 124),
# camelhead 4881 -> 0, nefertiti 17878 -> 0.
NEGATIVE_WEIGHTS = {"beetle.off": (10709, 124), "camelhead.off": (4881, 0), "nefertiti.obj": (17878, 0)}


@pytest.mark.slow
def test_matches_libigl_intrinsic_delaunay(real):
    name, mesh, triangulation, L = real
    V, F = _vertices_and_faces(mesh)
    L_igl, l_igl, F_igl = igl.intrinsic_delaunay_cotmatrix(V, F)
    # camelhead has needles whose cotangents (~1e2) are ill-conditioned in the flipped lengths: both
    # libigl's and our lengths agree with an extended-precision replay to ~1e-12 (test below), and the
    # Laplacians then differ by 3.5e-10 of the largest entry there (robust_laplacian agrees with ours
    # to 3e-12); the other meshes agree to ~1e-13.
    assert _relative(L, -L_igl) < (1e-9 if name == "camelhead.off" else 1e-12)
    # No co-circular quads here: the flipped triangulation itself is the same (as sets of faces).
    assert set(map(tuple, np.sort(np.asarray(triangulation.faces), axis=1).tolist())) == set(
        map(tuple, np.sort(F_igl, axis=1).tolist())
    )
    # libigl's own Delaunay check gives our triangulation the verdict it gives its own: every edge
    # Delaunay, except (camelhead) 8 corners of needles with lengths ~1e-4 of their neighbours'.
    lengths = np.sqrt(np.asarray(triangulation.face_lengths_sq(mesh)))
    ours = igl.is_intrinsic_delaunay(lengths, np.asarray(triangulation.faces).astype(np.int64))
    assert np.sum(ours == 0) == np.sum(igl.is_intrinsic_delaunay(l_igl, F_igl) == 0) == (8 if name == "camelhead.off" else 0)
    M = intrinsic_delaunay_mass_matrix(mesh, triangulation=triangulation).to_scipy()
    assert _relative(M, igl.massmatrix_intrinsic(l_igl, F_igl, igl.MASSMATRIX_TYPE_VORONOI)) < 1e-12
    np.testing.assert_allclose(M.sum(), igl.doublearea(V, F).sum() / 2, rtol=1e-12)  # flips keep the area
    # Identities: symmetric, L 1 = 0, PSD flags.
    assert abs(L - L.T).max() == 0
    assert abs(L @ np.ones(L.shape[0])).max() < 1e-12 * abs(L).max()
    # Weights: the plain cotan Laplacian has many negative ones, the intrinsic Delaunay one only on
    # boundary edges (counts in NEGATIVE_WEIGHTS).
    plain, intrinsic = NEGATIVE_WEIGHTS[name]
    assert _n_negative_weights(-igl.cotmatrix(V, F)) == plain
    assert _n_negative_weights(L) == _n_negative_weights(-L_igl) == intrinsic
    upper = _off_diagonal(L)
    negative = np.stack([upper.row[upper.data > 0], upper.col[upper.data > 0]], axis=1)
    boundary = set(map(tuple, np.asarray(mesh.edges)[mesh.topology.boundary_edges].tolist()))
    assert set(map(tuple, negative.tolist())) <= boundary


@pytest.mark.slow
def test_replayed_lengths_match_an_extended_precision_replay(real):
    """The JAX replay of the flips against the same flips in 80-bit `np.longdouble`, from the same coordinates."""
    _, mesh, triangulation, _ = real
    V, _ = _vertices_and_faces(mesh)
    edges = np.asarray(mesh.edges)
    slots = np.asarray(triangulation.flip_slots)
    extended = np.zeros(edges.shape[0] + slots.shape[0] * slots.shape[2], dtype=np.longdouble)
    vectors = V.astype(np.longdouble)[edges[:, 1]] - V.astype(np.longdouble)[edges[:, 0]]
    extended[: edges.shape[0]] = np.sum(vectors * vectors, axis=1)

    def heron(x, y, z):  # plain Heron: extended precision absorbs its cancellation on these meshes
        return np.sqrt(np.maximum(2 * (x * y + y * z + z * x) - x * x - y * y - z * z, 0)) / 4

    for step in range(slots.shape[0]):
        ab, ia, ib, ja, jb = extended[slots[step]]  # after the previous steps wrote theirs
        areas = heron(ab, ia, ib) + heron(ab, ja, jb)
        start = edges.shape[0] + step * slots.shape[2]
        extended[start : start + slots.shape[2]] = ((ia - ib - ja + jb) ** 2 + 16 * areas**2) / (4 * np.where(ab > 0, ab, 1))
    reference = extended[np.asarray(triangulation.face_length_slots)].astype(np.float64)
    # Lengths that went through several flips collect ~1e-13 of rounding (measured <= 4.3e-13).
    np.testing.assert_allclose(triangulation.face_lengths_sq(mesh), reference, rtol=2e-12)


@pytest.mark.slow
def test_matches_robust_laplacian(real):
    name, mesh, triangulation, L = real
    V, F = _vertices_and_faces(mesh)
    L_robust, M_robust = robust_laplacian.mesh_laplacian(V, F, mollify_factor=0.0)
    difference = (L - L_robust).tocoo()
    differing = np.unique(difference.row[np.abs(difference.data) > 1e-10 * abs(L).max()])
    if name == "camelhead.off":
        assert _relative(L, L_robust) < 1e-10  # measured 3.4e-12
        M = intrinsic_delaunay_mass_matrix(mesh, triangulation=triangulation, mass="barycentric").to_scipy()
        assert _relative(M, M_robust) < 1e-12  # robust_laplacian's mass matrix is the barycentric one
    elif name == "nefertiti.obj":
        # robust_laplacian leaves one edge unflipped at weight -9.7e-7 (within its own flip tolerance);
        # we flip it: the Laplacians differ only in the rows of that quad's four vertices (by ~1e-7).
        assert differing.size == 4
        positive = _off_diagonal(L_robust)
        assert set(positive.row[positive.data > 0]) | set(positive.col[positive.data > 0]) <= set(differing)
        keep = sp.diags(np.isin(np.arange(L.shape[0]), differing, invert=True).astype(float))
        assert _relative(keep @ L, keep @ L_robust) < 1e-12
    else:
        # beetle has 11 boundary loops: robust_laplacian's tufted cover also flips boundary edges, so
        # its Laplacian has no negative weight at all and differs from ours (and libigl's) near the
        # boundary; away from it they agree.
        assert _n_negative_weights(L_robust) == 0 < _n_negative_weights(L)
        near_boundary = np.zeros(L.shape[0], dtype=bool)
        near_boundary[mesh.topology.boundary_vertices] = True
        for _ in range(3):  # three rings around the boundary, in the flipped triangulation
            near_boundary |= (abs(L) @ near_boundary) > 0
        assert near_boundary[differing].all()


@pytest.mark.slow
def test_harmonic_interpolation_obeys_the_maximum_principle():
    """Harmonic measure of each boundary vertex of camelhead: `L_ff U = -L_fc` (data e_k on the boundary)."""
    mesh, triangulation, intrinsic = _prepared("camelhead.off")
    boundary = np.asarray(mesh.topology.boundary_vertices)
    solutions = {}
    for name, L in (("cotan", cotan_laplacian(mesh)), ("intrinsic", intrinsic)):
        free_free, free_fixed = dirichlet_blocks(L, boundary)
        solutions[name] = spla.splu(free_free.to_scipy().tocsc()).solve(-free_fixed.to_scipy().toarray())
        # Boundary data 1 everywhere interpolates to 1 (L 1 = 0): columns sum to 1.
        np.testing.assert_allclose(solutions[name].sum(axis=1), 1.0, rtol=1e-12)
    # Intrinsic Delaunay: every harmonic measure lies in [0, 1], the range of its data (measured: min 0.0).
    assert solutions["intrinsic"].min() >= -1e-15 and solutions["intrinsic"].max() <= 1.0
    # Plain cotan: boundary vertex 3265 reaches the interior only through the edge to vertex 1026, of
    # weight -0.079 (the flips replace that edge: intrinsically 3265 has boundary neighbours only, and
    # its harmonic measure is 0). With the plain cotan Laplacian its harmonic measure is negative at
    # every one of the 11325 free vertices, down to -0.0269: the maximum principle fails everywhere.
    cotan = solutions["cotan"]
    column = int(np.flatnonzero(boundary == 3265)[0])
    assert np.flatnonzero(cotan.min(axis=0) < 0).tolist() == [column]
    assert np.all(cotan[:, column] < 0) and cotan.shape[0] == 11325
    assert -0.027 < cotan.min() < -0.026
    # harmonic_interpolation(robust=...) is that solve, differentiable: the harmonic measure of 3265
    # and of its neighbour along the boundary, both columns at once.
    data = np.zeros((boundary.size, 2))
    data[column, 0] = data[column + 1, 1] = 1.0
    free = np.setdiff1d(np.arange(mesh.n_vertices), boundary)
    robust = harmonic_interpolation(mesh, fixed_vertices=boundary, fixed_values=data, robust=triangulation)
    np.testing.assert_allclose(robust[free], solutions["intrinsic"][:, [column, column + 1]], rtol=0, atol=1e-12)
    plain = harmonic_interpolation(mesh, fixed_vertices=boundary, fixed_values=data)
    np.testing.assert_allclose(plain[free], cotan[:, [column, column + 1]], rtol=0, atol=1e-12)


def test_delaunay_mesh_needs_no_flips_and_gives_the_cotan_laplacian(icosphere3):
    mesh = icosphere3  # acute triangles only: already Delaunay
    triangulation = intrinsic_delaunay(mesh)
    assert triangulation.n_flips == 0 and triangulation.n_rounds == 0
    np.testing.assert_array_equal(triangulation.faces, mesh.faces)
    L = intrinsic_delaunay_laplacian(mesh, triangulation=triangulation)
    cotan = cotan_laplacian(mesh)
    assert L.pattern is cotan.pattern  # the mesh's own cached plan: L + cotan-pattern matrices work
    # Lengths route (Kahan's Heron area) vs the embedding route (cross products): rounding only.
    np.testing.assert_allclose(L.values, cotan.values, rtol=1e-13, atol=1e-13 * np.abs(cotan.values).max())


def _jittered_sphere(subdivisions: int, amount: float, seed: int = 0) -> Mesh:
    """Icosphere with vertices moved tangentially by `amount` edge lengths, back onto the sphere (obtuse faces)."""
    mesh = unit_icosphere(subdivisions)
    V = np.asarray(mesh.vertices)
    noise = np.random.default_rng(seed).standard_normal(V.shape) * amount * 1.1 / 2**subdivisions
    noise -= np.sum(noise * V, axis=1, keepdims=True) * V
    moved = V + noise
    return mesh.with_vertices(moved / np.linalg.norm(moved, axis=1, keepdims=True))


def _energy(mesh: Mesh, triangulation: IntrinsicTriangulation, u, w):
    """`u^T L u + w . diag(M)` of the intrinsic Delaunay operators."""
    L = intrinsic_delaunay_laplacian(mesh, triangulation=triangulation)
    M = intrinsic_delaunay_mass_matrix(mesh, triangulation=triangulation)
    return jnp.vdot(u, L @ u) + jnp.vdot(w, M.diagonal())


@pytest.fixture(scope="module")
def jittered():
    """A small mesh with flips, its triangulation, the energy's gradient and the lengths' directional derivative (jitted once)."""
    mesh = _jittered_sphere(1, 0.3)
    triangulation = intrinsic_delaunay(mesh)
    rng = np.random.default_rng(1)
    u, w = (jnp.asarray(rng.standard_normal(mesh.n_vertices)) for _ in range(2))
    energy = lambda V: _energy(mesh.with_vertices(V), triangulation, u, w)
    gradient = jax.jit(jax.grad(energy))  # reverse mode, through the operators
    lengths_sq = lambda V: triangulation.face_lengths_sq(mesh.with_vertices(V))
    derivative = jax.jit(lambda V, direction: jax.jvp(lengths_sq, (V,), (direction,))[1])  # forward mode, the replay
    return mesh, triangulation, (u, w), gradient, derivative


@pytest.mark.slow
def test_gradients_match_finite_differences_of_the_flipped_operator(jittered):
    mesh, triangulation, (u, w), gradient, derivative = jittered
    assert triangulation.n_flips == 16 and triangulation.n_rounds == 2
    V = mesh.vertices
    # Against central differences of the true intrinsic Delaunay energy, the flips recomputed at every
    # point: steps of 1e-6 keep the same flips (checked), so these are derivatives of the fixed
    # triangulation. Truncation ~1e-11 (step^2 times third derivatives), rounding ~1e-10 relative.

    def retriangulated(W):
        """The energy and squared lengths of `W` on its own intrinsic Delaunay triangulation, checked to be `V`'s."""
        moved = mesh.with_vertices(W)
        flipped = intrinsic_delaunay(moved)
        np.testing.assert_array_equal(flipped.faces, triangulation.faces)
        return _energy(moved, flipped, u, w), flipped.face_lengths_sq(moved)

    for direction in np.random.default_rng(2).standard_normal((3,) + V.shape):
        energy_change, length_change = central_difference(retriangulated, V, direction, eps=1e-6)
        # Rounding ~1e-10 relative over the step 1e-6 (above); the lengths' too, relative to their largest change.
        np.testing.assert_allclose(jnp.vdot(gradient(V), direction), energy_change, rtol=1e-8)
        scale = np.abs(length_change).max()  # the lengths' rounding is relative to their largest change
        np.testing.assert_allclose(derivative(V, jnp.asarray(direction)), length_change, atol=1e-8 * scale)


@pytest.mark.slow
def test_jit_and_vmap_equal_eager(jittered):
    mesh, triangulation, *_ = jittered
    L = intrinsic_delaunay_laplacian(mesh, triangulation=triangulation).values
    M = intrinsic_delaunay_mass_matrix(mesh, triangulation=triangulation).values

    def operators(scale, mesh, triangulation):
        scaled = mesh.with_vertices(scale * mesh.vertices)
        return (
            intrinsic_delaunay_laplacian(scaled, triangulation=triangulation).values,
            intrinsic_delaunay_mass_matrix(scaled, triangulation=triangulation).values,
        )

    # Scaled copies under jit(vmap): L is scale invariant, M scales with the square (fusion: rounding).
    scales = jnp.asarray([1.0, 0.5, 2.0])
    L_batch, M_batch = jax.jit(jax.vmap(operators, in_axes=(0, None, None)))(scales, mesh, triangulation)
    np.testing.assert_allclose(L_batch, jnp.stack([L, L, L]), rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(M_batch, jnp.stack([M, 0.25 * M, 4.0 * M]), rtol=1e-13)


def test_higher_genus_matches_libigl(data_mesh):
    mesh = data_mesh("double-torus.obj")  # genus 2
    V, F = _vertices_and_faces(mesh)
    triangulation = intrinsic_delaunay(mesh)
    assert triangulation.n_flips == 1076
    L = intrinsic_delaunay_laplacian(mesh, triangulation=triangulation).to_scipy()
    assert _relative(L, -igl.intrinsic_delaunay_cotmatrix(V, F)[0]) < 1e-12
    assert _n_negative_weights(L) == 0 < _n_negative_weights(-igl.cotmatrix(V, F))


def test_flips_that_join_two_vertices_twice():
    """A doubly covered triangle with a vertex near one edge: flipping that edge adds a second edge v - c."""
    V = np.array([[0, 0, 0], [1, 0, 0], [0.5, 0.8, 0], [0.5, 0.01, 0]], dtype=float)
    F = np.array([[0, 1, 3], [1, 2, 3], [2, 0, 3], [0, 2, 1]])
    mesh = Mesh.from_arrays(V, F)
    triangulation = intrinsic_delaunay(mesh)
    assert triangulation.n_flips == 1
    faces = np.asarray(triangulation.faces)
    pairs = np.sort(np.concatenate([faces[:, [1, 2]], faces[:, [2, 0]], faces[:, [0, 1]]]), axis=1).tolist()
    assert pairs.count([2, 3]) == 4  # two distinct edges, each in two faces
    L = intrinsic_delaunay_laplacian(mesh, triangulation=triangulation).to_scipy()
    assert _relative(L, -igl.intrinsic_delaunay_cotmatrix(V, F)[0]) < 1e-13


def test_laplacian_and_mass_is_a_named_pair_of_the_mesh_or_its_intrinsic_triangulation(without_type_checker):
    mesh = _jittered_sphere(2, 0.4)
    triangulation = intrinsic_delaunay(mesh)
    assert triangulation.n_flips > 0
    for mass in ("voronoi", "barycentric", "galerkin"):
        own = laplacian_and_mass(mesh, mass=mass)
        L, M = own  # still unpacks
        assert L is own.laplacian and M is own.mass
        np.testing.assert_array_equal(own.laplacian.values, cotan_laplacian(mesh).values)
        np.testing.assert_array_equal(own.mass.values, mass_matrix(mesh, mass=mass).values)
        robust = laplacian_and_mass(mesh, mass=mass, robust=triangulation)
        expected_L = intrinsic_delaunay_laplacian(mesh, triangulation=triangulation)
        expected_M = intrinsic_delaunay_mass_matrix(mesh, triangulation=triangulation, mass=mass)
        np.testing.assert_array_equal(robust.laplacian.values, expected_L.values)
        np.testing.assert_array_equal(robust.mass.values, expected_M.values)
        # Flips keep the metric: both sum to the surface area (the sum of every entry, for each choice).
        np.testing.assert_allclose(float(jnp.sum(robust.mass.values)), float(jnp.sum(M.values)), rtol=1e-13)
    with pytest.raises(DDGInputError, match="robust: expected True, False or an IntrinsicTriangulation"):
        laplacian_and_mass(mesh, robust="yes")


def test_lengths_core_on_a_delta_complex_matches_libigl():
    """Faces repeating a vertex (loop edges) and vertex pairs joined by several edges, against libigl (the
    Galerkin mass integrates the sum of a repeated vertex's hat functions: libigl's full mass matrix)."""
    F = np.array([[0, 1, 1], [0, 1, 2], [1, 2, 3], [2, 3, 0], [3, 0, 2], [4, 4, 3]])
    rng = np.random.default_rng(2)
    lengths = rng.uniform(1.0, 1.5, F.shape)  # every triple satisfies the triangle inequality
    plan = triangulation_plan(F, 6)  # vertex 5 is unreferenced
    L = cotan_laplacian_from_lengths_sq(lengths**2, plan)
    assert L.positive_semidefinite and L.symmetric
    padded = lambda A: sp.block_diag([A, sp.csr_matrix((1, 1))])  # libigl sizes by the largest index used
    assert _relative(L.to_scipy(), padded(-igl.cotmatrix_intrinsic(lengths, F))) < 1e-14
    for mass, igl_mass in IGL_MASS.items():
        M = mass_matrix_from_lengths_sq(lengths**2, plan, mass=mass).to_scipy()
        assert _relative(M, padded(igl.massmatrix_intrinsic(lengths, F, igl_mass))) < 1e-14, mass


@pytest.mark.slow
def test_degenerate_faces_give_finite_values_and_gradients(jittered):
    # Without mollification (mollify_factor=0: the exact flat face; test_mollification_* has the default).
    # Face (2, 0, 1) is flat: vertex 1 lies on the segment 0 - 2, a straight angle opposite the edge
    # 0 - 2, which is flipped away (to 1 - 3).
    V = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [1, 1, 0], [1, -1, 0]], dtype=float)
    F = np.array([[0, 2, 3], [2, 0, 1], [1, 0, 4], [2, 1, 4]])
    triangulation = intrinsic_delaunay(Mesh.from_arrays(V, F), mollify_factor=0.0)
    assert triangulation.n_flips == 1
    faces_after = set(map(tuple, np.sort(np.asarray(triangulation.faces), axis=1).tolist()))
    assert faces_after == {(0, 1, 3), (1, 2, 3), (0, 1, 4), (1, 2, 4)}
    # Its other angles are right angles: weights 0 up to rounding, none negative beyond it.
    L = intrinsic_delaunay_laplacian(Mesh.from_arrays(V, F), triangulation=triangulation).to_scipy()
    assert _off_diagonal(L).data.max() < 1e-15
    # A flat face on the boundary cannot be flipped: it contributes nothing.
    boundary_flat = Mesh.from_arrays(V, F[1:])
    flat_triangulation = intrinsic_delaunay(boundary_flat, mollify_factor=0.0)
    assert flat_triangulation.n_flips == 0
    L = intrinsic_delaunay_laplacian(boundary_flat, triangulation=flat_triangulation).to_scipy()
    assert abs(L[0, 2]) == 0 and np.all(np.isfinite(L.toarray()))
    # Derivatives where the fixed flips meet degenerate lengths: the two ends of a flipped edge moved
    # onto one point (zero-length diagonal `ab` in the replay), a flat sphere, every vertex at one point.
    mesh, triangulation, _, gradient, derivative = jittered
    flipped = np.asarray(mesh.edges)[int(np.asarray(triangulation.flip_slots)[0, 0, 0])]
    P = np.asarray(mesh.vertices)
    for W in (np.where(np.arange(P.shape[0])[:, None] == flipped[1], P[flipped[0]], P), P * [1, 1, 0], 0 * P):
        moved = mesh.with_vertices(W)
        assert np.all(np.isfinite(intrinsic_delaunay_laplacian(moved, triangulation=triangulation).values))
        assert np.all(np.isfinite(intrinsic_delaunay_mass_matrix(moved, triangulation=triangulation).values))
        assert np.all(np.isfinite(gradient(jnp.asarray(W))))
        assert np.all(np.isfinite(derivative(jnp.asarray(W), jnp.ones_like(W))))


def _degenerate_sphere() -> Mesh:
    """icosphere(2) with face 0 collinear (a corner moved onto the midpoint of its opposite edge) and
    vertex `F[5, 1]` moved onto `F[5, 0]` (a zero-length edge: faces 5 and 41 collapse)."""
    mesh = unit_icosphere(2)
    V, F = np.asarray(mesh.vertices).copy(), np.asarray(mesh.faces)
    V[F[0, 2]] = 0.5 * (V[F[0, 0]] + V[F[0, 1]])
    V[F[5, 1]] = V[F[5, 0]]
    return mesh.with_vertices(V)


def test_mollification_matches_robust_laplacian_on_degenerate_meshes():
    """`robust=True` on a closed mesh with a collinear face and coincident vertices: robust_laplacian's
    mollified intrinsic Delaunay operators (`mollify_factor=1e-5`, its default), positive semidefinite."""
    mesh = _degenerate_sphere()
    V, F = _vertices_and_faces(mesh)
    L, M = laplacian_and_mass(mesh, mass="barycentric", robust=True)
    L_robust, M_robust = robust_laplacian.mesh_laplacian(V, F, mollify_factor=1e-5)
    L, M = L.to_scipy(), M.to_scipy()
    # Entries up to ~1e4 (angles of ~1e-5 rad in the mollified needles): measured 1.7e-12 of the largest.
    assert _relative(L, L_robust) < 1e-10
    assert _relative(M, M_robust) < 1e-12
    # A matrix flagged PSD is PSD: symmetric, L 1 = 0, no eigenvalue below rounding of its norm.
    dense = L.toarray()
    eigenvalues = np.linalg.eigvalsh(dense)
    assert np.array_equal(dense, dense.T) and abs(dense.sum(axis=1)).max() < 1e-12 * abs(dense).max()
    assert eigenvalues[0] > -1e-14 * eigenvalues[-1] and eigenvalues[1] > 0.1  # one component: one zero
    # Without mollification robust_laplacian's Laplacian of this mesh is not even finite.
    assert not np.all(np.isfinite(robust_laplacian.mesh_laplacian(V, F, mollify_factor=0.0)[0].data))


def test_mollification_changes_nothing_without_degenerate_faces():
    mesh = _jittered_sphere(2, 0.4)
    mollified, plain = intrinsic_delaunay(mesh), intrinsic_delaunay(mesh, mollify_factor=0.0)
    assert mollified.mollify_factor == 1e-5 and plain.mollify_factor == 0.0 and mollified.n_flips == plain.n_flips > 0
    assert np.array_equal(np.asarray(mollified.faces), np.asarray(plain.faces))
    assert np.array_equal(np.asarray(mollified.face_lengths_sq(mesh)), np.asarray(plain.face_lengths_sq(mesh)))


def test_plain_route_refuses_degenerate_faces_and_robust_handles_them(icosphere2):
    """`robust=False` refuses a mesh whose cotan Laplacian is indefinite by rounding (found once, on the
    host), naming the faces and the remedy; under jit the positions cannot be checked and nothing raises."""
    mesh = _degenerate_sphere()
    with pytest.raises(MeshDataError, match=r"faces \[0, 5, 41\] \(3 in all\) have zero or near-zero area.*Pass robust=True"):
        laplacian_and_mass(mesh)
    assert check_mesh(mesh).zero_area_faces.tolist() == [0, 5, 41]
    assert degenerate_faces(mesh) is degenerate_faces(mesh)  # measured once per mesh object
    assert degenerate_faces(icosphere2).size == 0
    laplacian_and_mass(icosphere2)  # a healthy mesh passes
    values = jax.jit(lambda W: laplacian_and_mass(mesh.with_vertices(W)).laplacian.values)(mesh.vertices)
    assert np.all(np.isfinite(values))
    L = laplacian_and_mass(mesh, robust=True).laplacian
    assert L.positive_semidefinite and np.all(np.isfinite(np.asarray(L.values)))


@pytest.mark.slow
def test_mollified_replay_differentiates_at_degenerate_positions(icosphere2):
    """The gradient through the mollification (its `delta` is a maximum over faces) and the flips, against
    central differences, at positions where `delta > 0`: one collinear face (two degenerate faces would
    tie for the maximum, a kink that central differences straddle)."""
    mesh = icosphere2
    V, F = np.asarray(mesh.vertices).copy(), np.asarray(mesh.faces)
    V[F[0, 2]] = 0.5 * (V[F[0, 0]] + V[F[0, 1]])
    mesh = mesh.with_vertices(V)
    # Central differences of an energy of ~5e2 with a step of 1e-7: measured 1.3e-9 apart.
    _check_energy_gradient(mesh, intrinsic_delaunay(mesh), seed=4, eps=1e-7, rtol=1e-7)


def _check_energy_gradient(mesh, triangulation, *, seed: int, eps: float, rtol: float) -> None:
    """The jitted gradient of `_energy` in the positions is finite and matches a central difference along a random direction."""
    rng = np.random.default_rng(seed)
    u, w = (jnp.asarray(rng.standard_normal(mesh.n_vertices)) for _ in range(2))
    energy = jax.jit(lambda V: _energy(mesh.with_vertices(V), triangulation, u, w))
    gradient = jax.jit(jax.grad(lambda V: _energy(mesh.with_vertices(V), triangulation, u, w)))(mesh.vertices)
    assert np.all(np.isfinite(gradient))
    direction = rng.standard_normal(gradient.shape)
    numeric = central_difference(energy, mesh.vertices, direction, eps)
    np.testing.assert_allclose(np.sum(np.asarray(gradient) * direction), numeric, rtol=rtol)


def _fins(n_fins: int = 3, seed: int = 0) -> Mesh:
    """`n_fins` squares of 2 x 2 cells (8 triangles each) sharing the edge from (0, 0, 0) to (0, 0, 1): a
    non-manifold edge (the spine: 3 faces at each of its two edges), jittered off any co-circular quad."""
    rng = np.random.default_rng(seed)
    vertices = [np.array([0.0, 0.0, z]) for z in (0.0, 0.5, 1.0)]  # the spine: vertices 0, 1, 2
    faces = []
    for fin in range(n_fins):
        angle = 2 * np.pi * fin / n_fins + 0.3 * fin
        direction = np.array([np.cos(angle), np.sin(angle), 0.0])
        grid = np.zeros((3, 3), dtype=np.int64)  # grid[i, j]: distance i / 2 along `direction`, height j / 2
        grid[0] = [0, 1, 2]
        for i in (1, 2):
            for j in range(3):
                grid[i, j] = len(vertices)
                vertices.append(i / 2 * direction + np.array([0.0, 0.0, j / 2]) + 0.08 * rng.standard_normal(3))
        for i in range(2):
            for j in range(2):
                faces += [[grid[i, j], grid[i + 1, j], grid[i + 1, j + 1]], [grid[i, j], grid[i + 1, j + 1], grid[i, j + 1]]]
    return Mesh.from_arrays(np.array(vertices), np.array(faces))


def _flipped_sphere() -> Mesh:
    """A jittered icosphere (flips needed) with some faces reversed: inconsistently oriented, edge-manifold."""
    mesh = _jittered_sphere(2, 0.4)
    F = np.asarray(mesh.faces).copy()
    F[::7] = F[::7, ::-1]
    return Mesh.from_arrays(mesh.vertices, F)


def _mixed() -> Mesh:
    """The flipped sphere with a fin of two triangles on one of its edges (non-manifold) and a zero-area
    face on another (its third corner the midpoint of that edge; a new vertex, so the edge has 3 faces)."""
    mesh = _flipped_sphere()
    V, F = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    a, b = F[0, 0], F[0, 1]
    c, d = F[40, 0], F[40, 1]
    normal = V[a] + V[b]
    extra = [V[a] + 0.3 * normal, V[b] + 0.25 * normal + 0.05 * (V[b] - V[a]), 0.5 * (V[c] + V[d])]
    n = V.shape[0]
    faces = np.concatenate([F, [[a, b, n + 1], [a, n + 1, n], [c, d, n + 2]]])
    return Mesh.from_arrays(np.concatenate([V, np.array(extra)]), faces)


def _moebius() -> Mesh:
    return load_data_mesh("moebius.obj")


@pytest.mark.parametrize("make", [_moebius, _fins, _flipped_sphere, _mixed])
def test_non_manifold_and_non_oriented_meshes_match_robust_laplacian(make):
    """`robust=True` on meshes robust_laplacian handles and the manifold path refuses: the tufted cover
    (`ddgjax.laplacian._tufted`), halved, against `robust_laplacian.mesh_laplacian` entry by entry."""
    mesh = make()
    report = check_mesh(mesh)
    assert not report.is_oriented  # the tufted path, not the manifold one
    triangulation = intrinsic_delaunay(mesh)
    assert triangulation.sheets == 2 and triangulation.faces.shape == (2 * mesh.n_faces, 3)
    L, M = laplacian_and_mass(mesh, mass="barycentric", robust=triangulation)
    L, M = L.to_scipy(), M.to_scipy()
    V, F = _vertices_and_faces(mesh)
    L_robust, M_robust = robust_laplacian.mesh_laplacian(V, F, mollify_factor=1e-5)
    # Same cover, same flips (no ties in the angular gluing here): measured at most 4.2e-15 (L) and 7.5e-16 (M).
    assert _relative(L, L_robust) < 1e-12
    assert _relative(M, M_robust) < 1e-12
    dense = L.toarray()
    assert np.array_equal(dense, dense.T) and abs(dense.sum(axis=1)).max() < 1e-12 * abs(dense).max()
    # The cover is intrinsic Delaunay everywhere (it has no boundary): no negative weight beyond rounding.
    assert _off_diagonal(L).data.max() < 1e-12 * abs(dense).max()
    # robust=True takes the same route, and the total mass is the area (mollification aside: 1e-5 margins).
    L_true = laplacian_and_mass(mesh, mass="barycentric", robust=True).laplacian
    assert abs(L_true.to_scipy() - L).max() == 0
    np.testing.assert_allclose(M.sum(), igl.doublearea(V, F).sum() / 2, rtol=1e-4)  # lengths mollified by 1e-5


def test_manifold_oriented_meshes_keep_the_flat_path(data_mesh):
    """An edge-manifold, oriented mesh is flipped as it is (`sheets=1`), boundary edges kept."""
    mesh = data_mesh("hexagon.obj")
    triangulation = intrinsic_delaunay(mesh)
    assert triangulation.sheets == 1 and triangulation.faces.shape == (mesh.n_faces, 3)


def test_eigenpairs_of_the_moebius_strip_match_scipy_on_robust_laplacian():
    mesh = _moebius()
    k = 8
    values, vectors = eigenpairs(mesh, k, mass="barycentric", robust=True)
    V, F = _vertices_and_faces(mesh)
    L_robust, M_robust = robust_laplacian.mesh_laplacian(V, F, mollify_factor=1e-5)
    expected = np.sort(spla.eigsh(L_robust.tocsc(), k, M_robust.tocsc(), sigma=-1e-8)[0])
    # Measured 1.1e-16 apart; the first value is a zero (Neumann, one component), checked absolutely.
    np.testing.assert_allclose(np.asarray(values), expected, rtol=1e-10, atol=1e-12)
    # M-orthonormal eigenvectors of robust_laplacian's pencil (the same matrices to 1e-15): measured 1.3e-13, the
    # near-double pairs (a strip's modes come in close pairs) leave the iterative solver that much of a mixture.
    X = np.asarray(vectors)
    np.testing.assert_allclose(X.T @ (M_robust @ X), np.eye(k), atol=1e-11)
    residual = L_robust @ X - (M_robust @ X) * np.asarray(values)
    assert abs(residual).max() < 1e-12 * abs(L_robust).max()  # measured 4e-17


@pytest.mark.slow
def test_tufted_operators_differentiate_for_fixed_flips():
    """The tufted cover's flips replay in JAX: the energy's gradient against central differences."""
    mesh = _fins()
    triangulation = intrinsic_delaunay(mesh)
    assert triangulation.sheets == 2 and triangulation.n_flips > 0
    # Central differences with a step of 1e-6 (truncation ~eps^2, rounding ~1e-16 / eps): measured 1.7e-11 apart.
    _check_energy_gradient(mesh, triangulation, seed=5, eps=1e-6, rtol=1e-9)


def test_bad_input(without_type_checker, icosphere1, icosphere2):
    mesh = icosphere1
    with pytest.raises(DDGInputError, match="expected a ddgjax Mesh"):
        intrinsic_delaunay(np.asarray(mesh.vertices))
    with pytest.raises(DDGInputError, match="triangulation: expected an IntrinsicTriangulation"):
        intrinsic_delaunay_laplacian(mesh, triangulation="flips")
    with pytest.raises(DDGInputError, match="was built for another connectivity"):
        intrinsic_delaunay_laplacian(icosphere2, triangulation=intrinsic_delaunay(mesh))
    with pytest.raises(DDGInputError, match="mass: expected one of 'voronoi', 'barycentric', 'galerkin'"):
        intrinsic_delaunay_mass_matrix(mesh, mass="lumped")
    for factor in (-1e-5, np.nan, True, "1e-5"):
        with pytest.raises(DDGInputError, match="mollify_factor: expected a finite number >= 0"):
            intrinsic_delaunay(mesh, mollify_factor=factor)
    with pytest.raises(DDGInputError, match="needs concrete vertex positions.*pass triangulation="):
        jax.jit(lambda V: intrinsic_delaunay_laplacian(mesh.with_vertices(V)).values)(mesh.vertices)
    plan = triangulation_plan(np.asarray(mesh.faces), mesh.n_vertices)
    with pytest.raises(DDGInputError, match=r"lengths_sq: expected shape \(80, 3\)"):
        cotan_laplacian_from_lengths_sq(np.ones((80, 2)), plan)
    with pytest.raises(DDGInputError, match="plan: expected a TriangulationPlan"):
        mass_matrix_from_lengths_sq(np.ones((80, 3)), mesh)
    with pytest.raises(DDGInputError, match=r"faces: vertex indices must lie in \[0, 3\)"):
        triangulation_plan([[0, 1, 3]], 3)
    with pytest.raises(DDGInputError, match="faces: expected an \\(nf, 3\\) integer array"):
        triangulation_plan([[0.0, 1.0, 2.0]], 3)


@pytest.mark.slow
def test_poisson_problem_with_the_intrinsic_laplacian_matches_libigl_and_differentiates():
    """`solve_poisson(robust=...)`: `L phi = -M rho` with the intrinsic Delaunay L and lumped mass on a
    closed surface (zero-mean rho and phi), against SciPy on libigl's intrinsic Delaunay Laplacian and
    robust_laplacian's mass; the gradient in the vertex positions through the replayed flips."""
    mesh = _jittered_sphere(3, 0.4)
    V, F = _vertices_and_faces(mesh)
    triangulation = intrinsic_delaunay(mesh)
    rho = np.asarray(mesh.vertices)[:, 2] ** 2 + np.asarray(mesh.vertices)[:, 0]
    phi = solve_poisson(mesh, rho, mass="barycentric", robust=True)
    L = -igl.intrinsic_delaunay_cotmatrix(V, F)[0]
    M = robust_laplacian.mesh_laplacian(V, F)[1]
    area = M.diagonal()
    compatible = rho - area @ rho / area.sum()
    expected = np.linalg.lstsq(L.toarray(), -(M @ compatible), rcond=None)[0]  # 642 unknowns: dense
    expected = expected - area @ expected / area.sum()
    # Two direct solves of the same matrices (libigl's and ours agree to ~1e-13): measured 2e-14 apart.
    assert np.abs(np.asarray(phi) - expected).max() < 1e-12 * np.abs(expected).max()
    assert abs(area @ np.asarray(phi)) < 1e-12  # the zero-mean solution

    @jax.jit
    def value_and_grad(W):
        return jax.value_and_grad(lambda W: jnp.sum(solve_poisson(mesh.with_vertices(W), rho, robust=triangulation) ** 2))(W)

    _, gradient = value_and_grad(mesh.vertices)
    direction = np.random.default_rng(3).standard_normal(V.shape)
    numeric = central_difference(lambda W: value_and_grad(W)[0], mesh.vertices, direction, eps=1e-6)
    # Finite differences: the solve's round-off (~1e-14 of the energy of ~60) over eps = 1e-6 is ~1e-8 relative
    # (measured 1.4e-8); truncation O(eps^2) is below it.
    np.testing.assert_allclose(np.sum(np.asarray(gradient) * direction), numeric, rtol=1e-7)
    # The Galerkin mass of the intrinsic triangles: libigl's full mass matrix on its intrinsic Delaunay
    # lengths and faces (the same flips here).
    L, lengths, faces = igl.intrinsic_delaunay_cotmatrix(V, F)
    M = igl.massmatrix_intrinsic(lengths, faces, igl.MASSMATRIX_TYPE_FULL)
    area = np.asarray(M.sum(axis=1)).ravel()
    compatible = rho - area @ rho / area.sum()
    expected = np.linalg.lstsq(-L.toarray(), -(M @ compatible), rcond=None)[0]
    expected = expected - area @ expected / area.sum()
    phi = solve_poisson(mesh, rho, mass="galerkin", robust=triangulation)
    assert np.abs(np.asarray(phi) - expected).max() < 1e-12 * np.abs(expected).max()  # measured 1.9e-14
