"""The vocabulary of ddgjax's public API, as data: one name per concept, its values, its one default.

docs/conventions.md's "Arguments" table is generated from `TERMS` (`python -m ddgjax._vocabulary`
rewrites it; a test fails when the page is stale), and tests/test_signatures.py walks every public
signature against these rules:

- a parameter never takes a name listed as a synonym of a term (`n_eigenpairs` for `k`, `seed` for `key`);
- options (parameters with a default) are keyword-only, except those in `POSITIONAL_WITH_DEFAULT`;
- a single math letter (`A`, `b`, `u`, `L`) is positional-only (`linear_solve(A, b, /, *, ...)`), except
  `LETTERS_BY_KEYWORD` (`k`, `n`, `t`: counts and times users name);
- every function with a term's parameter uses the term's default, except those in `DEFAULT_EXCEPTIONS`.

Each exception says why in its entry. The vocabulary is DESIGN.md's ("Conventions"); an issue that
names a concept otherwise defers to it.
"""

from __future__ import annotations

from typing import NamedTuple


class _NoDefault:
    """A term whose default belongs to each function (a tolerance, a count): namesakes may differ."""

    def __repr__(self) -> str:
        return "per function"


PER_FUNCTION = _NoDefault()


class Term(NamedTuple):
    """One row of the conventions table.

    Attributes:
        concept: what the parameter means.
        parameters: the parameter names this row governs (checked).
        spelled: how the table shows them (markdown).
        values: its values or shape (markdown).
        where: the functions that take it (markdown).
        synonyms: names refused for this concept anywhere in the public API.
        default: the default every function with one of `parameters` uses, or `PER_FUNCTION`.
    """

    concept: str
    parameters: tuple[str, ...]
    spelled: str
    values: str
    where: str
    synonyms: tuple[str, ...] = ()
    default: object = PER_FUNCTION


TERMS: tuple[Term, ...] = (
    Term(
        "the mesh or curve a function works on",
        ("mesh", "curve", "tet_mesh"),
        "`mesh`, `curve`, `tet_mesh` (first, positional)",
        "`ddgjax.Mesh`, `ddgjax.Curve`, `ddgjax.volume.TetMesh` (`ddgjax.volume`'s own functions name it `tet_mesh`; the problem "
        "layer's `mesh` takes either kind: `solve_poisson`, `harmonic_interpolation`, `eigenpairs`, `heat_distance`)",
        "everywhere, except where a callable is minimised: `minimize_shape(loss, mesh, ...)` follows SciPy's and optimistix's "
        "`minimise(fn, y0)`, and `save_mesh(path, mesh)` follows `numpy.save(file, arr)` and libigl",
        synonyms=("surface", "polyline", "tetmesh", "tets_mesh"),
    ),
    Term(
        "constrained vertices (Dirichlet data, pins, handles, anchors)",
        ("fixed_vertices",),
        "`fixed_vertices=`",
        "`(n_fixed,)` distinct vertex indices (host data)",
        "`solve_poisson`, `harmonic_interpolation` (meshes and `ddgjax.graph`), `tutte_layout`, `lscm`, `interpolate_field`, "
        "`large_steps`, `minimize_shape`, `minimize_energy`, `biharmonic_deformation`, `arap`",
        synonyms=(
            "boundary_vertices",
            "pinned",
            "pinned_vertices",
            "handles",
            "handle_vertices",
            "anchors",
            "constrained_vertices",
            "b_vertices",
        ),
    ),
    Term(
        "their values",
        ("fixed_values",),
        "`fixed_values=`",
        "`(n_fixed,)`, `(n_fixed, k)`",
        "the same",
        synonyms=("boundary_values", "boundary_positions", "pinned_values", "handle_positions", "bc", "constrained_values"),
    ),
    Term(
        "a time step",
        ("tau",),
        "`tau=`",
        "a positive number",
        "`curve_shortening_flow`, `mean_curvature_flow`, `euler_flow`",
        synonyms=("dt", "time_step", "step_size", "h"),
    ),
    Term(
        "a fluid's frame rotation and viscosity",
        ("rotation", "viscosity"),
        "`rotation=`, `viscosity=`",
        "`Omega` about +z (Coriolis parameter `2 Omega z`); kinematic viscosity `nu >= 0`",
        "`euler_flow`",
        synonyms=("omega_frame", "nu"),
        default=0.0,
    ),
    Term(
        "the heat methods' diffusion time",
        ("t_coef",),
        "`t_coef=`",
        "a positive number: the time in units of the squared mean edge length (1, as the papers and potpourri3d)",
        "`heat_distance`, `vector_heat_solver`, `parallel_transport`, `log_map`, `signed_heat_distance`, "
        "`point_cloud_heat_distance`",
        synonyms=("t_factor", "time_factor"),
        default=1.0,
    ),
    Term(
        "the number of steps, the saving stride",
        ("steps", "save_every"),
        "`steps=`, `save_every=`",
        "integers",
        "every flow and optimisation loop",
        synonyms=("n_steps", "num_steps", "iterations", "n_iterations", "nit"),
    ),
    Term(
        "the mass matrix",
        ("mass",),
        "`mass=`",
        '`ddgjax.MASS_MATRICES`: `"voronoi"` (mixed Voronoi, libigl\'s default, the default), `"barycentric"`, `"galerkin"` '
        "(full FEM); an operator that divides by vertex areas accepts `ddgjax.LUMPED_MASS_MATRICES` and refuses "
        '`"galerkin"` naming them',
        "`mass_matrix`, `laplacian_and_mass`, `solve_poisson`, `poisson_energy`, `screened_dirichlet_energy`, "
        "`mean_curvature_flow`, `eigenpairs`, `diffusion_operators`, `ddgjax.batch.lumped_mass` / `mass_apply`, "
        "`heat_distance`, `vector_heat_solver`, `signed_heat_distance`, `connection_mass_matrix`, "
        "`smoothest_field`, `intrinsic_delaunay_mass_matrix`, `sharded_cg`, `biharmonic_deformation`, `fluid_basis`",
        synonyms=("mass_type", "mass_matrix_type", "lumping"),
        default="voronoi",
    ),
    Term(
        "the dual cell of DEC and of pointwise quantities",
        ("dual",),
        "`dual=`",
        '`ddgjax.DUAL_CELLS`: `"voronoi"`, `"circumcentric"`, `"barycentric"` (on tets: libigl\'s hybrid Voronoi cells, true '
        "circumcentric cells, centroids)",
        "`vertex_dual_areas`, `ddgjax.volume.vertex_dual_volumes`, Hodge stars of surfaces and tet meshes, pointwise "
        "curvatures, `willmore_energy`, `hodge_decomposition`",
        synonyms=("dual_cell", "dual_type"),
        default="voronoi",
    ),
    Term(
        "uniform or cotan edge weights",
        ("weights",),
        "`weights=`",
        '`ddgjax.LAPLACIAN_WEIGHTS`: `"uniform"`, `"cotan"` (nothing else: per-element weights have names of their own, '
        "`edge_weights=`, `source_weights=`)",
        "`tutte_embedding`, `large_steps`, `minimize_shape`, `laplacian_smoothing_loss`",
        synonyms=("weight_type", "laplacian_weights"),
        default="uniform",
    ),
    Term(
        "the boundary condition",
        ("boundary",),
        "`boundary=`",
        '`ddgjax.BOUNDARY_CONDITIONS`: `"neumann"`, `"dirichlet"` (the heat method adds `"average"`, its default)',
        "`eigenpairs`, `heat_distance`, `heat_distance_solver`",
        synonyms=("boundary_condition", "bc_type"),
        default="neumann",
    ),
    Term(
        "the target shape of a flattening's boundary",
        ("shape",),
        "`shape=`",
        '`"circle"` (the unit circle), `"square"`, `"rectangle"` (BFF), explicit `(nb, 2)` positions',
        "`tutte_embedding`, `harmonic_map`, `boundary_first_flattening`",
        synonyms=("boundary_shape", "target_shape"),
    ),
    Term(
        "how the connection treats boundary vertices",
        ("boundary_scaling",),
        "`boundary_scaling=`",
        '`"geodesic"` (angle sums rescaled to pi), `"unscaled"`',
        "`ddgjax.fields`",
        default="geodesic",
    ),
    Term(
        "the algorithm of this function",
        ("method",),
        "`method=`",
        'per function (`"explicit"` / `"implicit"` flows, `"arpack"` / `"subspace"` eigensolvers, `"kdtree"` / `"brute"` '
        "nearest neighbours); never the linear-solve backend (`solver=`)",
        "where there is a choice of algorithm",
        synonyms=("algorithm", "algo", "mode"),
    ),
    Term(
        "the backend of the sparse linear solves",
        ("solver",),
        "`solver=`",
        '`ddgjax.LINEAR_SOLVERS`: `"auto"`, `"cholesky"`, `"superlu"`, `"cg"`, `"pyamg"`',
        "`linear_solve`, `factorize` and every problem-level function that solves (`solve_poisson`, `eigenpairs`, "
        "`heat_distance`, `vector_heat_solver`, `signed_heat_distance`, `point_cloud_heat_distance`, the parametrisations, "
        "the fields, `mean_curvature_flow`, `large_steps`, ...)",
        synonyms=("backend", "linear_solver", "solver_method"),
        default="auto",
    ),
    Term(
        "the intrinsic Delaunay operators",
        ("robust",),
        "`robust=`",
        "`False`, `True` (mollified: `intrinsic_delaunay(mesh, mollify_factor=1e-5)`; on a non-manifold or non-oriented "
        "mesh its tufted cover, halved, as robust_laplacian), or an `IntrinsicTriangulation`",
        "`laplacian_and_mass`, `solve_poisson`, `harmonic_interpolation`, `eigenpairs`, `heat_distance`, "
        "`vector_heat_solver`, `signed_heat_distance`, `diffusion_operators` (default `True` there: learning datasets hold "
        "bad meshes, and DiffusionNet uses robust_laplacian's operators)",
        synonyms=("intrinsic", "intrinsic_delaunay", "use_intrinsic"),
        default=False,
    ),
    Term(
        "intrinsic mollification",
        ("mollify_factor",),
        "`mollify_factor=`",
        "a nonnegative number, in units of the mean edge length (robust_laplacian's default `1e-5`; `0` turns it off)",
        "`intrinsic_delaunay` and the point-cloud triangulations",
        synonyms=("mollify", "mollification"),
        default=1e-5,
    ),
    Term(
        "the neighbourhood of each point of a cloud",
        ("n_neighbors",),
        "`n_neighbors=`",
        "integer (30 in `ddgjax.pointcloud`, robust_laplacian's and potpourri3d's default; 10 in `knn_graph`, scikit-learn's)",
        "`ddgjax.pointcloud`, `ddgjax.graph.knn_graph`",
        synonyms=("k_neighbors", "n_neighbours", "num_neighbors", "knn"),
        default=30,
    ),
    Term(
        "a graph's edges, their weights and its vertex count",
        ("edge_weights",),
        "`edges` (positional), `edge_weights=`, `n_vertices=`",
        "`(ne, 2)` host integers; `(ne,)` nonnegative floats, differentiable (default ones); an integer",
        "`ddgjax.graph`; `edge_weights=` also in `planned_connection_laplacian`",
        synonyms=("edge_weight_values",),
        default=None,
    ),
    Term(
        "the number of eigenpairs",
        ("k", "k_source", "k_target", "k_final"),
        "`k` (positional where it is required; `k=` where it has a default; `k_source=`, `k_target=` for a functional "
        "map's two sides, `k_final=` for a refinement's last size)",
        "integer",
        "`eigenpairs`, `smallest_eigenpairs`, `diffusion_operators`, `spectral_shape`, `descriptors`, `functional_map`, "
        "`match_shapes`, `zoomout_refine`, `fluid_basis`, `euler_flow`",
        synonyms=("n_eigenpairs", "n_eigs", "num_eigs", "n_eigenvalues", "num_eigenvalues", "n_modes", "num_modes", "k_eig"),
    ),
    Term(
        "the weight of a functional map's orientation term",
        ("orientation_weight",),
        "`orientation_weight=`",
        "a number `>= 0` (pyFM's `w_orient`, 0 there; 1 here: without it a symmetric pair's map may come out mirrored)",
        "`functional_map`, `match_shapes`",
        synonyms=("w_orient",),
        default=1.0,
    ),
    Term(
        "a polyharmonic order",
        ("order",),
        "`order=`",
        "a positive integer (1 harmonic, 2 biharmonic, 3 triharmonic)",
        "`biharmonic_deformation`",
        synonyms=("polyharmonic_order",),
        default=2,
    ),
    Term(
        "an iteration's limits",
        ("max_steps", "rtol"),
        "`max_steps=`, `rtol=`",
        "an integer; a relative tolerance (each function says of what)",
        '`linear_solve`, `factorize` (`"cg"`, `"pyamg"`), `arap`, `functional_map` (`"cg"`), `icp_refine`, '
        "`euler_flow` (Newton steps per time step), "
        "`geodesic_centroid` (`max_steps=` only: its walk over vertices ends exactly)",
        synonyms=("max_iter", "maxiter", "max_iters", "max_iterations", "tol", "tolerance", "rel_tol"),
    ),
    Term(
        "what a failure does",
        ("throw",),
        "`throw=`",
        "`True` (default: raise) or `False` (return the outcome)",
        "every computation that can fail",
        synonyms=("raise_on_failure", "check", "strict"),
        default=True,
    ),
    Term(
        "a progress bar",
        ("progress",),
        "`progress=`",
        "`bool`, off by default (the command line turns it on)",
        "long loops (flows, optimisation, datasets: `diffusion_operators_of_meshes`)",
        synonyms=("verbose", "show_progress", "progress_bar", "tqdm"),
        default=False,
    ),
    Term(
        "randomness",
        ("key",),
        "`key=`",
        "a JAX PRNG key (`jax.random.key(0)`), or an integer seed where the sampling runs on the host",
        "`sample_points`, `minimize_shape`, `random_polygon`, `geodesic_error`",
        synonyms=("seed", "rng", "random_state", "prng_key", "rng_key"),
    ),
    Term(
        "where per-element values live",
        ("at",),
        "`at=`",
        '`"vertices"`, `"faces"`',
        "`ddgjax.dec.flat` / `sharp`, `field_to_vectors`, `stream_function_velocity`, `ddgjax.batch.unpad`",
        synonyms=("location", "on"),
    ),
    Term(
        "the padded sizes of a batch of meshes",
        ("n_vertices", "n_faces", "degree"),
        "`n_vertices=`, `n_faces=` (`degree=` for neighbour tables)",
        "integers, at least the largest mesh's; default `ddgjax.batch.bucket(largest)`",
        "`MeshBatch.from_meshes`, `pad_vertex_values`, `stack_diffusion_operators`",
        synonyms=("nv", "nf", "num_vertices", "num_faces"),
    ),
    Term(
        "a folder for results cached on disk by content",
        ("cache_dir",),
        "`cache_dir=`",
        "a path, or `None` (no cache, the default)",
        "`diffusion_operators`, `diffusion_operators_of_meshes`",
        synonyms=("cache", "cache_path", "cache_folder"),
        default=None,
    ),
    Term(
        "the element type of built-in shapes",
        ("dtype",),
        "`dtype=`",
        "a floating dtype",
        "`ddgjax.mesh` and `ddgjax.curves` shapes",
        default=None,
    ),
)

#: Single letters a caller may pass by keyword: counts and times users name (`k=20`, `n=100`, `t=0.1`).
LETTERS_BY_KEYWORD = frozenset({"k", "n", "t"})

#: Options (parameters with a default) that may be passed by position, and why.
POSITIONAL_WITH_DEFAULT: dict[str, str] = {
    "ddgjax.mesh.icosphere": "a built-in shape's resolution, positional as in trimesh.creation.icosphere(subdivisions)",
    "ddgjax.mesh.uv_sphere": "a built-in shape's resolution (trimesh.creation.uv_sphere(count))",
    "ddgjax.mesh.cylinder": "a built-in shape's resolution",
    "ddgjax.mesh.disk": "a built-in shape's resolution",
    "ddgjax.mesh.grid": "a built-in shape's resolution",
    "ddgjax.volume.tet_ball": "a built-in shape's resolution",
    "ddgjax.volume.tet_box": "a built-in shape's resolution",
    "ddgjax.volume.tet_shell": "a built-in shape's resolution",
    "ddgjax.curves.flower": "a built-in shape's resolution",
    "ddgjax.curves.star": "a built-in shape's number of tips",
    "ddgjax.curves.CurveFlowResult.curve": "an index into the run's history, as a sequence is indexed",
    "ddgjax.pde.MeanCurvatureFlowResult.mesh": "an index into the run's history, as a sequence is indexed",
    "ddgjax.optim.scale_by_adam_uniform": "optax.scale_by_adam's signature (b1, b2, eps), so the two are interchangeable",
    "ddgjax.plot.polyline": "the drawn curve's closedness, as ddgjax.Curve(points, closed)",
    "ddgjax.plot.show": "the values drawn on the mesh, as plt.plot(x, y)",
    "ddgjax.sharding.shard_batch": "the sharding to place on, as jax.device_put(x, sharding)",
}

#: Functions whose default for a term's parameter differs from the term's, and why (`"function:parameter"`).
DEFAULT_EXCEPTIONS: dict[str, str] = {
    "ddgjax.geodesics.heat_distance:boundary": 'the heat method\'s own condition, "average" (Crane et al. 2017, section 3.2.2)',
    "ddgjax.geodesics.heat_distance_solver:boundary": 'the heat method\'s own condition, "average" (Crane et al. 2017)',
    "ddgjax.learn.diffusion_operators:robust": "learning datasets hold bad meshes; DiffusionNet uses robust_laplacian's operators",
    "ddgjax.learn.diffusion_operators_of_meshes:robust": "as diffusion_operators",
    "ddgjax.graph.knn_graph:n_neighbors": "scikit-learn's kneighbors_graph default (a graph, not a surface patch)",
}


def conventions_table() -> str:
    """The "Arguments" table of docs/conventions.md, in markdown."""
    rows = ["| concept | name | values / shape | where |", "|---|---|---|---|"]
    rows += [f"| {term.concept} | {term.spelled} | {term.values} | {term.where} |" for term in TERMS]
    return "\n".join(rows) + "\n"


TABLE_START = "<!-- vocabulary: generated from ddgjax/_vocabulary.py by `python -m ddgjax._vocabulary`; edit it there -->\n"
TABLE_END = "<!-- end of vocabulary -->\n"


def with_table(page: str) -> str:
    """`page` (docs/conventions.md) with the text between the vocabulary markers replaced by `conventions_table()`."""
    start, end = page.index(TABLE_START) + len(TABLE_START), page.index(TABLE_END)
    return page[:start] + conventions_table() + page[end:]


if __name__ == "__main__":
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "docs" / "conventions.md"
    path.write_text(with_table(path.read_text()))
    print(f"wrote the vocabulary table of {path}")
