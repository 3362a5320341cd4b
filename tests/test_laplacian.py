"""Tests for ddgjax.laplacian: cotan Laplacian, mass matrices, energy, converters (the DEC identity
`d0^T *1 d0 = L`: tests/test_dec_operators.py)."""

from __future__ import annotations

import gpytoolbox
import igl
import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import pytest
import robust_laplacian
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from jax.test_util import check_grads

from ddgjax import DDGInputError
from ddgjax.laplacian import _cotan as cotan_module
from ddgjax.laplacian import (
    cotan_laplacian,
    cotan_laplacian_from_lengths_sq,
    dirichlet_energy,
    from_pytorch3d_cot_laplacian,
    laplacian_apply,
    mass_matrix,
    mass_matrix_from_lengths_sq,
    to_gpytoolbox_cotangent_laplacian,
    to_igl_cotmatrix,
    to_pytorch3d_cot_laplacian,
    triangulation_plan,
)
from ddgjax.laplacian.internal import vertex_plan
from ddgjax.mesh import Mesh, face_edge_lengths_sq, grid

from conftest import data_path
from finite_differences import central_difference
from mesh_union import disjoint_union

# jax.test_util.check_grads compares with central finite differences of step 1e-4: their truncation
# error is ~1e-8 relative, so its float64 default tolerance (1e-5) is used; exact derivative
# identities (forward = reverse mode, grad_u E = L u) are checked to round-off separately.

# Jitted once per mesh topology: eager dispatch of every small op (recompiled for each new shape)
# would dominate the test time.
_laplacian = jax.jit(lambda m: cotan_laplacian(m))
_dense_laplacian = jax.jit(lambda m: cotan_laplacian(m).todense())
# Dense L and the three mass matrices in one program, compiled once per topology.
_dense_matrices = jax.jit(
    lambda m: (
        cotan_laplacian(m).todense(),
        *(mass_matrix(m, mass=mass).todense() for mass in ("voronoi", "barycentric", "galerkin")),
    )
)
_mass = jax.jit(mass_matrix, static_argnames="mass")
_apply = jax.jit(laplacian_apply)

REAL_MESHES = ["beetle.off", "nefertiti.obj", "stanford-bunny.obj", "camelhead.off"]
MASS_TYPES = {"voronoi": igl.MASSMATRIX_TYPE_VORONOI, "barycentric": igl.MASSMATRIX_TYPE_BARYCENTRIC}


def _load(name):
    V, F = igl.read_triangle_mesh(str(data_path("meshes", name)))  # keeps vertex order and unreferenced vertices
    return V, F, Mesh.from_arrays(V, F)


def _relative(a: sp.spmatrix, b: sp.spmatrix) -> float:
    return abs(a - b).max() / abs(b).max()


@pytest.fixture(scope="module")
def real():
    """The real meshes and their disjoint union: `[(name, V, F, rows)]` and the union mesh, whose block
    `rows` of every vertex-indexed matrix or array is that mesh's own. Each function is compiled once
    for the union, not once per mesh (compiling dominates these tests' time); every comparison below
    is made block by block, at the scale of the mesh itself."""
    loaded = [_load(name)[:2] for name in REAL_MESHES]
    union = disjoint_union(loaded)
    parts = [(name, V, F, union.vertices_of(k)) for k, (name, (V, F)) in enumerate(zip(REAL_MESHES, loaded))]
    return parts, union.mesh


def _block(matrix: sp.spmatrix, rows: slice) -> sp.csr_matrix:
    return sp.csr_matrix(matrix)[rows][:, rows]


@pytest.mark.slow
def test_matches_libigl_and_gpytoolbox(real):
    parts, mesh = real
    L = _laplacian(mesh)
    ours, for_igl, for_gpytoolbox = L.to_scipy(), to_igl_cotmatrix(L), to_gpytoolbox_cotangent_laplacian(L)
    masses = {mass: _mass(mesh, mass=mass).to_scipy() for mass in ("voronoi", "barycentric", "galerkin")}
    # Matrix-free L u (these meshes have high-degree vertices: the COO tail of the pattern is used).
    U = np.random.default_rng(0).standard_normal((mesh.n_vertices, 2))
    applied = np.asarray(_apply(mesh, jnp.asarray(U)))
    for name, V, F, rows in parts:
        expected = -igl.cotmatrix(V, F)
        # nefertiti has angles up to 179.6 degrees: libigl's cotangent formula and ours round differently
        # on those slivers by ~1e-11 of the largest entry; everything else agrees to ~3e-13.
        assert _relative(_block(ours, rows), expected) < 1e-10, name
        assert _relative(_block(for_igl, rows), igl.cotmatrix(V, F)) < 1e-10, name
        assert _relative(_block(for_gpytoolbox, rows), gpytoolbox.cotangent_laplacian(V, F)) < 1e-10, name
        for mass, igl_type in MASS_TYPES.items():
            assert _relative(_block(masses[mass], rows), igl.massmatrix(V, F, igl_type)) < 1e-12, (name, mass)
        galerkin = _block(masses["galerkin"], rows)
        assert _relative(galerkin, igl.massmatrix(V, F, igl.MASSMATRIX_TYPE_FULL)) < 1e-12, name
        assert _relative(galerkin, gpytoolbox.massmatrix(V, F, type="full")) < 1e-12, name
        own = vertex_plan(Mesh.from_arrays(V, F)).pattern  # the mesh's own storage (host work, no compilation)
        assert own.nnz > own.width * V.shape[0], name
        scale = np.abs(expected).max() * np.abs(U[rows]).max()
        np.testing.assert_allclose(applied[rows], _block(ours, rows) @ U[rows], rtol=0, atol=1e-12 * scale, err_msg=name)
        # libigl: as above (slivers).
        np.testing.assert_allclose(applied[rows], expected @ U[rows], rtol=0, atol=1e-10 * scale, err_msg=name)
    assert vertex_plan(mesh).pattern.nnz > vertex_plan(mesh).pattern.width * mesh.n_vertices  # the union's tail too


@pytest.mark.slow
def test_the_mesh_operators_are_the_lengths_core_on_the_mesh_plan():
    """`cotan_laplacian(mesh)` and `mass_matrix(mesh)` are the intrinsic core on the mesh's squared edge
    lengths; the plan cached for a mesh (vertex pairs from its topology) is the one a face list gives
    (`triangulation_plan`, vertex pairs by its own sort). Small meshes with boundaries, non-manifold
    and non-orientable ones, and slivers (nefertiti_loop1), as one disjoint union."""
    names = ("tet.obj", "small_disk.obj", "hourglass_ico.obj", "moebius.obj", "triple_vierbein.obj", "nefertiti_loop1.ply")
    mesh = disjoint_union([_load(name)[:2] for name in names]).mesh
    plan = triangulation_plan(np.asarray(mesh.faces), mesh.n_vertices)
    cached = vertex_plan(mesh)
    for field in ("source", "slot_corners", "corner_slots", "faces"):
        np.testing.assert_array_equal(getattr(plan, field), getattr(cached, field), err_msg=field)
    assert plan.pattern.nnz == cached.pattern.nnz and plan.pattern.width == cached.pattern.width
    np.testing.assert_array_equal(plan.pattern.cols, cached.pattern.cols)
    lengths_sq = face_edge_lengths_sq(mesh)
    L = _laplacian(mesh)
    core = cotan_laplacian_from_lengths_sq(lengths_sq, plan)
    # The same formula; the areas from the embedding against Kahan's formula on the lengths: round-off
    # of the slivers' areas (nefertiti's angles reach 179.6 degrees).
    np.testing.assert_allclose(core.values, L.values, rtol=0, atol=1e-11 * np.abs(L.values).max())
    for mass in ("voronoi", "barycentric", "galerkin"):
        M, core = _mass(mesh, mass=mass), mass_matrix_from_lengths_sq(lengths_sq, plan, mass=mass)
        assert core.pattern.nnz == M.pattern.nnz
        np.testing.assert_allclose(core.values, M.values, rtol=0, atol=1e-12 * np.abs(M.values).max(), err_msg=mass)


def test_robust_laplacian_on_delaunay_meshes(icosphere2):
    # The equilateral hexagon mesh and an icosphere are Delaunay: robust_laplacian's intrinsic
    # Delaunay Laplacian equals the cotan one (its mass is the barycentric lumped one). Ours on both
    # at once, as blocks of their disjoint union (one compilation).
    parts = [_arrays(icosphere2), _load("hexagon.obj")[:2]]
    union = disjoint_union(parts)
    L, M = _laplacian(union.mesh).to_scipy(), _mass(union.mesh, mass="barycentric").to_scipy()
    for k, (V, F) in enumerate(parts):
        L_robust, M_robust = robust_laplacian.mesh_laplacian(np.asarray(V, float), np.asarray(F))
        # robust_laplacian re-derives the cotangents from edge lengths: another rounding (measured 8e-16).
        assert _relative(_block(L, union.vertices_of(k)), L_robust) < 1e-13
        assert _relative(_block(M, union.vertices_of(k)), M_robust) < 1e-13
    weights = -_block(L, union.vertices_of(1))  # the hexagon's (V, F: the last part's)
    interior = np.setdiff1d(np.arange(V.shape[0]), igl.boundary_loop(F))
    interior_weights = weights[interior][:, interior]
    off_diagonal = interior_weights[interior_weights.nonzero()]
    off_diagonal = np.asarray(off_diagonal).ravel()
    off_diagonal = off_diagonal[off_diagonal > 0]
    # hexagon.obj is a *nearly* equilateral triangulation (angles within ~0.01 degree of 60): weights
    # within 1e-3 of the equilateral 2 cot(60) / 2 = 1/sqrt(3).
    np.testing.assert_allclose(off_diagonal, 1 / np.sqrt(3), rtol=1e-3)


def _arrays(mesh):
    return np.asarray(mesh.vertices), np.asarray(mesh.faces)


def _single(V, F):
    return Mesh.from_arrays(np.asarray(V, float), np.asarray(F))


RIGHT = ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])
EQUILATERAL = ([[0, 0, 0], [1, 0, 0], [0.5, np.sqrt(3) / 2, 0]], [[0, 1, 2]])
TETRAHEDRON = (
    [[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]],
    [[0, 1, 2], [0, 3, 1], [0, 2, 3], [1, 3, 2]],
)
CUBE_V = [[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)]
CUBE_F = [
    [0, 2, 3], [0, 3, 1], [4, 5, 7], [4, 7, 6], [0, 1, 5], [0, 5, 4],
    [2, 6, 7], [2, 7, 3], [0, 4, 6], [0, 6, 2], [1, 3, 7], [1, 7, 5],
]  # fmt: skip


@pytest.fixture(scope="module")
def elements():
    return {
        name: _single(*data)
        for name, data in {
            "right": RIGHT,
            "equilateral": EQUILATERAL,
            "tetrahedron": TETRAHEDRON,
            "cube": (CUBE_V, CUBE_F),
        }.items()
    }


def _closed_forms(mesh, scale):
    """Dense L and the three mass matrices of `mesh` scaled by `scale` (same topology: one compilation)."""
    return tuple(np.asarray(matrix) for matrix in _dense_matrices(mesh.with_vertices(np.asarray(mesh.vertices) * scale)))


@pytest.mark.parametrize("scale", [1e-8, 1.0, 1e8])
@pytest.mark.slow
def test_single_element_closed_forms(elements, scale):
    s3 = np.sqrt(3)
    L, voronoi, barycentric, galerkin = _closed_forms(elements["right"], scale)
    np.testing.assert_allclose(L, [[1, -0.5, -0.5], [-0.5, 0.5, 0], [-0.5, 0, 0.5]], atol=1e-15)
    area = 0.5 * scale**2
    # Right triangle: circumcentre at the hypotenuse midpoint, so the right-angle corner gets A/2.
    np.testing.assert_allclose(np.diag(voronoi), area * np.array([0.5, 0.25, 0.25]), rtol=1e-14)
    np.testing.assert_allclose(np.diag(barycentric), np.full(3, area / 3), rtol=1e-14)
    np.testing.assert_allclose(galerkin, area / 12 * (np.ones((3, 3)) + np.eye(3)), rtol=1e-14)

    L, voronoi, _, _ = _closed_forms(elements["equilateral"], scale)
    np.testing.assert_allclose(L, (3 * np.eye(3) - np.ones((3, 3))) / (2 * s3), rtol=1e-14, atol=1e-15)
    np.testing.assert_allclose(np.diag(voronoi), np.full(3, s3 / 12 * scale**2), rtol=1e-14)

    L, voronoi, _, _ = _closed_forms(elements["tetrahedron"], scale)
    # Edge length 2 sqrt(2) scale; every edge sees two 60-degree angles: w = 1/sqrt(3).
    np.testing.assert_allclose(L, (4 * np.eye(4) - np.ones((4, 4))) / s3, rtol=1e-14, atol=1e-15)
    np.testing.assert_allclose(np.diag(voronoi), np.full(4, s3 / 4 * 8 * scale**2), rtol=1e-14)

    L, voronoi, _, galerkin = _closed_forms(elements["cube"], scale)
    # Each cube edge sees two 45-degree angles (w = 1); each face diagonal two right angles (w = 0).
    graph = np.array([[float(sum(a != b for a, b in zip(p, q)) == 1) for q in CUBE_V] for p in CUBE_V])
    np.testing.assert_allclose(L, np.diag(graph.sum(1)) - graph, atol=1e-14)
    np.testing.assert_allclose(np.trace(voronoi), 6 * scale**2, rtol=1e-14)
    np.testing.assert_allclose(galerkin.sum(), 6 * scale**2, rtol=1e-14)


def test_identities_symmetry_and_psd():
    """On each small mesh (a block of their disjoint union: one compilation for all five)."""
    names = ("tet.obj", "small_disk.obj", "hourglass_ico.obj", "moebius.obj", "triple_vierbein.obj")
    union = disjoint_union([_load(name)[:2] for name in names])
    everything = _dense_matrices(union.mesh)
    for k, name in enumerate(names):
        rows = union.vertices_of(k)
        dense, galerkin = (np.asarray(everything[i])[rows, rows] for i in (0, 3))
        scale = np.abs(dense).max()
        np.testing.assert_allclose(dense @ np.ones(dense.shape[0]), 0, atol=1e-14 * scale, err_msg=name)
        np.testing.assert_array_equal(dense, dense.T, err_msg=name)
        assert np.linalg.eigvalsh(dense).min() >= -1e-12 * scale, name
        np.testing.assert_array_equal(galerkin, galerkin.T, err_msg=name)
        assert np.linalg.eigvalsh(galerkin).min() > 0, name


def test_linear_precision_on_flat_meshes():
    """On each flat mesh (a block of their disjoint union, all in z = 0: one compilation)."""
    regular = grid(6, 7)
    meshes = [_load("disk.obj")[:2], _load("small_disk.obj")[:2], (np.asarray(regular.vertices), np.asarray(regular.faces))]
    union = disjoint_union(meshes)
    V = np.asarray(union.mesh.vertices)
    u = 0.3 * V[:, 0] - 1.7 * V[:, 1] + 2.0
    result = np.asarray(_apply(union.mesh, jnp.asarray(u)))
    interior = np.setdiff1d(np.arange(union.mesh.n_vertices), union.mesh.topology.boundary_vertices)
    for k in range(len(meshes)):
        rows = union.vertices_of(k)
        own = interior[(interior >= rows.start) & (interior < rows.stop)]
        assert np.abs(result[own]).max() < 1e-12 * np.abs(u[rows]).max(), k


def test_unreferenced_vertices_have_empty_rows():
    _, _, mesh = _load("stanford-bunny.obj")
    unreferenced = mesh.topology.unreferenced_vertices
    assert unreferenced.size > 0
    L = _laplacian(mesh).to_scipy()
    assert abs(L[unreferenced]).max() == 0
    assert np.all(np.asarray(_mass(mesh, mass="voronoi").diagonal())[unreferenced] == 0)


DEGENERATE_V = [[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0], [1, 1, 0], [1, 0, 0.5]]
DEGENERATE_F = [[0, 1, 2], [1, 4, 2], [0, 3, 1], [1, 3, 4], [1, 5, 4]]  # face 2 is collinear (zero area)


@pytest.mark.slow
def test_degenerate_faces_contribute_nothing_with_finite_gradients():
    V = jnp.asarray(DEGENERATE_V, dtype=float)
    mesh = Mesh.from_arrays(V, DEGENERATE_F)
    without = Mesh.from_arrays(V, [f for k, f in enumerate(DEGENERATE_F) if k != 2])
    L = _dense_laplacian(mesh)
    assert np.all(np.isfinite(L))
    # Edge (0, 3) exists only in the zero-area face: its weight is 0; the rest matches the mesh without it.
    dense_without = np.asarray(_dense_laplacian(without))
    np.testing.assert_allclose(L, dense_without, atol=1e-15)
    u = jnp.arange(6.0)

    def energies(W):
        moved = mesh.with_vertices(W)
        return jnp.stack(
            [dirichlet_energy(moved, u)]
            + [jnp.sum(mass_matrix(moved, mass=k) @ u) for k in ("voronoi", "barycentric", "galerkin")]
        )

    jacobian = jax.jit(jax.jacrev(energies))
    for W in (V, V.at[5].set(V[1])):  # also a collapsed (zero-length) edge
        assert np.all(np.isfinite(jacobian(W)))


@pytest.mark.slow
def test_jit_vmap_and_gradients(icosphere1):
    mesh = icosphere1
    V = mesh.vertices
    rng = np.random.default_rng(0)
    batch = V[None] * (1 + 0.1 * jnp.asarray(rng.random((3, 1, 1)))) + 0.01 * jnp.asarray(rng.standard_normal((3,) + V.shape))
    assemble = jax.jit(lambda W: cotan_laplacian(mesh.with_vertices(W)).values)
    batched = jax.vmap(assemble)(batch)
    eager = cotan_laplacian(mesh.with_vertices(batch[1])).values
    np.testing.assert_allclose(batched[1], eager, rtol=1e-14, atol=1e-15)  # fusion order: round-off
    np.testing.assert_allclose(batched[2], assemble(batch[2]), rtol=1e-14, atol=1e-15)
    u = jnp.asarray(rng.standard_normal((mesh.n_vertices, 2)))
    # Forward mode of the assembled matrix against finite differences (the matrix-free energy, forward
    # and reverse mode to second order against each other and finite differences:
    # test_forward_mode_equals_reverse_mode).
    energy = jax.jit(lambda W: 0.5 * jnp.vdot(u, cotan_laplacian(mesh.with_vertices(W)) @ u))
    check_grads(energy, (batch[0],), order=1, modes=("fwd",))
    # grad_u of the energy is L u.
    np.testing.assert_allclose(jax.jit(jax.grad(lambda w: dirichlet_energy(mesh, w)))(u), _apply(mesh, u), rtol=1e-13, atol=1e-14)
    # Dirichlet energy = 1/2 int |grad u|^2 from the hat gradients: exact for linear u on a flat grid.
    flat = grid(3, 3, size=2.0)
    linear = 2.0 * flat.vertices[:, 0] + 3.0 * flat.vertices[:, 1]
    np.testing.assert_allclose(jax.jit(dirichlet_energy)(flat, linear), 0.5 * 13.0 * 4.0, rtol=1e-13)


@pytest.mark.slow
def test_forward_mode_equals_reverse_mode(icosphere1):
    """The energy's derivatives in the vertex positions (u with two columns), to second order: forward
    and reverse mode against each other and against central differences."""
    mesh = icosphere1
    rng = np.random.default_rng(1)
    V = mesh.vertices + 0.05 * jnp.asarray(rng.standard_normal(mesh.vertices.shape))
    u = jnp.asarray(rng.standard_normal((mesh.n_vertices, 2)))
    directions = jnp.asarray(rng.standard_normal((3,) + V.shape))

    def energy(W):
        return dirichlet_energy(mesh.with_vertices(W), u)

    def values(W):
        return cotan_laplacian(mesh.with_vertices(W)).values

    @jax.jit  # one program, also evaluated at the shifted positions of the finite differences
    def derivatives(W, v):
        grad = jax.grad(energy)(W)
        return {
            "energy": energy(W),
            "grad": grad,
            "jvp": jax.jvp(energy, (W,), (v,))[1],
            "grad . v": jnp.vdot(grad, v),
            "hvp fwd-over-rev": jax.jvp(jax.grad(energy), (W,), (v,))[1],
            "hvp rev-over-rev": jax.grad(lambda X: jnp.vdot(jax.grad(energy)(X), v))(W),
            "jacfwd L": jax.jacfwd(values)(W),
            "jacrev L": jax.jacrev(values)(W),
            "hvps": jax.vmap(lambda d: jax.jvp(jax.grad(energy), (W,), (d,))[1])(directions),
        }

    r = derivatives(V, directions[0])
    np.testing.assert_allclose(r["jvp"], r["grad . v"], rtol=1e-12)
    np.testing.assert_allclose(r["hvp fwd-over-rev"], r["hvp rev-over-rev"], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(r["jacfwd L"], r["jacrev L"], rtol=0, atol=1e-13)
    for k in range(3):
        np.testing.assert_allclose(r["hvps"][k], derivatives(V, directions[k])["hvp fwd-over-rev"], rtol=1e-13, atol=1e-13)

    def central(key, step):  # central difference of derivatives(...)[key] along directions[0]
        d = directions[0]
        return central_difference(lambda W: derivatives(W, d)[key], V, d, step)

    # The directional derivative against central differences of the energy, as jax.test_util.check_grads
    # does: step 1e-4, truncation ~1e-8 relative, its float64 tolerance 1e-5.
    np.testing.assert_allclose(r["jvp"], central("energy", 1e-4), rtol=1e-5, atol=1e-5)
    finite = central("grad", 1e-5)
    scale = np.abs(r["hvp fwd-over-rev"]).max()
    # The Hessian-vector product against central differences of the reverse-mode gradient: step 1e-5
    # leaves a truncation error O(step^2) times the third derivatives (measured 8e-9 of the scale).
    np.testing.assert_allclose(r["hvp fwd-over-rev"], finite, rtol=0, atol=1e-7 * scale)


def _fan(n_rim: int) -> Mesh:
    """A cone over a closed rim of `n_rim` vertices: one apex of degree `n_rim` (the pattern's COO tail)."""
    angles = 2 * np.pi * np.arange(n_rim) / n_rim
    rim = np.stack([np.cos(angles), np.sin(angles), 0.1 * np.sin(3 * angles)], axis=1)
    V = np.concatenate([[[0.0, 0.0, 0.7]], [[0.0, 0.0, -0.7]], rim])
    rim_index = 2 + np.arange(n_rim)
    upper = np.stack([np.zeros(n_rim, int), rim_index, np.roll(rim_index, -1)], axis=1)
    lower = np.stack([np.ones(n_rim, int), np.roll(rim_index, -1), rim_index], axis=1)
    return Mesh.from_arrays(V, np.concatenate([upper, lower]))


@pytest.mark.slow
def test_laplacian_apply_is_matrix_free_and_equals_the_matrix(icosphere2):
    fan = _fan(40)
    assert vertex_plan(fan).pattern.nnz > vertex_plan(fan).pattern.width * fan.n_vertices  # its apex overflows into the tail
    # The icosphere and the grid as one mesh, their disjoint union (ELL storage only: no tail), and the
    # fan (with the tail): one compilation each; each part at its own scale.
    regular = disjoint_union([_arrays(icosphere2), _arrays(grid(5, 4))])
    pattern = vertex_plan(regular.mesh).pattern
    assert pattern.nnz == pattern.width * regular.mesh.n_vertices
    for mesh, blocks in ((regular.mesh, [regular.vertices_of(0), regular.vertices_of(1)]), (fan, [slice(0, fan.n_vertices)])):
        L = _laplacian(mesh).to_scipy()
        U = np.random.default_rng(2).standard_normal((mesh.n_vertices, 3))
        applied, column = np.asarray(_apply(mesh, jnp.asarray(U))), np.asarray(_apply(mesh, jnp.asarray(U[:, 0])))
        for rows in blocks:
            scale = abs(_block(L, rows)).max() * np.abs(U[rows]).max()
            np.testing.assert_allclose(applied[rows], (L @ U)[rows], rtol=0, atol=1e-13 * scale)
            np.testing.assert_allclose(column[rows], (L @ U[:, 0])[rows], rtol=0, atol=1e-13 * scale)
    # No matrix and no scatter-add: the corner -> edge gather is a fixed gather; the tail's sorted
    # segment_sum is absent on an icosphere. The energy's gradient in the vertices is written out (its
    # custom JVP): one more fixed gather of per-corner weights (beside the energy's own), applied to the
    # positions, and no scatter-add; a gradient in u alone skips it.
    mesh = icosphere2
    forward = str(jax.make_jaxpr(lambda W: laplacian_apply(mesh.with_vertices(W), W))(mesh.vertices))
    assert "scatter-add" not in forward and forward.count("ddgjax_gather_sum") == 1
    reverse = str(jax.make_jaxpr(jax.grad(lambda W: dirichlet_energy(mesh.with_vertices(W), mesh.vertices)))(mesh.vertices))
    assert reverse.count("ddgjax_gather_sum") == 2 and "scatter" not in reverse
    in_u = str(jax.make_jaxpr(jax.grad(lambda u: dirichlet_energy(mesh, u)))(mesh.vertices[:, 0]))
    assert in_u.count("ddgjax_gather_sum") == 1 and "scatter" not in in_u
    with pytest.raises(DDGInputError, match="u: expected shape"):
        laplacian_apply(mesh, jnp.ones(mesh.n_vertices + 1))
    with pytest.raises(DDGInputError, match="u: expected shape"):
        laplacian_apply(mesh, jnp.ones((mesh.n_vertices, 2, 2)))


@pytest.mark.slow
def test_mass_plus_laplacian_matches_scipy(real):
    parts, mesh = real
    L = _laplacian(mesh)
    reference = L.to_scipy()
    for mass in ("voronoi", "barycentric", "galerkin"):
        M = _mass(mesh, mass=mass)
        for t in (1e-3, 0.5):
            heat = M + t * L  # the heat method's and implicit mean curvature flow's operator
            assert heat.pattern.nnz == L.pattern.nnz and heat.positive_semidefinite
            errors = (
                heat.to_scipy() - (M.to_scipy() + t * reference),
                (M - t * L).to_scipy() - (M.to_scipy() - t * reference),
                (L + M).to_scipy() - (reference + M.to_scipy()),
            )
            for name, _, _, rows in parts:  # each mesh at its own scale
                scale = abs(_block(reference, rows)).max()
                assert all(abs(_block(error, rows)).max() <= 1e-15 * scale for error in errors), (name, mass, t)
            assert not (M - t * L).positive_semidefinite and (M - t * L).symmetric


@pytest.mark.slow
def test_heat_operator_solves_with_lineax_cg_and_differentiates(icosphere2):
    mesh = icosphere2
    t = 0.01
    rng = np.random.default_rng(3)
    b = jnp.asarray(rng.standard_normal(mesh.n_vertices))
    weights = jnp.asarray(rng.standard_normal(mesh.n_vertices))
    solver = lx.CG(rtol=1e-13, atol=1e-13)

    def solve(W):
        moved = mesh.with_vertices(W)
        # Both flagged PSD and t >= 0 is concrete: M + t L carries the tags lineax.CG needs.
        operator = mass_matrix(moved) + t * cotan_laplacian(moved)
        return lx.linear_solve(operator.as_lineax_operator(), b, solver).value

    def objective(W):  # a scalar of the solution, and the solution
        x = solve(W)
        return jnp.vdot(weights, x), x

    # One compiled program gives the solution, the scalar and its gradient through lineax's implicit
    # differentiation (an adjoint CG solve) w.r.t. vertex positions; the finite differences reuse it.
    value_and_grad = jax.jit(jax.value_and_grad(objective, has_aux=True))
    V = mesh.vertices + 0.02 * jnp.asarray(rng.standard_normal(mesh.vertices.shape))
    moved = mesh.with_vertices(V)
    expected = spla.spsolve((mass_matrix(moved).to_scipy() + t * cotan_laplacian(moved).to_scipy()).tocsc(), np.asarray(b))
    (_, x), gradient = value_and_grad(V)
    np.testing.assert_allclose(x, expected, rtol=1e-10, atol=1e-12)  # CG stops at 1e-13 relative
    direction = jnp.asarray(rng.standard_normal(V.shape))
    finite = central_difference(lambda W: value_and_grad(W)[0][0], V, direction, eps=1e-4)
    # Against central differences in a random direction, as jax.test_util.check_grads does: step 1e-4,
    # truncation ~1e-8 relative, its float64 tolerance 1e-5.
    np.testing.assert_allclose(jnp.vdot(gradient, direction), finite, rtol=1e-5, atol=1e-5)

    # A traced time step cannot be proven nonnegative; the caller asserts it for lineax.
    def traced(step):
        operator = mass_matrix(mesh) + step * cotan_laplacian(mesh)
        assert operator.symmetric and not operator.positive_semidefinite
        return lx.linear_solve(operator.as_lineax_operator(positive_semidefinite=True), b, solver).value

    jax.eval_shape(traced, t)  # traces lineax.CG (which refuses untagged operators) without compiling


def test_converters_pytorch3d_by_hand():
    # Two triangles sharing edge (1, 2): unit right triangles forming the unit square.
    mesh = _single([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], [[0, 1, 2], [1, 3, 2]])
    # PyTorch3D: W_ij = cot a + cot b, zero diagonal. Edge (1,2) is opposite two right angles: 0;
    # the four sides each see one 45-degree angle: 1.
    expected = np.array([[0, 1, 1, 0], [1, 0, 0, 1], [1, 0, 0, 1], [0, 1, 1, 0]], dtype=float)
    W = to_pytorch3d_cot_laplacian(cotan_laplacian(mesh))
    np.testing.assert_allclose(W.toarray(), expected, atol=1e-15)
    assert W.diagonal().max() == 0
    np.testing.assert_allclose(from_pytorch3d_cot_laplacian(W).toarray(), cotan_laplacian(mesh).todense(), atol=1e-15)


def test_bad_arguments(icosphere0, icosphere1):
    mesh = icosphere0
    with pytest.raises(DDGInputError, match="equal shapes"):
        cotan_laplacian(mesh) + cotan_laplacian(icosphere1)
    with pytest.raises(DDGInputError, match="mass: expected one of 'voronoi', 'barycentric', 'galerkin'"):
        mass_matrix(mesh, mass="lumped")
    with pytest.raises(TypeError, match="positional"):
        mass_matrix(mesh, "galerkin")  # options are keyword-only


@pytest.mark.slow
def test_energy_gradient_closed_form_equals_autodiff_of_the_assembly(real):
    """The per-face derivative of `dirichlet_energy` (its custom JVP) against autodiff through the
    assembled matrix, on slivers (beetle, nefertiti), unreferenced vertices (bunny) and a boundary
    (camelhead); one and two columns of `u`. On the union the energy is the sum of the meshes' own, so
    the gradient's block of each mesh is that mesh's gradient."""
    parts, mesh = real
    rng = np.random.default_rng(3)
    for u in (jnp.asarray(rng.standard_normal(mesh.n_vertices)), jnp.asarray(rng.standard_normal((mesh.n_vertices, 2)))):
        closed = jax.jit(jax.grad(lambda W, u=u: dirichlet_energy(mesh.with_vertices(W), u)))(mesh.vertices)
        assembled = jax.jit(jax.grad(lambda W, u=u: 0.5 * jnp.vdot(u, cotan_laplacian(mesh.with_vertices(W)) @ u)))(mesh.vertices)
        assert np.all(np.isfinite(closed))
        closed, assembled = np.asarray(closed), np.asarray(assembled)
        for name, _, _, rows in parts:
            scale = np.abs(assembled[rows]).max()
            np.testing.assert_allclose(closed[rows], assembled[rows], rtol=0, atol=1e-11 * scale, err_msg=name)


def _plain_energy(V, F, u):
    """`1/4 sum_f sum_k cot_k |u_{k+1} - u_{k+2}|^2` written from scratch: `cot_k = a . b / |a x b|` with `a`, `b`
    the two edges leaving corner `k` (no ddgjax code; NaN on zero-area faces, which the test meshes lack)."""
    P = V[F]
    total = 0.0
    for k in range(3):
        a, b = P[:, (k + 1) % 3] - P[:, k], P[:, (k + 2) % 3] - P[:, k]
        cot = jnp.sum(a * b, axis=-1) / jnp.linalg.norm(jnp.cross(a, b), axis=-1)
        difference = (u[F[:, (k + 1) % 3]] - u[F[:, (k + 2) % 3]]).reshape(F.shape[0], -1)
        total = total + 0.25 * jnp.sum(cot * jnp.sum(difference**2, axis=-1))
    return total


@pytest.mark.slow
def test_energy_gradient_equals_autodiff_of_the_plain_formula_and_libigl_differences(real):
    """The written-out vertex gradient of `dirichlet_energy` against (1) reverse-mode autodiff of the
    per-face cotangent formula written from scratch, on the union of the real meshes (slivers of
    nefertiti up to 179.6 degrees, a boundary on camelhead, unreferenced vertices on the bunny),
    one and two columns of u; (2) libigl: the energy is `-u^T igl.cotmatrix u / 2`, and the gradient's
    directional derivatives are central differences of libigl's energy."""
    parts, mesh = real
    rng = np.random.default_rng(7)
    F = jnp.asarray(mesh.faces)
    for u in (jnp.asarray(rng.standard_normal(mesh.n_vertices)), jnp.asarray(rng.standard_normal((mesh.n_vertices, 2)))):
        ours = np.asarray(jax.jit(jax.grad(lambda W, u=u: dirichlet_energy(mesh.with_vertices(W), u)))(mesh.vertices))
        plain = np.asarray(jax.jit(jax.grad(lambda W, u=u: _plain_energy(W, F, u)))(mesh.vertices))
        for name, _, _, rows in parts:
            # The edge form loses digits in proportion to a sliver's aspect ratio: ~1e-13 on nefertiti.
            np.testing.assert_allclose(ours[rows], plain[rows], rtol=0, atol=1e-12 * np.abs(plain[rows]).max(), err_msg=name)
    u = rng.standard_normal(mesh.n_vertices)
    energy, gradient = jax.jit(jax.value_and_grad(lambda W: dirichlet_energy(mesh.with_vertices(W), jnp.asarray(u))))(
        mesh.vertices
    )
    gradient = np.asarray(gradient)
    total = 0.0
    for name, V, F_part, rows in parts:

        def igl_energy(W, F_part=F_part, rows=rows):
            return -0.5 * u[rows] @ (igl.cotmatrix(W, F_part) @ u[rows])

        total += igl_energy(V)
        size = np.ptp(V, axis=0).max()
        for frequencies in rng.standard_normal((2, 3, 3)):
            # A smooth deformation field: every edge changes in proportion to its length, so the slivers'
            # large second derivatives do not swamp the differences.
            direction = np.sin(V @ frequencies / size)
            step = 1e-5 * size
            central = central_difference(igl_energy, V, direction, step)
            scale = np.abs(gradient[rows]).sum(axis=1) @ np.abs(direction).sum(axis=1)
            # Truncation ~1e-10 relative, round-off ~1e-16 |E| / step: 1e-7 of the derivative's scale.
            np.testing.assert_allclose(np.vdot(gradient[rows], direction), central, rtol=0, atol=1e-7 * scale, err_msg=name)
    np.testing.assert_allclose(float(energy), total, rtol=1e-12)


@pytest.mark.slow
def test_energy_gradient_in_chunks_equals_the_plain_formula(monkeypatch, icosphere2):
    """Large meshes run the gradient's per-face pass in chunks of `FACES_PER_CHUNK` faces (a loop and a
    remainder): shrunk here so that icosphere(2) (320 faces) takes that route, against autodiff of the
    plain formula, one and two columns of u, and second order (forward-over-reverse = reverse-over-reverse)."""
    monkeypatch.setattr(cotan_module, "FACES_PER_CHUNK", 64)  # 5 chunks of 64, no remainder; 3 of 96 below
    mesh = icosphere2
    rng = np.random.default_rng(11)
    V = mesh.vertices + 0.05 * jnp.asarray(rng.standard_normal(mesh.vertices.shape))
    for u in (jnp.asarray(rng.standard_normal(mesh.n_vertices)), jnp.asarray(rng.standard_normal((mesh.n_vertices, 2)))):
        ours = jax.jit(jax.grad(lambda W, u=u: dirichlet_energy(mesh.with_vertices(W), u)))(V)
        plain = jax.jit(jax.grad(lambda W, u=u: _plain_energy(W, mesh.faces, u)))(V)
        np.testing.assert_allclose(ours, plain, rtol=0, atol=1e-13 * np.abs(plain).max())
    monkeypatch.setattr(cotan_module, "FACES_PER_CHUNK", 96)  # 3 chunks and a remainder of 32
    u = jnp.asarray(rng.standard_normal(mesh.n_vertices))
    v = jnp.asarray(rng.standard_normal(V.shape))

    def energy(W):
        return dirichlet_energy(mesh.with_vertices(W), u)

    ours = jax.jit(jax.grad(energy))(V)
    plain = jax.jit(jax.grad(lambda W: _plain_energy(W, mesh.faces, u)))(V)
    np.testing.assert_allclose(ours, plain, rtol=0, atol=1e-13 * np.abs(plain).max())
    forward_over_reverse = jax.jit(lambda W: jax.jvp(jax.grad(energy), (W,), (v,))[1])(V)
    reverse_over_reverse = jax.jit(jax.grad(lambda W: jnp.vdot(jax.grad(energy)(W), v)))(V)
    plain_hvp = jax.jit(lambda W: jax.jvp(jax.grad(lambda X: _plain_energy(X, mesh.faces, u)), (W,), (v,))[1])(V)
    np.testing.assert_allclose(forward_over_reverse, reverse_over_reverse, rtol=0, atol=1e-12 * np.abs(plain_hvp).max())
    np.testing.assert_allclose(forward_over_reverse, plain_hvp, rtol=0, atol=1e-11 * np.abs(plain_hvp).max())


@pytest.mark.parametrize("scale", [1e-8, 1e8])
def test_energy_gradient_in_float32_scales_as_one_over_length(scale, icosphere2):
    """`E` is scale-invariant on a surface, so `grad_V E` scales as `1 / s`; the closed form keeps its
    factors in float32 range at edge lengths 1e-8 and 1e8 (`|n|^-3` alone would overflow at 1e-8)."""
    mesh = icosphere2
    V = np.asarray(mesh.vertices, np.float32)
    u = jnp.asarray(np.random.default_rng(5).standard_normal(mesh.n_vertices), jnp.float32)
    gradient = jax.jit(jax.grad(lambda W: dirichlet_energy(mesh.with_vertices(W), u)))
    unit, scaled = gradient(jnp.asarray(V)), gradient(jnp.asarray(V * np.float32(scale)))
    assert scaled.dtype == jnp.float32 and np.all(np.isfinite(scaled))
    # float32 (eps 1.2e-7): the scaled vertices and the per-face factors each round, summed over ~6 faces a vertex.
    np.testing.assert_allclose(np.asarray(scaled) * scale, unit, rtol=0, atol=1e-5 * np.abs(unit).max())
