"""Property tests (hypothesis): on random meshes with degenerate faces, coincident vertices, strips and several
components, every operator either refuses clearly (`MeshDataError`, a failure result) or returns finite values
that keep its invariants.

The meshes are six fixed connectivities (a closed icosahedron, a coarse torus, a strip, one triangle, a disk and
a disjoint union of three components) with random positions: jittered, scaled, and with faces made collinear,
edges collapsed to a point (coincident vertices) and faces collapsed to a point. Only positions vary, so the
compiled programs are reused across examples (six sizes: within a kernel's program cache).

The policy under test (ddgjax.mesh._check): faces of zero or near-zero area make the plain cotan route refuse
on concrete positions (`MeshDataError` naming `robust=True`); `robust=True` (mollified intrinsic Delaunay) works
on every mesh, with a positive semidefinite Laplacian; angle defects keep Gauss-Bonnet on every mesh.
"""

from __future__ import annotations

import functools

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.csgraph as csgraph
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ddgjax import RESULTS, MeshDataError
from ddgjax.geodesics import heat_distance
from ddgjax.laplacian import cotan_laplacian, intrinsic_delaunay, laplacian_and_mass, mass_matrix
from ddgjax.mesh import Mesh, check_mesh, disk, face_areas, grid, icosphere, torus, vertex_angle_defects
from ddgjax.pde import solve_poisson
from ddgjax.spectral import eigenpairs

from mesh_union import disjoint_union

pytestmark = pytest.mark.slow  # each example builds and solves several operators

SETTINGS = settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow], derandomize=True)
BASES = ("icosahedron", "torus", "strip", "triangle", "disk", "components")


@functools.cache
def _base(name: str) -> Mesh:
    triangle = (np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.3, 0.8, 0.0]]), np.array([[0, 1, 2]]))
    if name == "triangle":
        return Mesh.from_arrays(*triangle)
    if name == "components":
        strip = grid(3, 1)
        parts = [icosphere(0), strip.with_vertices(np.asarray(strip.vertices) + [3.0, 0.0, 0.0])]
        return disjoint_union(
            [(np.asarray(m.vertices), np.asarray(m.faces)) for m in parts] + [(triangle[0] - 3.0, triangle[1])]
        ).mesh
    shapes = {
        "icosahedron": lambda: icosphere(0),
        "torus": lambda: torus(n_major=6, n_minor=4),
        "strip": lambda: grid(4, 1),
        "disk": lambda: disk(2),
    }
    return shapes[name]()


@pytest.fixture(scope="module", autouse=True)
def _built_bases():
    """The connectivities, built before hypothesis draws: building the first meshes of a process (lazy imports)
    can move `random`'s global state, which hypothesis forbids inside a strategy."""
    for name in BASES:
        _base(name)


@st.composite
def meshes(draw) -> tuple[Mesh, np.ndarray, bool]:
    """`(mesh, vertices, modified)`: a base connectivity, random positions for it, and whether a degeneracy was made."""
    mesh = _base(draw(st.sampled_from(BASES)))
    V, F, edges = np.array(mesh.vertices), np.asarray(mesh.faces), np.asarray(mesh.edges)
    scale = np.mean(np.linalg.norm(V[edges[:, 1]] - V[edges[:, 0]], axis=1))
    V = V + 0.1 * scale * np.random.default_rng(draw(st.integers(0, 2**32 - 1))).standard_normal(V.shape)
    kinds = draw(st.lists(st.sampled_from(["collinear", "coincident", "point"]), max_size=2))
    for kind in kinds:
        if kind == "coincident":  # an edge collapsed: its faces have two coincident corners
            i, j = edges[draw(st.integers(0, edges.shape[0] - 1))]
            V[j] = V[i]
        else:
            f, k = draw(st.integers(0, F.shape[0] - 1)), draw(st.integers(0, 2))
            a, b, c = F[f, k], F[f, (k + 1) % 3], F[f, (k + 2) % 3]
            V[a] = 0.5 * (V[b] + V[c]) if kind == "collinear" else V[b]
            if kind == "point":
                V[c] = V[b]
    return mesh, draw(st.sampled_from([1e-3, 1.0, 1e3])) * V, bool(kinds)


def _mesh(drawn) -> tuple[Mesh, bool]:
    """The drawn positions on their connectivity (built outside the strategy, which only draws numbers)."""
    mesh, vertices, modified = drawn
    return mesh.with_vertices(vertices), modified


def _components(mesh: Mesh) -> tuple[int, np.ndarray]:
    """Vertex connected components along the edges: `(count, label per vertex)`."""
    edges = np.asarray(mesh.edges)
    n = mesh.n_vertices
    adjacency = sp.coo_matrix((np.ones(edges.shape[0]), (edges[:, 0], edges[:, 1])), shape=(n, n))
    return csgraph.connected_components(adjacency, directed=False)


def _is_degenerate(mesh: Mesh) -> bool:
    return check_mesh(mesh).zero_area_faces.size > 0


def _refusal(mesh: Mesh, robust: bool) -> str | None:
    """What the operators' `MeshDataError` must say for this mesh, or `None` when they must run."""
    if robust:  # a mesh collapsed to a point has no length to mollify with
        return "every vertex lies at one point" if np.ptp(np.asarray(mesh.vertices), axis=0).max() == 0 else None
    return "have zero or near-zero area.*Pass robust=True" if _is_degenerate(mesh) else None


def _refused_or_outcome(run, mesh: Mesh, robust, modified: bool):
    """`run(robust)`'s successful value, or `None` after checking it refused (`_refusal`) or failed with an outcome.

    A refusal is a `MeshDataError` with the expected words; a failure is a `.result`, never silent, and
    only a modified (degenerate) mesh may fail.
    """
    refusal = _refusal(mesh, bool(robust))
    if refusal:
        with pytest.raises(MeshDataError, match=refusal):
            run(robust)
        return None
    solution = run(robust)
    if solution.result != RESULTS.successful:
        assert modified
        return None
    return solution


def _check_psd_laplacian(L, what: str):
    """Flagged symmetric PSD; symmetric, zero row sums and no eigenvalue below rounding, all measured."""
    assert L.symmetric and L.positive_semidefinite, what
    dense = L.to_scipy().toarray()
    largest = np.abs(dense).max()
    assert np.all(np.isfinite(dense)) and np.array_equal(dense, dense.T), what
    assert np.abs(dense.sum(axis=1)).max() <= 1e-12 * largest, what
    eigenvalues = np.linalg.eigvalsh(dense)
    # Backward-stable eigenvalues of a PSD matrix: within a few eps of its norm below zero.
    assert eigenvalues[0] >= -1e-13 * eigenvalues[-1], (what, eigenvalues[0], eigenvalues[-1])


@SETTINGS
@given(meshes())
def test_cotan_laplacian_and_mass_matrices(drawn):
    """Plain route: refused on degenerate faces; elsewhere a PSD Laplacian. The mass matrices work on every
    mesh: lumped ones non-negative, every one symmetric and summing to the area."""
    mesh, _ = _mesh(drawn)
    refusal = _refusal(mesh, robust=False)
    if refusal:
        with pytest.raises(MeshDataError, match=refusal):
            laplacian_and_mass(mesh)
    else:
        L, _ = laplacian_and_mass(mesh)
        _check_psd_laplacian(L, "cotan")
    area = float(np.sum(face_areas(mesh)))
    for mass in ("voronoi", "barycentric", "galerkin"):
        M = mass_matrix(mesh, mass=mass).to_scipy().toarray()
        assert np.all(np.isfinite(M)) and np.array_equal(M, M.T), mass
        np.testing.assert_allclose(M.sum(), area, rtol=1e-12, err_msg=mass)
        if mass == "galerkin":
            assert np.linalg.eigvalsh(M)[0] >= -1e-14 * np.abs(M).max()
        else:
            assert np.all(np.diag(M) >= 0), mass


@SETTINGS
@given(meshes())
def test_robust_laplacian_is_psd_on_every_mesh(drawn):
    """`robust=True` (mollified intrinsic Delaunay) never refuses an oriented manifold mesh: L PSD, M positive
    on every vertex and at least the area (mollification only lengthens edges; exactly the area without it)."""
    mesh, _ = _mesh(drawn)
    refusal = _refusal(mesh, robust=True)
    if refusal:
        with pytest.raises(MeshDataError, match=refusal):
            laplacian_and_mass(mesh, robust=True)
        return
    L, M = laplacian_and_mass(mesh, robust=True, mass="barycentric")
    _check_psd_laplacian(L, "robust")
    masses = np.asarray(M.diagonal())
    area = float(np.sum(face_areas(mesh)))
    assert np.all(masses > 0)
    if _is_degenerate(mesh):
        assert masses.sum() >= area * (1 - 1e-12)
    else:
        np.testing.assert_allclose(masses.sum(), area, rtol=1e-12)


@SETTINGS
@given(meshes())
def test_angle_defects_keep_gauss_bonnet(drawn):
    mesh, _ = _mesh(drawn)
    defects = np.asarray(vertex_angle_defects(mesh))
    assert np.all(np.isfinite(defects))
    # Each defect is 2 pi less a sum of angles: a few ulps of 2 pi each.
    np.testing.assert_allclose(defects.sum(), 2 * np.pi * mesh.topology.euler_characteristic, atol=1e-12 * mesh.n_vertices)


@SETTINGS
@given(meshes(), st.booleans())
def test_eigenpairs_are_non_negative_with_one_zero_per_component(drawn, robust):
    mesh, modified = _mesh(drawn)
    k = min(6, mesh.n_vertices - 1)
    solution = _refused_or_outcome(lambda robust: eigenpairs(mesh, k, robust=robust, throw=False), mesh, robust, modified)
    if solution is None:
        return
    values = np.asarray(solution.value.values)
    n_components, _ = _components(mesh)
    # Rounding of the eigenvalues: eps times the largest one, bounded by max L_ii / M_ii (Gershgorin). A
    # mollified point has a mass of ~1e-10 of its neighbours' and makes that 1e11 times the smallest
    # nonzero eigenvalue (measured: the zero eigenvalue at 2.6e-6 of the next one).
    L, M = laplacian_and_mass(mesh, robust=robust)
    rounding = 100 * np.finfo(float).eps * float(np.max(np.asarray(L.diagonal()) / np.asarray(M.diagonal())))
    tolerance = rounding + 1e-10 * abs(values[-1])
    assert np.all(np.isfinite(values)) and np.all(np.diff(values) >= -tolerance)
    zeros = min(k, n_components)
    assert np.all(np.abs(values[:zeros]) <= tolerance), values
    if k > n_components:
        assert values[n_components] > tolerance, values


@SETTINGS
@given(meshes(), st.booleans(), st.data())
def test_heat_distance_is_non_negative_and_infinite_off_the_source_component(drawn, robust, data):
    mesh, modified = _mesh(drawn)
    source = data.draw(st.integers(0, mesh.n_vertices - 1))
    solution = _refused_or_outcome(lambda robust: heat_distance(mesh, source, robust=robust, throw=False), mesh, robust, modified)
    if solution is None:
        return
    distance = np.asarray(solution.value)
    _, labels = _components(mesh)
    reached = labels == labels[source]
    assert not np.any(np.isnan(distance))
    assert np.all(np.isfinite(distance[reached])) and np.all(np.isinf(distance[~reached]))
    # The shift makes each reached component's minimum 0; on coarse jittered meshes (a 6 x 4 torus) the
    # heat method's minimum need not sit at the source vertex itself.
    assert np.all(distance[reached] >= 0) and distance[reached].min() == 0


@SETTINGS
@given(meshes(), st.booleans(), st.integers(0, 2**32 - 1))
def test_poisson_solution_solves_the_compatible_problem(drawn, robust, seed):
    """No fixed vertices: per component a compatible right-hand side and a zero-mean solution, `L phi = -M rho_c`."""
    mesh, modified = _mesh(drawn)
    rho = np.random.default_rng(seed).standard_normal(mesh.n_vertices)
    triangulation = intrinsic_delaunay(mesh) if robust and _refusal(mesh, True) is None else robust
    solution = _refused_or_outcome(
        lambda robust: solve_poisson(mesh, rho, robust=robust, throw=False), mesh, triangulation, modified
    )
    if solution is None:
        return
    phi = np.asarray(solution.value)
    L, M = laplacian_and_mass(mesh, robust=triangulation)
    L, masses = L.to_scipy(), np.asarray(M.diagonal())
    n_components, labels = _components(mesh)
    component_mass = np.bincount(labels, weights=masses, minlength=n_components)
    compatible = rho - (np.bincount(labels, weights=masses * rho, minlength=n_components) / component_mass)[labels]
    assert np.all(np.isfinite(phi))
    mean = np.bincount(labels, weights=masses * phi, minlength=n_components) / component_mass
    assert np.all(np.abs(mean) <= 1e-10 * np.abs(phi).max())
    residual = L @ phi + masses * compatible
    # A direct solve leaves round-off (measured <= 3e-16 on CPU); the CG an accelerator defaults to stops at a
    # relative residual of 1e-10 in the 2-norm, up to sqrt(n) times the largest entry.
    assert np.abs(residual).max() <= 1e-8 * (abs(L).max() * np.abs(phi).max() + np.abs(masses * rho).max())


def test_cotan_laplacian_of_a_degenerate_mesh_is_not_flagged_psd(icosphere2):
    """The plain cotan Laplacian, assembled regardless of a face of relative area 1e-16: indefinite by rounding
    (smallest eigenvalue far below its typical scale), so it must not carry the PSD flag."""
    mesh = icosphere2
    V, F = np.asarray(mesh.vertices).copy(), np.asarray(mesh.faces)
    a, b, c = V[F[0]]
    away = (c - (a + b) / 2) / np.linalg.norm(c - (a + b) / 2)
    V[F[0, 2]] = (a + b) / 2 + 2e-16 * np.linalg.norm(b - a) * away
    L = cotan_laplacian(mesh.with_vertices(V))
    dense = L.to_scipy().toarray()
    assert np.linalg.eigvalsh(dense)[0] < -1e-3 * np.median(np.diag(dense))  # what the flag would promise away
    assert not L.positive_semidefinite
