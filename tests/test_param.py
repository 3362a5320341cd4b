"""Tests for ddgjax.param: libigl references (harmonic, LSCM and its matrix), the stereographic projection of
a hemisphere with a fitted rate, Tutte's no-flip guarantee on the shared disks, BFF's boundary lengths,
angles and rectangle, distortion measures in closed form, gradients against finite differences, jit,
tiny / float32 / unreferenced-vertex meshes and bad input."""

from __future__ import annotations

import igl
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from ddgjax import DDGInputError
from ddgjax.mesh import Mesh, disk
from ddgjax.param import (
    boundary_first_flattening,
    conformal_energy_matrix,
    harmonic_map,
    lscm,
    map_distortion,
    spectral_conformal_map,
    tutte_embedding,
)

from conftest import load_data_mesh

DISK_MESHES = ("small_disk.obj", "disk.obj", "hemisphere.obj", "hexagon.obj", "camelhead.off")


def _similarity_error(uv, reference, *, rigid=False):
    """Largest distance between `uv` fitted to `reference` by the best similarity (rotation, scale,
    translation; `rigid`: no scale) and `reference`, relative to the reference's extent."""
    z, w = uv[:, 0] + 1j * uv[:, 1], reference[:, 0] + 1j * reference[:, 1]
    z, w = z - z.mean(), w - w.mean()
    factor = np.vdot(z, w) / np.vdot(z, z)
    if rigid:
        factor /= abs(factor)
    return np.abs(factor * z - w).max() / np.abs(w).max()


def _hemisphere(n_rings: int) -> tuple[Mesh, np.ndarray]:
    """The unit upper hemisphere as the inverse stereographic image of `disk(n_rings)` (vertices on the
    sphere, boundary on the equator), and the disk's positions: its exact conformal map with scale 1
    on the boundary (the stereographic projection from the south pole)."""
    flat = disk(n_rings)
    P = np.asarray(flat.vertices)[:, :2]
    r2 = np.sum(P * P, axis=1)
    V = np.column_stack([2 * P / (1 + r2)[:, None], (1 - r2) / (1 + r2)])
    return Mesh.from_arrays(V, np.asarray(flat.faces)), P


def _turning_angles(polygon):
    edges = np.roll(polygon, -1, axis=0) - polygon
    before = np.roll(edges, 1, axis=0)
    return np.arctan2(before[:, 0] * edges[:, 1] - before[:, 1] * edges[:, 0], np.sum(before * edges, axis=1))


def _fitted_rate(hs, errors):
    return np.polyfit(np.log(hs), np.log(errors), 1)[0]


@pytest.fixture(scope="module")
def hemisphere():
    return load_data_mesh("hemisphere.obj")


def test_harmonic_map_equals_igl_harmonic_up_to_a_similarity(hemisphere):
    """libigl: the circle by arc length (map_vertices_to_circle) and the cotan harmonic extension; its boundary
    loop starts elsewhere, so the two agree up to a rotation."""
    V, F = np.asarray(hemisphere.vertices), np.asarray(hemisphere.faces, dtype=np.int64)
    loop = igl.boundary_loop(F)
    expected = igl.harmonic(V, F, loop, igl.map_vertices_to_circle(V, loop), 1)
    assert _similarity_error(np.asarray(harmonic_map(hemisphere)), expected) < 1e-10
    assert _similarity_error(np.asarray(tutte_embedding(hemisphere, weights="cotan")), expected) < 1e-10


@pytest.mark.slow
def test_the_cotan_harmonic_map_can_flip_where_tutte_does_not():
    """A jittered disk with a tall bump: obtuse angles give negative cotan weights, and the harmonic map
    flips faces (libigl's harmonic map flips the same ones); uniform Tutte, with positive weights, flips
    none; `map_distortion` reports both."""
    flat = disk(6)
    V = np.asarray(flat.vertices).copy()
    inner = np.setdiff1d(np.arange(flat.n_vertices), flat.topology.boundary_vertices)
    V[inner, :2] += np.random.default_rng(0).uniform(-0.05, 0.05, (inner.size, 2))
    V[:, 2] = 3.0 * np.exp(-np.sum(V[:, :2] ** 2, axis=1) / 0.05)
    mesh = Mesh.from_arrays(V, np.asarray(flat.faces))
    harmonic = map_distortion(mesh, harmonic_map(mesh))
    assert int(harmonic.n_flipped) == 5  # measured
    F = np.asarray(mesh.faces, dtype=np.int64)
    loop = igl.boundary_loop(F)
    expected = igl.harmonic(V, F, loop, igl.map_vertices_to_circle(V, loop), 1)
    np.testing.assert_array_equal(np.asarray(map_distortion(mesh, expected).flipped), np.asarray(harmonic.flipped))
    assert int(map_distortion(mesh, tutte_embedding(mesh)).n_flipped) == 0


@pytest.mark.slow
def test_lscm_equals_igl_lscm_and_its_energy_matrix(hemisphere):
    """Same pins, same positions: the same map (libigl solves the same quadratic form, `Q` below); the sum of
    the per-face conformal energies is `1/2 x^T Q x`."""
    V, F = np.asarray(hemisphere.vertices), np.asarray(hemisphere.faces, dtype=np.int64)
    loop = np.asarray(hemisphere.topology.boundary_loops[0])
    pins = np.array([loop[3], loop[60]])
    positions = np.array([[0.0, 0.0], [1.0, 0.5]])
    uv = np.asarray(lscm(hemisphere, fixed_vertices=pins, fixed_values=positions))
    expected, Q_igl = igl.lscm(V, F, pins, positions)
    np.testing.assert_allclose(uv, expected, rtol=0, atol=1e-10)
    Q = conformal_energy_matrix(hemisphere).to_scipy()
    assert abs(Q - Q_igl).max() < 1e-12
    x = np.concatenate([uv[:, 0], uv[:, 1]])
    energy = float(map_distortion(hemisphere, uv).total_conformal_energy)
    np.testing.assert_allclose(energy, 0.5 * x @ (Q @ x), rtol=1e-10)
    # The default pins keep their 3D distance.
    default = np.asarray(lscm(hemisphere))
    a, b = loop[0], loop[loop.size // 2]
    np.testing.assert_allclose(np.linalg.norm(default[a] - default[b]), np.linalg.norm(V[a] - V[b]), rtol=1e-12)


@pytest.mark.slow
def test_conformal_maps_of_the_hemisphere_converge():
    """BFF with u = 0 is the stereographic projection up to a rigid motion (scale 1 on the equator), with error
    O(h^2) (measured rate 2.0); LSCM and the spectral map are conformal in the limit (mean quasi-conformal
    ratio - 1 falls as O(h), measured 1.0), but pinned / free boundaries pick other conformal maps than the
    stereographic one (LSCM stays 3% off it, the spectral map 0.2%), so only their distortion is checked."""
    hs, bff_errors, distortions = [], [], {"lscm": [], "bff": [], "spectral": []}
    for n in (4, 8, 16):
        mesh, expected = _hemisphere(n)
        hs.append(1 / n)
        uv = boundary_first_flattening(mesh)
        bff_errors.append(_similarity_error(np.asarray(uv), expected, rigid=True))
        distortions["bff"].append(float(map_distortion(mesh, uv).mean_conformal_distortion) - 1)
        if n < 16:  # two sizes give their rates; each size is a compilation of its own
            for name, f in (("lscm", lscm), ("spectral", spectral_conformal_map)):
                distortions[name].append(float(map_distortion(mesh, f(mesh)).mean_conformal_distortion) - 1)
    # O(h^2) discretisation error of BFF: measured 2.95e-4 at 16 rings (4.5e-3, 1.2e-3 before), rate 1.96.
    assert bff_errors[-1] < 3e-4
    assert _fitted_rate(hs, bff_errors) > 1.8
    # O(h) conformal distortion: measured 0.067 (LSCM, spectral at 8 rings), 0.033 (BFF at 16); rates 1.02.
    for name, values in distortions.items():
        assert values[-1] < 0.07, name
        assert _fitted_rate(hs[: len(values)], values) > 0.9, name
    mesh, expected = _hemisphere(8)
    # The spectral map's free boundary picks a conformal map 0.2 % off the stereographic one: measured 2.4e-3.
    assert _similarity_error(np.asarray(spectral_conformal_map(mesh)), expected) < 5e-3


@pytest.mark.parametrize("name", DISK_MESHES)
@pytest.mark.slow
def test_tutte_has_no_flipped_triangles(name, data_mesh):
    """Positive weights and a convex boundary: every triangle keeps a positive area (Floater 1997)."""
    mesh = data_mesh(name)
    uv = tutte_embedding(mesh)
    distortion = map_distortion(mesh, uv)
    assert int(distortion.n_flipped) == 0
    assert np.all(np.asarray(distortion.area_ratio) > 0)
    if name == "hexagon.obj":
        square = tutte_embedding(mesh, shape="square")
        assert int(map_distortion(mesh, square).n_flipped) == 0
        np.testing.assert_allclose(np.abs(np.asarray(square)).max(axis=0), [1.0, 1.0], rtol=0, atol=1e-12)


def test_tutte_places_the_boundary_by_arc_length(hemisphere):
    loop = np.asarray(hemisphere.topology.boundary_loops[0])
    V = np.asarray(hemisphere.vertices)[loop]
    lengths = np.linalg.norm(np.roll(V, -1, axis=0) - V, axis=1)
    t = np.concatenate([[0.0], np.cumsum(lengths)[:-1]]) / lengths.sum()
    uv = np.asarray(tutte_embedding(hemisphere))[loop]
    np.testing.assert_allclose(uv, np.column_stack([np.cos(2 * np.pi * t), np.sin(2 * np.pi * t)]), rtol=0, atol=1e-13)
    given = np.column_stack([np.cos(2 * np.pi * t), np.sin(2 * np.pi * t)]) * 3.0
    np.testing.assert_allclose(np.asarray(tutte_embedding(hemisphere, shape=given))[loop], given, rtol=0, atol=1e-13)


@pytest.mark.slow
def test_bff_boundary_lengths_angles_and_rectangle(hemisphere):
    """u = 0 keeps each boundary edge's length up to the closing correction (2e-10 on this regular 100-edge
    boundary); target angles are the turning angles of the result exactly (the correction
    changes lengths only); the rectangle has four right angles, straight sides elsewhere."""
    loop = np.asarray(hemisphere.topology.boundary_loops[0])
    V = np.asarray(hemisphere.vertices)[loop]
    lengths = np.linalg.norm(np.roll(V, -1, axis=0) - V, axis=1)
    uv = np.asarray(boundary_first_flattening(hemisphere))
    flat = uv[loop]
    new_lengths = np.linalg.norm(np.roll(flat, -1, axis=0) - flat, axis=1)
    assert np.abs(new_lengths / lengths - 1).max() < 1e-8  # the closing correction: measured 2e-10
    np.testing.assert_allclose(flat[0], [0.0, 0.0], atol=1e-14)

    rng = np.random.default_rng(0)
    angles = 2 * np.pi / loop.size * (1 + 0.5 * rng.uniform(-1, 1, loop.size))
    angles *= 2 * np.pi / angles.sum()
    curve = np.asarray(boundary_first_flattening(hemisphere, boundary_angles=angles))[loop]
    np.testing.assert_allclose(_turning_angles(curve), angles, rtol=0, atol=1e-10)

    scaled = np.asarray(boundary_first_flattening(hemisphere, boundary_scale=np.full(loop.size, np.log(2.0))))
    assert _similarity_error(scaled, uv) < 1e-10  # a constant u is a global scale by e^u
    np.testing.assert_allclose(
        np.linalg.norm(scaled[loop[1]] - scaled[loop[0]]) / np.linalg.norm(flat[1] - flat[0]), 2.0, rtol=1e-12
    )

    rectangle = np.asarray(boundary_first_flattening(hemisphere, shape="rectangle"))
    turning = _turning_angles(rectangle[loop])
    corners = np.round(np.arange(4) * loop.size / 4).astype(int)
    np.testing.assert_allclose(turning[corners], np.pi / 2, atol=1e-10)
    np.testing.assert_allclose(np.delete(turning, corners), 0.0, atol=1e-10)
    assert int(map_distortion(hemisphere, rectangle).n_flipped) == 0

    circle = np.asarray(boundary_first_flattening(hemisphere, shape="circle"))[loop]
    radii = np.linalg.norm(circle - circle.mean(axis=0), axis=1)
    # A regular-ish polygon: constant turning per dual length, which varies little here (measured 1.1e-6).
    assert radii.std() / radii.mean() < 1e-5


def test_map_distortion_in_closed_form():
    """Identity of a flat mesh: conformal; x stretched by 2: ratio 2, energy A (s1 - s2)^2 / 2 = A / 2; a
    reflection: every face flipped, area ratio -1 ... normalised by the (negative) total, so +1."""
    mesh = disk(3)
    V = np.asarray(mesh.vertices)
    areas = np.asarray(map_distortion(mesh, V[:, :2]).surface_areas)
    identity = map_distortion(mesh, V[:, :2])
    np.testing.assert_allclose(identity.conformal_distortion, 1.0, atol=1e-12)
    np.testing.assert_allclose(identity.area_ratio, 1.0, atol=1e-12)
    np.testing.assert_allclose(identity.conformal_energy, 0.0, atol=1e-14)
    stretched = map_distortion(mesh, V[:, :2] * np.array([2.0, 1.0]))
    np.testing.assert_allclose(stretched.conformal_distortion, 2.0, rtol=1e-12)
    np.testing.assert_allclose(stretched.conformal_energy, areas / 2, rtol=1e-12)
    np.testing.assert_allclose(stretched.area_ratio, 1.0, rtol=1e-12)
    mirrored = map_distortion(mesh, V[:, :2] * np.array([-1.0, 1.0]))
    assert bool(np.all(mirrored.flipped)) and int(mirrored.n_flipped) == mesh.n_faces
    np.testing.assert_allclose(mirrored.conformal_energy, 2 * areas, rtol=1e-12)  # |J|^2/2 - det J = 1 + 1


def test_map_distortion_is_finite_on_degenerate_faces():
    """A zero-area surface face and a collapsed image: finite gradients everywhere (values: 1 and inf)."""
    V = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0], [1, 1, 0]])
    F = np.array([[0, 1, 2], [0, 1, 3], [1, 4, 2]])
    mesh = Mesh.from_arrays(V, F)
    uv = V[:, :2].copy()
    uv[4] = [0.5, 0.5]  # the third face's image collapses onto its edge 1-2

    def loss(vertices, uv):
        d = map_distortion(mesh.with_vertices(vertices), uv)
        return jnp.sum(d.conformal_energy) + jnp.sum(jnp.where(jnp.isfinite(d.conformal_distortion), d.conformal_distortion, 0.0))

    d = map_distortion(mesh, uv)
    assert float(d.conformal_distortion[1]) == 1.0 and np.isinf(float(d.conformal_distortion[2]))
    gradients = jax.grad(loss, argnums=(0, 1))(jnp.asarray(V), jnp.asarray(uv))
    assert all(np.all(np.isfinite(np.asarray(g))) for g in gradients)


def _curved_patch():
    """A small curved disk (19 vertices) with jittered vertices: no symmetry hides a wrong derivative."""
    mesh, _ = _hemisphere(2)
    V = np.asarray(mesh.vertices) + 0.03 * np.random.default_rng(1).uniform(-1, 1, (mesh.n_vertices, 3))
    return mesh.with_vertices(V)


@pytest.mark.slow
def test_gradients_of_a_distortion_energy_match_finite_differences():
    """One energy through four maps (LSCM, BFF's Dirichlet-to-Neumann and Neumann-to-Dirichlet paths, the
    harmonic map), so one compilation covers them; weights break the symmetries of a plain sum."""
    mesh = _curved_patch()
    rng = np.random.default_rng(2)
    weights = rng.uniform(0.5, 1.5, (4, mesh.n_faces))
    maps = (
        lscm,
        boundary_first_flattening,
        lambda m: boundary_first_flattening(m, shape="rectangle"),
        lambda m: tutte_embedding(m, weights="cotan"),
    )

    def energy(vertices):
        moved = mesh.with_vertices(vertices)
        total = 0.0
        for w, flatten in zip(weights, maps):
            d = map_distortion(moved, flatten(moved))
            total = total + jnp.sum(w * d.conformal_energy) + jnp.sum(w * d.area_ratio**2)
        return total

    # Jitted: the finite differences and the reverse pass run compiled programs, not op-by-op dispatch.
    # Finite differences at eps = 1e-6: the solves' rounding in an energy of ~120 over eps, against directional
    # derivatives down to ~8, leaves up to 5e-9 relative (measured along random directions).
    check_grads(jax.jit(energy), (mesh.vertices,), order=1, modes=("rev",), eps=1e-6, atol=1e-8, rtol=1e-8)


@pytest.mark.slow
def test_spectral_map_gradient_matches_finite_differences():
    mesh = _curved_patch()

    def energy(vertices):
        moved = mesh.with_vertices(vertices)
        return map_distortion(moved, spectral_conformal_map(moved, regularization=1e-4)).total_conformal_energy

    # A larger regularisation than the default: the eigenproblem's conditioning grows with the mass ratio
    # 1 / regularization and amplifies round-off in the finite differences (with 1e-8 they scatter by 1e-5
    # relative; the gradient itself is the same; measured 3.5e-9 at 1e-4). Values go through a dense eigensolve
    # here (38 unknowns).
    check_grads(jax.jit(energy), (mesh.vertices,), order=1, modes=("rev",), eps=1e-5, atol=1e-7, rtol=1e-7)


@pytest.mark.slow
def test_jit_and_eager_agree(hemisphere):
    for flatten in (lscm, boundary_first_flattening, tutte_embedding):
        eager = flatten(hemisphere)
        jitted = jax.jit(lambda V, f=flatten: f(hemisphere.with_vertices(V)))(hemisphere.vertices)
        np.testing.assert_allclose(np.asarray(jitted), np.asarray(eager), rtol=0, atol=1e-12)


@pytest.mark.slow
def test_single_triangle_unreferenced_vertices_and_float32():
    """A single triangle: Tutte puts it on the circle; LSCM, BFF and the spectral map give a similar copy
    (BFF with u = 0 a congruent one). An unreferenced vertex goes to the origin and changes nothing else."""
    V = np.array([[0.0, 0, 0], [2, 0, 0], [0.5, 1.5, 0.3]])
    F = np.array([[0, 1, 2]])
    triangle = Mesh.from_arrays(V, F)
    np.testing.assert_allclose(np.linalg.norm(np.asarray(tutte_embedding(triangle)), axis=1), 1.0, rtol=1e-14)
    lengths = lambda P: np.linalg.norm(P - np.roll(P, -1, axis=0), axis=1)
    for flatten in (lscm, spectral_conformal_map):
        uv = np.asarray(flatten(triangle))
        np.testing.assert_allclose(lengths(uv) / lengths(uv).sum(), lengths(V) / lengths(V).sum(), rtol=1e-10)
    np.testing.assert_allclose(lengths(np.asarray(boundary_first_flattening(triangle))), lengths(V), rtol=1e-12)

    mesh, _ = _hemisphere(4)  # as in the convergence test: its programs are compiled already
    extra = Mesh.from_arrays(np.vstack([np.asarray(mesh.vertices), [[5.0, 5, 5]]]), np.asarray(mesh.faces))
    for flatten in (lscm, boundary_first_flattening, spectral_conformal_map):  # Tutte: BFF's extension
        with_extra, without = np.asarray(flatten(extra)), np.asarray(flatten(mesh))
        np.testing.assert_allclose(with_extra[-1], 0.0, atol=0)
        # The spectral map: ARPACK (122 unknowns) against ARPACK with one vertex more, each accurate to the
        # eigenproblem's conditioning (mass ratio 1 / regularization): measured 2.2e-11; the solves agree to round-off.
        tolerance = 1e-9 if flatten is spectral_conformal_map else 1e-11
        np.testing.assert_allclose(with_extra[:-1], without, rtol=0, atol=tolerance)

    single = mesh.with_vertices(np.asarray(mesh.vertices, dtype=np.float32))
    for flatten in (tutte_embedding, lscm):
        uv = flatten(single)
        assert uv.dtype == jnp.float32
        # float32 geometry: relative error of a few float32 ulps times the conditioning (measured 1.8e-6).
        np.testing.assert_allclose(np.asarray(uv), np.asarray(flatten(mesh)), rtol=0, atol=1e-5)


def test_not_a_disk_is_refused(icosphere1):
    closed = icosphere1
    with pytest.raises(DDGInputError, match=r"mesh: tutte_embedding needs a topological disk.*closed"):
        tutte_embedding(closed)
    flat = disk(3)
    V, F = np.asarray(flat.vertices), np.asarray(flat.faces)
    annulus = Mesh.from_arrays(V, F[6:])  # the six centre triangles removed: two boundary loops
    with pytest.raises(DDGInputError, match="2 boundary loops"):
        lscm(annulus)
    two = Mesh.from_arrays(np.vstack([V, V + 3]), np.vstack([F, F + V.shape[0]]))
    with pytest.raises(DDGInputError, match="2 connected components"):
        boundary_first_flattening(two)
    with pytest.raises(DDGInputError, match="mesh: spectral_conformal_map"):
        spectral_conformal_map(closed)


def test_bad_arguments_are_refused(hemisphere, without_type_checker):
    nb = hemisphere.topology.boundary_loops[0].size
    loop = np.asarray(hemisphere.topology.boundary_loops[0])
    cases = [
        (lambda: tutte_embedding(hemisphere, weights="mean"), "weights"),
        (lambda: tutte_embedding(hemisphere, shape="triangle"), "shape: expected one of 'circle', 'square'"),
        (lambda: tutte_embedding(hemisphere, shape=np.zeros((nb - 1, 2))), r"shape: expected shape \(100, 2\)"),
        (lambda: tutte_embedding(hemisphere, solver="lu"), "solver: expected one of"),
        (lambda: tutte_embedding(np.zeros((3, 3))), "mesh: expected a ddgjax Mesh"),
        (lambda: lscm(hemisphere, fixed_vertices=[loop[0]], fixed_values=[[0.0, 0.0]]), "fixed_vertices: expected at least two"),
        (lambda: lscm(hemisphere, fixed_vertices=[0, 0], fixed_values=np.eye(2)), "distinct"),
        (lambda: lscm(hemisphere, fixed_vertices=[0, 10**6]), "must lie in"),
        (lambda: lscm(hemisphere, fixed_vertices=[0, 1], fixed_values=np.zeros((2, 2))), "one point"),
        (
            lambda: lscm(hemisphere, fixed_vertices=[0, 1], fixed_values=np.zeros((3, 2))),
            r"fixed_values: expected shape \(2, 2\)",
        ),
        (lambda: lscm(hemisphere, fixed_values=np.zeros((2, 2))), "fixed_values: given without fixed_vertices"),
        (lambda: lscm(hemisphere, solver="lu"), "solver: expected one of"),
        (lambda: boundary_first_flattening(hemisphere, boundary_angles=np.ones(nb)), "2 pi"),
        (lambda: boundary_first_flattening(hemisphere, boundary_scale=np.zeros(3)), "boundary_scale"),
        (lambda: boundary_first_flattening(hemisphere, shape="circle", boundary_scale=np.zeros(nb)), "at most one"),
        (lambda: boundary_first_flattening(hemisphere, shape="rectangle", corners=[loop[0], loop[1], loop[2], 0]), "not on"),
        (lambda: boundary_first_flattening(hemisphere, shape="oval"), "shape"),
        (lambda: map_distortion(hemisphere, np.zeros((3, 2))), "uv: expected shape"),
        (lambda: spectral_conformal_map(hemisphere, regularization=0.0), "regularization"),
    ]
    for call, message in cases:
        with pytest.raises(DDGInputError, match=message):
            call()
    extra = Mesh.from_arrays(np.vstack([np.asarray(hemisphere.vertices), [[5.0, 5, 5]]]), np.asarray(hemisphere.faces))
    with pytest.raises(DDGInputError, match="belong to no face"):
        lscm(extra, fixed_vertices=[0, hemisphere.n_vertices], fixed_values=np.eye(2))


@pytest.mark.slow
def test_outcomes_without_throw(hemisphere, monkeypatch):
    """Every map takes `throw=False` and returns a `Solution` with the same map and the solves' outcome and
    stats; a failed eigensolve (ARPACK's non-convergence, forced) is the spectral map's `eigensolver_failed`."""
    import scipy.sparse.linalg

    from ddgjax import RESULTS, Solution

    for flatten in (tutte_embedding, harmonic_map, lscm, boundary_first_flattening, spectral_conformal_map):
        solution = flatten(hemisphere, throw=False)
        assert isinstance(solution, Solution) and solution.result == RESULTS.successful, flatten.__name__
        np.testing.assert_allclose(solution.value, flatten(hemisphere), rtol=0, atol=1e-12)
    assert float(tutte_embedding(hemisphere, throw=False).stats["residual"]) < 1e-10
    iterative = lscm(hemisphere, solver="cg", throw=False)
    assert iterative.result == RESULTS.successful and int(iterative.stats["num_steps"]) > 0
    assert boundary_first_flattening(hemisphere, shape="rectangle", throw=False).result == RESULTS.successful

    def no_convergence(*args, **kwargs):
        raise scipy.sparse.linalg.ArpackNoConvergence("forced", np.zeros(0), np.zeros((0, 0)))

    monkeypatch.setattr(scipy.sparse.linalg, "eigsh", no_convergence)
    assert spectral_conformal_map(hemisphere, throw=False).result == RESULTS.eigensolver_failed
    with pytest.raises(Exception, match="The eigensolver did not converge"):
        spectral_conformal_map(hemisphere)
