"""Geodesic distance by the heat method (Crane, Weischedel & Wardetzky 2013), differentiable.

Three steps on a triangle mesh, with `L` the PSD cotan Laplacian and `M` a mass matrix:

1. heat flow for a short time `t = t_coef * h^2` (`h` the mean edge length), one backward-Euler
   step from the sources: `(M + t L) u = delta` (`delta` the sources' hat-function weights: 1 at a
   source vertex, the barycentric coordinates of a source point inside a face);
2. the normalised negative gradient per face, `X = -grad u / |grad u|`, the direction of growing
   distance (0 where `grad u` vanishes, so nothing divides by zero);
3. the Poisson problem `L phi = -div X` (`div` the integrated divergence, `ddgjax.dec.divergence`:
   the weak form holds the natural Neumann condition, and `div X` sums to zero on each connected
   component, so the system is compatible), solved with one vertex pinned per component;
4. `phi` is defined up to one constant per connected component: each component that holds a source
   is shifted so that its smallest value is 0 (so no distance is negative; with one source vertex
   that is the source), or, when that is lower, so that the sources sit at 0 (the mean over its
   source points of `phi` at their face's corners less the corners' straight-line distance from the
   point, as geometry-central shifts); every vertex of a component without a source, and every
   unreferenced vertex, is at distance `inf` (unreachable).

On a mesh with boundary, step 1 takes the average of the Neumann solution and the Dirichlet one
(`u = 0` on the boundary), as the paper recommends against distances that bend towards the boundary
(`boundary="average"`, default; `"neumann"` or `"dirichlet"` for one of the two). On a mesh whose
vertices all lie on the boundary (a strip, a single triangle) the Dirichlet heat is zero, so
`"average"` is the Neumann flow alone there and `"dirichlet"` is refused. Unreferenced vertices are
held at `u = 0` and `phi = 0` (they belong to no face). The result approximates the geodesic
distance to first order in `h` (the smoothing by `t ~ h^2` is part of the method).

In a solid (`ddgjax.volume.TetMesh`, the paper's volumetric case) the same steps run on tets: `L`
and `M` of `ddgjax.volume`, `X` per tet from the hat-function gradients (`tet_hat_gradients`), the
integrated divergence `-sum_t V_t grad phi_i . X_t` (so `div grad u = -L u`, as on faces), `h` the
mean edge length of the tet mesh and the boundary the boundary surface's vertices; the distance
approximates the Euclidean one in a convex solid (the distance inside the solid in general). Sources
are vertices there (no points inside tets).

`HeatDistanceSolver` keeps the factorisations of `M + t L` (and of its Dirichlet block) and of the
pinned `L`, and the component of each vertex, so each query is three sparse solves and two sweeps over the faces;
`heat_distance(mesh, sources)` builds one and queries it, differentiably in the vertex positions
(every step is a JAX function of them and the solves differentiate implicitly). Eagerly it runs one
compiled program for the matrices, factors them outside every program (so each program can be kept
across processes: `ddgjax._program_store`) and one for the query. Each solve reports its outcome (`ddgjax.RESULTS`); a query's `result` is the first failing
solve's (heat flow, its Dirichlet half, Poisson), and `throw=False` returns a `ddgjax.Solution` whose
`stats` hold the largest relative residual of the solves and their total CG iterations.

References: K. Crane, C. Weischedel, M. Wardetzky, "Geodesics in heat: a new approach to computing
distance based on heat flow", ACM TOG 32(5) (2013), and "The heat method for distance computation",
CACM 60(11) (2017). potpourri3d: `MeshHeatMethodDistanceSolver(V, F, t_coef).compute_distance(v)`;
libigl: `igl.heat_geodesics_precompute` / `igl.heat_geodesics_solve`.
"""

from __future__ import annotations

import functools
import weakref

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int

from .._compile import at_top_level, kernel
from .._errors import DDGInputError, check_choice, first_indices
from .._indexing import take_rows
from .._numerics import safe_norm
from .._options import BOUNDARY_CONDITIONS, check_solver
from .._results import RESULTS, Solution, first_failure, outcome
from ..discretization import discretize
from ..discretization.internal import DirichletData, cell_measure_gradients, cells, domain_edge_lengths, require_domain
from ..laplacian import IntrinsicTriangulation
from ..mesh import (
    Mesh,
    MeshTopology,
)
from ..solve import Factorization, LinearSolution, factorize
from ..solve.internal import cholmod_analysis, kept_analysis
from ..sparse import DirichletPlan, SparseMatrix, SparsityPattern, dirichlet_blocks, dirichlet_plan
from ..volume import TetMesh, TetTopology

HEAT_BOUNDARY_CONDITIONS = ("average", *BOUNDARY_CONDITIONS)
"""`boundary=` of the heat method: `BOUNDARY_CONDITIONS` and their mean, `"average"` (module docstring)."""


class HeatMethodSteps(eqx.Module):
    """The heat method's intermediate quantities (module docstring), from `HeatDistanceSolver.steps`.

    Attributes:
        heat: `(nv,)` `u`, the heat after time `t`.
        field: `(nf, 3)` `X = -grad u / |grad u|` per face (`(nt, 3)` per tet on a `TetMesh`). With
            `robust=`, `(nf, 2)` per face of the intrinsic triangulation, in that face's planar layout
            (corner 0 at the origin, corner 1 on the x axis: `ddgjax.discretization.internal.intrinsic_measure_gradients`).
        divergence: `(nv,)` the integrated divergence of `X` (`ddgjax.dec.divergence`; the DDG
            exercises' `div` is its negative).
        distance: `(nv,)` `phi` shifted per connected component (module docstring, step 4): `>= 0`,
            `inf` where no source reaches.
    """

    heat: Float[Array, " nv"]
    field: Float[Array, "nc d"]
    divergence: Float[Array, " nv"]
    distance: Float[Array, " nv"]


class HeatDistanceSolver(eqx.Module):
    """The heat method's kept factorisations for one mesh: `solver.distance(sources)` per query (module docstring).

    Made by `heat_distance_solver(mesh, ...)`; a pytree, so it passes into `jit` (and its queries
    `vmap` over sources of one shape).

    Attributes:
        mesh: the mesh (a triangle mesh or a `TetMesh`).
        t: the heat flow's time `t_coef * h^2`.
        factors: the kept factorisations and per-cell data its queries read (`HeatFactors`).
    """

    mesh: Mesh | TetMesh
    t: Float[Array, ""]
    factors: HeatFactors

    @property
    def n_pinned(self) -> int:
        """The number of vertices the Poisson solve pins (one per connected component, and unreferenced ones)."""
        return self.factors.poisson_plan.fixed.shape[0]

    def distance(self, sources, *, throw: bool = True) -> Float[Array, " nv"] | Solution:
        """Geodesic distance from the sources to every vertex, `(nv,)`: `>= 0`, `inf` where no source reaches.

        Args:
            sources: vertex indices, `(m,)` integers (or one integer); or points inside faces, a pair
                `(faces (m,), barycentric (m, 3))` (the barycentric coordinates of each point in its
                face, in the face's vertex order, summing to 1; triangle meshes only).
            throw: raise when a solve fails (default), or return a `ddgjax.Solution` (module docstring).
        """
        return self._run(sources, throw, lambda steps: steps.distance)

    def steps(self, sources, *, throw: bool = True) -> HeatMethodSteps | Solution:
        """The distance and the intermediate quantities that lead to it (`HeatMethodSteps`); arguments as `distance`."""
        return self._run(sources, throw, lambda steps: steps)

    def _run(self, sources, throw: bool, pick):
        # Only the Dirichlet heat flow is kept exactly when `boundary="dirichlet"` on a mesh with boundary.
        corners, weights = _sources(self.mesh, sources, dirichlet=self.factors.heat is None)
        steps, result, stats = _query(self.mesh, self.factors, corners, weights)
        return outcome(pick(steps), result, throw, stats)


class HeatFactors(eqx.Module):
    """The heat method's kept factorisations and per-cell data: what a query reads besides the mesh.

    Shared by `HeatDistanceSolver` and the vector heat method's solver (`ddgjax.geodesics.VectorHeatSolver`),
    which nest it.

    Attributes:
        heat: factorisation of `M + t L` for the Neumann heat flow (of its free-free block, with the
            unreferenced vertices held at 0, when there are any); `None` with `boundary="dirichlet"`
            on a mesh with boundary.
        heat_plan: the unreferenced vertices' `DirichletPlan` for `heat`, else `None`.
        heat_dirichlet: factorisation of the free-free block of `M + t L` with the boundary (and
            unreferenced) vertices held at 0 (`boundary="average"` or `"dirichlet"` on a mesh with
            boundary and at least one interior vertex), else `None`.
        heat_dirichlet_plan: its `DirichletPlan`, else `None`.
        poisson: factorisation of `L` with one vertex per component pinned (its free-free block).
        poisson_plan: the pins' `DirichletPlan`.
        components: `(nv,)` the connected component of each vertex (the unreferenced vertices share
            one label past those of the faces' components).
        cells: `(nc, k)` the cells the field lives on: the mesh's faces, the intrinsic triangulation's
            faces with `robust=`, a `TetMesh`'s tets.
        area_gradients: `(nf, 3, 3)` each face's area times the gradient of each corner's hat
            function, `A_f grad phi_k` (`ddgjax.mesh.face_hat_gradients`): a query's two sweeps over
            the faces, the field `X` and its divergence `-sum_f A_f grad phi_i . X_f`, read only these.
            With `robust=`, `(nf, 3, 2)` on the intrinsic faces, each in its own planar layout, from
            their lengths alone (`ddgjax.discretization.internal.cell_measure_gradients`). On a
            `TetMesh` `(nt, 4, 3)`, `V_t grad phi_k` (`ddgjax.volume.tet_hat_gradients`).
    """

    # Factorisations; the vector heat solver's assembly holds the matrices for a moment before factoring them.
    heat: Factorization | SparseMatrix | None
    heat_plan: DirichletPlan | None
    heat_dirichlet: Factorization | SparseMatrix | None
    heat_dirichlet_plan: DirichletPlan | None
    poisson: Factorization | SparseMatrix
    poisson_plan: DirichletPlan
    components: Int[Array, " nv"]
    cells: Int[Array, "nc k"]
    area_gradients: Float[Array, "nc k d"]


class _Plans(eqx.Module):
    """The host data of the heat method for one triangulation: the held vertices of the Neumann heat
    flow (the unreferenced ones; `None` without any) and of the Dirichlet one (`None` when it is not
    run), whether the Neumann flow is run, the Poisson solve's pins and the vertices' components."""

    heat: DirichletPlan | None
    heat_dirichlet: DirichletPlan | None
    poisson: DirichletPlan
    components: Int[Array, " nv"]
    neumann: bool = eqx.field(static=True)


_PLANS: "weakref.WeakKeyDictionary[MeshTopology | TetTopology, dict]" = weakref.WeakKeyDictionary()


def _plans(mesh: Mesh | TetMesh, boundary: str, pattern: SparsityPattern, cached: bool) -> _Plans:
    """`_Plans` on the Laplacian's `pattern`: the mesh's own (`cached` per connectivity) or its intrinsic
    triangulation's (the same vertices and components, so the mesh's pins serve it too)."""
    if not cached:
        return _build_plans(mesh, boundary, pattern)
    cache = _PLANS.setdefault(mesh.topology, {})
    if boundary not in cache:
        cache[boundary] = _build_plans(mesh, boundary, pattern)
    return cache[boundary]


def _build_plans(mesh: Mesh | TetMesh, boundary: str, pattern: SparsityPattern) -> _Plans:
    topology = mesh.topology
    unreferenced = topology.unreferenced_vertices
    # The Dirichlet heat flow holds u = 0 on the boundary and on the vertices of no face.
    held = np.union1d(topology.boundary_vertices, unreferenced)
    dirichlet = boundary != "neumann" and topology.boundary_vertices.size > 0
    if dirichlet and held.size == mesh.n_vertices:
        if boundary == "dirichlet":
            raise DDGInputError(
                f'boundary: "dirichlet" holds the heat at 0 on the boundary, and all {mesh.n_vertices} vertices of '
                "this mesh lie on its boundary (or in no face: a strip, a single triangle), so the heat would be 0 "
                'everywhere; use boundary="average" (the default) or "neumann"'
            )
        dirichlet = False  # "average": the Dirichlet heat is 0, so the Neumann flow alone gives the same field
    with jax.ensure_compile_time_eval():  # host data even when a caller's jit traces this call (it is cached)
        pins = DirichletData(mesh, None, None, (), pattern)  # one pinned vertex per component (and unreferenced ones)
        return _Plans(
            heat=dirichlet_plan(pattern, unreferenced) if unreferenced.size else None,
            heat_dirichlet=dirichlet_plan(pattern, held) if dirichlet else None,
            poisson=dirichlet_plan(pattern, pins.fixed),
            components=pins.labels,
            neumann=not (dirichlet and boundary == "dirichlet"),
        )


def check_t_coef(t_coef) -> float:
    """`t_coef` (the heat methods' time in units of `h^2`) as a float if it is a positive host number, else `DDGInputError`."""
    if isinstance(t_coef, bool) or not isinstance(t_coef, (int, float, np.integer, np.floating)) or not t_coef > 0:
        raise DDGInputError(f"t_coef: expected a positive number, got {t_coef!r}")
    return float(t_coef)


def _operators(mesh: Mesh | TetMesh, t_coef, mass: str, boundary: str, robust, solver: str):
    """Checked options, then `(L, M, plans, t_coef, triangulation)`: what the kernels below take (host work and
    plans here; `triangulation` the intrinsic one with `robust=`, else `None`)."""
    check_choice("boundary", boundary, HEAT_BOUNDARY_CONDITIONS)
    check_solver(solver)
    check_t_coef(t_coef)
    discretization = discretize(mesh, mass=mass, robust=robust, caller="heat_distance")
    L, M = discretization.laplacian, discretization.mass
    plans = _plans(mesh, boundary, discretization.pattern, cached=discretization.triangulation is None)
    t_coef = jax.device_put(np.asarray(float(t_coef), L.values.dtype))
    return L, M, plans, t_coef, discretization.triangulation


def heat_distance_solver(
    mesh: Mesh | TetMesh,
    *,
    t_coef: float = 1.0,
    mass: str = "voronoi",
    boundary: str = "average",
    robust: bool | IntrinsicTriangulation = False,
    solver: str = "auto",
) -> HeatDistanceSolver:
    r"""Factor the heat method's systems for `mesh` once (module docstring); query with `.distance(sources)`.

    $$(M + tL)\, u = \delta, \qquad X = -\frac{\nabla u}{\lVert \nabla u \rVert}, \qquad L\phi = -\nabla \cdot X$$

    Args:
        mesh: a triangle mesh (several components, boundaries, any genus, unreferenced vertices), or a
            `ddgjax.volume.TetMesh` (module docstring).
        t_coef: the heat flow's time in units of the squared mean edge length (1 in the paper).
        mass: the mass matrix `M`: `"voronoi"` (default), `"barycentric"` or `"galerkin"`.
        boundary: the heat flow's boundary condition on a mesh with boundary: `"average"` (default:
            the mean of the Neumann and Dirichlet heat flows), `"neumann"` or `"dirichlet"` (refused
            on a mesh with no interior vertex, and its queries refuse sources on the boundary).
        robust: the intrinsic Delaunay Laplacian and mass instead of the mesh's (`True`, or an
            `IntrinsicTriangulation` inside `jit`; `ddgjax.laplacian.laplacian_and_mass`): accurate on
            meshes with obtuse triangles, as potpourri3d's default `use_robust=True`. Triangle meshes
            only (a `TetMesh` takes `False`).
        solver: the backend of the kept factorisations (`ddgjax.LINEAR_SOLVERS`, `ddgjax.solve.factorize`).

    Returns:
        `HeatDistanceSolver`; its queries take `throw=`.

    potpourri3d: `MeshHeatMethodDistanceSolver(V, F, t_coef=1.0)` (defaults compared in `heat_distance`);
    libigl: `igl.heat_geodesics_precompute(V, F, t, data)`.

    Examples:
        >>> import ddgjax
        >>> solver = ddgjax.geodesics.heat_distance_solver(ddgjax.mesh.icosphere(3))
        >>> from_one = solver.distance(0)
        >>> from_two = solver.distance([0, 100])  # the factorisations are reused
        >>> round(float(from_one.max()), 1), bool(from_two.max() < from_one.max())
        (3.1, True)
    """
    mesh = require_domain("mesh", mesh)
    L, M, plans, t_coef, triangulation = _operators(mesh, t_coef, mass, boundary, robust, solver)
    with cholmod_analysis(kept_analysis(mesh.n_vertices)):  # kept for many queries: the faster solves
        t, factors = _factorizations(mesh, L, M, plans, t_coef, triangulation, solver)
        if at_top_level():
            jax.block_until_ready(factors)  # the factorisations run in the block
    return HeatDistanceSolver(mesh=mesh, t=t, factors=factors)


def heat_distance(
    mesh: Mesh | TetMesh,
    sources,
    *,
    t_coef: float = 1.0,
    mass: str = "voronoi",
    boundary: str = "average",
    robust: bool | IntrinsicTriangulation = False,
    solver: str = "auto",
    throw: bool = True,
) -> Float[Array, " nv"] | Solution:
    r"""Geodesic distance from `sources` to every vertex by the heat method (Crane, Weischedel & Wardetzky 2013), `(nv,)`.

    With `L` the PSD cotan Laplacian, `M` the mass matrix and `h` the mean edge length:

    $$(M + tL)\, u = \delta, \qquad X = -\frac{\nabla u}{\lVert \nabla u \rVert}, \qquad L\phi = -\nabla \cdot X$$

    1. `(M + t L) u = delta`, $t = t_\mathrm{coef} h^2$: one backward-Euler step of the heat flow from the
       sources (`delta`: the sources' hat-function weights);
    2. `X = -grad u / |grad u|` on each face (0 where `grad u = 0`);
    3. `L phi = -div X` (integrated divergence; one vertex pinned per connected component);
    4. on each connected component that holds a source, `phi` shifted so that its minimum is 0, or
       so that the sources sit at 0 when that is lower (the mean over the component's source points
       of `phi` at their face's corners less each corner's straight-line distance from the point);
       `inf` on every other component.

    Convention: distances are never negative; each component holding a source has minimum 0 (with
    one source vertex, at or next to the source: the heat method's field is smooth, not exact), and every vertex no source reaches (another connected
    component, or an unreferenced vertex) is at distance `inf`, so mask them with `jnp.isfinite`
    before summing. A source inside a face gives its corners about their straight-line distance
    from it. First-order accurate in `h` (the smoothing by `t ~ h^2` belongs to the method: a larger
    `t_coef` gives smoother, less accurate distances). With `boundary="average"` (default) the heat
    flow on a mesh with boundary is the mean of its Neumann and Dirichlet (`u = 0` on the boundary)
    solutions, the paper's remedy against distances bent towards the boundary; on a mesh with no
    interior vertex (a strip, a single triangle) the Dirichlet heat is 0 and the Neumann flow alone
    is used; `"neumann"` and `"dirichlet"` use one of them (`"dirichlet"` refuses sources on the
    boundary, which would emit no heat, and meshes with no interior vertex). Several components,
    boundaries, unreferenced vertices, obtuse triangles and any genus are fine. Differentiable in the vertex positions (every step is a JAX function of them,
    the solves by implicit differentiation), under `jit`, `grad` and `vmap`; an eager call runs two
    compiled programs after the Laplacian's and factors between them. For many queries on one mesh keep the factorisations:
    `heat_distance_solver(mesh, ...).distance(sources)`.

    Args:
        mesh: a triangle mesh, or a `ddgjax.volume.TetMesh` (distance inside the solid, module docstring).
        sources: vertex indices, `(m,)` integers (or one integer); or points inside faces, a pair
            `(faces (m,), barycentric (m, 3))` (triangle meshes only).
        t_coef: the heat flow's time in units of `h^2` (default 1, the paper's).
        mass: `M`, one of `ddgjax.MASS_MATRICES` (default `"voronoi"`).
        boundary: `"average"` (default), `"neumann"` or `"dirichlet"` (the heat flow's boundary condition).
        robust: the intrinsic Delaunay Laplacian and lumped mass (`True`, or an
            `IntrinsicTriangulation` inside `jit`): accurate on meshes with obtuse triangles.
        solver: the backend of the three sparse solves, one of `ddgjax.LINEAR_SOLVERS` (default `"auto"`).
        throw: raise when a solve fails (default), or return a `ddgjax.Solution` (`result`: the first
            failing solve's outcome; `stats`: `"residual"`, the largest relative residual of the solves,
            and `"num_steps"`, their CG iterations).

    Returns:
        `(nv,)` distances, `>= 0`, `inf` where no source reaches (in a `ddgjax.Solution` with `throw=False`).

    Equivalents and their defaults: libigl `igl.heat_geodesics_precompute(V, F, data)` /
    `igl.heat_geodesics_solve(data, gamma)` has the same defaults (`t = h^2`, Voronoi mass, the average of
    the Neumann and Dirichlet heat flows) but shifts every component by one constant, the mean over the
    sources, so several sources give negative distances and other components finite ones. potpourri3d
    `MeshHeatMethodDistanceSolver(V, F, t_coef=1.0, use_robust=True).compute_distance(v)` (geometry-central)
    differs in three defaults: it uses the intrinsic Delaunay Laplacian of a mollified tufted cover
    (`use_robust=True`; here `robust=False`, and `robust=True` is the mollified intrinsic Delaunay Laplacian
    without the tufted cover), the lumped barycentric mass (here `"voronoi"`:
    pass `mass="barycentric"`), and the Neumann heat flow only (here `"average"` on meshes with boundary:
    pass `boundary="neumann"`); `t_coef` means the same (`t = t_coef h^2`, `h` the mean edge length).
    To match it, pass `mass="barycentric", boundary="neumann"` and compare with its `use_robust=False`:
    the two agree to 1e-4-3e-4 of the bounding box's diameter (spot, bunny, camelhead; tests). Its
    default `use_robust=True` differs from `robust=True` here by the tufted cover: 0.6% of the diameter
    on spot, 1.5% on camelhead (a boundary and many obtuse triangles, where the robust and the plain
    Laplacian differ by 7%). ddgjax keeps libigl's defaults, the conventions' `mass="voronoi"`, and the
    paper's boundary average. potpourri3d too shifts by one constant, the sources' mean (its distances
    can be negative with several sources, and are a finite constant on components without a source).

    Reference: K. Crane, C. Weischedel, M. Wardetzky, "Geodesics in heat" (2013), sections 3.1-3.2 and
    (boundary conditions) 3.4; "The heat method for distance computation" (2017).

    Examples:
        >>> import ddgjax
        >>> distance = ddgjax.geodesics.heat_distance(ddgjax.mesh.icosphere(3), 0)
        >>> distance.shape, float(distance.min())
        ((642,), 0.0)
        >>> round(float(distance.max()), 1)  # pi at the antipode
        3.1
    """
    mesh = require_domain("mesh", mesh)
    _source_points(mesh, sources)  # refuse malformed sources before building the Laplacian
    L, M, plans, t_coef, triangulation = _operators(mesh, t_coef, mass, boundary, robust, solver)
    corners, weights = _sources(mesh, sources, dirichlet=not plans.neumann)
    _, factors = _factorizations(mesh, L, M, plans, t_coef, triangulation, solver)
    steps, result, stats = _query(mesh, factors, corners, weights)
    return outcome(steps.distance, result, throw, stats)


class _Systems(eqx.Module):
    """The heat method's matrices before factorisation: `M + t L` on the free vertices of each heat flow
    that runs (`None` for one that does not), the pinned `L`, and the cells' measure-weighted gradients."""

    t: Float[Array, ""]
    heat: SparseMatrix | None
    heat_dirichlet: SparseMatrix | None
    poisson: SparseMatrix
    cells: Int[Array, "nc k"]
    area_gradients: Float[Array, "nc k d"]


def _systems_of(mesh: Mesh | TetMesh, L: SparseMatrix, M: SparseMatrix, plans: _Plans, t_coef, triangulation) -> _Systems:
    """`_Systems` of `M + t L`, its Dirichlet block and the pinned `L` (module docstring)."""
    t = t_coef * jnp.mean(domain_edge_lengths(mesh)) ** 2
    heat_matrix = M + t * L
    return _Systems(
        t=t,
        heat=held_block(heat_matrix, plans.heat) if plans.neumann else None,
        heat_dirichlet=None if plans.heat_dirichlet is None else held_block(heat_matrix, plans.heat_dirichlet),
        poisson=held_block(L, plans.poisson),
        cells=cells(mesh, triangulation),
        area_gradients=cell_measure_gradients(mesh, triangulation),
    )


def _factorizations(mesh: Mesh | TetMesh, L: SparseMatrix, M: SparseMatrix, plans: _Plans, t_coef, triangulation, solver: str):
    """`(t, HeatFactors)`: the factorisations of `M + t L`, its Dirichlet block and the pinned `L` (module docstring).

    Called eagerly, the matrices come from one compiled program and are factored after it, on concrete
    values (`ddgjax.solve.factorize`: the definiteness check on the host, outside every program), so
    each program can be kept across processes; under a transformation everything is traced inline.
    """
    systems = _systems(mesh, L, M, plans, t_coef, triangulation)
    factor = functools.partial(factorize, solver=solver)
    return systems.t, HeatFactors(
        heat=None if systems.heat is None else factor(systems.heat),
        heat_plan=plans.heat if plans.neumann else None,
        heat_dirichlet=None if systems.heat_dirichlet is None else factor(systems.heat_dirichlet),
        heat_dirichlet_plan=plans.heat_dirichlet,
        poisson=factor(systems.poisson),
        poisson_plan=plans.poisson,
        components=plans.components,
        cells=systems.cells,
        area_gradients=systems.area_gradients,
    )


def held_block(matrix: SparseMatrix, plan: DirichletPlan | None) -> SparseMatrix:
    """`matrix`, or its free-free block when `plan` holds some indices at 0."""
    return matrix if plan is None else dirichlet_blocks(matrix, plan)[0]


def solve_held(factor: Factorization, plan: DirichletPlan | None, rhs) -> tuple[LinearSolution, Float[Array, " nv"]]:
    """`(solution, x)`: `A x = rhs` on the free indices, `x = 0` on those `plan` holds (`held_block`'s)."""
    if plan is None:
        solution = factor.solve(rhs, throw=False)
        return solution, solution.value
    solution = factor.solve(rhs[plan.free], throw=False)
    return solution, plan.join(solution.value, jnp.zeros(plan.fixed.shape[0], rhs.dtype))


def _heat_method(mesh: Mesh | TetMesh, factors: HeatFactors, corners, weights) -> tuple[HeatMethodSteps, RESULTS, dict]:
    """The four steps (module docstring) with kept factorisations: `(steps, result, stats)`."""
    delta = jnp.zeros(mesh.n_vertices, weights.dtype).at[corners.ravel()].add(weights.ravel())
    flows = ((factors.heat, factors.heat_plan), (factors.heat_dirichlet, factors.heat_dirichlet_plan))
    heats = [solve_held(factor, plan, delta) for factor, plan in flows if factor is not None]
    u = sum(heat for _, heat in heats) / len(heats)  # the Neumann and / or the Dirichlet heat flow; their mean
    # `A_f grad u` has the direction of `grad u` (`ddgjax.dec.gradient`); the divergence is `ddgjax.dec.divergence`'s weak form.
    cell_vertices = factors.cells
    g = jnp.einsum("fk,fkd->fd", take_rows(u, cell_vertices), factors.area_gradients)
    norm = safe_norm(g, keepdims=True)
    field = jnp.where(norm > 0, -g / jnp.where(norm > 0, norm, 1.0), 0.0)
    corner_divergence = jnp.einsum("fkd,fd->fk", factors.area_gradients, field)
    div = -jax.ops.segment_sum(corner_divergence.reshape(-1), cell_vertices.reshape(-1), num_segments=mesh.n_vertices)
    poisson, phi = solve_held(factors.poisson, factors.poisson_plan, -div)
    steps = HeatMethodSteps(heat=u, field=field, divergence=div, distance=_shift(mesh, phi, factors.components, corners, weights))
    solutions = [solution for solution, _ in heats] + [poisson]
    stats = {
        "residual": jnp.max(jnp.stack([solution.residual for solution in solutions])),
        "num_steps": sum(solution.num_steps for solution in solutions),
    }
    return steps, first_failure(*(solution.result for solution in solutions)), stats


def _shift(mesh: Mesh | TetMesh, phi, components, corners, weights) -> Float[Array, " nv"]:
    """Step 4 (module docstring): each component holding a source shifted down to its minimum or to its
    sources' level, whichever is lower (so never below 0), and `inf` on every other component."""
    n = phi.shape[0]
    source_components = components[corners[:, 0]]  # a face's three corners share its component
    positions = mesh.vertices[corners]
    points = jnp.sum(weights[:, :, None] * positions, axis=1)
    # The straight-line distance in the face from each source point to its corners (0 for a source vertex).
    offsets = safe_norm(points[:, None, :] - positions)
    level = jax.ops.segment_sum(jnp.sum(weights * (phi[corners] - offsets), axis=1), source_components, n)
    total = jax.ops.segment_sum(jnp.sum(weights, axis=1), source_components, n)
    level = jnp.where(total != 0, level / jnp.where(total != 0, total, 1.0), jnp.inf)
    shift = jnp.minimum(jax.ops.segment_min(phi, components, n), level)
    reached = jnp.zeros(n, bool).at[source_components].set(True)
    return jnp.where(reached[components], phi - shift[components], jnp.inf)


# The kernels' first parameter is `domain`: one named `mesh` would be checked to be a triangle mesh
# (`ddgjax._compile.kernel`), and these serve tet meshes too.
@kernel
def _systems(domain: Mesh | TetMesh, L, M, plans: _Plans, t_coef, triangulation) -> _Systems:
    return _systems_of(domain, L, M, plans, t_coef, triangulation)


@kernel
def _query(domain: Mesh | TetMesh, factors: HeatFactors, corners, weights):
    return _heat_method(domain, factors, corners, weights)


def _sources(mesh: Mesh | TetMesh, sources, *, dirichlet: bool) -> tuple[np.ndarray, Float[ArrayLike, "m 3"]]:
    """`(corners (m, 3), weights (m, 3))`: each source point as hat-function weights on a face's corners
    (a source vertex `v` is the corners `(v, v, v)` with weights `(1, 0, 0)`), after refusing sources
    that cannot emit heat: unreferenced vertices, and (`dirichlet`: only the Dirichlet heat flow is
    run) points on the boundary."""
    corners, weights = _source_points(mesh, sources)
    topology = mesh.topology
    unreferenced = np.isin(corners[:, 0], topology.unreferenced_vertices)
    if unreferenced.any():
        raise DDGInputError(
            f"sources: vertices {np.unique(corners[unreferenced, 0])[:5].tolist()} belong to no face or tet "
            "(unreferenced), so no distance spreads from them; pass vertices of the mesh's faces or tets"
        )
    if dirichlet:
        silent = np.isin(corners, topology.boundary_vertices).all(axis=1)
        if silent.any():
            raise DDGInputError(
                f"sources: the sources at positions {first_indices(silent)} lie on the boundary (a boundary vertex, "
                'or a point in a face whose corners are all boundary vertices), where boundary="dirichlet" holds the '
                'heat at 0, so they emit none; use boundary="average" (the default) or "neumann", or sources off the boundary'
            )
    return corners, weights


def _source_points(mesh: Mesh | TetMesh, sources) -> tuple[np.ndarray, Float[ArrayLike, "m 3"]]:
    """`_sources` before the checks of what the sources emit."""
    n = mesh.n_vertices
    if isinstance(sources, tuple) and isinstance(mesh, TetMesh):
        raise DDGInputError(
            "sources: a TetMesh takes source vertices (a 1-d integer array), not (faces, barycentric) points; "
            "to start from a point inside the solid, add it as a vertex of the tet mesh"
        )
    if isinstance(sources, tuple):
        if len(sources) != 2:
            raise DDGInputError("sources: a pair (faces (m,), barycentric (m, 3)) for points inside faces")
        faces, weights = np.asarray(sources[0]), jnp.asarray(sources[1])
        if faces.ndim != 1 or not np.issubdtype(faces.dtype, np.integer) or faces.size == 0:
            raise DDGInputError(f"sources: expected a non-empty 1-d integer array of face indices, got {faces!r}")
        if faces.min() < 0 or faces.max() >= mesh.n_faces:
            raise DDGInputError(f"sources: face indices must lie in [0, {mesh.n_faces})")
        if weights.shape != (faces.size, 3):
            raise DDGInputError(f"sources: expected barycentric coordinates of shape ({faces.size}, 3), got {weights.shape}")
        return np.asarray(mesh.topology.faces)[faces], weights.astype(mesh.vertices.dtype)
    vertices = np.atleast_1d(np.asarray(sources))
    if vertices.ndim != 1 or vertices.size == 0 or not np.issubdtype(vertices.dtype, np.integer):
        raise DDGInputError(
            f"sources: expected vertex indices (a non-empty 1-d integer array) or (faces, barycentric), got {sources!r}"
        )
    if vertices.min() < 0 or vertices.max() >= n:
        raise DDGInputError(f"sources: vertex indices must lie in [0, {n}), got {vertices[(vertices < 0) | (vertices >= n)][:5]}")
    weights = np.zeros((vertices.size, 3), mesh.vertices.dtype)  # host data: an eager query dispatches nothing here
    weights[:, 0] = 1.0
    return np.repeat(vertices[:, None], 3, axis=1), weights
