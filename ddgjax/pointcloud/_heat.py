"""Geodesic distance, parallel transport and the log map on a point cloud, on its tufted intrinsic Delaunay triangulation.

As geometry-central's `PointCloudHeatSolver` ("we basically just run the mesh version on the tufted
triangulation of the point cloud"), potpourri3d's `PointCloudHeatSolver(P).compute_distance(i)`:
the heat method of Crane, Weischedel & Wardetzky 2013 (`ddgjax.geodesics._heat`) on the faces of
`point_cloud_triangulation(points)`, an intrinsic triangulation known by its edge lengths only, so
the gradient step works per face from lengths:

1. `(M + t L) u = delta_sources`, `L`, `M` = `point_cloud_laplacian`, `t = t_coef * h^2` with `h`
   the mean edge length of the flipped tufted cover (geometry-central's time scale);
2. per cover face `f`, with `K_f` its cotan stiffness matrix (`(K_f u)_a = 1/2 sum cot(c) (u_a - u_b)`
   over its other corners `b`, `c` the corner opposite `ab`): `|grad u|_f = sqrt(u^T K_f u / A_f)`,
   and the integrated divergence of `X = -grad u / |grad u|` at a corner `a` is
   `-int_f X . grad phi_a = (K_f u)_a / |grad u|_f` (0 where `grad u` vanishes);
3. `L phi = -div` with one point pinned per connected component, divided by the cover's
   multiplicity as `L` is;
4. shifted as the mesh heat method shifts its vertex sources (`ddgjax.geodesics._heat._shift`, which
   takes a `Mesh` for sources inside faces): each component holding a source has its minimum, or
   its sources' mean level where lower, at 0; other components are `inf`.

So the distance is exactly the mesh heat method run on that intrinsic triangulation with the
barycentric mass and the Neumann heat flow (the cover is closed), differentiable in the points for
the fixed triangulation. potpourri3d shifts by the sources' mean instead (the same with one source).

Vector heat method (Sharp, Soliman & Crane 2019, as `ddgjax.geodesics.VectorHeatSolver` on meshes
and geometry-central's `PointCloudHeatSolver::transportTangentVectors` / `computeLogMap`): each
point has an oriented tangent frame from its PCA normal, and `A` is the complex connection
Laplacian with `L`'s weights on the cover's edges and the minimal rotations between neighbouring
normals as transport (`ddgjax.pointcloud._transport`); `M + t A` is factorised once, with the same
`t` and the same held points (those in no triangle get zero vectors).

- `transport(source, vector)`: `(M + t A) Y = Y_0` from the sources' unit directions; the result is
  `Y / |Y|` times the nearest source's magnitude (the diffused magnitudes over the diffused
  indicator, `|z|` itself for one source), in world coordinates.
- `log_map(source)`: the horizontal field `H` (the source's `e1` diffused), the radial field `R` (the
  unit directions away from the source, in the tangent planes of its cover neighbours `j`, weighted
  by the cotan weights `w_sj`, diffused: the point-cloud stand-in for the mesh's outward ball), and
  the heat distance `r` above: `log(x) = r(x) unit(R conj(H))(x)`, in the source's frame. On the
  unit sphere the directions are within 0.04 rad of the exact ones and the norms are the heat
  distance (tests).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse
import scipy.sparse.csgraph
from jaxtyping import Array, ArrayLike, Float, Inexact, Int

from .._compile import at_top_level, kernel
from .._errors import DDGInputError
from .._indexing import take_rows
from .._numerics import safe_div, safe_sqrt
from .._options import check_solver
from .._results import Solution, first_failure, outcome
from ..fields import TangentBases
from ..fields.internal import unit
from ..geodesics.internal import check_t_coef, combined_stats, held_block, point_masses, solve_held, source_vectors
from ..mesh import corner_cotangents_from_lengths_sq, face_areas_from_lengths_sq
from ..solve import Factorization, LinearSolution, factorize
from ..solve.internal import cholmod_analysis, kept_analysis
from ..sparse import DirichletPlan, SparseMatrix, dirichlet_blocks, dirichlet_plan
from ._laplacian import _COVER_MULTIPLICITY, _triangulation_for, laplacian_and_mass_from_lengths_sq
from ._transport import orientation_tree, oriented_frames, point_cloud_connection_laplacian, tangent_coordinates
from ._triangulation import PointCloudTriangulation, check_points


class PointCloudHeatSolver(eqx.Module):
    """The heat methods' kept factorisations for one point cloud: `.distance`, `.transport`, `.log_map` per query.

    Made by `point_cloud_heat_solver(points, ...)` (module docstring); a pytree.

    Attributes:
        points: `(n, 3)` the positions.
        triangulation: the cloud's `PointCloudTriangulation`.
        t: the heat flow's time `t_coef * h^2`.
        heat: factorisation of `M + t L` (its free block when some points belong to no triangle).
        heat_plan: the `DirichletPlan` holding those points at 0, else `None`.
        poisson: factorisation of `L` with one point per component pinned.
        poisson_plan: the pins' `DirichletPlan`.
        components: `(n,)` each point's connected component.
        cotangents: `(n_cover, 3)` each cover face's corner cotangents.
        areas: `(n_cover,)` each cover face's area.
        frames: the points' oriented tangent frames (`tangent_frames`).
        vector_heat: factorisation of the vector heat operator `M + t A` (its free block as `heat`),
            `A` the complex connection Laplacian (`ddgjax.pointcloud._transport`); `None` when made with
            `vector_heat=False` (distances only).
    """

    points: Float[Array, "n 3"]
    triangulation: PointCloudTriangulation
    t: Float[Array, ""]
    heat: Factorization
    heat_plan: DirichletPlan | None
    poisson: Factorization
    poisson_plan: DirichletPlan
    components: Int[Array, " n"]
    cotangents: Float[Array, "n_cover 3"]
    areas: Float[Array, " n_cover"]
    frames: TangentBases
    vector_heat: Factorization | None

    @property
    def tangent_frames(self) -> TangentBases:
        """`TangentBases(e1, e2, normal)`, `(n, 3)` each: the frames of `transport` and `log_map`.

        `normal` the PCA normal oriented consistently along the cloud (outward on a closed surface),
        `e1` the world axis least aligned with it made tangent, `e2 = normal x e1`. potpourri3d:
        `PointCloudHeatSolver.get_tangent_frames()` (other frames: compare angles in 3-D).
        """
        return self.frames

    def distance(self, sources, *, throw: bool = True) -> Float[Array, " n"] | Solution:
        """Geodesic distance from the source points (indices, `(m,)` or one integer) to every point, `(n,)`.

        `>= 0`, `inf` on components no source reaches. `throw=False` returns a `ddgjax.Solution`
        (`stats`: the largest relative residual of the two solves and their CG iterations).
        """
        corners, weights = _sources(self.points.shape[0], sources, self.points.dtype)
        distance, result, stats = _query(self, corners, weights)
        return outcome(distance, result, throw, stats)

    def transport(self, source, vector, *, throw: bool = True) -> Float[Array, "n 3"] | Solution:
        """Parallel transport of tangent vectors from source points to every point, `(n, 3)` world coordinates.

        The vector heat method's Algorithm 1 (module docstring): each point gets the vector of its
        nearest source transported along the shortest geodesic, in its tangent plane
        (`tangent_frames`); zero vectors on components no source reaches and at points in no triangle.

        Args:
            source: a point index or `(m,)` point indices.
            vector: `(3,)` (or `(m, 3)`, one per source) world-coordinate vectors at the sources,
                projected on their tangent planes.
            throw: raise when a solve fails (default), or return a `ddgjax.Solution` (`stats` as `distance`).

        potpourri3d: `PointCloudHeatSolver(P).transport_tangent_vector(i, [x, y])` (`(n, 2)` in its
        own frames) / `transport_tangent_vectors(idx, vectors)`.
        """
        self._require_vector_heat("transport")
        corners, _ = _sources(self.points.shape[0], source, self.points.dtype, "source")
        sources = jnp.asarray(corners[:, 0])
        value, result, stats = _transport(self, sources, source_vectors(vector, sources.shape[0], self.points.dtype))
        return outcome(value, result, throw, stats)

    def log_map(self, source, *, throw: bool = True) -> Float[Array, "n 2"] | Solution:
        """The logarithmic map at a source point, `(n, 2)`: each point's coordinates in the source's frame.

        Row `x` is `r(x) (cos a, sin a)`, `r` the heat-method distance (`distance`) and `a` the angle
        at the source, from `e1` towards `e2` of `tangent_frames` there, of the shortest geodesic to
        `x` (module docstring); `inf` on components the source does not reach.

        Args:
            source: one point index.
            throw: raise when a solve fails (default), or return a `ddgjax.Solution`.

        potpourri3d: `PointCloudHeatSolver(P).compute_log_map(i)` (in its own frame at `i`).
        """
        self._require_vector_heat("log_map")
        if np.ndim(source) != 0:
            raise DDGInputError(f"source: expected one point index, got {source!r}")
        corners, weights = _sources(self.points.shape[0], source, self.points.dtype, "source")
        value, result, stats = _log_map(self, corners, weights)
        return outcome(value, result, throw, stats)

    def _require_vector_heat(self, query: str) -> None:
        if self.vector_heat is None:
            raise DDGInputError(
                f"solver: {query} needs the vector heat factorisation, and this solver was made with "
                "vector_heat=False (distances only): make it with point_cloud_heat_solver(points, vector_heat=True)"
            )


def point_cloud_heat_solver(
    points: ArrayLike,
    *,
    n_neighbors: int = 30,
    t_coef: float = 1.0,
    mollify_factor: float = 1e-5,
    triangulation: PointCloudTriangulation | None = None,
    solver: str = "auto",
    vector_heat: bool = True,
) -> PointCloudHeatSolver:
    r"""Factor the heat method's systems for a point cloud once (module docstring); query with `.distance(sources)`.

    $$(M + tL)\, u = \delta, \qquad X = -\frac{\nabla u}{\lVert \nabla u \rVert}, \qquad L\phi = -\nabla \cdot X$$

    Args:
        points: `(n, 3)` finite positions.
        n_neighbors: the neighbourhood size of the triangulation (keyword-only; default 30).
        t_coef: the heat flow's time in units of `h^2`, `h` the mean edge length of the tufted
            triangulation (keyword-only; default 1, potpourri3d's `t_coef`).
        mollify_factor: the triangulation's mollification (keyword-only; default `1e-5`).
        triangulation: `point_cloud_triangulation(points, ...)` to reuse (needed under `jit` / `grad`).
        solver: the backend of the kept factorisations (`ddgjax.LINEAR_SOLVERS`).
        vector_heat: also factor the vector heat operator, for `.transport` and `.log_map` (default);
            `False` makes a solver for `.distance` alone, which skips the costliest of the three
            factorisations (the complex system's real form, twice the size: benchmarks/README.md).

    Returns:
        `PointCloudHeatSolver`: `.distance(sources)`, `.transport(source, vector)`, `.log_map(source)`,
        `.tangent_frames`. It holds three factorisations (`M + t L`, the pinned `L`, the complex
        `M + t A`), or the first two with `vector_heat=False`.

    potpourri3d: `PointCloudHeatSolver(P, t_coef=1.0)` (its neighbourhood size is fixed at 30; it
    factors each system on the first query that needs it).

    Examples:
        >>> import ddgjax
        >>> points = ddgjax.mesh.icosphere(3).vertices
        >>> solver = ddgjax.pointcloud.point_cloud_heat_solver(points, n_neighbors=10)
        >>> solver.distance(0).shape, solver.log_map(0).shape
        ((642,), (642, 2))
    """
    points = check_points(points)
    check_solver(solver)
    check_t_coef(t_coef)
    if not isinstance(vector_heat, (bool, np.bool_)):
        raise DDGInputError(f"vector_heat: expected True or False, got {vector_heat!r}")
    triangulation = _triangulation_for(points, triangulation, n_neighbors=n_neighbors, mollify_factor=mollify_factor)
    heat_plan, poisson_plan, components = _plans(triangulation, triangulation.plan.pattern)
    parents, trees = orientation_tree(triangulation)
    with cholmod_analysis(kept_analysis(points.shape[0])):
        # The matrices from one compiled program, factored outside it (the definiteness check on the
        # host), so that the program can be kept across processes (`ddgjax._program_store`).
        t, heat, poisson, cotangents, areas, frames, vector_system = _systems(
            points, triangulation, heat_plan, poisson_plan, parents, trees, float(t_coef), vector_heat=bool(vector_heat)
        )
        heat, poisson = (factorize(matrix, solver=solver) for matrix in (heat, poisson))
        vector_heat = None if vector_system is None else factorize(vector_system, solver=solver)
        if at_top_level():
            jax.block_until_ready((heat, poisson, vector_heat))
    return PointCloudHeatSolver(
        points=points,
        triangulation=triangulation,
        t=t,
        heat=heat,
        heat_plan=heat_plan,
        poisson=poisson,
        poisson_plan=poisson_plan,
        components=components,
        cotangents=cotangents,
        areas=areas,
        frames=frames,
        vector_heat=vector_heat,
    )


def point_cloud_heat_distance(
    points: ArrayLike,
    sources,
    *,
    n_neighbors: int = 30,
    t_coef: float = 1.0,
    mollify_factor: float = 1e-5,
    triangulation: PointCloudTriangulation | None = None,
    solver: str = "auto",
    throw: bool = True,
) -> Float[Array, " n"] | Solution:
    r"""Geodesic distance on a point cloud from source points, by the heat method on its tufted triangulation, `(n,)`.

    $$(M + tL)\, u = \delta, \qquad X = -\frac{\nabla u}{\lVert \nabla u \rVert}, \qquad L\phi = -\nabla \cdot X$$

    `point_cloud_heat_solver(points, ...).distance(sources)` (module docstring): first-order
    accurate in the point spacing; `>= 0` with minimum 0 on each component holding a source, `inf`
    on the others. Differentiable in `points` for a fixed `triangulation`.

    Args:
        points: `(n, 3)` finite positions.
        sources: point indices, `(m,)` integers or one integer.
        n_neighbors, t_coef, mollify_factor, triangulation, solver: as `point_cloud_heat_solver`.
        throw: raise when a solve fails (default), or return a `ddgjax.Solution`.

    Returns:
        `(n,)` distances.

    potpourri3d: `PointCloudHeatSolver(P, t_coef=1.0).compute_distance(i)` /
    `compute_distance_multisource(idx)` (which shifts by the sources' mean rather than to 0).

    Examples:
        >>> import ddgjax
        >>> points = ddgjax.mesh.icosphere(3).vertices
        >>> distance = ddgjax.pointcloud.point_cloud_heat_distance(points, 0, n_neighbors=10)
        >>> distance.shape, float(distance.min()), round(float(distance.max()), 1)  # pi at the antipode
        ((642,), 0.0, 3.1)
    """
    _sources(np.shape(points)[0] if np.ndim(points) == 2 else 0, sources, np.float64)  # refuse bad sources first
    solver_ = point_cloud_heat_solver(
        points,
        n_neighbors=n_neighbors,
        t_coef=t_coef,
        mollify_factor=mollify_factor,
        triangulation=triangulation,
        solver=solver,
        vector_heat=False,
    )
    return solver_.distance(sources, throw=throw)


def point_cloud_parallel_transport(
    points: ArrayLike,
    source,
    vector,
    *,
    n_neighbors: int = 30,
    t_coef: float = 1.0,
    mollify_factor: float = 1e-5,
    triangulation: PointCloudTriangulation | None = None,
    solver: str = "auto",
    throw: bool = True,
) -> Float[Array, "n 3"] | Solution:
    """Parallel transport of tangent vectors from source points to every point of a cloud, `(n, 3)` world coordinates.

    `point_cloud_heat_solver(points, ...).transport(source, vector)` (module docstring): the vector
    heat method with the point-cloud connection Laplacian; differentiable in `points` (for a fixed
    `triangulation`) and `vector` away from the cut locus. Keep the solver for several queries.

    Args:
        points: `(n, 3)` finite positions.
        source: a point index or `(m,)` point indices.
        vector: `(3,)` (or `(m, 3)`) world-coordinate vectors at the sources, projected on their tangent planes.
        n_neighbors, t_coef, mollify_factor, triangulation, solver: as `point_cloud_heat_solver`.
        throw: raise when a solve fails (default), or return a `ddgjax.Solution`.

    Returns:
        `(n, 3)` tangent vectors in the frames' tangent planes (`PointCloudHeatSolver.tangent_frames`).

    potpourri3d: `PointCloudHeatSolver(P).transport_tangent_vector(i, [x, y])` (`(n, 2)` in its frames).
    """
    _sources(np.shape(points)[0] if np.ndim(points) == 2 else 0, source, np.float64, "source")
    solver_ = point_cloud_heat_solver(
        points, n_neighbors=n_neighbors, t_coef=t_coef, mollify_factor=mollify_factor, triangulation=triangulation, solver=solver
    )
    return solver_.transport(source, vector, throw=throw)


def point_cloud_log_map(
    points: ArrayLike,
    source,
    *,
    n_neighbors: int = 30,
    t_coef: float = 1.0,
    mollify_factor: float = 1e-5,
    triangulation: PointCloudTriangulation | None = None,
    solver: str = "auto",
    throw: bool = True,
) -> Float[Array, "n 2"] | Solution:
    """The logarithmic map of a point cloud at a source point, `(n, 2)` in the source's tangent frame.

    `point_cloud_heat_solver(points, ...).log_map(source)` (module docstring): the heat distance times
    the direction of the radial field against the transported `e1`.

    Args:
        points: `(n, 3)` finite positions.
        source: one point index.
        n_neighbors, t_coef, mollify_factor, triangulation, solver: as `point_cloud_heat_solver`.
        throw: raise when a solve fails (default), or return a `ddgjax.Solution`.

    Returns:
        `(n, 2)` coordinates along `e1`, `e2` of `PointCloudHeatSolver.tangent_frames` at the source.

    potpourri3d: `PointCloudHeatSolver(P).compute_log_map(i)` (in its own frame at `i`).
    """
    if np.ndim(source) != 0:
        raise DDGInputError(f"source: expected one point index, got {source!r}")
    _sources(np.shape(points)[0] if np.ndim(points) == 2 else 0, source, np.float64, "source")
    solver_ = point_cloud_heat_solver(
        points, n_neighbors=n_neighbors, t_coef=t_coef, mollify_factor=mollify_factor, triangulation=triangulation, solver=solver
    )
    return solver_.log_map(source, throw=throw)


def _plans(triangulation: PointCloudTriangulation, pattern) -> tuple[DirichletPlan | None, DirichletPlan, Int[Array, " n"]]:
    """`(heat_plan, poisson_plan, components)` on the host: points in no triangle held, one pin per component."""
    n = triangulation.n_points
    faces = np.asarray(triangulation.faces)
    rows, cols = faces[:, [0, 1, 2]].reshape(-1), faces[:, [1, 2, 0]].reshape(-1)
    graph = scipy.sparse.coo_matrix((np.ones(rows.size), (rows, cols)), shape=(n, n))
    _, labels = scipy.sparse.csgraph.connected_components(graph, directed=False)
    unreferenced = np.setdiff1d(np.arange(n), faces.reshape(-1))
    _, pins = np.unique(labels, return_index=True)
    return (
        dirichlet_plan(pattern, unreferenced) if unreferenced.size else None,
        dirichlet_plan(pattern, pins),
        jnp.asarray(labels.astype(np.int32)),
    )


@kernel(static_argnames=("vector_heat",))
def _systems(points, triangulation, heat_plan, poisson_plan, parents, trees, t_coef, *, vector_heat: bool):
    """`(t, M + t L, pinned L, cotangents, areas, frames, M + t A)`, the matrices' free blocks (module
    docstring); `M + t A` is `None` without `vector_heat`."""
    lengths_sq = triangulation.face_lengths_sq(points)
    L, M = laplacian_and_mass_from_lengths_sq(lengths_sq, triangulation)
    t = t_coef * jnp.mean(safe_sqrt(lengths_sq)) ** 2  # each cover edge is in two faces: the mean over edges
    areas = face_areas_from_lengths_sq(lengths_sq)
    cotangents = corner_cotangents_from_lengths_sq(lengths_sq, areas=areas)
    frames = oriented_frames(points, triangulation.neighbors, parents, trees)
    vector_system = _vector_heat_system(L, M, t, frames, heat_plan) if vector_heat else None
    return (
        t,
        held_block(M + t * L, heat_plan),
        held_block(L, poisson_plan),
        cotangents,
        areas,
        frames,
        vector_system,
    )


def _vector_heat_system(L, M, t, frames, heat_plan) -> SparseMatrix:
    """`M + t A` (its free block when points are held), `A` the complex connection Laplacian."""
    A = point_cloud_connection_laplacian(L, frames)
    vector_heat = M + t * A
    if heat_plan is not None:  # the free block, from the real and imaginary parts (`dirichlet_blocks` takes real values)
        real, imag = (
            dirichlet_blocks(SparseMatrix(part, vector_heat.pattern), heat_plan)[0]
            for part in (vector_heat.values.real, vector_heat.values.imag)
        )
        vector_heat = SparseMatrix(
            jax.lax.complex(real.values, imag.values), real.pattern, hermitian=True, positive_semidefinite=True
        )
    return vector_heat


@kernel
def _query(solver: PointCloudHeatSolver, corners, weights):
    return _distance(solver, corners, weights)


def _distance(solver: PointCloudHeatSolver, corners, weights):
    n = solver.points.shape[0]
    delta = jnp.zeros(n, weights.dtype).at[corners[:, 0]].add(weights[:, 0])
    heat, u = solve_held(solver.heat, solver.heat_plan, delta)
    faces = solver.triangulation.faces
    face_u = take_rows(u, faces)
    # (K_f u)_a = 1/2 [cot_c (u_a - u_b) + cot_b (u_a - u_c)] for the corners (a, b, c) in cyclic order.
    following, opposite = jnp.roll(face_u, -1, axis=1), jnp.roll(face_u, 1, axis=1)
    cot = solver.cotangents
    stiffness_u = 0.5 * (jnp.roll(cot, 1, axis=1) * (face_u - following) + jnp.roll(cot, -1, axis=1) * (face_u - opposite))
    energy = 0.5 * jnp.sum(cot * (following - opposite) ** 2, axis=1)  # u^T K_f u = A |grad u|^2
    norm_sq = jnp.where(solver.areas > 0, energy / jnp.where(solver.areas > 0, solver.areas, 1.0), 0.0)
    norm = safe_sqrt(norm_sq)
    corner_div = jnp.where(norm[:, None] > 0, stiffness_u / jnp.where(norm > 0, norm, 1.0)[:, None], 0.0)
    div = jax.ops.segment_sum(corner_div.reshape(-1), faces.reshape(-1), num_segments=n) / _COVER_MULTIPLICITY
    poisson, phi = solve_held(solver.poisson, solver.poisson_plan, -div)
    distance = _shift(phi, solver.components, corners[:, 0])
    stats = {"residual": jnp.maximum(heat.residual, poisson.residual), "num_steps": heat.num_steps + poisson.num_steps}
    return distance, first_failure(heat.result, poisson.result), stats


@kernel
def _transport(solver: PointCloudHeatSolver, sources, vectors):
    """`(vectors (n, 3), result, stats)` of `PointCloudHeatSolver.transport` (as the mesh's vector heat method)."""
    n = solver.points.shape[0]
    z = tangent_coordinates(vectors, solver.frames, sources)
    magnitude = jnp.abs(z)
    # Unit directions diffused (as geometry-central): each source steers its own region whatever its magnitude.
    vector, Y = _solve_columns_held(solver.vector_heat, solver.heat_plan, point_masses(n, sources, unit(z)))
    solutions = [vector]
    if sources.shape[0] == 1:  # the diffused magnitude over the diffused indicator is |z| exactly
        magnitude = magnitude[0]
    else:
        rhs = jnp.stack([point_masses(n, sources, magnitude), point_masses(n, sources, jnp.ones_like(magnitude))], axis=1)
        scalar, u = _solve_columns_held(solver.heat, solver.heat_plan, rhs)
        solutions.append(scalar)
        magnitude = safe_div(u[:, 0], u[:, 1])  # 0 where no source reaches
    field = unit(Y) * magnitude
    return (field.real[:, None] * solver.frames.e1 + field.imag[:, None] * solver.frames.e2, *combined_stats(*solutions))


@kernel
def _log_map(solver: PointCloudHeatSolver, corners, weights):
    """`(log (n, 2), result, stats)` of `PointCloudHeatSolver.log_map`: the transported `e1` (horizontal field
    `H`), the diffused outward field (radial `R`) and the heat distance `r`: `log = r unit(R conj(H))`."""
    n = solver.points.shape[0]
    source = corners[0, 0]
    faces = solver.triangulation.faces
    # The source's cover edges with their cotan weights: the corner after it (opposite the corner
    # before) and the one before it (opposite the corner after).
    targets = jnp.concatenate([jnp.roll(faces, -1, axis=1), jnp.roll(faces, -2, axis=1)]).reshape(-1)
    cot = solver.cotangents
    edge_weights = jnp.concatenate([jnp.roll(cot, -2, axis=1), jnp.roll(cot, -1, axis=1)]).reshape(-1)
    at_source = jnp.tile(faces == source, (2, 1)).reshape(-1)
    # The unit field pointing away from the source, in each neighbour's tangent plane (the outward ball).
    away = take_rows(solver.points, targets) - solver.points[source]
    direction = unit(tangent_coordinates(away, solver.frames, targets))
    values = jnp.where(at_source, 0.5 * edge_weights, 0.0) * direction
    radial_rhs = jnp.zeros(n, values.dtype).at[targets].add(values)
    radial, R = _solve_columns_held(solver.vector_heat, solver.heat_plan, radial_rhs)
    horizontal, H = _solve_columns_held(
        solver.vector_heat, solver.heat_plan, point_masses(n, corners[:, 0], jnp.ones(1, values.dtype))
    )
    r, heat_result, heat_stats = _distance(solver, corners, weights)
    angle = unit(R * jnp.conj(H))
    reached = jnp.isfinite(r)
    log = jnp.stack([angle.real, angle.imag], axis=-1) * jnp.where(reached, r, 0.0)[:, None]
    log = jnp.where(reached[:, None], log, jnp.inf)
    vector_result, vector_stats = combined_stats(radial, horizontal)
    stats = {
        "residual": jnp.maximum(heat_stats["residual"], vector_stats["residual"]),
        "num_steps": heat_stats["num_steps"] + vector_stats["num_steps"],
    }
    return log, first_failure(heat_result, vector_result), stats


def _solve_columns_held(factor: Factorization, plan: DirichletPlan | None, rhs) -> tuple[LinearSolution, Inexact[Array, "n *k"]]:
    """`solve_held` for complex or several right-hand sides (its annotation says one real column)."""
    if plan is None:
        solution = factor.solve(rhs, throw=False)
        return solution, solution.value
    solution = factor.solve(rhs[plan.free], throw=False)
    value = solution.value
    zeros = jnp.zeros((plan.fixed.shape[0], *value.shape[1:]), value.real.dtype)
    if jnp.iscomplexobj(value):  # `join` takes real values: the two parts
        return solution, jax.lax.complex(plan.join(value.real, zeros), plan.join(value.imag, zeros))
    return solution, plan.join(value, zeros)


def _shift(phi, components, sources) -> Float[Array, " n"]:
    """Step 4 (module docstring) for source points: per component `phi - min(min phi, mean phi at its sources)`, or `inf`."""
    n = phi.shape[0]
    source_components = components[sources]
    level = jax.ops.segment_sum(phi[sources], source_components, n)
    count = jax.ops.segment_sum(jnp.ones_like(phi[sources]), source_components, n)
    level = jnp.where(count > 0, level / jnp.where(count > 0, count, 1.0), jnp.inf)
    shift = jnp.minimum(jax.ops.segment_min(phi, components, n), level)
    reached = jnp.zeros(n, bool).at[source_components].set(True)
    return jnp.where(reached[components], phi - shift[components], jnp.inf)


def _sources(n: int, sources, dtype, name: str = "sources") -> tuple[np.ndarray, np.ndarray]:
    """`(corners (m, 3), weights (m, 3))` of source points as the mesh heat method takes them: `(i, i, i)`, `(1, 0, 0)`."""
    indices = np.atleast_1d(np.asarray(sources))
    if indices.ndim != 1 or indices.size == 0 or not np.issubdtype(indices.dtype, np.integer):
        raise DDGInputError(f"{name}: expected point indices (a non-empty 1-d integer array), got {sources!r}")
    if indices.min() < 0 or indices.max() >= n:
        raise DDGInputError(f"{name}: point indices must lie in [0, {n}), got {indices[(indices < 0) | (indices >= n)][:5]}")
    weights = np.zeros((indices.size, 3), dtype)
    weights[:, 0] = 1.0
    return np.repeat(indices[:, None], 3, axis=1), weights
