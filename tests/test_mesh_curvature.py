"""Discrete curvatures (ddgjax.mesh._curvature): Gauss-Bonnet, references, convergence, variational identities.

Meshes are joined into disjoint unions (tests/mesh_union.py) so that each group is evaluated by one
compiled call; compiling, not running, dominates these tests' time.
"""

from __future__ import annotations

import gpytoolbox
import igl
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from ddgjax import DDGInputError, MeshDataError
from ddgjax.io import _read_obj, _read_with_trimesh
from ddgjax.laplacian import laplacian_apply
from ddgjax.mesh import (
    Mesh,
    disk,
    enclosed_volume,
    icosphere,
    torus,
    total_area,
    total_mean_curvature,
    vertex_angle_defects,
    vertex_dual_areas,
    vertex_gauss_curvature_normals,
    vertex_mean_curvature_normals,
    vertex_mean_curvatures,
    vertex_normals,
    vertex_pointwise_gaussian_curvatures,
    vertex_pointwise_mean_curvature_normals,
    vertex_pointwise_mean_curvatures,
    vertex_principal_curvatures,
)

from conftest import data_path, load_data_mesh, unit_icosphere
from mesh_union import disjoint_union


@jax.jit
def curvatures(mesh: Mesh) -> dict:
    """Everything pointwise and integrated in one compiled call."""
    return {
        "defects": vertex_angle_defects(mesh),
        "K": vertex_pointwise_gaussian_curvatures(mesh),
        "H": vertex_pointwise_mean_curvatures(mesh),
        "HN": vertex_pointwise_mean_curvature_normals(mesh),
        "HN_integrated": vertex_mean_curvature_normals(mesh),
        "H_integrated": vertex_mean_curvatures(mesh),
        "KN": vertex_gauss_curvature_normals(mesh),
        "principal": vertex_principal_curvatures(mesh),
    }


def fitted_rate(h, errors) -> float:
    """Slope of log(error) against log(h) (least squares)."""
    return float(np.polyfit(np.log(h), np.log(errors), 1)[0])


def torus_analytic(vertices: np.ndarray, axis: int, R: float, r: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact K and H of the torus of revolution about coordinate `axis` at the given points."""
    rho = np.linalg.norm(np.delete(vertices, axis, axis=1), axis=1)
    cos_v = (rho - R) / r
    return cos_v / (r * (R + r * cos_v)), (R + 2 * r * cos_v) / (2 * r * (R + r * cos_v))


def arrays(mesh: Mesh) -> tuple[np.ndarray, np.ndarray]:
    return np.asarray(mesh.vertices), np.asarray(mesh.faces)


# Synthetic shapes, one union: icospheres of radius 2 at levels 1-3, tori (R=1, r=1/4) at two
# resolutions, and a flat disk.
RADIUS, R, r = 2.0, 1.0, 0.25
SPHERE_LEVELS = [1, 2, 3]
TORUS_RESOLUTIONS = [(24, 8), (48, 16)]
SYNTHETIC_PARTS = (
    [("sphere", level, icosphere(level, radius=RADIUS)) for level in SPHERE_LEVELS]
    + [("torus", n, torus(major_radius=R, minor_radius=r, n_major=n[0], n_minor=n[1])) for n in TORUS_RESOLUTIONS]
    + [("flat disk", 3, disk(3))]
)
SYNTHETIC = disjoint_union([arrays(mesh) for _, _, mesh in SYNTHETIC_PARTS])


@pytest.fixture(scope="module")
def synthetic() -> list[dict]:
    """Per part: its mesh and every curvature of it (sliced from one evaluation of the union)."""
    values = jax.tree_util.tree_map(np.asarray, curvatures(SYNTHETIC.mesh))
    parts = []
    for k, (kind, size, mesh) in enumerate(SYNTHETIC_PARTS):
        vertices = SYNTHETIC.vertices_of(k)
        parts.append({"kind": kind, "size": size, "mesh": mesh} | {key: value[vertices] for key, value in values.items()})
    return parts


REAL_NAMES = ["camelhead.off", "torus.obj"]


@pytest.fixture(scope="module")
def real() -> dict:
    """camelhead (boundary, slivers) and torus.obj (R=1, r=1/4 about y), evaluated as one union."""
    meshes = [load_data_mesh(name) for name in REAL_NAMES]
    union = disjoint_union([arrays(mesh) for mesh in meshes])
    values = jax.tree_util.tree_map(np.asarray, curvatures(union.mesh))
    return {
        name: {"mesh": mesh, "V": arrays(mesh)[0], "F": arrays(mesh)[1]}
        | {key: value[union.vertices_of(k)] for key, value in values.items()}
        for k, (name, mesh) in enumerate(zip(REAL_NAMES, meshes))
    }


# A closed bumpy icosahedron (no symmetry to hide sign errors) for jit / vmap / gradient checks, and the
# same connectivity with degenerate positions (vertex 11 onto vertex 0: faces 0 and 4 get zero area;
# vertex 4 onto the midpoint of 3-9: face 10 collinear). Reusing one Mesh object (with_vertices)
# reuses the compiled functions; a new Mesh would compile anew.
SMALL = unit_icosphere(0)
SMALL = SMALL.with_vertices(SMALL.vertices * jnp.array([1.0, 1.2, 0.8]) + 0.05 * jnp.cos(2.0 * SMALL.vertices))
DEGENERATE_VERTICES = SMALL.vertices.at[11].set(SMALL.vertices[0]).at[4].set(0.5 * (SMALL.vertices[3] + SMALL.vertices[9]))


def bumpy_union() -> tuple[Mesh, int]:
    """A bumpy closed sphere and, disjoint from it, a bumpy disk (boundary), for the variational identities.

    Returns the mesh and the number of vertices of the closed part (which come first).
    """
    sphere, patch = unit_icosphere(1), disk(2)
    V_sphere = np.asarray(sphere.vertices) * [1.0, 1.3, 0.7] + 0.1 * np.sin(3.0 * np.asarray(sphere.vertices))
    V_disk = np.asarray(patch.vertices) + [3.0, 0.0, 0.0]
    V_disk[:, 2] = 0.3 * np.cos(2.0 * V_disk[:, 0])
    union = disjoint_union([(V_sphere, np.asarray(sphere.faces)), (V_disk, np.asarray(patch.faces))])
    return union.mesh, sphere.n_vertices


BUMPY, N_CLOSED = bumpy_union()


# ---------------------------------------------------------------- Gauss-Bonnet and references


@pytest.mark.slow
def test_gauss_bonnet_on_every_test_mesh():
    """sum K_i = 2 pi chi on all meshes in tests/data/meshes, non-manifold and non-orientable ones included.

    The meshes are joined into one disjoint union so the defects come from one compiled call; each
    mesh's sum and chi are read off its vertex / edge / face ranges. nefertiti_loop1.ply (400 k faces,
    made by tests/conftest.py) is the large one.
    """
    folder = data_path("meshes")
    paths = sorted(p for p in folder.iterdir() if p.suffix in (".obj", ".off", ".ply"))
    assert len(paths) >= 20 and "nefertiti_loop1.ply" in [p.name for p in paths]
    union = disjoint_union([_read_obj(p) if p.suffix == ".obj" else _read_with_trimesh(p, p.suffix[1:]) for p in paths])
    topology = union.mesh.topology
    defects = np.asarray(jax.jit(vertex_angle_defects)(union.mesh))
    owner = np.searchsorted(union.vertex_offsets, np.arange(union.mesh.n_vertices), side="right") - 1
    referenced = np.ones(union.mesh.n_vertices, dtype=bool)
    referenced[topology.unreferenced_vertices] = False
    n_vertices = np.bincount(owner[referenced], minlength=len(paths))
    n_edges = np.bincount(union.edge_owner, minlength=len(paths))
    n_faces = np.diff(union.face_offsets)
    chi = n_vertices - n_edges + n_faces
    sums = np.bincount(owner, weights=defects, minlength=len(paths))
    for path, total, expected, nv, nf in zip(paths, sums, chi, n_vertices, n_faces):
        # Round-off: each defect is 2 pi minus a sum of angles, exact to a few ulps of 2 pi; the total
        # error grows at most linearly in the number of vertices and corners (measured: <= 1e-11).
        assert abs(total - 2 * np.pi * expected) < 4 * np.finfo(float).eps * 2 * np.pi * (nv + 3 * nf), path.name
    assert dict(zip([p.name for p in paths], chi.tolist()))["hourglass_ico.obj"] == 3


def test_angle_defects_match_libigl_and_gpytoolbox(real, synthetic):
    camel = real["camelhead.off"]
    V, F, defects = camel["V"], camel["F"], camel["defects"]
    boundary = np.zeros(V.shape[0], dtype=bool)
    boundary[camel["mesh"].topology.boundary_vertices] = True
    # libigl: 2 pi - sum theta everywhere, i.e. ours + pi on the boundary.
    np.testing.assert_allclose(defects + np.pi * boundary, igl.gaussian_curvature(V, F), atol=1e-13)
    # gpytoolbox: 0 on the boundary; its arccos loses ~5e-6 on camelhead's 0.55-degree slivers (DESIGN.md).
    np.testing.assert_allclose(np.where(boundary, 0.0, defects), gpytoolbox.angle_defect(V, F), atol=1e-5)
    # On a well-shaped mesh (angles 54-72 degrees) gpytoolbox's arccos agrees to round-off.
    sphere = synthetic[1]
    expected = gpytoolbox.angle_defect(*arrays(sphere["mesh"]))
    np.testing.assert_allclose(sphere["defects"], expected, atol=1e-13)


def test_mean_curvature_normals_match_libigl_cotmatrix(real):
    camel = real["camelhead.off"]
    expected = -igl.cotmatrix(camel["V"], camel["F"]) @ camel["V"] / 2
    assert np.max(np.abs(camel["HN_integrated"] - expected)) < 1e-10 * np.max(np.abs(expected))


# ---------------------------------------------------------------- orientation

SIGNED = {
    "vertex_mean_curvatures": vertex_mean_curvatures,
    "vertex_pointwise_mean_curvatures": vertex_pointwise_mean_curvatures,
    "vertex_principal_curvatures": vertex_principal_curvatures,
    "total_mean_curvature": total_mean_curvature,
    "vertex_gauss_curvature_normals": vertex_gauss_curvature_normals,
}


@pytest.mark.parametrize(
    "name, problem",
    [("moebius.obj", "consistently oriented faces"), ("triple_vierbein.obj", "edge-manifold")],
)
def test_signed_curvatures_refuse_meshes_without_an_orientation(name, problem, data_mesh):
    """Signed dihedral angles are arbitrary without a consistent orientation: the signed curvatures
    refuse (also under jit: the check reads the host topology); the unsigned ones still work."""
    mesh = data_mesh(name)
    for function_name, function in SIGNED.items():
        for call in (function, jax.jit(function)):
            with pytest.raises(MeshDataError, match=rf"ddgjax\.mesh\.{function_name} .*needs .*{problem}"):
                call(mesh)
    unsigned = jax.jit(
        lambda m: (
            vertex_angle_defects(m),
            vertex_pointwise_gaussian_curvatures(m),
            vertex_mean_curvature_normals(m),
            vertex_pointwise_mean_curvature_normals(m),
        )
    )(mesh)
    assert all(np.all(np.isfinite(np.asarray(value))) for value in unsigned)
    # The mean curvature normal needs no orientation: it is still half the area gradient L V.
    V, F = arrays(mesh)
    np.testing.assert_allclose(unsigned[2], -igl.cotmatrix(V, F) @ V / 2, rtol=0, atol=1e-13)


# ---------------------------------------------------------------- convergence to analytic curvature


@pytest.mark.slow
def test_sphere_curvatures_converge(synthetic):
    errors = {"K": [], "H": [], "HN": [], "k1": [], "k2": []}
    for part in synthetic[: len(SPHERE_LEVELS)]:
        errors["K"].append(np.max(np.abs(part["K"] - 1 / RADIUS**2)))
        errors["H"].append(np.max(np.abs(part["H"] - 1 / RADIUS)))
        errors["HN"].append(np.max(np.abs(np.linalg.norm(part["HN"], axis=1) - 1 / RADIUS)))
        errors["k1"].append(np.max(np.abs(part["principal"][:, 0] - 1 / RADIUS)))
        errors["k2"].append(np.max(np.abs(part["principal"][:, 1] - 1 / RADIUS)))
        assert abs(float(np.sum(part["defects"])) - 4 * np.pi) < 1e-12  # sum of <= 642 defects: round-off
        # The Gauss curvature normal points outward on a sphere.
        assert np.all(np.sum(part["KN"] * np.asarray(part["mesh"].vertices), axis=1) > 0)
    h = 2.0 ** -np.asarray(SPHERE_LEVELS)
    # |HN| is exact to round-off on the level-1 icosphere (its vertex stars are all regular), so its
    # rate is fitted on levels 2-3.
    first = {"HN": 1}
    # K, H, |HN|: measured rates 1.9-2.0. k1,2 = H +- sqrt(H^2 - K): at an umbilic point (every point of
    # a sphere) H^2 - K is an O(h^2) error whose square root is O(h): measured rates 1.1 (k1), 0.8 (k2).
    minimum = {"K": 1.8, "H": 1.8, "HN": 1.8, "k1": 0.7, "k2": 0.7}
    for name, error in errors.items():
        assert fitted_rate(h[first.get(name, 0) :], error[first.get(name, 0) :]) > minimum[name], (name, error)
    # Total mean curvature 1/2 sum l theta -> 4 pi r (measured relative error 1.6e-3 at level 3: O(h^2)).
    total = float(np.sum(synthetic[len(SPHERE_LEVELS) - 1]["H_integrated"]))
    assert abs(total - 4 * np.pi * RADIUS) < 3e-3 * 4 * np.pi * RADIUS


@pytest.mark.slow
def test_torus_curvatures_converge_at_second_order(synthetic):
    errors = {"K": [], "H": [], "k1": [], "k2": []}
    for part in synthetic[len(SPHERE_LEVELS) : len(SPHERE_LEVELS) + len(TORUS_RESOLUTIONS)]:
        K, H = torus_analytic(np.asarray(part["mesh"].vertices), 2, R, r)
        errors["K"].append(np.max(np.abs(part["K"] - K)))
        errors["H"].append(np.max(np.abs(part["H"] - H)))
        errors["k1"].append(np.max(np.abs(part["principal"][:, 0] - 1 / r)))
        errors["k2"].append(np.max(np.abs(part["principal"][:, 1] - K * r)))
        assert abs(float(np.sum(part["defects"]))) < 1e-11
    h = 1.0 / np.asarray([n for n, _ in TORUS_RESOLUTIONS])
    for name, error in errors.items():
        # Measured: rates 1.94-2.0 on this regular grid.
        assert fitted_rate(h, error) > 1.8, (name, error)


def test_torus_obj_curvatures_against_analytic_and_libigl(real):
    part = real["torus.obj"]
    K, H = torus_analytic(part["V"], 1, R, r)  # SOURCES.md: axis y, vertices exactly on the torus
    # 3,840 vertices with 50% slightly obtuse faces: the mixed-area estimates are within ~7% of |K|max = 1/(r(R-r)).
    assert np.max(np.abs(part["K"] - K)) < 0.07 * 16 / 3
    assert np.max(np.abs(part["H"] - H)) < 0.07 * 4
    # libigl's quadric fit (principal_curvature) is the independent reference: ours is closer to exact.
    _, _, igl_max, igl_min = igl.principal_curvature(part["V"], part["F"])[:4]
    ours = part["principal"]
    assert np.median(np.abs(ours[:, 0] - 1 / r)) < np.median(np.abs(igl_max - 1 / r))
    assert np.median(np.abs(ours[:, 1] - K * r)) < np.median(np.abs(igl_min - K * r))
    # Two discretisations of k2 (libigl's fits a quadric per vertex): measured correlation 0.9993.
    assert np.corrcoef(ours[:, 1], igl_min)[0, 1] > 0.99


def test_flat_disk_has_zero_curvature_inside(synthetic):
    part = synthetic[-1]
    interior = np.ones(part["mesh"].n_vertices, dtype=bool)
    interior[part["mesh"].topology.boundary_vertices] = False
    # Flat: every dihedral angle is exactly 0, angle sums at interior vertices are 2 pi to round-off.
    assert np.all(part["H_integrated"] == 0.0)
    np.testing.assert_allclose(part["defects"][interior], 0.0, atol=1e-14)
    # The boundary defects of a flat disk sum to 2 pi (the turning of the boundary polygon).
    assert abs(float(np.sum(part["defects"])) - 2 * np.pi) < 1e-13


# ---------------------------------------------------------------- variational identities


@jax.jit
def identity_gradients(V) -> dict:
    mesh = BUMPY.with_vertices(V)
    functions = {
        "area": total_area,
        "volume": enclosed_volume,
        "total_H": total_mean_curvature,
        "total_K": lambda m: jnp.sum(vertex_angle_defects(m)),
    }
    gradients = {name: jax.grad(lambda V, f=f: f(BUMPY.with_vertices(V)))(V) for name, f in functions.items()}
    gradients["LV"] = laplacian_apply(mesh, V)
    gradients["2HN"] = 2.0 * vertex_mean_curvature_normals(mesh)
    gradients["normals/3"] = vertex_normals(mesh, weighting="area", normalize=False) / 3.0
    gradients["KN"] = vertex_gauss_curvature_normals(mesh)
    return gradients


@pytest.fixture(scope="module")
def identities():
    return jax.tree_util.tree_map(np.asarray, identity_gradients(BUMPY.vertices))


def test_area_gradient_is_laplacian_of_positions(identities):
    # d(area)/dV = L V with the PSD L (DESIGN.md): moving a vertex away from its neighbours adds area.
    # Holds on both parts (closed and with boundary).
    np.testing.assert_allclose(identities["area"], identities["LV"], atol=1e-14)
    np.testing.assert_allclose(identities["2HN"], identities["LV"], atol=1e-14)


def test_volume_gradient_is_area_weighted_normals_over_three(identities):
    closed = slice(0, N_CLOSED)
    np.testing.assert_allclose(identities["volume"][closed], identities["normals/3"][closed], atol=1e-15)


def test_total_mean_curvature_gradient_is_gauss_curvature_normal(identities):
    # Schlaefli: sum_e l_e d(theta_e) = 0 on a closed polyhedron, so only d(l_e) terms remain.
    closed = slice(0, N_CLOSED)
    np.testing.assert_allclose(identities["total_H"][closed], identities["KN"][closed], atol=1e-14)
    assert np.max(np.abs(identities["KN"][closed])) > 1e-2
    # With boundary, Schlaefli fails (no dihedral angle on boundary edges): the identity does not hold there.
    assert np.max(np.abs(identities["total_H"][N_CLOSED:] - identities["KN"][N_CLOSED:])) > 1e-3


def test_total_angle_defect_has_zero_gradient(identities):
    # Sum of defects = 2 pi chi is topological, on the closed part and the part with boundary alike.
    assert np.max(np.abs(identities["total_K"])) < 1e-13


def weighted_outputs(V):
    """A fixed random weighting of every output of `curvatures` and the total mean curvature: a wrong
    or non-finite gradient of any of them shows (weights from the host: random numbers generated
    inside jit compile the RNG)."""
    mesh = SMALL.with_vertices(V)
    outputs = curvatures(mesh) | {"total_H": total_mean_curvature(mesh)}
    rng = np.random.default_rng(0)
    return sum(jnp.sum(rng.normal(size=jnp.shape(outputs[name])) * outputs[name]) for name in sorted(outputs))


WEIGHTED_OUTPUTS = jax.jit(weighted_outputs)


@pytest.mark.slow
def test_gradients_match_finite_differences():
    # Central differences in float64 with eps=1e-6: truncation ~1e-12, round-off ~1e-16 |f| / eps ~1e-10
    # relative (measured 1.4e-10).
    check_grads(WEIGHTED_OUTPUTS, (SMALL.vertices,), order=1, modes=("rev",), eps=1e-6, atol=1e-8, rtol=1e-8)


SMALL_BATCH = jnp.stack([SMALL.vertices, 2.0 * SMALL.vertices, SMALL.vertices[:, ::-1], DEGENERATE_VERTICES])


@pytest.fixture(scope="module")
def small_batch() -> dict:
    """`curvatures` of SMALL, scaled by 2, mirrored, and degenerate: one vmapped, compiled call."""
    return jax.tree_util.tree_map(np.asarray, jax.jit(jax.vmap(lambda V: curvatures(SMALL.with_vertices(V))))(SMALL_BATCH))


def test_gauss_bonnet_with_coincident_vertices_is_the_collapsed_mesh():
    """Two vertices of a sphere moved onto one point: the faces of their edge collapse, and the defects
    are those of the mesh with that edge collapsed (merged vertex: the two defects' sum; every other
    vertex: its own). Each collapsed face has no angle at its coincident corners (0 / 0); they share
    pi, so the sum is 4 pi (it was 3 x 2 pi when those corners counted 0). A face collapsed to a point
    (three coincident vertices) also keeps 4 pi, with finite gradients."""
    V, F = np.asarray(SMALL.vertices).copy(), np.asarray(SMALL.faces)
    V[11] = V[0]
    degenerate = np.asarray(vertex_angle_defects(SMALL.with_vertices(V)))
    merged_faces = np.where(F == 11, 0, F)
    merged_faces = merged_faces[(merged_faces != np.roll(merged_faces, 1, axis=1)).all(axis=1)]
    assert merged_faces.shape[0] == F.shape[0] - 2  # faces 0 and 4 collapsed
    merged = np.asarray(vertex_angle_defects(Mesh.from_arrays(V, merged_faces)))  # vertex 11 unreferenced: 0
    np.testing.assert_allclose(degenerate[0] + degenerate[11], merged[0], rtol=1e-14)
    keep = np.arange(12) != 11
    keep[0] = False
    np.testing.assert_allclose(degenerate[keep], merged[keep], atol=1e-14)
    np.testing.assert_allclose(degenerate.sum(), 4 * np.pi, rtol=1e-14)
    point = V.copy()
    point[F[7]] = point[F[7, 0]]  # face 7 collapsed to a point: pi / 3 at each of its corners
    np.testing.assert_allclose(np.sum(vertex_angle_defects(SMALL.with_vertices(point))), 4 * np.pi, rtol=1e-14)
    gradient = jax.grad(lambda W: jnp.sum(vertex_angle_defects(SMALL.with_vertices(W)) ** 2))(jnp.asarray(point))
    assert np.all(np.isfinite(np.asarray(gradient)))


@pytest.mark.slow
def test_degenerate_faces_give_finite_values_and_gradients(small_batch):
    for name, value in small_batch.items():
        assert np.all(np.isfinite(value[3])), name
    np.testing.assert_allclose(small_batch["defects"][3].sum(), 4 * np.pi, rtol=1e-14)  # Gauss-Bonnet kept
    # The same reverse pass as check_grads above (compiled once); a NaN in any output's gradient propagates.
    _, pullback = jax.vjp(WEIGHTED_OUTPUTS, DEGENERATE_VERTICES)
    assert np.all(np.isfinite(np.asarray(pullback(jnp.ones(()))[0])))


def test_jit_and_vmap_equal_eager(small_batch):
    # vertex_principal_curvatures computes K and H inside: one eager call covers their code paths.
    np.testing.assert_allclose(small_batch["principal"][0], vertex_principal_curvatures(SMALL), rtol=1e-13, atol=1e-14)
    np.testing.assert_allclose(small_batch["defects"][0], vertex_angle_defects(SMALL), rtol=1e-13, atol=1e-14)
    # Scale: integrated K is invariant, pointwise K scales as 1/s^2 and H as 1/s. A mirror image
    # (reversed orientation) keeps K and flips the sign of H.
    np.testing.assert_allclose(small_batch["defects"][1], small_batch["defects"][0], atol=1e-14)
    np.testing.assert_allclose(small_batch["K"][1], small_batch["K"][0] / 4, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(small_batch["H"][1], small_batch["H"][0] / 2, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(small_batch["K"][2], small_batch["K"][0], rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(small_batch["H"][2], -small_batch["H"][0], rtol=1e-12, atol=1e-14)


@pytest.mark.slow
def test_pointwise_curvatures_divide_by_the_chosen_dual():
    """`dual=` picks the area every pointwise curvature divides by (default "voronoi", the mixed area)."""

    @jax.jit
    def by_dual(mesh):
        return {
            dual: {
                "areas": vertex_dual_areas(mesh, dual=dual),
                "K": vertex_pointwise_gaussian_curvatures(mesh, dual=dual),
                "H": vertex_pointwise_mean_curvatures(mesh, dual=dual),
                "HN": vertex_pointwise_mean_curvature_normals(mesh, dual=dual),
                "principal": vertex_principal_curvatures(mesh, dual=dual),
            }
            for dual in ("voronoi", "circumcentric", "barycentric")
        }

    values = jax.tree_util.tree_map(np.asarray, by_dual(SMALL))
    default = jax.tree_util.tree_map(np.asarray, curvatures(SMALL))
    for dual, got in values.items():
        areas = got["areas"]
        np.testing.assert_allclose(got["K"], default["defects"] / areas, rtol=1e-13, err_msg=dual)
        np.testing.assert_allclose(got["H"], default["H_integrated"] / areas, rtol=1e-13, err_msg=dual)
        np.testing.assert_allclose(got["HN"], default["HN_integrated"] / areas[:, None], rtol=1e-13, err_msg=dual)
        np.testing.assert_allclose(got["principal"].sum(axis=1), 2 * got["H"], rtol=1e-13, err_msg=dual)
    assert np.abs(values["barycentric"]["areas"] - values["voronoi"]["areas"]).max() > 1e-3
    for key in ("K", "H", "HN", "principal"):
        np.testing.assert_allclose(default[key], values["voronoi"][key], rtol=1e-14, err_msg=key)
    with pytest.raises(DDGInputError, match="dual: expected one of 'voronoi', 'circumcentric', 'barycentric'"):
        vertex_pointwise_gaussian_curvatures(SMALL, dual="mixed")
