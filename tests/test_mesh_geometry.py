"""Per-element geometry: dual areas, normals, dihedral angles, area and volume (ddgjax.mesh._geometry)."""

from __future__ import annotations

import functools

import igl
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from conftest import shared_path
from ddgjax._errors import DDGInputError
from ddgjax.io import load_mesh
from ddgjax.mesh import (
    Mesh,
    corner_dual_areas_from_lengths_sq,
    edge_dihedral_angles,
    enclosed_volume,
    face_areas,
    face_normals,
    icosphere,
    total_area,
    vertex_dual_areas,
    vertex_normals,
)


@jax.jit
def geometry(mesh: Mesh) -> dict:
    """Every quantity of the module in one compiled call: one compilation per mesh size keeps the
    suite fast (compiling, not running, dominates on these meshes)."""
    return {
        "voronoi": vertex_dual_areas(mesh, "voronoi"),
        "barycentric": vertex_dual_areas(mesh, "barycentric"),
        "circumcentric": vertex_dual_areas(mesh, "circumcentric"),
        "normals_area": vertex_normals(mesh, weighting="area"),
        "normals_angle": vertex_normals(mesh, weighting="angle"),
        "normals_uniform": vertex_normals(mesh, weighting="uniform"),
        "face_normals": face_normals(mesh),
        "face_areas": face_areas(mesh),
        "dihedral": edge_dihedral_angles(mesh),
        "area": total_area(mesh),
        "volume": enclosed_volume(mesh),
    }


@functools.lru_cache(maxsize=None)
def real_mesh(name: str):
    mesh = load_mesh(shared_path("meshes", name))
    return mesh, np.asarray(mesh.vertices), np.asarray(mesh.faces)


def relative_error(got, expected) -> float:
    return float(np.max(np.abs(np.asarray(got) - expected)) / np.max(np.abs(expected)))


# One triangle mesh, re-positioned with `with_vertices` (a new Mesh object would compile anew: its
# topology is a static, identity-hashed part of the pytree).
TRIANGLE = Mesh.from_arrays(np.eye(3), np.array([[0, 1, 2]]))


def single_triangle(points) -> Mesh:
    return TRIANGLE.with_vertices(jnp.asarray(points, dtype=jnp.float64))


# A closed, bumpy icosahedron (no symmetry to hide sign errors) for jit / vmap / gradient checks, and
# the same connectivity with degenerate positions: vertex 11 moved onto vertex 0 (faces 0 and 4 get
# zero area, edge 0-11 zero length) and vertex 4 onto the midpoint of 3-9 (face 10 collinear, a
# 180-degree corner). Sharing the connectivity shares the compiled functions.
SMALL = icosphere(0)
SMALL = SMALL.with_vertices(SMALL.vertices * jnp.array([1.0, 1.3, 0.7]) + 0.1 * jnp.sin(3.0 * SMALL.vertices))
SPHERE = icosphere(2)
DEGENERATE_VERTICES = SMALL.vertices.at[11].set(SMALL.vertices[0]).at[4].set(0.5 * (SMALL.vertices[3] + SMALL.vertices[9]))


# ---------------------------------------------------------------- dual areas

@pytest.mark.parametrize("name", ["beetle.off", "nefertiti.obj", "camelhead.off", "stanford-bunny.obj"])
@pytest.mark.parametrize("kind", ["voronoi", "barycentric"])
def test_dual_areas_match_libigl_massmatrix(name, kind):
    mesh, V, F = real_mesh(name)
    igl_kind = igl.MASSMATRIX_TYPE_VORONOI if kind == "voronoi" else igl.MASSMATRIX_TYPE_BARYCENTRIC
    expected = igl.massmatrix(V, F, igl_kind).diagonal()
    got = np.asarray(geometry(mesh)[kind])
    assert relative_error(got, expected) < 1e-10
    # Entrywise too (slivers to 179.6 degrees on nefertiti): the per-vertex relative error stays at round-off.
    referenced = expected > 0
    assert np.max(np.abs(got[referenced] - expected[referenced]) / expected[referenced]) < 1e-10
    assert np.all(got[mesh.topology.unreferenced_vertices] == 0.0)


def test_dual_areas_all_kinds_sum_to_total_area():
    mesh, V, F = real_mesh("beetle.off")
    area = igl.doublearea(V, F).sum() / 2
    values = geometry(mesh)
    assert abs(float(values["area"]) - area) < 1e-13 * area
    for kind in ("voronoi", "barycentric", "circumcentric"):
        assert abs(float(jnp.sum(values[kind])) - area) < 1e-12 * area


def test_circumcentric_equals_voronoi_without_obtuse_triangles():
    # A level-2 icosphere's largest angle is ~72 degrees, so the mixed area is purely circumcentric.
    values = geometry(SPHERE)
    np.testing.assert_allclose(values["circumcentric"], values["voronoi"], rtol=1e-13)


@pytest.mark.parametrize(
    "points, voronoi, circumcentric",
    [
        # Equilateral: the three shares are equal.
        ([[0, 0, 0], [1, 0, 0], [0.5, np.sqrt(3) / 2, 0]], [1 / 3] * 3, [1 / 3] * 3),
        # Right angle at corner 0: circumcentre at the hypotenuse midpoint, A/2 and A/4 both ways.
        ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [0.5, 0.25, 0.25], [0.5, 0.25, 0.25]),
        # Obtuse at corner 0 (120 degrees): mixed A/2, A/4; the circumcentre is the reflection of corner 0
        # across the far edge, so corner 0's circumcentric cell is the whole face.
        ([[0, 0, 0], [1, 0, 0], [-0.5, np.sqrt(3) / 2, 0]], [0.5, 0.25, 0.25], [1.0, 0.0, 0.0]),
    ],
)
def test_corner_dual_areas_closed_form(points, voronoi, circumcentric):
    values = geometry(single_triangle(points))
    area = float(values["area"])
    for kind, expected in [("voronoi", voronoi), ("circumcentric", circumcentric), ("barycentric", [1 / 3] * 3)]:
        np.testing.assert_allclose(values[kind], area * np.asarray(expected), rtol=1e-13, atol=1e-16)


def test_circumcentric_share_is_negative_beyond_ninety_degrees():
    # Corner 0 at 150 degrees: circumcentre far outside, the far corners' shares go negative.
    angle = np.radians(150)
    values = geometry(single_triangle([[0, 0, 0], [1, 0, 0], [np.cos(angle), np.sin(angle), 0]]))
    shares = np.asarray(values["circumcentric"])
    assert shares[1] < 0 and shares[2] < 0
    assert abs(shares.sum() - float(values["area"])) < 1e-15


def test_dual_areas_intrinsic_core_matches_extrinsic():
    mesh, V, F = real_mesh("camelhead.off")
    l2 = np.stack([np.sum((V[F[:, (k + 2) % 3]] - V[F[:, (k + 1) % 3]]) ** 2, axis=1) for k in range(3)], axis=1)
    intrinsic = jax.jit(lambda l2: {kind: corner_dual_areas_from_lengths_sq(l2, kind=kind) for kind in ("voronoi", "circumcentric")})(l2)
    for kind, corners in intrinsic.items():
        summed = np.bincount(F.ravel(), weights=np.asarray(corners).ravel(), minlength=V.shape[0])
        # Kahan's area vs the cross-product area on camelhead's 0.55-degree slivers: agree to ~1e-12.
        assert relative_error(summed, np.asarray(geometry(mesh)[kind])) < 1e-11


def test_dual_areas_reject_unknown_kind():
    with pytest.raises(DDGInputError, match="kind: expected one of"):
        vertex_dual_areas(SMALL, "mixed")


# ---------------------------------------------------------------- normals

@pytest.mark.parametrize("name", ["beetle.off", "stanford-bunny.obj"])
def test_vertex_normals_match_libigl(name):
    mesh, V, F = real_mesh(name)
    referenced = np.ones(V.shape[0], dtype=bool)
    referenced[mesh.topology.unreferenced_vertices] = False
    for weighting, igl_kind in [
        ("area", igl.PER_VERTEX_NORMALS_WEIGHTING_TYPE_AREA),
        ("angle", igl.PER_VERTEX_NORMALS_WEIGHTING_TYPE_ANGLE),
        ("uniform", igl.PER_VERTEX_NORMALS_WEIGHTING_TYPE_UNIFORM),
    ]:
        got = np.asarray(geometry(mesh)[f"normals_{weighting}"])
        expected = igl.per_vertex_normals(V, F, igl_kind)
        np.testing.assert_allclose(got[referenced], expected[referenced], atol=1e-13)
        # libigl gives NaN at unreferenced vertices; ddgjax the zero vector.
        assert np.all(got[~referenced] == 0.0)


def test_face_normals_match_libigl_and_are_unit():
    mesh, V, F = real_mesh("camelhead.off")
    normals = np.asarray(geometry(mesh)["face_normals"])
    np.testing.assert_allclose(normals, igl.per_face_normals(V, F, np.zeros(3)), atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-14)


def test_vertex_normals_reject_unknown_weighting():
    with pytest.raises(DDGInputError, match="weighting"):
        vertex_normals(SMALL, weighting="mean")


def test_vertex_normals_point_outward_on_sphere():
    values = geometry(SPHERE)
    for weighting in ("area", "angle", "uniform"):
        normals = np.asarray(values[f"normals_{weighting}"])
        # Within 2 degrees of the radial direction at every vertex of a level-2 icosphere (measured: 1.4).
        assert np.all(np.sum(normals * np.asarray(SPHERE.vertices), axis=1) > np.cos(np.radians(2)))


# ---------------------------------------------------------------- dihedral angles

def test_dihedral_angles_of_regular_tetrahedron():
    mesh, _, _ = real_mesh("tet.obj")
    # Exterior dihedral angle of the regular tetrahedron: pi - arccos(1/3) (the file is rounded to ~1e-6).
    np.testing.assert_allclose(geometry(mesh)["dihedral"], np.pi - np.arccos(1 / 3), atol=1e-5)


def test_dihedral_angles_match_normal_angles_and_sign():
    mesh, V, F = real_mesh("beetle.off")
    topology = mesh.topology
    theta = np.asarray(geometry(mesh)["dihedral"])
    normals = igl.per_face_normals(V, F, np.zeros(3))
    interior = topology.edge_face_counts == 2
    n0, n1 = normals[topology.edge_faces[interior, 0]], normals[topology.edge_faces[interior, 1]]
    unsigned = np.arctan2(np.linalg.norm(np.cross(n0, n1), axis=1), np.sum(n0 * n1, axis=1))
    np.testing.assert_allclose(np.abs(theta[interior]), unsigned, atol=1e-12)
    assert np.all(theta[topology.boundary_edges] == 0.0)
    # Convex sphere: all positive. A mirror image reverses the orientation and flips every sign.
    theta = np.asarray(geometry(SPHERE)["dihedral"])
    assert np.all(theta > 0)
    mirrored = SPHERE.with_vertices(SPHERE.vertices * jnp.array([-1.0, 1.0, 1.0]))
    np.testing.assert_allclose(geometry(mirrored)["dihedral"], -theta, atol=1e-14)


# ---------------------------------------------------------------- area and volume

def test_total_area_and_enclosed_volume_against_references():
    import trimesh

    mesh, V, F = real_mesh("nefertiti.obj")
    values = geometry(mesh)
    volume = trimesh.Trimesh(V, F, process=False).volume
    # Coordinates ~200 and volume ~1e7: trimesh sums tetrahedra to the origin, so its own round-off is ~1e-12.
    assert abs(float(values["volume"]) - volume) < 1e-11 * volume
    # Regular tetrahedron with edge sqrt(8/3) (tet.obj, unit circumradius): a^3 / (6 sqrt 2), file rounding ~1e-6.
    tet, _, _ = real_mesh("tet.obj")
    assert abs(float(geometry(tet)["volume"]) - np.sqrt(8 / 3) ** 3 / (6 * np.sqrt(2))) < 1e-5
    assert abs(float(geometry(tet)["area"]) - np.sqrt(3) * 8 / 3) < 1e-5


# ---------------------------------------------------------------- jit, vmap, gradients

def weighted_outputs(V):
    """One random weighting of every output: a wrong (or non-finite) gradient of any of them shows."""
    outputs = geometry(SMALL.with_vertices(V))
    return sum(jnp.sum(jax.random.normal(jax.random.key(k), jnp.shape(outputs[name])) * outputs[name]) for k, name in enumerate(sorted(outputs)))


WEIGHTED_OUTPUTS = jax.jit(weighted_outputs)


def test_jit_and_vmap_equal_eager():
    batch = jnp.stack([SMALL.vertices, 1.5 * SMALL.vertices, SMALL.vertices + 0.3])
    batched = jax.vmap(lambda V: geometry(SMALL.with_vertices(V)))(batch)
    eager_functions = {
        "voronoi": lambda m: vertex_dual_areas(m, "voronoi"),
        "circumcentric": lambda m: vertex_dual_areas(m, "circumcentric"),
        "normals_angle": lambda m: vertex_normals(m, weighting="angle"),
        "dihedral": edge_dihedral_angles,
        "volume": enclosed_volume,
    }
    for k in range(3):
        mesh = SMALL.with_vertices(batch[k])
        for name, function in eager_functions.items():
            np.testing.assert_allclose(batched[name][k], function(mesh), rtol=1e-13, atol=1e-15, err_msg=name)
    # Scale and translation: areas scale by s^2, volume by s^3, normals and angles are invariant.
    np.testing.assert_allclose(batched["voronoi"][1], 2.25 * batched["voronoi"][0], rtol=1e-13)
    np.testing.assert_allclose(batched["volume"][1], 3.375 * batched["volume"][0], rtol=1e-13)
    np.testing.assert_allclose(batched["volume"][2], batched["volume"][0], rtol=1e-13)
    np.testing.assert_allclose(batched["dihedral"][2], batched["dihedral"][0], atol=1e-14)


def test_gradients_match_finite_differences():
    # Central differences in float64 with eps=1e-6: agreement to ~1e-6 is the expected accuracy.
    check_grads(WEIGHTED_OUTPUTS, (SMALL.vertices,), order=1, modes=("rev",), eps=1e-6, atol=1e-6, rtol=1e-6)


def test_degenerate_faces_give_finite_values_and_gradients():
    values = geometry(SMALL.with_vertices(DEGENERATE_VERTICES))
    assert float(values["face_areas"][0]) == 0.0 and float(values["face_areas"][4]) == 0.0
    assert float(values["face_areas"][10]) < 1e-16
    for name, value in values.items():
        assert np.all(np.isfinite(np.asarray(value))), name
    # The same reverse pass as check_grads above (compiled once); a NaN in any output's gradient propagates.
    _, pullback = jax.vjp(WEIGHTED_OUTPUTS, DEGENERATE_VERTICES)
    assert np.all(np.isfinite(np.asarray(pullback(1.0)[0])))
