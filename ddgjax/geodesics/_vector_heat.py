"""Parallel transport, the logarithmic map and geodesic centroids by the vector heat method, differentiable.

The vector heat method (Sharp, Soliman & Crane 2019) diffuses tangent vectors for a short time with the
connection Laplacian `A` (`ddgjax.fields.connection_laplacian(mesh, n=1)`, complex Hermitian in the
vertices' polar coordinates) instead of the cotan Laplacian `L`. With `M` the lumped mass matrix,
`t = t_coef * h^2` (`h` the mean edge length) and tangent vectors at vertex `i` written as complex
numbers `z = v . e1_i + i v . e2_i` in the frames of `ddgjax.fields.tangent_bases`:

- **Parallel transport** (the paper's Algorithm 1): one backward-Euler step of the vector heat flow
  `(M + t A) Y = Y_0` from the sources' unit directions `Y_0 = z / |z|` (as geometry-central, so each
  source steers its own region whatever its magnitude), the scalar heat flows `(M + t L) u = |z|` and
  `(M + t L) phi = 1_sources`, and the transported field `X = Y / |Y| * u / phi`: the direction of the
  diffused vector is the transport along the shortest geodesic from the nearest source (the
  connection's diffusion is dominated by the shortest path for small `t`), the magnitude the nearest
  source's (for one source `u / phi = |z|` exactly, and the scalar flows are not run).
- **Logarithmic map** (the paper's Algorithm 2, section 7.1): the *horizontal* field `H`, the source's
  `e1` transported everywhere (above); the *radial* field `R`, the vector heat flow of the unit field
  pointing away from the source in its one-ring, integrated against the hat functions in closed form
  (the paper's Appendix A, geometry-central's `addVertexOutwardBall`), normalised; the distance `r`
  integrated from `R` (the paper's Poisson step): on each edge `a -> b` of length `l_ab` the mean
  tangential component of `R`, `f_ab = l_ab (<R_a, e_ab> - <R_b, e_ba>) / 2` (`e_ab` the unit edge
  direction at `a`), is `r_b - r_a`, and `L r = b`, `b_a = -sum_b w_ab f_ab` with `L`'s cotan weights
  `w_ab` (the least-squares fit of `r` to the `f_ab`, so `L r = L d` exactly when `R` is the gradient of a
  piecewise linear `d`), solved with the kept pinned `L` and shifted to 0 at the source. At the source
  the radial field points along each of its edges, so its component there is 1; geometry-central sets
  the source's `R` to 0, which halves the flux out of the source and leaves its radii short by one
  constant per source (measured 0.26-0.50 `h` on spot, fertility, camelhead; 0.5 `h` on icospheres): the
  same solve otherwise (tests), and 5-8 times more accurate on the unit sphere (mean relative error
  0.47 % against 3.6 % on icosphere(4), and 0.51 % for potpourri3d's default `"AffineLocal"` log map).
  Parallel transport keeps angles, so the angle of `R` against `H` at `x` is the angle at the source of
  the geodesic to `x` against `e1`: `log_s(x) = r(x) (R/H)(x) / |(R/H)(x)|`, in the source's frame
  `(e1, e2)`. With `robust=True` the radius is the heat method's distance (`heat_distance` with the
  Neumann heat flow, on the kept intrinsic `M + t L` and `L`): the radial field transported along the
  mesh's edges with the intrinsic weights is too coarse to integrate where many edges were flipped
  (measured 5.3 % against the heat method's 1.2 % on camelhead).
- **Geodesic centroid** (Karcher mean, section 7.2, geometry-central `findCenter`): from a source
  vertex `c`, the weighted mean `m = sum_k w_k log_c(x_k) / sum_k w_k` of the log map at `c`; the
  centre moves to the vertex whose log coordinates lie nearest to `m` (a discrete step along `m`) until
  it stays; the final centre is the point of the mesh whose log coordinates are `m`, found in the
  triangles of `c`'s faces laid out by `log_c` (barycentric coordinates).

`VectorHeatSolver` keeps the factorisations of `M + t L` (scalar heat), `M + t A` (vector heat, solved
as its real form of twice the size) and the pinned `L` (the heat method's Poisson step), the tangent
frames, the radial field's right-hand side per corner and the edges' polar angles, lengths and weights; a query
is one vector solve (transport) or two vector solves and one Poisson solve (log map; `robust=True`: the
heat method's two scalar solves), in one compiled program.
`robust=True` replaces the scalar operators by the intrinsic Delaunay ones, and the connection
Laplacian's cotan weights by the intrinsic Delaunay weights of the mesh's edges (non-negative, 0 on
an edge the intrinsic triangulation flipped away; transport still along mesh edges): a face with an
angle near `pi` (a flat cap), whose cotan weight is large and negative, would otherwise make
`M + t A` indefinite (`RESULTS.not_positive_definite`). A mesh with two vertices at one point (an
edge of length 0, which `robust=True` accepts) has no tangent direction along that edge and no corner
angles at its ends, so no transport through them has a meaning: every query reports
`RESULTS.coincident_vertices` (merge the vertices first).
Every step is a JAX function of the vertex positions and the solves differentiate implicitly, so the
results are differentiable in the positions away from the cut locus (where the transported direction
jumps) and from the source (where the log map's direction is undefined). Each solve reports its outcome
(`ddgjax.RESULTS`); `throw=False` returns a `ddgjax.Solution` whose `stats` hold the largest relative
residual and the CG iterations.

References: N. Sharp, Y. Soliman, K. Crane, "The vector heat method", ACM TOG 38(3) (2019), sections
4-7; K. Crane, C. Weischedel, M. Wardetzky, "Geodesics in heat" (2013). potpourri3d:
`MeshVectorHeatSolver(V, F, t_coef, use_intrinsic_delaunay)` with `transport_tangent_vector(v, vector)`,
`transport_tangent_vectors(vs, vectors)`, `compute_log_map(v, strategy="VectorHeat")`; geometry-central
`VectorHeatMethodSolver::transportTangentVectors`, `computeLogMap`, `findCenter`.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Complex, Float, Int

from .._compile import at_top_level, kernel
from .._errors import DDGInputError
from .._indexing import take_rows, take_rows_or_zero
from .._numerics import safe_div, safe_norm
from .._options import LUMPED_MASS_MATRICES, check_mass, check_solver
from .._results import RESULTS, Solution, first_failure, outcome
from ..discretization import discretize
from ..discretization.internal import cell_measure_gradients, cells
from ..fields import connection_laplacian, connection_mass_matrix
from ..fields.internal import (
    FieldPlan,
    connection_angles,
    plan_of,
    planned_connection_laplacian,
    planned_tangent_bases,
    require_referenced,
    scaled_corner_angles,
    unit,
)
from ..laplacian import IntrinsicTriangulation
from ..laplacian.internal import vertex_plan
from ..mesh import (
    Mesh,
    corner_angles,
    edge_lengths,
    face_areas,
    face_vertex_positions,
    require_mesh,
    scatter_corners_to_vertices,
)
from ..solve import Factorization, factorize
from ..solve.internal import cholmod_analysis, kept_analysis
from ..sparse import SparseMatrix
from ._heat import HeatFactors, _heat_method, _plans, check_t_coef, held_block, solve_held

_INSIDE = 1e-9
"""How far outside a face (in barycentric coordinates) a centroid still counts as inside it."""


class GeodesicCentroid(NamedTuple):
    """A geodesic centroid (`geodesic_centroid`), a point of the mesh; unpacks as `vertex, face, barycentric, position`.

    Attributes:
        vertex: `()` the vertex the discrete walk ended at (the log map's base).
        face: `()` the face holding the centroid (a face of `vertex`).
        barycentric: `(3,)` its barycentric coordinates in `face` (the face's vertex order): pass
            `(face[None], barycentric[None])` as the sources of `heat_distance`.
        position: `(3,)` the centroid in world coordinates.
    """

    vertex: Int[Array, ""]
    face: Int[Array, ""]
    barycentric: Float[Array, " 3"]
    position: Float[Array, " 3"]


class VectorHeatSolver(eqx.Module):
    """The vector heat method's kept factorisations for one mesh (module docstring).

    Made by `vector_heat_solver(mesh, ...)`; a pytree, so it passes into `jit`, and its queries take a
    traced source vertex (they `vmap` over sources).

    Attributes:
        mesh: the mesh.
        kept: the factorisations and per-face data the queries read (`_Kept`).
    """

    mesh: Mesh
    kept: "_Kept"

    def transport(self, source, vector, *, throw: bool = True) -> Float[Array, "nv 3"] | Solution:
        """Parallel transport of tangent vectors from source vertices to every vertex, `(nv, 3)` world coordinates.

        Each vertex gets the vector of its nearest source transported along the shortest geodesic
        (the paper's Algorithm 1, module docstring), tangent to its frame (`e1`, `e2`); zero vectors
        on components that hold no source.

        Args:
            source: a vertex index, or `(m,)` vertex indices (concrete values are checked; under
                `jit` a traced index is taken as is).
            vector: `(3,)` (or `(m, 3)`, one per source) world-coordinate vectors at the sources; the
                part along the source's normal is dropped (the vector is projected on its tangent plane).
            throw: raise when a solve fails (default), or return a `ddgjax.Solution` (module docstring).
        """
        sources = _source_vertices(self.mesh, source)
        vectors = source_vectors(vector, sources.shape[0], self.kept.e1.dtype)
        value, result, stats = _transport(self.mesh, self.kept, sources, vectors)
        return outcome(value, result, throw, stats)

    def log_map(self, source, *, throw: bool = True) -> Float[Array, "nv 2"] | Solution:
        """The logarithmic map at a source vertex, `(nv, 2)`: each vertex's coordinates in the source's frame.

        Row `x` is `r(x) (cos a, sin a)`: `r` the geodesic distance (the radial field integrated;
        the heat method's with `robust=True`), `a` the angle
        at the source, from `e1` towards `e2` (`tangent_bases(mesh)` at the source), of the shortest
        geodesic to `x` (module docstring); `inf` on components the source does not reach.

        Args:
            source: a vertex index (checked when concrete; traced under `jit`).
            throw: raise when a solve fails (default), or return a `ddgjax.Solution`.
        """
        (source,) = _source_vertices(self.mesh, source, single=True)
        value, result, stats = _log_map(self.mesh, self.kept, source)
        return outcome(value, result, throw, stats)


class _Kept(eqx.Module):
    """What a `VectorHeatSolver` keeps besides its mesh (a kernel takes the mesh apart, as the heat method's).

    Attributes:
        t: the heat flows' time `t_coef * h^2`.
        scalar: the scalar heat method's `HeatFactors` (the Neumann heat flow `M + t L`, the pinned
            Poisson solve, components, `A_f grad phi_k`), as `HeatDistanceSolver` keeps them.
        vector_heat: factorisation of the vector heat operator `M + t A` (complex Hermitian).
        e1, e2, normal: `(nv, 3)` the vertices' tangent frames (`ddgjax.fields.tangent_bases`).
        outward: `(3, nf, 3)` the log map's radial right-hand side for each corner taken as the source, at
            it, at the next corner and at the previous one (`_outward_ball_corners`; it needs no source).
        edge_directions: `(ne, 2)` `exp(-i theta)`, `theta` each edge's polar angle at its low and its high end
            (a tangent vector's component along the edge is the real part of their product).
        edge_lengths: `(ne,)` the edges' lengths.
        edge_weights: `(ne,)` `L`'s weights of the mesh's edges (the cotan weights; with `robust=True` the
            intrinsic Delaunay ones, also the connection Laplacian's).
        coincident: `()` whether an edge has length exactly 0 (`check_mesh`'s zero-length edges), where
            those angles are undefined: every query then reports `RESULTS.coincident_vertices`.
        integrated: whether the log map's radius integrates the radial field (static; `False` with
            `robust=True`: the heat method's distance, module docstring).
    """

    t: Float[Array, ""]
    # Matrices between `_systems` and `_factored`, factorisations after.
    scalar: HeatFactors
    vector_heat: Factorization | SparseMatrix
    e1: Float[Array, "nv 3"]
    e2: Float[Array, "nv 3"]
    normal: Float[Array, "nv 3"]
    outward: Complex[Array, "3 nf 3"]
    edge_directions: Complex[Array, "ne 2"]
    edge_lengths: Float[Array, " ne"]
    edge_weights: Float[Array, " ne"]
    coincident: Bool[Array, ""]
    integrated: bool = eqx.field(static=True, default=True)


def vector_heat_solver(
    mesh: Mesh,
    *,
    t_coef: float = 1.0,
    mass: str = "voronoi",
    robust: bool | IntrinsicTriangulation = False,
    solver: str = "auto",
) -> VectorHeatSolver:
    r"""Factor the vector heat method's systems for `mesh` once (module docstring); query `.transport`, `.log_map`.

    $$(M + tA)\, Y = Y_0, \qquad (M + tL)\, u = u_0, \qquad (M + tL)\, \varphi = \varphi_0, \qquad X = \frac{Y}{\lvert Y \rvert} \, \frac{u}{\varphi}$$

    Args:
        mesh: a manifold, consistently oriented triangle mesh with every vertex in a face (boundaries,
            several components and any genus are fine; `MeshDataError` otherwise).
        t_coef: the heat flows' time in units of the squared mean edge length (1 in the paper).
        mass: the lumped mass matrix `M` of both flows, `"voronoi"` (default) or `"barycentric"`
            (potpourri3d's; `"galerkin"` is refused: the vector flow needs a lumped mass,
            `ddgjax.fields.connection_mass_matrix`).
        robust: the intrinsic Delaunay `L` and `M` (`True` or an `IntrinsicTriangulation`,
            `ddgjax.laplacian.laplacian_and_mass`), and their edge weights in the connection
            Laplacian (module docstring): for meshes with degenerate or obtuse faces.
        solver: the backend of the kept factorisations (`ddgjax.LINEAR_SOLVERS`).

    Returns:
        `VectorHeatSolver`; its queries take `throw=`.

    potpourri3d: `MeshVectorHeatSolver(V, F, t_coef=1.0, use_intrinsic_delaunay=True)`: compare with
    `use_intrinsic_delaunay=False` and `mass="barycentric"` (tests).

    Examples:
        >>> import jax.numpy as jnp
        >>> import ddgjax
        >>> solver = ddgjax.geodesics.vector_heat_solver(ddgjax.mesh.icosphere(3))
        >>> vectors = solver.transport(0, jnp.array([0.0, 0.0, 1.0]))
        >>> coordinates = solver.log_map(0)
        >>> vectors.shape, coordinates.shape
        ((642, 3), (642, 2))
    """
    mesh = require_mesh("mesh", mesh)
    L, M, A, MA, weights, plans, field_plan, t_coef, triangulation = _operators(mesh, t_coef, mass, robust, solver)
    with cholmod_analysis(kept_analysis(mesh.n_vertices)):  # kept for many queries: the faster solves
        systems = _systems(mesh, L, M, A, MA, weights, plans.poisson, plans.components, field_plan, t_coef, triangulation)
        kept = _factored(systems, solver)
        if at_top_level():
            jax.block_until_ready(kept)  # the factorisations run in the block
    return VectorHeatSolver(mesh=mesh, kept=kept)


def parallel_transport(
    mesh: Mesh,
    source,
    vector,
    *,
    t_coef: float = 1.0,
    mass: str = "voronoi",
    robust: bool | IntrinsicTriangulation = False,
    solver: str = "auto",
    throw: bool = True,
) -> Float[Array, "nv 3"] | Solution:
    r"""Parallel transport of a tangent vector at a source vertex to every vertex along shortest geodesics, `(nv, 3)`.

    The vector heat method's Algorithm 1 (module docstring): $(M + tA)\, Y = Y_0$, the direction of $Y$
    with the source's magnitude (with several sources, the nearest source's: the diffused magnitudes
    over the diffused indicator). The result at vertex `i` is a world-coordinate vector in its
    tangent plane (`Re z e1_i + Im z e2_i`). Differentiable in the vertex positions and `vector`
    away from the cut locus. For many queries keep the factorisations: `vector_heat_solver(mesh).transport(...)`.

    Args:
        mesh: the mesh (as `vector_heat_solver`).
        source: a vertex index (or `(m,)` indices).
        vector: `(3,)` (or `(m, 3)`) world-coordinate vectors at the sources, projected on their tangent planes.
        t_coef, mass, robust, solver: as `vector_heat_solver`.
        throw: raise when a solve fails (default), or return a `ddgjax.Solution`.

    Returns:
        `(nv, 3)` tangent vectors (in a `ddgjax.Solution` with `throw=False`).

    potpourri3d: `MeshVectorHeatSolver(V, F).transport_tangent_vector(v, [x, y])` returns `(nv, 2)`
    coordinates in its own frames (`get_tangent_frames()`); here world coordinates. Reference: Sharp,
    Soliman & Crane (2019), Algorithm 1.

    Examples:
        >>> import jax.numpy as jnp
        >>> import ddgjax
        >>> sphere = ddgjax.mesh.icosphere(3)
        >>> vectors = ddgjax.geodesics.parallel_transport(sphere, 0, jnp.array([0.0, 0.0, 1.0]))
        >>> vectors.shape, bool(jnp.allclose(jnp.linalg.norm(vectors, axis=1), 1.0))  # the length is kept
        ((642, 3), True)
    """
    mesh = require_mesh("mesh", mesh)
    sources = _source_vertices(mesh, source)  # refuse bad sources before factoring
    source_vectors(vector, sources.shape[0], mesh.vertices.dtype)
    return vector_heat_solver(mesh, t_coef=t_coef, mass=mass, robust=robust, solver=solver).transport(source, vector, throw=throw)


def log_map(
    mesh: Mesh,
    source,
    *,
    t_coef: float = 1.0,
    mass: str = "voronoi",
    robust: bool | IntrinsicTriangulation = False,
    solver: str = "auto",
    throw: bool = True,
) -> Float[Array, "nv 2"] | Solution:
    r"""The logarithmic map at a source vertex, `(nv, 2)` coordinates in the source's tangent frame.

    $$\log_s(x) = r(x) \, \frac{(R/H)(x)}{\lvert (R/H)(x) \rvert}$$

    (module docstring): `R` the diffused radial field, `H` the
    source's `e1` transported, `r` the distance integrated from the unit radial field, `L r = b` with
    `b_a = -sum_b w_ab l_ab (<R_a, e_ab> - <R_b, e_ba>) / 2` over the edges `a -> b` (the component of
    `R` at the source along each of its edges taken as 1), shifted to 0 at the source (with
    `robust=True`, the heat method's distance); coordinates along `e1` and `e2` of
    `ddgjax.fields.tangent_bases(mesh)` at the source. On the unit sphere $\lvert \log_s(x) \rvert \approx \arccos \langle x, s \rangle$
    (mean relative error 0.47 % on icosphere(4), 0.29 % on icosphere(5)) and its direction is that of
    `x - s` projected on the tangent plane (tests). Differentiable in the vertex positions away from the
    source and the cut locus; `inf` on components without the source. For many queries keep the
    factorisations: `vector_heat_solver(mesh).log_map(source)`.

    Args:
        mesh: the mesh (as `vector_heat_solver`).
        source: a vertex index.
        t_coef, mass, robust, solver: as `vector_heat_solver`.
        throw: raise when a solve fails (default), or return a `ddgjax.Solution`.

    Returns:
        `(nv, 2)` log coordinates (in a `ddgjax.Solution` with `throw=False`).

    potpourri3d: `MeshVectorHeatSolver(V, F, use_intrinsic_delaunay=False).compute_log_map(v,
    strategy="VectorHeat")` (the paper's algorithm; its default `"AffineLocal"` is the affine heat
    method, accurate near the source and poor far from it on real meshes), in its own frame at `v`: the
    two differ by the rotation between the frames' first axes, and with `mass="barycentric"` the radii
    differ by one constant (geometry-central's radial field is 0 at the source: module docstring).
    Reference: Sharp, Soliman & Crane (2019), section 7.1 and Algorithm 2; geometry-central
    `VectorHeatMethodSolver::computeLogMap`.

    Examples:
        >>> import jax.numpy as jnp
        >>> import ddgjax
        >>> sphere = ddgjax.mesh.icosphere(3)
        >>> coordinates = ddgjax.geodesics.log_map(sphere, 0)
        >>> exact = jnp.arccos(jnp.clip(sphere.vertices @ sphere.vertices[0], -1.0, 1.0))  # great-circle distance
        >>> coordinates.shape, bool(jnp.mean(jnp.abs(jnp.linalg.norm(coordinates, axis=1) - exact)) < 0.02)
        ((642, 2), True)
    """
    mesh = require_mesh("mesh", mesh)
    _source_vertices(mesh, source, single=True)
    return vector_heat_solver(mesh, t_coef=t_coef, mass=mass, robust=robust, solver=solver).log_map(source, throw=throw)


def geodesic_centroid(
    mesh: Mesh,
    sources,
    *,
    source_weights=None,
    max_steps: int = 64,
    t_coef: float = 1.0,
    mass: str = "voronoi",
    robust: bool | IntrinsicTriangulation = False,
    solver: str = "auto",
    throw: bool = True,
) -> GeodesicCentroid | Solution:
    """The weighted geodesic centroid (Karcher mean) of source vertices, a point of the mesh (`GeodesicCentroid`).

    Minimises `sum_k w_k d(c, x_k)^2` by the fixed-point iteration of the vector heat method's paper
    (section 7.2; module docstring): at the current vertex `c`, `m = sum_k w_k log_c(x_k) / sum_k w_k`;
    `c` moves to the vertex whose log coordinates are nearest to `m` and stops when it stays (the walk
    is discrete, so it ends exactly: no `rtol`); the centroid is then the point whose log coordinates
    at `c` are `m`, in one of `c`'s faces. It starts at the heaviest source. Converges when the sources
    lie well inside a convex geodesic ball (the Karcher mean is unique there); on the unit sphere two
    points give the midpoint of their great-circle arc (tests). The position and barycentric
    coordinates are differentiable in the vertex positions and `source_weights` for a fixed final vertex and
    face; runs as one `lax.while_loop` (jit-able).

    Args:
        mesh: the mesh (as `vector_heat_solver`).
        sources: `(m,)` vertex indices (or one).
        source_weights: `(m,)` non-negative weights of the sources, not all 0 (default: equal).
        max_steps: the most moves of the walk (`RESULTS.max_steps_reached` beyond; default 64).
        t_coef, mass, robust, solver: as `vector_heat_solver`.
        throw: raise when a solve fails or the walk does not settle (default), or return a
            `ddgjax.Solution` (`stats`: `"num_steps"`, the moves made).

    Returns:
        `GeodesicCentroid(vertex, face, barycentric, position)` (in a `ddgjax.Solution` with `throw=False`).

    geometry-central: `findCenter(mesh, geom, vectorHeatSolver, points, p=2)` (it traces geodesics
    from a surface point; not in potpourri3d).
    """
    mesh = require_mesh("mesh", mesh)
    points = _source_vertices(mesh, sources)
    m = points.shape[0]
    if source_weights is None:
        source_weights = jnp.ones(m, mesh.vertices.dtype)
    else:
        source_weights = jnp.asarray(source_weights, mesh.vertices.dtype)
        if source_weights.shape != (m,):
            raise DDGInputError(f"source_weights: expected shape ({m},), one per source, got {source_weights.shape}")
        if not isinstance(source_weights, jax.core.Tracer) and (
            np.any(np.asarray(source_weights) < 0) or not np.any(np.asarray(source_weights) > 0)
        ):
            raise DDGInputError("source_weights: expected non-negative weights, not all 0")
    if isinstance(max_steps, bool) or not isinstance(max_steps, (int, np.integer)) or max_steps < 1:
        raise DDGInputError(f"max_steps: expected a positive integer, got {max_steps!r}")
    vector_solver = vector_heat_solver(mesh, t_coef=t_coef, mass=mass, robust=robust, solver=solver)
    value, result, stats = _centroid(mesh, vector_solver.kept, points, source_weights, max_steps=int(max_steps))
    return outcome(value, result, throw, stats)


def _operators(mesh: Mesh, t_coef, mass: str, robust, solver: str):
    """Checked options, then the host-built operators and plans the factor kernel takes."""
    check_mass(mass, LUMPED_MASS_MATRICES)
    check_solver(solver)
    check_t_coef(t_coef)
    field_plan = plan_of(mesh)
    require_referenced(mesh, "vector_heat_solver")
    discretization = discretize(mesh, mass=mass, robust=robust, caller="vector_heat_solver")
    L, M, triangulation = discretization.laplacian, discretization.mass, discretization.triangulation
    plans = _plans(mesh, "neumann", discretization.pattern, cached=triangulation is None)
    edges = mesh.topology.edges
    # `L`'s weights of the mesh's edges: the cotan weights, or the intrinsic Delaunay ones (>= 0; 0 where flipped away).
    weights = -take_rows_or_zero(L.values, jnp.asarray(discretization.pattern.slots(edges[:, 0], edges[:, 1])))
    if triangulation is None:
        A, MA = connection_laplacian(mesh, n=1), connection_mass_matrix(mesh, mass=mass)
    else:
        A = planned_connection_laplacian(
            mesh, field_plan, vertex_plan(mesh), 1.0, boundary_scaling="geodesic", edge_weights=weights
        )
        MA = M
    t_coef = jax.device_put(np.asarray(float(t_coef), L.values.dtype))
    return L, M, A, MA, weights, plans, field_plan, t_coef, triangulation


def _factored(kept: _Kept, solver: str) -> _Kept:
    """`kept` with its three matrices factored. Called eagerly, on concrete values after `_systems`'s program
    (the definiteness check on the host, outside every program, so each can be kept across processes)."""
    factor = functools.partial(factorize, solver=solver)
    return eqx.tree_at(
        lambda k: (k.scalar.heat, k.vector_heat, k.scalar.poisson),
        kept,
        (factor(kept.scalar.heat), factor(kept.vector_heat), factor(kept.scalar.poisson)),
    )


@kernel
def _systems(mesh: Mesh, L, M, A, MA, weights, poisson_plan, components, field_plan: FieldPlan, t_coef, triangulation) -> _Kept:
    """The solver's data with the heat, vector heat and pinned Poisson matrices unfactored (`_factored`)."""
    lengths = edge_lengths(mesh)
    t = t_coef * jnp.mean(lengths) ** 2
    e1, e2, normal = planned_tangent_bases(mesh, field_plan)
    corners = face_vertex_positions(mesh)
    areas = face_areas(mesh)
    opposite = safe_norm(jnp.roll(corners, -1, axis=1) - jnp.roll(corners, -2, axis=1))
    angles = connection_angles(mesh, field_plan, boundary_scaling="geodesic")
    first = angles.corner_polar
    return _Kept(
        t=t,
        scalar=HeatFactors(
            heat=M + t * L,
            heat_plan=None,
            heat_dirichlet=None,
            heat_dirichlet_plan=None,
            poisson=held_block(L, poisson_plan),
            poisson_plan=poisson_plan,
            components=components,
            cells=cells(mesh, triangulation),
            area_gradients=cell_measure_gradients(mesh, triangulation),
        ),
        vector_heat=MA + t * A,
        e1=e1,
        e2=e2,
        normal=normal,
        outward=_outward_ball_corners(
            corner_angles(mesh),
            safe_div(2.0 * areas[:, None], opposite),
            first,
            first + scaled_corner_angles(mesh, field_plan, "geodesic"),
        ),
        edge_directions=jnp.exp(-1j * angles.edge_polar),
        edge_lengths=lengths,
        edge_weights=weights,
        coincident=jnp.any(jnp.all(mesh.vertices[mesh.edges[:, 0]] == mesh.vertices[mesh.edges[:, 1]], axis=1)),
        integrated=triangulation is None,
    )


def _meaningful(solver: _Kept) -> RESULTS:
    """`RESULTS.coincident_vertices` where the mesh has a zero-length edge (no vector query has a meaning there)."""
    return RESULTS.where(solver.coincident, RESULTS.coincident_vertices, RESULTS.successful)


def _source_vertices(mesh: Mesh, source, *, single: bool = False) -> Int[ArrayLike, " m"]:
    """`source` as a `(m,)` integer array (`(1,)` when `single`), refusing malformed or out-of-range concrete indices.

    Concrete indices stay a NumPy array (in JAX's canonical integer type): unpacked or passed to a kernel
    on the host, they compile no eager program."""
    what = "a vertex index" if single else "a vertex index or a 1-d array of them"
    if isinstance(source, jax.core.Tracer):
        if not jnp.issubdtype(source.dtype, jnp.integer) or source.ndim > (0 if single else 1):
            raise DDGInputError(f"source: expected {what}, got a traced {source.dtype} array of shape {source.shape}")
        return jnp.atleast_1d(source)
    vertices = np.atleast_1d(np.asarray(source))
    if (
        vertices.ndim != 1
        or vertices.size == 0
        or (single and vertices.size != 1)
        or not np.issubdtype(vertices.dtype, np.integer)
        or (single and np.ndim(source) != 0)
    ):
        raise DDGInputError(f"source: expected {what}, got {source!r}")
    outside = (vertices < 0) | (vertices >= mesh.n_vertices)
    if outside.any():
        raise DDGInputError(f"source: vertex indices must lie in [0, {mesh.n_vertices}), got {vertices[outside][:5].tolist()}")
    return vertices.astype(jax.dtypes.canonicalize_dtype(vertices.dtype))


def source_vectors(vector, m: int, dtype) -> Float[ArrayLike, "m 3"]:
    """`vector` as `(m, 3)` (one `(3,)` vector is shared by the `m` sources only when `m == 1`); concrete
    ones on the host (as `_source_vertices`)."""
    vector = jnp.asarray(vector, dtype) if isinstance(vector, jax.core.Tracer) else np.asarray(vector, dtype)
    if vector.shape == (3,):
        vector = vector[None]
    if vector.shape != (m, 3):
        raise DDGInputError(
            f"vector: expected a (3,) world-coordinate vector per source, shape ({m}, 3) or (3,) for one, got {vector.shape}"
        )
    return vector


def combined_stats(*solutions) -> tuple[RESULTS, dict]:
    result = first_failure(*(solution.result for solution in solutions))
    return result, {
        "residual": jnp.max(jnp.stack([solution.residual for solution in solutions])),
        "num_steps": sum(solution.num_steps for solution in solutions),
    }


def point_masses(n: int, indices, values) -> Array:
    """`(n,)` zeros with `values` added at `indices` (the heat flows' initial conditions)."""
    return jnp.zeros(n, values.dtype).at[indices].add(values)


@kernel
def _transport(mesh: Mesh, solver: _Kept, sources, vectors):
    """`(vectors (nv, 3), result, stats)` of `VectorHeatSolver.transport`."""
    n = mesh.n_vertices
    z = jax.lax.complex(jnp.sum(vectors * solver.e1[sources], -1), jnp.sum(vectors * solver.e2[sources], -1))
    magnitude = jnp.abs(z)
    # Unit directions diffused (as geometry-central): each source steers its own region whatever its magnitude.
    vector_solution = solver.vector_heat.solve(point_masses(n, sources, unit(z)), throw=False)
    solutions = [vector_solution]
    if sources.shape[0] == 1:  # the diffused magnitude over the diffused indicator is |z| exactly
        magnitude = magnitude[0]
    else:
        rhs = jnp.stack([point_masses(n, sources, magnitude), point_masses(n, sources, jnp.ones_like(magnitude))], axis=1)
        scalar_solution = solver.scalar.heat.solve(rhs, throw=False)
        solutions.append(scalar_solution)
        magnitude = safe_div(scalar_solution.value[:, 0], scalar_solution.value[:, 1])  # 0 where no source reaches
    field = unit(vector_solution.value) * magnitude
    value = field.real[:, None] * solver.e1 + field.imag[:, None] * solver.e2
    result, stats = combined_stats(*solutions)
    return value, first_failure(_meaningful(solver), result), stats


def _outward_ball_corners(theta, h, first, second) -> Complex[Array, "3 nf 3"]:
    """The radial field's right-hand side per face and source corner, in closed form (the paper's Appendix A,
    geometry-central's `addVertexOutwardBall`): `[0, f, k]` at the source (corner `k`), `[1, f, k]` at the next
    corner and `[2, f, k]` at the previous one, in those vertices' polar coordinates (`first`, `second` the
    corners' polar angles of their first and second edges, `theta` the corner angles, `h` the heights)."""
    h_next, h_prev = jnp.roll(h, -1, axis=1), jnp.roll(h, -2, axis=1)
    gamma = jnp.roll(theta, -1, axis=1)  # the angle at the next corner
    # Per corner k taken as the source s, with a = the next corner and b = the previous one:
    # the face seen from the edge s -> a (at a), from the edge s -> b (at b), and at s itself.
    along = theta * jnp.cos(theta) - jnp.sin(theta)
    at_next = (-theta * jnp.sin(theta) + 1j * along) / (2.0 * h_next) * jnp.exp(1j * jnp.roll(second, -1, axis=1))
    at_prev = (-theta * jnp.sin(theta) - 1j * along) / (2.0 * h_prev) * jnp.exp(1j * jnp.roll(first, -2, axis=1))
    alpha = jnp.pi / 2.0 - gamma
    at_self = (
        -(theta * jnp.cos(alpha) + jnp.cos(alpha - theta) * jnp.sin(theta)) / (2.0 * h)
        - 1j * (jnp.cos(alpha) - jnp.cos(alpha - 2.0 * theta) + 2.0 * theta * jnp.sin(alpha)) / (4.0 * h)
    ) * jnp.exp(1j * first)
    return jnp.stack([at_self, at_next, at_prev])


def _outward_ball(mesh: Mesh, solver: _Kept, source) -> Array:
    """The radial field's right-hand side at a (possibly traced) source vertex, `(nv,)` complex: the unit
    field pointing away from the source in its one-ring, integrated against the hat functions, in each
    vertex's polar coordinates (the kept `_outward_ball_corners` of the source's corners)."""
    at_self, at_next, at_prev = jnp.where(mesh.faces == source, solver.outward, 0.0)
    # Per corner m of each face: its own value when it is the source, from the previous corners when they are.
    corner = at_self + jnp.roll(at_next, 1, axis=1) + jnp.roll(at_prev, 2, axis=1)
    # One real corner-to-vertex sum of (real, imaginary): XLA:CPU's complex scatter-add is several times slower.
    summed = scatter_corners_to_vertices(mesh, jnp.stack([corner.real, corner.imag], axis=-1))
    return jax.lax.complex(summed[:, 0], summed[:, 1])


def _log_map_steps(mesh: Mesh, solver: _Kept, source):
    """`(log (nv, 2), result, stats)` at a (possibly traced) source vertex: the module docstring's algorithm."""
    n = mesh.n_vertices
    radial = _outward_ball(mesh, solver, source)
    horizontal = jnp.zeros(n, radial.dtype).at[source].set(1.0)
    # Two one-column solves: faster than one two-column solve with a simplicial CHOLMOD factor.
    radial_solution = solver.vector_heat.solve(radial, throw=False)
    horizontal_solution = solver.vector_heat.solve(horizontal, throw=False)
    R = unit(radial_solution.value).at[source].set(0.0)  # no direction at the source (as geometry-central)
    H = unit(horizontal_solution.value)
    if solver.integrated:
        poisson_solution, r = _radius(mesh, solver, R, source)
        result, stats = combined_stats(radial_solution, horizontal_solution, poisson_solution)
    else:
        r, result, stats = _heat_radius(mesh, solver, source, radial_solution, horizontal_solution)
    direction = R * jnp.conj(H)
    reached = solver.scalar.components == solver.scalar.components[source]
    log = jnp.stack([direction.real, direction.imag], axis=-1) * jnp.where(reached, r, 0.0)[:, None]
    log = jnp.where(reached[:, None], log, jnp.inf)
    return log, first_failure(_meaningful(solver), result), stats


def _heat_radius(mesh: Mesh, solver: _Kept, source, *vector_solutions):
    """`(r, result, stats)`: the heat method's distance from the source on the kept intrinsic `M + t L` and `L`
    (`robust=True`), with the outcome and statistics of `vector_solutions` folded in."""
    corners = jnp.full((1, 3), source)
    weights = jnp.zeros((1, 3), solver.t.dtype).at[0, 0].set(1.0)
    steps, heat_result, heat_stats = _heat_method(mesh, solver.scalar, corners, weights)
    vector_result, vector_stats = combined_stats(*vector_solutions)
    stats = {
        "residual": jnp.maximum(heat_stats["residual"], vector_stats["residual"]),
        "num_steps": heat_stats["num_steps"] + vector_stats["num_steps"],
    }
    return steps.distance, first_failure(heat_result, vector_result), stats


def _radius(mesh: Mesh, solver: _Kept, R, source):
    """`(solution, r)`: the distance from the source integrated from the unit radial field `R` (0 at the source).

    On each edge `a -> b` the field's mean tangential component times the length, `f_ab = l (<R_a, e_ab> - <R_b, e_ba>) / 2`
    (`e_ab` the unit edge direction at `a` in polar coordinates), is the difference `r_b - r_a`; `L r = b` with
    `b_a = -sum_b w_ab f_ab` is the least-squares fit of `r` to the `f_ab` with `L`'s edge weights `w_ab`, so
    `L r = L d` exactly when `R` is the gradient of a piecewise linear `d`. `r` is then shifted to 0 at the source."""
    a, b = mesh.edges[:, 0], mesh.edges[:, 1]
    at_a = jnp.real(R[a] * solver.edge_directions[:, 0])
    at_b = jnp.real(R[b] * solver.edge_directions[:, 1])
    # At the source the radial field points along each of its edges: its component there is 1, not 0.
    at_a = jnp.where(a == source, 1.0, at_a)
    at_b = jnp.where(b == source, 1.0, at_b)
    flux = solver.edge_weights * solver.edge_lengths * (at_a - at_b) / 2.0
    rhs = jax.ops.segment_sum(jnp.concatenate([-flux, flux]), jnp.concatenate([a, b]), num_segments=mesh.n_vertices)
    solution, r = solve_held(solver.scalar.poisson, solver.scalar.poisson_plan, rhs)
    return solution, r - r[source]


@kernel
def _log_map(mesh: Mesh, solver: _Kept, source):
    return _log_map_steps(mesh, solver, source)


@kernel(static_argnames=("max_steps",))
def _centroid(mesh: Mesh, solver: _Kept, points, weights, *, max_steps: int):
    """`(GeodesicCentroid, result, stats)` of `geodesic_centroid`: the walk, then the point in one of its faces."""
    total = jnp.sum(weights)
    faces = mesh.faces

    def locate(c):
        """At vertex `c`: the mean log vector `m`, the face of `c` whose layout holds it best, its barycentric
        coordinates there, whether it lies inside, the vertex whose log coordinates are nearest to `m`."""
        log, result, _ = _log_map_steps(mesh, solver, c)
        m = jnp.sum(weights[:, None] * log[points], axis=0) / total
        corners = log[faces]  # (nf, 3, 2): every face laid out by the log map at `c`
        a, first, second = corners[:, 0], corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]
        p = m - a
        det = first[:, 0] * second[:, 1] - first[:, 1] * second[:, 0]
        safe = jnp.where(det != 0, det, 1.0)
        beta = (p[:, 0] * second[:, 1] - p[:, 1] * second[:, 0]) / safe
        gamma = (first[:, 0] * p[:, 1] - first[:, 1] * p[:, 0]) / safe
        barycentric = jnp.stack([1.0 - beta - gamma, beta, gamma], axis=-1)
        usable = jnp.any(faces == c, axis=1) & (det != 0) & jnp.all(jnp.isfinite(corners), axis=(1, 2))
        depth = jnp.where(usable, jnp.min(barycentric, axis=-1), -jnp.inf)
        face = jnp.argmax(depth)
        nearest = jnp.argmin(jnp.where(jnp.isfinite(log[:, 0]), jnp.sum((log - m) ** 2, axis=-1), jnp.inf))
        return face, barycentric[face], depth[face] >= -_INSIDE, nearest, result

    def cond(state):
        _, _, step, done, _ = state
        return ~done & (step < max_steps)

    def body(state):
        c, previous, step, _, result = state
        _, _, inside, nearest, located = locate(c)
        # Inside `c`'s star the walk is over; a walk back to the previous vertex is a tie between the two.
        done = inside | (nearest == c) | (nearest == previous)
        return jnp.where(done, c, nearest), c, step + 1, done, first_failure(result, located)

    start = points[jnp.argmax(weights)]
    c, _, steps, settled, result = jax.lax.while_loop(
        cond, body, (start, jnp.asarray(-1, start.dtype), jnp.asarray(0), jnp.asarray(False), RESULTS.successful)
    )
    face, barycentric, _, _, final = locate(c)
    barycentric = jnp.clip(barycentric, 0.0, None)  # `m` past the mesh's boundary: the nearest point of the face
    barycentric = barycentric / jnp.sum(barycentric)
    position = barycentric @ take_rows(mesh.vertices, faces[face])
    result = first_failure(result, final, RESULTS.where(settled, RESULTS.successful, RESULTS.max_steps_reached))
    return GeodesicCentroid(c, face, barycentric, position), result, {"num_steps": steps}
