"""Per-element geometry: dual areas, normals, dihedral angles, area and volume (ddgjax.mesh._geometry).

Real meshes are joined into one disjoint union (tests/mesh_union.py) and evaluated by one compiled
call; so are the synthetic cases. Compiling, not running, dominates these tests' time.
"""

from __future__ import annotations

import igl
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from ddgjax import DDGInputError
from ddgjax.mesh import (
    Mesh,
    corner_angles,
    corner_angles_from_lengths_sq,
    corner_cotangents,
    corner_cotangents_from_lengths_sq,
    corner_dual_areas_from_lengths_sq,
    edge_dihedral_angles,
    enclosed_volume,
    face_areas,
    face_areas_from_lengths_sq,
    face_edge_lengths_sq,
    face_normals,
    total_area,
    vertex_dual_areas,
    vertex_normals,
)

from conftest import load_data_mesh, unit_icosphere
from mesh_union import disjoint_union


@jax.jit
def geometry(mesh: Mesh) -> dict:
    """Every quantity of the module in one compiled call."""
    return {
        "voronoi": vertex_dual_areas(mesh),
        "barycentric": vertex_dual_areas(mesh, dual="barycentric"),
        "circumcentric": vertex_dual_areas(mesh, dual="circumcentric"),
        "normals_area": vertex_normals(mesh, weighting="area"),
        "normals_angle": vertex_normals(mesh, weighting="angle"),
        "normals_uniform": vertex_normals(mesh, weighting="uniform"),
        "face_normals": face_normals(mesh),
        "face_areas": face_areas(mesh),
        "dihedral": edge_dihedral_angles(mesh),
        "area": total_area(mesh),
        "volume": enclosed_volume(mesh),
    }


def relative_error(got, expected) -> float:
    return float(np.max(np.abs(np.asarray(got) - expected)) / np.max(np.abs(expected)))


REAL_NAMES = ["beetle.off", "nefertiti.obj", "camelhead.off", "stanford-bunny.obj"]


@pytest.fixture(scope="module")
def real():
    """The four real meshes as one union, their arrays, and every geometric quantity of the union."""
    meshes = [load_data_mesh(name) for name in REAL_NAMES]
    arrays = {name: (np.asarray(m.vertices), np.asarray(m.faces)) for name, m in zip(REAL_NAMES, meshes)}
    union = disjoint_union(list(arrays.values()))
    values = jax.tree_util.tree_map(np.asarray, geometry(union.mesh))
    return {"union": union, "arrays": arrays, "values": values, "meshes": dict(zip(REAL_NAMES, meshes))}


def part(real, name: str, key: str) -> np.ndarray:
    """The values of `key` restricted to the mesh `name` of the union."""
    union, k = real["union"], REAL_NAMES.index(name)
    value = real["values"][key]
    if key in ("face_normals", "face_areas"):
        return value[union.faces_of(k)]
    if key == "dihedral":
        return value[union.edges_of(k)]
    return value[union.vertices_of(k)]


# Synthetic cases, also one union: a level-2 icosphere (largest angle ~72 degrees) and one triangle
# that the closed-form tests re-position with `with_vertices` (no recompilation).
SPHERE = unit_icosphere(2)
SYNTHETIC = disjoint_union([(np.asarray(SPHERE.vertices), np.asarray(SPHERE.faces)), (np.eye(3), np.array([[0, 1, 2]]))])
TRIANGLE_VERTICES = SYNTHETIC.vertices_of(1)


def synthetic(triangle_points=None, scale=(1.0, 1.0, 1.0)) -> dict:
    triangle_points = np.eye(3) if triangle_points is None else triangle_points
    V = np.asarray(SYNTHETIC.mesh.vertices).copy() * np.asarray(scale)
    V[TRIANGLE_VERTICES] = triangle_points
    return jax.tree_util.tree_map(np.asarray, geometry(SYNTHETIC.mesh.with_vertices(V)))


def triangle_dual_areas(points) -> dict:
    values = synthetic(np.asarray(points, dtype=np.float64))
    return {key: values[key][TRIANGLE_VERTICES] for key in ("voronoi", "circumcentric", "barycentric")} | {
        "area": values["face_areas"][-1]
    }


# A closed, bumpy icosahedron (no symmetry to hide sign errors) for jit / vmap / gradient checks, and
# the same connectivity with degenerate positions: vertex 11 moved onto vertex 0 (faces 0 and 4 get
# zero area, edge 0-11 zero length) and vertex 4 onto the midpoint of 3-9 (face 10 collinear, a
# 180-degree corner). Sharing the connectivity shares the compiled functions.
ICOSAHEDRON = unit_icosphere(0)
SMALL = ICOSAHEDRON.with_vertices(ICOSAHEDRON.vertices * jnp.array([1.0, 1.3, 0.7]) + 0.1 * jnp.sin(3.0 * ICOSAHEDRON.vertices))
DEGENERATE_VERTICES = SMALL.vertices.at[11].set(SMALL.vertices[0]).at[4].set(0.5 * (SMALL.vertices[3] + SMALL.vertices[9]))


# ---------------------------------------------------------------- dual areas


@pytest.mark.parametrize("name", REAL_NAMES)
@pytest.mark.parametrize("dual", ["voronoi", "barycentric"])
def test_dual_areas_match_libigl_massmatrix(real, name, dual):
    V, F = real["arrays"][name]
    igl_kind = igl.MASSMATRIX_TYPE_VORONOI if dual == "voronoi" else igl.MASSMATRIX_TYPE_BARYCENTRIC
    expected = igl.massmatrix(V, F, igl_kind).diagonal()
    got = part(real, name, dual)
    assert relative_error(got, expected) < 1e-10
    # Entrywise too (slivers to 179.6 degrees on nefertiti): the per-vertex relative error stays at round-off.
    referenced = expected > 0
    assert np.max(np.abs(got[referenced] - expected[referenced]) / expected[referenced]) < 1e-10
    assert np.all(got[real["meshes"][name].topology.unreferenced_vertices] == 0.0)


def test_dual_areas_of_every_dual_sum_to_total_area(real):
    V, F = real["arrays"]["beetle.off"]
    area = igl.doublearea(V, F).sum() / 2
    assert abs(part(real, "beetle.off", "face_areas").sum() - area) < 1e-13 * area
    for dual in ("voronoi", "barycentric", "circumcentric"):
        assert abs(part(real, "beetle.off", dual).sum() - area) < 1e-12 * area
    total = sum(igl.doublearea(V, F).sum() / 2 for V, F in real["arrays"].values())
    assert abs(float(real["values"]["area"]) - total) < 1e-12 * total


def test_circumcentric_equals_voronoi_without_obtuse_triangles():
    # A level-2 icosphere's largest angle is ~72 degrees, so the mixed area is purely circumcentric.
    values = synthetic()
    sphere = SYNTHETIC.vertices_of(0)
    np.testing.assert_allclose(values["circumcentric"][sphere], values["voronoi"][sphere], rtol=1e-13)


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
    values = triangle_dual_areas(points)
    for dual, expected in [("voronoi", voronoi), ("circumcentric", circumcentric), ("barycentric", [1 / 3] * 3)]:
        np.testing.assert_allclose(values[dual], values["area"] * np.asarray(expected), rtol=1e-13, atol=1e-16)


def test_circumcentric_share_is_negative_beyond_ninety_degrees():
    # Corner 0 at 150 degrees: circumcentre far outside, the far corners' shares go negative.
    angle = np.radians(150)
    values = triangle_dual_areas([[0, 0, 0], [1, 0, 0], [np.cos(angle), np.sin(angle), 0]])
    shares = values["circumcentric"]
    assert shares[1] < 0 and shares[2] < 0
    assert abs(shares.sum() - values["area"]) < 1e-15


def test_dual_areas_intrinsic_core_matches_extrinsic(real):
    V, F = real["arrays"]["camelhead.off"]
    l2 = np.stack([np.sum((V[F[:, (k + 2) % 3]] - V[F[:, (k + 1) % 3]]) ** 2, axis=1) for k in range(3)], axis=1)
    intrinsic = jax.jit(
        lambda l2: {dual: corner_dual_areas_from_lengths_sq(l2, dual=dual) for dual in ("voronoi", "circumcentric")}
    )(l2)
    for dual, corners in intrinsic.items():
        summed = np.bincount(F.ravel(), weights=np.asarray(corners).ravel(), minlength=V.shape[0])
        # Kahan's area vs the cross-product area on camelhead's 0.55-degree slivers: agree to ~1e-12.
        assert relative_error(summed, part(real, "camelhead.off", dual)) < 1e-11


@jax.jit
def both_routes(mesh: Mesh) -> dict:
    """Areas, angles, cotangents from the embedding and from the squared edge lengths alone."""
    lengths_sq = face_edge_lengths_sq(mesh)
    return {
        "areas": (face_areas(mesh), face_areas_from_lengths_sq(lengths_sq)),
        "angles": (corner_angles(mesh), corner_angles_from_lengths_sq(lengths_sq)),
        "cotangents": (corner_cotangents(mesh), corner_cotangents_from_lengths_sq(lengths_sq)),
        "lengths_sq": lengths_sq,
    }


def test_intrinsic_cores_match_the_extrinsic_routes(real):
    """The `*_from_lengths_sq` cores (Kahan's area, law of cosines) against cross products and atan2 of
    edge vectors, face by face, on beetle, nefertiti (needles to 0.065 and 179.6 degrees), camelhead
    and the bunny."""
    union = real["union"]
    r = jax.tree_util.tree_map(np.asarray, both_routes(union.mesh))
    V, F = np.asarray(union.mesh.vertices), np.asarray(union.mesh.faces)
    longest = np.sqrt(r["lengths_sq"].max(axis=1))
    areas = r["areas"][0]
    # Both routes start from the same rounded edge vectors, which close up only to the round-off of the
    # coordinates, eps |p|; a face's area, angles and cotangents are then determined to a relative
    # eps (|p| + l) l / A (a needle's condition number). Measured: at most 3x this bound (nefertiti).
    condition = np.finfo(float).eps * (np.abs(V[F]).max(axis=(1, 2)) + longest) * longest / areas
    assert condition.max() > 1e-12  # the slivers are really there
    assert np.all(np.abs(r["areas"][1] - areas) <= 8 * condition * areas)
    extrinsic, intrinsic = r["angles"]
    assert np.all(np.abs(intrinsic - extrinsic) <= 8 * condition[:, None])
    extrinsic, intrinsic = r["cotangents"]
    assert np.all(np.abs(intrinsic - extrinsic) <= 8 * condition[:, None] * (1 + np.abs(extrinsic)))
    assert np.degrees(r["angles"][0].min()) < 0.1 and np.degrees(r["angles"][0].max()) > 179.5


def test_dual_areas_reject_unknown_dual():
    with pytest.raises(DDGInputError, match="dual: expected one of 'voronoi', 'circumcentric', 'barycentric', got 'mixed'"):
        vertex_dual_areas(SMALL, dual="mixed")
    with pytest.raises(DDGInputError, match="dual: expected one of"):
        corner_dual_areas_from_lengths_sq(jnp.ones((1, 3)), dual="mixed")


# ---------------------------------------------------------------- normals


@pytest.mark.parametrize("name", ["beetle.off", "stanford-bunny.obj"])
def test_vertex_normals_match_libigl(real, name):
    V, F = real["arrays"][name]
    referenced = np.ones(V.shape[0], dtype=bool)
    referenced[real["meshes"][name].topology.unreferenced_vertices] = False
    for weighting, igl_kind in [
        ("area", igl.PER_VERTEX_NORMALS_WEIGHTING_TYPE_AREA),
        ("angle", igl.PER_VERTEX_NORMALS_WEIGHTING_TYPE_ANGLE),
        ("uniform", igl.PER_VERTEX_NORMALS_WEIGHTING_TYPE_UNIFORM),
    ]:
        got = part(real, name, f"normals_{weighting}")
        expected = igl.per_vertex_normals(V, F, igl_kind)
        np.testing.assert_allclose(got[referenced], expected[referenced], atol=1e-13)
        # libigl gives NaN at unreferenced vertices; ddgjax the zero vector.
        assert np.all(got[~referenced] == 0.0)


def test_face_normals_match_libigl_and_are_unit(real):
    V, F = real["arrays"]["camelhead.off"]
    normals = part(real, "camelhead.off", "face_normals")
    np.testing.assert_allclose(normals, igl.per_face_normals(V, F, np.zeros(3)), atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-14)


def test_vertex_normals_reject_unknown_weighting():
    with pytest.raises(DDGInputError, match="weighting: expected one of 'area', 'angle', 'uniform', got 'mean'"):
        vertex_normals(SMALL, weighting="mean")


def test_vertex_normals_point_outward_on_sphere():
    values = synthetic()
    sphere = SYNTHETIC.vertices_of(0)
    for weighting in ("area", "angle", "uniform"):
        normals = values[f"normals_{weighting}"][sphere]
        # Within 2 degrees of the radial direction at every vertex of a level-2 icosphere (measured: 1.4): the
        # averaged face normals of the uneven triangles tilt O(h) off the radius.
        assert np.all(np.sum(normals * np.asarray(SPHERE.vertices), axis=1) > np.cos(np.radians(2)))


# ---------------------------------------------------------------- dihedral angles, area, volume


def test_dihedral_angles_match_normal_angles_and_sign(real):
    mesh = real["meshes"]["beetle.off"]
    V, F = real["arrays"]["beetle.off"]
    topology = mesh.topology
    theta = part(real, "beetle.off", "dihedral")
    normals = igl.per_face_normals(V, F, np.zeros(3))
    interior = topology.edge_face_counts == 2
    n0, n1 = normals[topology.edge_faces[interior, 0]], normals[topology.edge_faces[interior, 1]]
    unsigned = np.arctan2(np.linalg.norm(np.cross(n0, n1), axis=1), np.sum(n0 * n1, axis=1))
    np.testing.assert_allclose(np.abs(theta[interior]), unsigned, atol=1e-12)
    assert np.all(theta[topology.boundary_edges] == 0.0)
    # Convex sphere: all positive. A mirror image reverses the orientation and flips every sign.
    values, mirrored = synthetic(), synthetic(scale=(-1.0, 1.0, 1.0))
    sphere = SYNTHETIC.edges_of(0)
    assert np.all(values["dihedral"][sphere] > 0)
    np.testing.assert_allclose(mirrored["dihedral"], -values["dihedral"], atol=1e-14)


def test_regular_icosahedron_closed_forms():
    values = jax.tree_util.tree_map(np.asarray, geometry(ICOSAHEDRON))
    edge = 1 / np.sin(2 * np.pi / 5)  # unit circumradius
    # Exterior dihedral angle pi - arccos(-sqrt(5)/3), area 5 sqrt(3) a^2, volume 5/12 (3 + sqrt 5) a^3.
    np.testing.assert_allclose(values["dihedral"], np.pi - np.arccos(-np.sqrt(5) / 3), rtol=1e-14)
    np.testing.assert_allclose(values["area"], 5 * np.sqrt(3) * edge**2, rtol=1e-14)
    np.testing.assert_allclose(values["volume"], 5 / 12 * (3 + np.sqrt(5)) * edge**3, rtol=1e-14)
    np.testing.assert_allclose(values["voronoi"], values["area"] / 12, rtol=1e-14)


def test_enclosed_volume_against_trimesh():
    import trimesh

    V, F = np.asarray(SMALL.vertices), np.asarray(SMALL.faces)
    expected = trimesh.Trimesh(V, F, process=False).volume
    assert abs(float(geometry(SMALL)["volume"]) - expected) < 1e-14 * expected


# ---------------------------------------------------------------- jit, vmap, gradients


def weighted_outputs(V):
    """A fixed random weighting of every output of `geometry`: a wrong or non-finite gradient of any
    of them shows (weights from the host: random numbers generated inside jit compile the RNG)."""
    outputs = geometry(SMALL.with_vertices(V))
    rng = np.random.default_rng(0)
    return sum(jnp.sum(rng.normal(size=jnp.shape(outputs[name])) * outputs[name]) for name in sorted(outputs))


WEIGHTED_OUTPUTS = jax.jit(weighted_outputs)


@pytest.mark.slow
def test_jit_and_vmap_equal_eager():
    batch = jnp.stack([SMALL.vertices, 1.5 * SMALL.vertices, SMALL.vertices + 0.3])
    batched = jax.vmap(lambda V: geometry(SMALL.with_vertices(V)))(batch)
    # Eager (op-by-op) evaluation compiles every primitive separately, so only a representative set is
    # compared: the mixed dual area (contains the circumcentric path), dihedral angles, the volume.
    eager_functions = {
        "voronoi": vertex_dual_areas,
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


@pytest.mark.slow
def test_gradients_match_finite_differences():
    # Central differences in float64 with eps=1e-6: O(eps^2) truncation + round-off / eps ~1e-10 relative
    # (measured 1.6e-10 of the projected cotangent).
    check_grads(WEIGHTED_OUTPUTS, (SMALL.vertices,), order=1, modes=("rev",), eps=1e-6, atol=1e-8, rtol=1e-8)


@pytest.mark.slow
def test_degenerate_faces_give_finite_values_and_gradients():
    values = geometry(SMALL.with_vertices(DEGENERATE_VERTICES))
    assert float(values["face_areas"][0]) == 0.0 and float(values["face_areas"][4]) == 0.0
    assert float(values["face_areas"][10]) < 1e-16
    for name, value in values.items():
        assert np.all(np.isfinite(np.asarray(value))), name
    # The same reverse pass as check_grads above (compiled once); a NaN in any output's gradient propagates.
    _, pullback = jax.vjp(WEIGHTED_OUTPUTS, DEGENERATE_VERTICES)
    assert np.all(np.isfinite(np.asarray(pullback(jnp.ones(()))[0])))
