"""Discrete curvatures (ddgjax.mesh._curvature): Gauss-Bonnet, references, convergence, variational identities."""

from __future__ import annotations

import functools
import gpytoolbox
import igl
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from conftest import shared_path
from ddgjax.io import _read_obj, _read_with_trimesh, load_mesh
from ddgjax.laplacian import laplacian_apply
from ddgjax.mesh import (
    Mesh,
    disk,
    enclosed_volume,
    gaussian_curvature,
    icosphere,
    mean_curvature,
    mean_curvature_normal,
    principal_curvatures,
    torus,
    total_area,
    total_mean_curvature,
    vertex_angle_defects,
    vertex_gauss_curvature_normals,
    vertex_mean_curvature_normals,
    vertex_mean_curvatures,
    vertex_normals,
)


@jax.jit
def curvatures(mesh: Mesh) -> dict:
    """Everything pointwise and integrated in one compiled call (one compilation per mesh size)."""
    return {
        "defects": vertex_angle_defects(mesh),
        "K": gaussian_curvature(mesh),
        "H": mean_curvature(mesh),
        "HN": mean_curvature_normal(mesh),
        "HN_integrated": vertex_mean_curvature_normals(mesh),
        "H_integrated": vertex_mean_curvatures(mesh),
        "principal": principal_curvatures(mesh),
        "total_H": total_mean_curvature(mesh),
    }


@functools.lru_cache(maxsize=None)
def real_mesh(name: str):
    mesh = load_mesh(shared_path("meshes", name))
    return mesh, np.asarray(mesh.vertices), np.asarray(mesh.faces)


def fitted_rate(h, errors) -> float:
    """Slope of log(error) against log(h) (least squares)."""
    return float(np.polyfit(np.log(h), np.log(errors), 1)[0])


def torus_analytic(vertices: np.ndarray, axis: int, R: float, r: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact K and H of the torus of revolution about coordinate `axis` at the given points."""
    rho = np.linalg.norm(np.delete(vertices, axis, axis=1), axis=1)
    cos_v = (rho - R) / r
    return cos_v / (r * (R + r * cos_v)), (R + 2 * r * cos_v) / (2 * r * (R + r * cos_v))


# A closed bumpy icosahedron (no symmetry to hide sign errors) for jit / vmap / gradient checks, and the
# same connectivity with degenerate positions (vertex 11 onto vertex 0: faces 0 and 4 get zero area;
# vertex 4 onto the midpoint of 3-9: face 10 collinear). Reusing one Mesh object (with_vertices)
# reuses the compiled functions; a new Mesh would compile anew.
SMALL = icosphere(0)
SMALL = SMALL.with_vertices(SMALL.vertices * jnp.array([1.0, 1.2, 0.8]) + 0.05 * jnp.cos(2.0 * SMALL.vertices))
DEGENERATE_VERTICES = SMALL.vertices.at[11].set(SMALL.vertices[0]).at[4].set(0.5 * (SMALL.vertices[3] + SMALL.vertices[9]))


def bumpy_union() -> tuple[Mesh, int]:
    """A bumpy closed sphere and, disjoint from it, a bumpy disk (boundary): one mesh, one compilation.

    Returns the mesh and the number of vertices of the closed part (which come first).
    """
    sphere, patch = icosphere(1), disk(2)
    V_sphere = np.asarray(sphere.vertices) * [1.0, 1.3, 0.7] + 0.1 * np.sin(3.0 * np.asarray(sphere.vertices))
    V_disk = np.asarray(patch.vertices) + [3.0, 0.0, 0.0]
    V_disk[:, 2] = 0.3 * np.cos(2.0 * V_disk[:, 0])
    faces = np.concatenate([np.asarray(sphere.faces), np.asarray(patch.faces) + sphere.n_vertices])
    return Mesh.from_arrays(np.concatenate([V_sphere, V_disk]), faces), sphere.n_vertices


BUMPY, N_CLOSED = bumpy_union()


SPHERES = {level: icosphere(level) for level in (1, 2, 3)}


# ---------------------------------------------------------------- Gauss-Bonnet and references

def test_gauss_bonnet_on_every_shared_mesh():
    """sum K_i = 2 pi chi on all meshes in ../shared/meshes, non-manifold and non-orientable ones included.

    The meshes are joined into one disjoint union so the defects are computed by one compiled call;
    each mesh's sum and chi are then read off its vertex / edge / face ranges.
    """
    folder = shared_path("meshes")
    # armadillo_loop1.ply (346 k faces) is a subdivision of armadillo.obj, which is included; leaving it
    # out halves this test's time.
    paths = sorted(p for p in folder.iterdir() if p.suffix in (".obj", ".off", ".ply") and p.name != "armadillo_loop1.ply")
    assert len(paths) >= 20
    parts = [_read_obj(p) if p.suffix == ".obj" else _read_with_trimesh(p, p.suffix[1:]) for p in paths]
    sizes = np.array([v.shape[0] for v, _ in parts])
    offsets = np.concatenate([[0], np.cumsum(sizes)])
    union = Mesh.from_arrays(
        np.concatenate([v for v, _ in parts]), np.concatenate([f + o for (_, f), o in zip(parts, offsets[:-1])])
    )
    topology = union.topology
    defects = np.asarray(jax.jit(vertex_angle_defects)(union))
    owner = np.searchsorted(offsets, np.arange(union.n_vertices), side="right") - 1
    referenced = np.ones(union.n_vertices, dtype=bool)
    referenced[topology.unreferenced_vertices] = False
    n_vertices = np.bincount(owner[referenced], minlength=len(paths))
    n_edges = np.bincount(owner[topology.edges[:, 0]], minlength=len(paths))
    n_faces = np.bincount(owner[topology.faces[:, 0]], minlength=len(paths))
    chi = n_vertices - n_edges + n_faces
    sums = np.bincount(owner, weights=defects, minlength=len(paths))
    for path, total, expected, nv, nf in zip(paths, sums, chi, n_vertices, n_faces):
        # Round-off: each defect is 2 pi minus a sum of angles, exact to a few ulps of 2 pi; the total
        # error grows at most linearly in the number of vertices and corners (measured: <= 1e-11).
        assert abs(total - 2 * np.pi * expected) < 4 * np.finfo(float).eps * 2 * np.pi * (nv + 3 * nf), path.name
    assert dict(zip([p.name for p in paths], chi.tolist()))["hourglass_ico.obj"] == 3


def test_angle_defects_match_libigl_and_gpytoolbox():
    mesh, V, F = real_mesh("camelhead.off")
    defects = np.asarray(curvatures(mesh)["defects"])
    boundary = np.zeros(V.shape[0], dtype=bool)
    boundary[mesh.topology.boundary_vertices] = True
    # libigl: 2 pi - sum theta everywhere, i.e. ours + pi on the boundary.
    np.testing.assert_allclose(defects + np.pi * boundary, igl.gaussian_curvature(V, F), atol=1e-13)
    # gpytoolbox: 0 on the boundary; its arccos loses ~5e-6 on camelhead's 0.55-degree slivers (DESIGN.md).
    np.testing.assert_allclose(np.where(boundary, 0.0, defects), gpytoolbox.angle_defect(V, F), atol=1e-5)
    # On a well-shaped mesh (angles 54-72 degrees) gpytoolbox's arccos agrees to round-off.
    sphere = SPHERES[2]
    expected = gpytoolbox.angle_defect(np.asarray(sphere.vertices), np.asarray(sphere.faces))
    np.testing.assert_allclose(curvatures(sphere)["defects"], expected, atol=1e-13)


def test_mean_curvature_normals_match_libigl_cotmatrix():
    mesh, V, F = real_mesh("camelhead.off")
    expected = -igl.cotmatrix(V, F) @ V / 2
    got = np.asarray(curvatures(mesh)["HN_integrated"])
    assert np.max(np.abs(got - expected)) < 1e-10 * np.max(np.abs(expected))


# ---------------------------------------------------------------- convergence to analytic curvature

def test_sphere_curvatures_converge_at_second_order():
    radius = 2.0
    levels = [1, 2, 3]
    errors = {"K": [], "H": [], "HN": [], "k1": [], "k2": []}
    for level in levels:
        sphere = SPHERES[level]
        values = curvatures(sphere.with_vertices(radius * sphere.vertices))
        errors["K"].append(np.max(np.abs(values["K"] - 1 / radius**2)))
        errors["H"].append(np.max(np.abs(values["H"] - 1 / radius)))
        errors["HN"].append(np.max(np.abs(jnp.linalg.norm(values["HN"], axis=1) - 1 / radius)))
        errors["k1"].append(np.max(np.abs(values["principal"][:, 0] - 1 / radius)))
        errors["k2"].append(np.max(np.abs(values["principal"][:, 1] - 1 / radius)))
        np.testing.assert_allclose(float(jnp.sum(values["defects"])), 4 * np.pi, rtol=1e-14)
    h = 2.0 ** -np.asarray(levels)
    for name, error in errors.items():
        # Measured: rates 1.9-2.0 for every quantity; umbilic k1 = k2 only to O(h) would give ~1.
        assert fitted_rate(h, error) > 1.8, (name, error)
    # Total mean curvature 1/2 sum l theta -> 4 pi r (measured relative error 1.6e-3 at level 3: O(h^2)).
    assert abs(float(values["total_H"]) - 4 * np.pi * radius) < 3e-3 * 4 * np.pi * radius


def test_torus_curvatures_converge_at_second_order():
    R, r = 1.0, 0.25
    resolutions = [(24, 8), (48, 16)]
    errors = {"K": [], "H": [], "k1": [], "k2": []}
    for n_major, n_minor in resolutions:
        mesh = torus(R, r, n_major, n_minor)
        values = curvatures(mesh)
        K, H = torus_analytic(np.asarray(mesh.vertices), 2, R, r)
        errors["K"].append(np.max(np.abs(values["K"] - K)))
        errors["H"].append(np.max(np.abs(values["H"] - H)))
        errors["k1"].append(np.max(np.abs(values["principal"][:, 0] - 1 / r)))
        errors["k2"].append(np.max(np.abs(values["principal"][:, 1] - K * r)))
        assert abs(float(jnp.sum(values["defects"]))) < 1e-11
    h = 1.0 / np.asarray([n for n, _ in resolutions])
    for name, error in errors.items():
        # Measured: rates 1.94-2.0 on this regular grid.
        assert fitted_rate(h, error) > 1.8, (name, error)


def test_torus_obj_curvatures_against_analytic_and_libigl():
    mesh, V, F = real_mesh("torus.obj")
    R, r = 1.0, 0.25  # SOURCES.md: axis y, vertices exactly on the torus
    K, H = torus_analytic(V, 1, R, r)
    values = curvatures(mesh)
    # 3,840 vertices with 50% slightly obtuse faces: the mixed-area estimates are within ~7% of |K|max = 1/(r(R-r)).
    assert np.max(np.abs(values["K"] - K)) < 0.07 * 16 / 3
    assert np.max(np.abs(values["H"] - H)) < 0.07 * 4
    # libigl's quadric fit (principal_curvature) is the independent reference: ours is closer to exact.
    _, _, igl_max, igl_min = igl.principal_curvature(V, F)[:4]
    ours = np.asarray(values["principal"])
    assert np.median(np.abs(ours[:, 0] - 1 / r)) < np.median(np.abs(igl_max - 1 / r))
    assert np.median(np.abs(ours[:, 1] - K * r)) < np.median(np.abs(igl_min - K * r))
    assert np.corrcoef(ours[:, 1], igl_min)[0, 1] > 0.99


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
    gradients = {name: jax.grad(lambda V: f(BUMPY.with_vertices(V)))(V) for name, f in functions.items()}
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
    # On a sphere the Gauss curvature normal points outward.
    sphere = SPHERES[2]
    normals = np.asarray(vertex_gauss_curvature_normals(sphere))
    assert np.all(np.sum(normals * np.asarray(sphere.vertices), axis=1) > 0)


def test_total_angle_defect_has_zero_gradient(identities):
    # Sum of defects = 2 pi chi is topological, on the closed part and the part with boundary alike.
    assert np.max(np.abs(identities["total_K"])) < 1e-13


def weighted_outputs(V):
    """One random weighting of every output: a wrong (or non-finite) gradient of any of them shows."""
    outputs = curvatures(SMALL.with_vertices(V))
    return sum(jnp.sum(jax.random.normal(jax.random.key(k), jnp.shape(outputs[name])) * outputs[name]) for k, name in enumerate(sorted(outputs)))


WEIGHTED_OUTPUTS = jax.jit(weighted_outputs)


def test_gradients_match_finite_differences():
    # Central differences in float64 with eps=1e-6: agreement to ~1e-6 is the expected accuracy.
    check_grads(WEIGHTED_OUTPUTS, (SMALL.vertices,), order=1, modes=("rev",), eps=1e-6, atol=1e-6, rtol=1e-6)


def test_degenerate_faces_give_finite_values_and_gradients():
    for name, value in curvatures(SMALL.with_vertices(DEGENERATE_VERTICES)).items():
        assert np.all(np.isfinite(np.asarray(value))), name
    # The same reverse pass as check_grads above (compiled once); a NaN in any output's gradient propagates.
    _, pullback = jax.vjp(WEIGHTED_OUTPUTS, DEGENERATE_VERTICES)
    assert np.all(np.isfinite(np.asarray(pullback(jnp.ones(()))[0])))


def test_jit_and_vmap_equal_eager():
    batch = jnp.stack([SMALL.vertices, 2.0 * SMALL.vertices, SMALL.vertices[:, ::-1]])
    batched = jax.vmap(lambda V: curvatures(SMALL.with_vertices(V)))(batch)
    for k in range(3):
        mesh = SMALL.with_vertices(batch[k])
        eager = {"defects": vertex_angle_defects(mesh), "H": mean_curvature(mesh), "principal": principal_curvatures(mesh)}
        for name, value in eager.items():
            np.testing.assert_allclose(batched[name][k], value, rtol=1e-13, atol=1e-14, err_msg=name)
    # Scale: integrated K is invariant, pointwise K scales as 1/s^2 and H as 1/s. A mirror image
    # (reversed orientation) keeps K and flips the sign of H.
    np.testing.assert_allclose(batched["defects"][1], batched["defects"][0], atol=1e-14)
    np.testing.assert_allclose(batched["K"][1], batched["K"][0] / 4, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(batched["H"][1], batched["H"][0] / 2, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(batched["K"][2], batched["K"][0], rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(batched["H"][2], -batched["H"][0], rtol=1e-12, atol=1e-14)


def test_flat_disk_has_zero_curvature_inside():
    flat = BUMPY.with_vertices(BUMPY.vertices.at[:, 2].set(0.0))
    values = curvatures(flat)
    interior = np.ones(BUMPY.n_vertices, dtype=bool)
    interior[BUMPY.topology.boundary_vertices] = False
    interior[:N_CLOSED] = False
    # Flat: every dihedral angle is exactly 0, angle sums at interior vertices are 2 pi to round-off.
    assert np.all(np.asarray(values["H_integrated"])[N_CLOSED:] == 0.0)
    np.testing.assert_allclose(np.asarray(values["defects"])[interior], 0.0, atol=1e-14)
    # Boundary defects of a flat disk sum to 2 pi (turning of the boundary polygon).
    assert abs(float(np.sum(np.asarray(values["defects"])[N_CLOSED:])) - 2 * np.pi) < 1e-13
