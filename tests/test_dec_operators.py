"""d0, d1 and the Hodge stars: exact identities, orientation refusals, the DDG reference solution,
gpytoolbox's `dec_*` and libigl's cotan / mass matrices.

Compile time dominates on small meshes, so each mesh's operators are built by one jitted call.
"""

from __future__ import annotations

import functools
import inspect

import gpytoolbox
import igl
import jax
import jax.numpy as jnp
import jax.test_util
import numpy as np
import pytest

import ddgjax.dec as dec
from ddgjax import DDGInputError, MeshDataError
from ddgjax.laplacian import cotan_laplacian, mass_matrix
from ddgjax.laplacian.internal import dec_plan, vertex_plan
from ddgjax.mesh import (
    Mesh,
    corner_dual_areas,
    corner_dual_areas_from_lengths_sq,
    edge_cotan_weights,
    face_areas,
    grid,
    vertex_dual_areas,
    vertex_pointwise_gaussian_curvatures,
    vertex_pointwise_mean_curvature_normals,
    vertex_pointwise_mean_curvatures,
    vertex_principal_curvatures,
)
from ddgjax.sparse import congruence

from conftest import data_path
from mesh_union import disjoint_union

ORIENTED = ["small_disk.obj", "bob_small.ply", "hourglass_ico.obj"]
ANY = ["small_disk.obj", "bob_small.ply", "hourglass_ico.obj", "moebius.obj", "triple_vierbein.obj"]
VERTEX_DUALS = ("circumcentric", "barycentric", "voronoi")


@functools.cache
def load(name: str) -> Mesh:
    V, F = igl.read_triangle_mesh(str(data_path("meshes", name)))
    return Mesh.from_arrays(V, F)


@functools.cache
def operators(name: str) -> dict:
    """Every operator of `name`'s mesh as host arrays, from one compiled function."""
    mesh = load(name)
    oriented = mesh.topology.is_oriented

    @jax.jit
    def build(mesh):
        out = {"d0": dec.d0(mesh), "cotan": edge_cotan_weights(mesh), "area": jnp.sum(face_areas(mesh))}
        for dual in VERTEX_DUALS:
            out[f"h0 {dual}"] = dec.hodge0(mesh, dual=dual).diagonal()
            out[f"h0inv {dual}"] = dec.hodge0(mesh, dual=dual, inverse=True).diagonal()
        for dual in ("circumcentric", "barycentric"):
            out[f"h1 {dual}"] = dec.hodge1(mesh, dual=dual).diagonal()
            out[f"h1inv {dual}"] = dec.hodge1(mesh, dual=dual, inverse=True).diagonal()
        out["default h0"] = dec.hodge0(mesh).diagonal()
        out["default h1"] = dec.hodge1(mesh).diagonal()
        out["mass"] = mass_matrix(mesh).diagonal()
        if oriented:
            out["d1"] = dec.d1(mesh)
            out["h2"] = dec.hodge2(mesh).diagonal()
            out["h2inv"] = dec.hodge2(mesh, inverse=True).diagonal()
        return out

    return jax.tree.map(np.asarray, build(mesh))


def to_scipy(matrix):
    return matrix.to_scipy() if hasattr(matrix, "to_scipy") else matrix


@pytest.mark.parametrize("name", ORIENTED)
@pytest.mark.slow
def test_d0_d1_form_an_exact_complex(name):
    mesh, ops = load(name), operators(name)
    D0, D1 = ops["d0"].to_scipy(), ops["d1"].to_scipy()
    assert D0.shape == (mesh.n_edges, mesh.n_vertices) and D1.shape == (mesh.n_faces, mesh.n_edges)
    # The patterns are already CSR (sorted columns in every row): scipy reads them as they are.
    assert D0.has_canonical_format and D1.has_canonical_format
    edges = mesh.topology.edges
    expected_d0 = np.zeros(D0.shape)
    expected_d0[np.arange(mesh.n_edges), edges[:, 0]] = -1
    expected_d0[np.arange(mesh.n_edges), edges[:, 1]] = 1
    np.testing.assert_array_equal(D0.toarray(), expected_d0)
    expected_d1 = np.zeros(D1.shape)
    expected_d1[np.arange(mesh.n_faces)[:, None], mesh.topology.face_edges] = mesh.topology.face_edge_signs
    np.testing.assert_array_equal(D1.toarray(), expected_d1)
    # d1 d0 = 0 exactly, in integer arithmetic.
    product = D1.astype(np.int64) @ D0.astype(np.int64)
    product.eliminate_zeros()
    assert product.nnz == 0


def test_patterns_are_traced_not_baked_in():
    """d0 / d1 patterns come from the mesh's integer leaves: a jit trace holds no mesh-sized constants."""
    mesh = load("bob_small.ply")
    jaxpr = jax.make_jaxpr(lambda m: (dec.d1(m).pattern.cols, dec.d0(m).pattern.cols, dec.hodge1(m).values))(mesh)
    assert all(np.size(c) < 16 for c in jaxpr.consts)


@pytest.mark.parametrize(
    ("name", "reason"),
    [("moebius.obj", "consistently oriented faces"), ("triple_vierbein.obj", "edge-manifold mesh")],
)
@pytest.mark.slow
def test_orientation_policy(name, reason):
    mesh = load(name)
    ne, nf = mesh.n_edges, mesh.n_faces
    refused = {
        "d1": lambda: dec.d1(mesh),
        "hodge2": lambda: dec.hodge2(mesh),
        "curl": lambda: dec.curl(mesh, jnp.zeros((nf, 3))),
        "integrate_2form": lambda: dec.integrate_2form(mesh, lambda p: p),
        "codifferential(degree=2)": lambda: dec.codifferential(mesh, jnp.zeros(nf), degree=2),
        "hodge_laplacian1": lambda: dec.hodge_laplacian1(mesh, jnp.zeros(ne)),
        "hodge_laplacian2": lambda: dec.hodge_laplacian2(mesh, jnp.zeros(nf)),
    }
    for operation, call in refused.items():
        with pytest.raises(MeshDataError, match=reason) as info:
            call()
        assert f"ddgjax.dec.{operation} needs" in str(info.value) and "edges [" in str(info.value)
    # Everything that needs no face orientation works (operators() built d0, *0, *1 on this mesh).
    ops = operators(name)
    assert all(np.all(np.isfinite(ops[key])) for key in ops if key.startswith("h"))
    assert ops["d0"].shape == (ne, mesh.n_vertices)


def test_bad_arguments():
    mesh = load("tet.obj")
    with pytest.raises(DDGInputError, match="dual: expected one of 'voronoi', 'circumcentric', 'barycentric', got 'dual'"):
        dec.hodge0(mesh, dual="dual")
    with pytest.raises(DDGInputError, match="dual: expected one of"):
        dec.edge_dual_length_ratios(mesh, dual="mixed")
    with pytest.raises(DDGInputError, match="degree: expected one of 0, 1, 2, got 3"):
        dec.hodge_star_entries(mesh, degree=3)


@pytest.mark.parametrize(
    "call",
    [
        dec.d0,
        dec.d1,
        dec.hodge0,
        dec.hodge1,
        dec.hodge2,
        dec.edge_dual_length_ratios,
        lambda m: dec.hodge_star_entries(m, degree=0),
        lambda m: dec.integrate_0form(m, jnp.sum),
        lambda m: dec.integrate_1form(m, lambda p: p),
        lambda m: dec.integrate_2form(m, lambda p: p),
        lambda m: dec.flat(m, jnp.zeros((4, 3))),
        lambda m: dec.sharp(m, jnp.zeros(6)),
        lambda m: dec.gradient(m, jnp.zeros(4)),
        lambda m: dec.divergence(m, jnp.zeros((4, 3))),
        lambda m: dec.curl(m, jnp.zeros((4, 3))),
        lambda m: dec.codifferential(m, jnp.zeros(6), degree=1),
        lambda m: dec.hodge_laplacian0(m, jnp.zeros(4)),
        lambda m: dec.hodge_laplacian1(m, jnp.zeros(6)),
        lambda m: dec.hodge_laplacian2(m, jnp.zeros(4)),
    ],
)
def test_every_operator_refuses_what_is_not_a_mesh(call, without_type_checker):
    """A (vertices, faces) pair or a bare array where a Mesh is expected: `DDGInputError` saying what to
    call (checked as a user sees it, without the suite's run-time type checker, which refuses first)."""
    mesh = load("tet.obj")
    V, F = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    with pytest.raises(DDGInputError, match=r"mesh: expected a ddgjax Mesh, got a tuple; .*Mesh\.from_arrays"):
        call((V, F))
    with pytest.raises(DDGInputError, match=r"mesh: expected a ddgjax Mesh, got an array of shape"):
        call(V)


def test_one_dual_vocabulary_and_default():
    """`dual=` is keyword-only with the default "voronoi" in ddgjax.mesh and ddgjax.dec alike, and the
    default *0 is the default mass matrix (libigl's Voronoi pairing with the cotan Laplacian)."""
    functions = [
        corner_dual_areas_from_lengths_sq,
        corner_dual_areas,
        vertex_dual_areas,
        vertex_pointwise_gaussian_curvatures,
        vertex_pointwise_mean_curvature_normals,
        vertex_pointwise_mean_curvatures,
        vertex_principal_curvatures,
        dec.edge_dual_length_ratios,
        dec.hodge_star_entries,
        dec.hodge0,
        dec.hodge1,
        dec.codifferential,
        dec.hodge_laplacian0,
        dec.hodge_laplacian1,
        dec.hodge_laplacian2,
    ]
    for function in functions:
        parameter = inspect.signature(function).parameters["dual"]
        assert parameter.kind is inspect.Parameter.KEYWORD_ONLY and parameter.default == "voronoi", function
    ops = operators("bob_small.ply")
    np.testing.assert_array_equal(ops["default h0"], ops["h0 voronoi"])
    np.testing.assert_array_equal(ops["default h0"], ops["mass"])
    # The Voronoi dual changes *0 only: its *1 is the circumcentric cotan ratio.
    np.testing.assert_array_equal(ops["default h1"], ops["h1 circumcentric"])


@pytest.fixture(scope="module")
def ddg_reference():
    """The genus-2 mesh of `test-dec-soln.txt`, its records, and its edge order mapped onto ours."""
    records: dict[str, list] = {}
    with open(data_path("ddg-exercises", "test-dec-soln.txt")) as handle:
        for line in handle:
            tag, *numbers = line.split()
            records.setdefault(tag, []).append(numbers)
    V = np.array(records.pop("v"), float)
    F = np.array(records.pop("f"), int) - 1
    values = {tag: np.array(rows, float).ravel() for tag, rows in records.items()}
    mesh = Mesh.from_arrays(V, F)
    # The file's edges: half-edges f0->f1, f1->f2, f2->f0 in face order; the first one met names it.
    half_edges = np.stack([F, np.roll(F, -1, axis=1)], axis=-1).reshape(-1, 2)
    low, high = half_edges.min(axis=1), half_edges.max(axis=1)
    _, first = np.unique(low * len(V) + high, return_index=True)
    first = np.sort(first)
    ours = mesh.topology.edges.astype(np.int64)
    index = np.searchsorted(ours[:, 0] * len(V) + ours[:, 1], low[first] * len(V) + high[first])
    sign = np.where(half_edges[first, 0] < half_edges[first, 1], 1.0, -1.0)
    return mesh, values, index, sign


@pytest.mark.slow
def test_ddg_reference_solution(ddg_reference):
    mesh, ref, index, sign = ddg_reference
    assert (mesh.n_vertices, mesh.n_faces, mesh.n_edges, mesh.topology.genus) == (3070, 6144, 9216, 2)
    # The course's *0 is barycentric (ddgjax's default dual is Voronoi); its *1 is the cotan ratio.
    stars = jax.jit(
        lambda m: (
            dec.hodge0(m, dual="barycentric").diagonal(),
            dec.hodge1(m, dual="circumcentric").diagonal(),
            dec.hodge2(m).diagonal(),
        )
    )(mesh)
    # The file's stars agree with ours to ~1e-6 relative only: evaluating ours in float32 moves them
    # 10x less than that, so the file's values came from slightly different positions than the
    # printed (float32-exact) ones. Measured: hodge0 6.2e-7 rel, hodge1 3.9e-6 abs (entries up to 2.2,
    # some near 0), hodge2 1.3e-6 rel. The course's own tests allow 1e-5 (1e-4 for hodge1).
    np.testing.assert_allclose(stars[0], ref["hodge0"], rtol=2e-6)
    np.testing.assert_allclose(np.asarray(stars[1])[index], ref["hodge1"], rtol=0, atol=1e-5)  # hodge1: measured 3.9e-6
    np.testing.assert_allclose(stars[2], ref["hodge2"], rtol=3e-6)  # hodge2: measured 1.3e-6
    # d0 and d1 are exact; the file's d0 has the opposite global sign.
    D0, D1 = dec.d0(mesh).to_scipy(), dec.d1(mesh).to_scipy()
    np.testing.assert_array_equal(-sign * (D0 @ ref["phi"])[index], ref["dPhi"])
    omega = np.zeros(mesh.n_edges)
    omega[index] = sign * ref["omega"]
    np.testing.assert_allclose(D1 @ omega, ref["dOmega"], rtol=0, atol=1e-16)


@pytest.mark.parametrize("name", ["bob_small.ply", "small_disk.obj"])
def test_against_gpytoolbox_dec(name):
    mesh, ops = load(name), operators(name)
    V, F = np.asarray(mesh.vertices), mesh.topology.faces
    _, E, _, _ = gpytoolbox.halfedge_edge_map(F)
    ours = mesh.topology.edges.astype(np.int64)
    index = np.searchsorted(ours[:, 0] * len(V) + ours[:, 1], E.min(axis=1) * len(V) + E.max(axis=1))
    sign = np.where(E[:, 0] < E[:, 1], 1.0, -1.0)
    # gpytoolbox orients edge e as E[e] and its d0 is u[E0] - u[E1]: minus ours on that orientation.
    permute = np.zeros((len(E), mesh.n_edges))
    permute[np.arange(len(E)), index] = sign
    np.testing.assert_array_equal(gpytoolbox.dec_d0(F).toarray(), -permute @ ops["d0"].to_scipy().toarray())
    np.testing.assert_array_equal(gpytoolbox.dec_d1(F).toarray(), ops["d1"].to_scipy().toarray() @ permute.T)
    np.testing.assert_allclose(ops["h0 barycentric"], gpytoolbox.dec_h0(V, F).diagonal(), rtol=1e-13)
    h1 = gpytoolbox.dec_h1(V, F).diagonal()
    np.testing.assert_allclose(ops["h1 circumcentric"][index], h1, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(ops["h1inv circumcentric"][index], gpytoolbox.dec_h1inv(V, F).diagonal(), rtol=1e-12)
    # gpytoolbox's dec_h2 is the face area, i.e. our *2^{-1}.
    np.testing.assert_allclose(ops["h2inv"], gpytoolbox.dec_h2(V, F).diagonal(), rtol=1e-13)
    np.testing.assert_allclose(ops["h2"], gpytoolbox.dec_h2inv(V, F).diagonal(), rtol=1e-13)


@pytest.mark.parametrize("name", ANY)
@pytest.mark.slow
def test_dec_laplacian_and_mass_match_libigl(name):
    """`d0^T *1 d0 = -igl.cotmatrix` and `*0` = libigl's lumped mass matrices, on any mesh."""
    mesh, ops = load(name), operators(name)
    V, F = np.asarray(mesh.vertices), mesh.topology.faces
    D0 = ops["d0"].to_scipy()
    L = D0.T @ (ops["h1 circumcentric"][:, None] * D0.toarray())
    expected = -igl.cotmatrix(V, F).toarray()
    np.testing.assert_allclose(L, expected, rtol=0, atol=1e-12 * np.abs(expected).max())
    np.testing.assert_array_equal(ops["h1 circumcentric"], ops["cotan"])
    for dual, kind in (("voronoi", igl.MASSMATRIX_TYPE_VORONOI), ("barycentric", igl.MASSMATRIX_TYPE_BARYCENTRIC)):
        np.testing.assert_allclose(ops[f"h0 {dual}"], igl.massmatrix(V, F, kind).diagonal(), rtol=1e-13)
    for dual in VERTEX_DUALS:
        assert ops[f"h0 {dual}"].sum() == pytest.approx(float(ops["area"]), rel=1e-13)


def _dec_laplacian_values(mesh: Mesh):
    """`d0^T *1 d0` on the cotan Laplacian's pattern (`ddgjax.sparse.congruence`), beside `cotan_laplacian`'s values."""
    pattern, plan = vertex_plan(mesh).pattern, dec_plan(mesh)
    dec_route = jax.jit(lambda m: congruence(dec.d0(m), dec.hodge1(m).diagonal(), pattern, plan).values)
    return np.asarray(dec_route(mesh)), np.asarray(jax.jit(lambda m: cotan_laplacian(m).values)(mesh)), pattern


@pytest.mark.slow
def test_d0_star1_d0_is_the_cotan_laplacian_on_every_test_mesh():
    """The DEC route to the Laplacian, `d0^T *1 d0`, against the lengths core `cotan_laplacian` assembles
    from: every test mesh (boundaries, slivers, non-manifold and non-orientable ones) as blocks of one
    disjoint union (one compilation, not 23)."""
    names = sorted(p.name for p in data_path("meshes").iterdir() if p.suffix in (".obj", ".off", ".ply"))
    assert len(names) >= 20 and "nefertiti_loop1.ply" in names  # tests/data/SOURCES.md
    union = disjoint_union([igl.read_triangle_mesh(str(data_path("meshes", name))) for name in names])
    dec_values, values, pattern = _dec_laplacian_values(union.mesh)
    owner = np.searchsorted(union.vertex_offsets, np.asarray(pattern.rows), side="right") - 1
    scale, error = np.zeros(len(names)), np.zeros(len(names))
    np.maximum.at(scale, owner, np.abs(values))
    np.maximum.at(error, owner, np.abs(dec_values - values))
    # Both routes sum the same cotangents in a different order (the diagonal: row sums vs scatter).
    worst = int(np.argmax(error / scale))
    assert error[worst] <= 1e-12 * scale[worst], names[worst]


@pytest.mark.slow
def test_d0_star1_d0_is_the_cotan_laplacian_on_builtin_shapes_and_differentiates(icosphere2):
    """A closed icosphere and a flat grid with boundary (their disjoint union); and the derivatives of
    `u^T L u` in the vertices through both routes."""
    mesh = disjoint_union([(np.asarray(m.vertices), np.asarray(m.faces)) for m in (icosphere2, grid(4, 5))]).mesh
    dec_values, values, _ = _dec_laplacian_values(mesh)
    np.testing.assert_allclose(dec_values, values, rtol=0, atol=1e-13)
    pattern, plan = vertex_plan(mesh).pattern, dec_plan(mesh)
    u = jnp.asarray(np.random.default_rng(4).standard_normal(mesh.n_vertices))

    def energies(W):
        moved = mesh.with_vertices(W)
        dec_route = congruence(dec.d0(moved), dec.hodge1(moved).diagonal(), pattern, plan)
        return jnp.stack([jnp.vdot(u, dec_route @ u), jnp.vdot(u, cotan_laplacian(moved) @ u)])

    jacobian = np.asarray(jax.jit(jax.jacrev(energies))(mesh.vertices))
    np.testing.assert_allclose(jacobian[0], jacobian[1], rtol=0, atol=1e-12 * np.abs(jacobian[1]).max())


@pytest.mark.parametrize("name", ["bob_small.ply", "small_disk.obj"])
def test_inverse_policy(name):
    ops = operators(name)
    for key in [k for k in ops if k.startswith("h") and "inv" not in k]:
        entries, inverse = ops[key], ops[key.replace(key.split()[0], key.split()[0] + "inv")]
        nonzero = entries != 0
        np.testing.assert_allclose(entries[nonzero] * inverse[nonzero], 1.0, rtol=1e-14, err_msg=key)
        assert np.all(inverse[~nonzero] == 0), key
    # Non-Delaunay edges have negative circumcentric weights, inverted as they are.
    assert np.any(operators("bob_small.ply")["h1inv circumcentric"] < 0)


def test_single_right_triangle_closed_forms():
    """Right isosceles triangle (0,0), (1,0), (0,1): every star entry by hand, and the inverse policy."""
    mesh = Mesh.from_arrays(np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]), np.array([[0, 1, 2]]))
    values = jax.jit(
        lambda m: {
            "h1": dec.hodge1(m, dual="circumcentric").diagonal(),
            "h1inv": dec.hodge1(m, dual="circumcentric", inverse=True).diagonal(),
            "h1 bary": dec.hodge1(m, dual="barycentric").diagonal(),
            "h0 bary": dec.hodge0(m, dual="barycentric").diagonal(),
            "h0": dec.hodge0(m, dual="circumcentric").diagonal(),
            "h0 voronoi": dec.hodge0(m).diagonal(),
            "h2": dec.hodge2(m).diagonal(),
            "h2inv": dec.hodge2(m, inverse=True).diagonal(),
        }
    )(mesh)
    # Edges (0,1), (0,2), (1,2): opposite angles 45, 45, 90 degrees; the zero weight inverts to 0.
    np.testing.assert_allclose(values["h1"], [0.5, 0.5, 0.0], atol=1e-16)
    np.testing.assert_allclose(values["h1inv"], [2.0, 2.0, 0.0], atol=1e-15)
    # Barycentre (1/3, 1/3) to the midpoints: sqrt(5)/6, sqrt(5)/6, sqrt(2)/6; lengths 1, 1, sqrt(2).
    np.testing.assert_allclose(values["h1 bary"], [np.sqrt(5) / 6, np.sqrt(5) / 6, 1 / 6], rtol=1e-15)
    np.testing.assert_allclose(values["h0 bary"], [1 / 6] * 3, rtol=1e-15)
    # Circumcentre at the hypotenuse midpoint: the right-angle corner gets 1/4, the others 1/8; the
    # mixed (Voronoi) rule counts a right angle as non-obtuse and agrees.
    np.testing.assert_allclose(values["h0"], [0.25, 0.125, 0.125], rtol=1e-15)
    np.testing.assert_allclose(values["h0 voronoi"], [0.25, 0.125, 0.125], rtol=1e-15)
    np.testing.assert_allclose(values["h2"], [2.0], rtol=1e-15)
    np.testing.assert_allclose(values["h2inv"], [0.5], rtol=1e-15)


@pytest.mark.slow
def test_degenerate_faces_give_finite_values_and_gradients():
    """One exactly collinear (zero-area) face and one needle: finite stars and finite gradients."""
    V = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0], [1, 1, 0], [1, 1e-9, 0]])
    mesh = Mesh.from_arrays(V, np.array([[0, 1, 3], [1, 2, 3], [0, 2, 1], [0, 4, 2]]))

    def stars(V):
        moved = mesh.with_vertices(V)
        # (*0 barycentric and *1 circumcentric are a third of the areas and the cotan weights, whose
        # degenerate cases the mesh tests cover.)
        values = [
            dec.hodge_star_entries(moved, degree=0, dual="circumcentric"),
            dec.hodge_star_entries(moved, degree=0, dual="voronoi"),
            dec.hodge_star_entries(moved, degree=1, dual="barycentric"),
            dec.hodge_star_entries(moved, degree=1, dual="barycentric", inverse=True),
            dec.hodge_star_entries(moved, degree=1, inverse=True),
        ]
        values += [dec.hodge_star_entries(moved, degree=2), dec.hodge_star_entries(moved, degree=2, inverse=True)]
        return jnp.concatenate(values)

    values, pullback = jax.vjp(jax.jit(stars), mesh.vertices)
    weights = jnp.asarray(np.random.default_rng(4).standard_normal(values.shape[0]))
    assert np.all(np.isfinite(np.asarray(values)))
    assert np.all(np.isfinite(np.asarray(pullback(weights)[0])))
    # *2 of the zero-area face 2 and its inverse (the last 2 x 4 entries): zero, the pseudo-inverse.
    assert float(values[-6]) == 0.0 and float(values[-2]) == 0.0


@pytest.mark.slow
def test_jit_vmap_grad_over_vertex_positions():
    mesh = load("tet.obj")
    scales = jnp.asarray([1.0, 2.0, 0.5])[:, None, None]

    def stars(V):
        moved = mesh.with_vertices(V)
        h1 = dec.hodge1(moved, dual="barycentric").diagonal()
        return dec.hodge0(moved).diagonal(), h1, dec.hodge2(moved).diagonal()

    h0, h1, h2 = jax.jit(jax.vmap(stars))(mesh.vertices[None] * scales)
    eager = jax.jit(stars)(mesh.vertices)
    for batched, single in zip((h0, h1, h2), eager, strict=True):
        np.testing.assert_allclose(batched[0], single, rtol=1e-15)
    # *1 is scale-invariant, *0 scales with the square of lengths, *2 with the inverse square.
    np.testing.assert_allclose(h1[1], h1[0], rtol=1e-14)
    np.testing.assert_allclose(h0[2], 0.25 * h0[0], rtol=1e-14)
    np.testing.assert_allclose(h2[1], 0.25 * h2[0], rtol=1e-14)
    w = jnp.asarray(np.random.default_rng(5).standard_normal(mesh.n_edges))
    perturbed = mesh.vertices + 0.1 * jnp.sqrt(jnp.arange(12.0).reshape(4, 3))
    # check_grads' float64 defaults (central differences with eps=1e-4, atol = rtol = 1e-5): the
    # truncation error of the finite difference is O(eps^2) ~ 1e-8 relative, so no finite-difference
    # check can confirm a gradient to 1e-10; 1e-5 still catches any wrong term.
    jax.test_util.check_grads(
        jax.jit(lambda V: jnp.sum(w * dec.hodge1(mesh.with_vertices(V), dual="barycentric").diagonal())),
        (perturbed,),
        order=1,
        modes=("rev",),
    )
