"""The intrinsic Delaunay triangulation of a mesh, and its cotan Laplacian and mass matrix.

The cotan weight of an edge, `w_ij = (cot a + cot b) / 2`, is negative where the two angles
opposite it sum past `pi`, and then the cotan Laplacian breaks the discrete maximum principle. The
*intrinsic* Delaunay triangulation keeps the vertices and the surface metric (the piecewise flat
metric of the mesh) and changes only which geodesic edges connect them: an interior edge whose
opposite angles sum past `pi` is flipped to the other diagonal of the quad its two triangles form,
laid flat in the plane, until no such edge is left (Lawson's algorithm, which terminates on any
piecewise flat surface; Bobenko & Springborn 2007). Boundary edges are never flipped (they count as
Delaunay). On the result every interior edge has `w_ij >= 0`, so the Laplacian of its edge lengths
satisfies the maximum principle wherever boundary edges do not spoil it (a boundary edge opposite
an obtuse angle keeps its negative weight, as in libigl).

Intrinsic mollification (Sharp & Crane 2020, section 4.5): before any flip, every edge length is
raised by the one smallest amount `delta >= 0` that gives every triangle the strict triangle
inequality with a margin `eps = mollify_factor * (mean edge length)`,

    delta = max(0, max over faces and corners of (l_C - l_A - l_B + eps)),   l_e <- l_e + delta,

so a face of zero area (collinear or coincident corners) gets a small positive one, and its
cotangents are finite and well conditioned. The flips then work on a surface whose every triangle
is non-degenerate, and the Laplacian is positive semidefinite on every mesh (the cotan Laplacian
of a degenerate mesh is not, in floating point: `ddgjax.mesh._check`). On a mesh without
near-degenerate faces `delta = 0` and nothing changes. `mollify_factor=1e-5` is robust_laplacian's
default; `0` turns mollification off.

Two phases (DESIGN.md):

1. `intrinsic_delaunay(mesh)` flips on the host (NumPy, from the concrete vertex positions) in
   *rounds*: each round evaluates the Delaunay condition on the edges that may have changed, picks
   a set of non-Delaunay edges no two of which share a face (each is the most violating edge among
   those touching its two faces), and flips them all at once. The result, an `IntrinsicTriangulation`,
   records the flipped faces, their vertex-pattern plan and the flips round by round.
2. `IntrinsicTriangulation.face_lengths_sq(mesh)` replays the flips in JAX: the lengths of the mesh
   edges `|p_i - p_j|^2`, mollified (`delta` recomputed from the positions), then a `lax.scan` over steps of a fixed number of flips from one round,
   each computing its new diagonals from the five lengths of their quads in one vectorised step.
   So the intrinsic edge lengths, and the Laplacian and mass matrix built from them
   (`ddgjax.laplacian._lengths`), are jit-compiled, differentiable functions of the vertex
   positions. The scan compiles its step once, whatever the number of rounds (an unrolled program
   took ~0.4 s of XLA compile time per round); step counts are padded to a multiple of 8, so a new
   flip sequence of a similar size often reuses the compiled program. Compiling the replay takes
   ~1 s, its gradient a few seconds (2-core CPU), once per mesh size and flip layout.

Derivatives are those of the *fixed* flipped triangulation. The flips depend on the geometry, but
only through strict inequalities: away from the measure-zero set of positions where some edge is
exactly Delaunay-critical (its opposite angles sum to exactly `pi`), a small motion keeps the same
flips, and the gradient is exact. At a critical edge the operator is still continuous (a co-circular
quad has cotan weight 0 on either diagonal), so one-sided derivatives exist but may differ.

Input: any triangle mesh. An edge-manifold, consistently oriented one (any genus, with or without
boundary; vertex non-manifold "bow ties" are fine) is flipped as it is. One with a non-manifold edge
(three or more faces) or inconsistent orientation (a Moebius strip, flipped faces) is replaced by its
*tufted cover* (`ddgjax.laplacian._tufted`, Sharp & Crane 2020): every face twice, once per
orientation, glued around each edge in angular order, a closed oriented surface, whose flips are
replayed the same way and whose operators are halved (`IntrinsicTriangulation.sheets`), as
robust_laplacian's `mesh_laplacian` on every mesh. The flipped triangulation may join two vertices by
several edges or contain a face that repeats a vertex (an intrinsic triangulation is a
Delta-complex); the operators handle both.

References: A. I. Bobenko, B. A. Springborn, "A discrete Laplace-Beltrami operator for simplicial
surfaces" (2007); M. Fisher, B. Springborn, P. Schroeder, A. I. Bobenko, "An algorithm for the
construction of intrinsic Delaunay triangulations with applications to digital geometry processing"
(2007); N. Sharp, Y. Soliman, K. Crane, "Navigating intrinsic triangulations" (2019); N. Sharp, K.
Crane, "A Laplacian for nonmanifold triangle meshes" (2020) (mollification). libigl
`intrinsic_delaunay_triangulation`, `intrinsic_delaunay_cotmatrix`; robust_laplacian (which uses the
tufted cover on every mesh, and so also flips boundary edges: the same operator on closed meshes, and
on non-manifold or non-oriented ones, where the cover is used here too).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from .._compile import device_array, kernel
from .._errors import DDGInputError, MeshDataError, is_traced
from .._indexing import take_rows
from .._numerics import safe_div, safe_sqrt
from .._options import check_mass
from ..mesh import Mesh, MeshTopology, face_areas_from_lengths_sq, require_mesh
from ..sparse import SparseMatrix
from ._flips import diagonal_after_flip, flip_to_delaunay, mollified, replay_layout
from ._lengths import cotan_laplacian_from_lengths_sq, mass_matrix_from_lengths_sq
from ._plan import TriangulationPlan, triangulation_plan, vertex_plan
from ._tufted import tufted_delaunay


class IntrinsicTriangulation(eqx.Module):
    """The intrinsic Delaunay triangulation of a mesh, as a replayable sequence of edge flips.

    Made by `intrinsic_delaunay(mesh)`. The replay (`face_lengths_sq`) fills a list of squared
    lengths: slots `0 .. ne-1` hold the mesh edges (`mesh.edges` order), and step `s` of the replay
    writes the new diagonals of its flips to slots `ne + s * width + p`.

    Attributes:
        plan: the flipped faces `(nf, 3)` and the storage plan of their operators (`TriangulationPlan`).
        face_length_slots: `(nf, 3)` the slot of the edge opposite each corner of `plan.faces`.
        flip_slots: `(n_steps, 5, width)` int32, per step up to `width` flips of one round (they
            share no face, so no flip of a step reads another's result): the slots of the squared
            lengths `ab, ia, ib, ja, jb` of the triangles `(i, a, b)` and `(j, b, a)` sharing the
            flipped edge `ab`. Padding columns read slot 0, and their results are never read.
        topology: the mesh's topology (static): the triangulation fits meshes with this connectivity.
        n_flips: total number of flips (static).
        n_rounds: number of rounds of independent flips on the host (static).
        mollify_factor: the mollification margin relative to the mean edge length (static; module
            docstring), applied to the mesh's lengths before the flips, on the host and in the replay.
        sheets: how many times the triangulation covers the mesh (static): 1 on an edge-manifold,
            consistently oriented mesh (its faces, flipped); 2 for the tufted cover of any other mesh
            (`2 nf` faces, every face once per orientation), whose operators are divided by 2.
    """

    plan: TriangulationPlan
    face_length_slots: Int[Array, "nf 3"]
    flip_slots: Int[Array, "n_steps 5 width"]
    topology: MeshTopology = eqx.field(static=True)
    n_flips: int = eqx.field(static=True)
    n_rounds: int = eqx.field(static=True)
    mollify_factor: float = eqx.field(static=True)
    sheets: int = eqx.field(static=True, default=1)

    @property
    def faces(self) -> Int[Array, "nf 3"]:
        """`(nf, 3)` the faces after the flips (counterclockwise where the mesh's are; `(2 nf, 3)` for a tufted cover)."""
        return self.plan.faces

    def face_lengths_sq(self, mesh: Mesh) -> Float[Array, "nf 3"]:
        """`(nf, 3)` squared intrinsic length of the edge opposite each corner of `self.faces`, for `mesh`'s vertices.

        The mesh's lengths mollified, then the flips replayed in JAX (module docstring):
        differentiable in `mesh.vertices`, under jit, grad and vmap (the mollification's `delta`,
        a maximum over faces, is differentiated where it is attained). libigl: the `l_intrinsic` of
        `intrinsic_delaunay_cotmatrix`, squared (which does not mollify).
        """
        mesh = _check_fits(self, mesh)
        return replayed_lengths_sq(
            mesh.vertices,
            mesh.edges,
            mesh.face_edges,
            self.flip_slots,
            self.face_length_slots,
            mollify_factor=self.mollify_factor,
        )


def intrinsic_delaunay(mesh: Mesh, *, mollify_factor: float = 1e-5) -> IntrinsicTriangulation:
    r"""Mollify `mesh`'s intrinsic metric, then flip its edges until every interior edge is Delaunay (host, NumPy).

    First the edge lengths are mollified (module docstring): each raised by the smallest `delta >= 0`
    that gives every triangle a strict triangle inequality with margin `mollify_factor` times the
    mean edge length (`0` turns it off; nothing changes on a mesh without near-degenerate faces).

    An interior edge `ab` with triangles `(i, a, b)` and `(j, b, a)` is Delaunay when its opposite
    angles satisfy $\alpha_i + \alpha_j \le \pi$, i.e. $\cot\alpha_i + \cot\alpha_j \ge 0$ (up to rounding,
    `DELAUNAY_TOLERANCE`); boundary edges are always Delaunay. A non-Delaunay edge is replaced by
    the diagonal `ij` of the quad laid flat: with `n_i = l_ab^2 + l_ia^2 - l_ib^2`,
    `n_j = l_ab^2 + l_ja^2 - l_jb^2` (`2 l_ab` times the projections of `i` and `j` onto `ab`) and the
    areas `A_i`, `A_j` of the two triangles,

    $$\ell_{ij}^2 = \frac{(n_i - n_j)^2 + 16 (A_i + A_j)^2}{4 \ell_{ab}^2}.$$

    The flips change neither the vertices nor the (mollified) metric; only the edges. Flips run in rounds
    of independent flips (module docstring), recorded for the JAX replay. Once per vertex positions:
    pass the result as `triangulation=` to the operators to reuse it (inside jit too).

    A mesh with a non-manifold edge or inconsistently oriented faces is replaced by its tufted cover
    (module docstring; `sheets=2`), which is then mollified and flipped the same way (boundary edges
    included: the cover has none), as robust_laplacian's `mesh_laplacian`.

    Args:
        mesh: a triangle mesh with concrete (not traced) vertices.
        mollify_factor: the mollification margin relative to the mean edge length, `>= 0`
            (keyword-only; robust_laplacian's `mollify_factor`, default `1e-5` as there).

    Returns:
        `IntrinsicTriangulation`.

    Raises `DDGInputError` for traced vertices, a non-mesh or a bad `mollify_factor`,
    `MeshDataError` for every vertex at one point (no length to mollify with).

    References: Bobenko & Springborn (2007); Fisher et al. (2007); Sharp & Crane (2020). libigl
    `intrinsic_delaunay_triangulation` (one flip at a time from a queue, no mollification; manifold
    meshes only); geometry-central `mollifyIntrinsic` then `flipToDelaunay` (`buildIntrinsicTuftedCover` first).

    Examples:
        >>> import jax.numpy as jnp
        >>> import ddgjax
        >>> sphere = ddgjax.mesh.icosphere(2)
        >>> flat = sphere.with_vertices(sphere.vertices * jnp.array([1.0, 1.0, 0.1]))  # obtuse triangles
        >>> triangulation = ddgjax.laplacian.intrinsic_delaunay(flat)
        >>> def largest_off_diagonal(L):
        ...     return float(jnp.max(L.todense() - jnp.diag(L.diagonal())))
        >>> largest_off_diagonal(ddgjax.laplacian.cotan_laplacian(flat)) > 0  # a negative edge weight
        True
        >>> largest_off_diagonal(ddgjax.laplacian.intrinsic_delaunay_laplacian(flat, triangulation=triangulation)) <= 1e-12
        True
    """
    mesh = require_mesh("mesh", mesh)
    if not (
        np.isscalar(mollify_factor) and np.isreal(mollify_factor) and np.isfinite(mollify_factor) and mollify_factor >= 0
    ) or isinstance(mollify_factor, (bool, np.bool_)):
        raise DDGInputError(
            f"mollify_factor: expected a finite number >= 0 (robust_laplacian's default 1e-5), got {mollify_factor!r}"
        )
    mollify_factor = float(mollify_factor)
    if is_traced(mesh.vertices):
        raise DDGInputError(
            "mesh: intrinsic_delaunay flips edges on the host and needs concrete vertex positions, got traced ones; "
            "build triangulation = intrinsic_delaunay(mesh) outside jit / grad / vmap and pass triangulation=triangulation"
        )
    topology = mesh.topology
    if topology is None:
        raise DDGInputError("mesh: intrinsic_delaunay needs the mesh's topology (a mesh made by Mesh.from_arrays or load_mesh)")
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    edges = topology.edges
    lengths_sq = np.sum((vertices[edges[:, 1]] - vertices[edges[:, 0]]) ** 2, axis=1)
    if not np.any(lengths_sq > 0):
        raise MeshDataError(
            "mesh: every vertex lies at one point (all edges have zero length): there is no metric to mollify "
            "or to build operators from"
        )
    if not topology.is_oriented:
        return _tufted_intrinsic_delaunay(vertices, topology, mollify_factor)
    lengths_sq = mollified(lengths_sq, topology.face_edges, mollify_factor, np, np.sqrt, np.take)
    faces, face_edges, rounds = flip_to_delaunay(topology, lengths_sq)
    # Without flips the triangulation is the mesh's: share the cached plan (and pattern) of `cotan_laplacian(mesh)`.
    plan = triangulation_plan(faces, topology.n_vertices) if rounds else vertex_plan(mesh)
    flip_slots, face_length_slots = replay_layout(rounds, face_edges, topology.n_edges)
    return IntrinsicTriangulation(
        plan=plan,
        face_length_slots=device_array(face_length_slots),
        flip_slots=device_array(flip_slots),
        topology=topology,
        n_flips=sum(quads.shape[0] for quads in rounds),
        n_rounds=len(rounds),
        mollify_factor=mollify_factor,
    )


def _tufted_intrinsic_delaunay(vertices: np.ndarray, topology: MeshTopology, mollify_factor: float) -> IntrinsicTriangulation:
    """`intrinsic_delaunay` of a non-manifold or non-oriented mesh: its flipped tufted cover (`sheets=2`)."""

    cover = tufted_delaunay(vertices, topology.faces, mollify_factor)
    # The cover's distinct edges are the mesh's (both the sorted distinct vertex pairs), so the replay reads mesh.edges.
    if not (np.array_equal(cover.edges, topology.edges) and np.array_equal(cover.face_edges, topology.face_edges)):
        raise RuntimeError("intrinsic_delaunay: the tufted cover's edges differ from the mesh's (please report this mesh)")
    return IntrinsicTriangulation(
        plan=triangulation_plan(cover.faces, topology.n_vertices),
        face_length_slots=device_array(cover.face_length_slots),
        flip_slots=device_array(cover.flip_slots),
        topology=topology,
        n_flips=cover.n_flips,
        n_rounds=cover.n_rounds,
        mollify_factor=mollify_factor,
        sheets=2,
    )


def intrinsic_delaunay_laplacian(mesh: Mesh, *, triangulation: IntrinsicTriangulation | None = None) -> SparseMatrix:
    """The cotan Laplacian of the intrinsic Delaunay triangulation (PSD, weak / integrated), a `SparseMatrix`.

    `L_ij = -(cot a_ij + cot b_ij) / 2` over the edges `ij` of the intrinsic Delaunay triangulation,
    `L_ii = -sum_{j != i} L_ij` (DESIGN.md's sign: `L == -igl.intrinsic_delaunay_cotmatrix(V, F)[0]`),
    from its squared edge lengths (`IntrinsicTriangulation.face_lengths_sq`,
    `cotan_laplacian_from_lengths_sq`). Every interior edge has a non-negative weight (up to a
    rounding-sized tolerance, `DELAUNAY_TOLERANCE`), so harmonic functions obey the maximum
    principle (boundary edges: module docstring). Equals
    `cotan_laplacian(mesh)` (to rounding, on the same pattern) on a mesh that is already intrinsically
    Delaunay and has no near-degenerate face. Flagged symmetric positive semidefinite, and it is on
    every mesh: the mollified triangles all have positive areas (module docstring), where the cotan
    Laplacian of a mesh with zero-area faces is indefinite by rounding.

    Differentiable in `mesh.vertices`, under jit / grad / vmap, when `triangulation` is given: the
    derivative of the fixed flipped triangulation, exact away from Delaunay-critical positions
    (module docstring). Without it the flips are computed here, on the host, from the concrete
    vertices (`intrinsic_delaunay(mesh)`); a traced mesh then raises `DDGInputError`.

    Args:
        mesh: a triangle mesh (non-manifold and non-oriented ones: the tufted cover, `intrinsic_delaunay`).
        triangulation: `intrinsic_delaunay(mesh)` for this connectivity (keyword-only), or `None`.

    Returns:
        `(nv, nv)` `SparseMatrix` on `triangulation.plan.pattern`.

    References: Bobenko & Springborn (2007); Fisher et al. (2007); Sharp & Crane (2020). libigl
    `intrinsic_delaunay_cotmatrix` (negated; no mollification, so equal where `delta = 0`);
    `robust_laplacian.mesh_laplacian(V, F, mollify_factor=...)` with the triangulation's
    `mollify_factor` (default `1e-5` in both) on closed meshes and on non-manifold or non-oriented ones
    (both use the tufted cover there, halved).
    """
    triangulation = _triangulation_for(mesh, triangulation)
    L = cotan_laplacian_from_lengths_sq(triangulation.face_lengths_sq(mesh), triangulation.plan)
    return L if triangulation.sheets == 1 else L / triangulation.sheets


def intrinsic_delaunay_mass_matrix(
    mesh: Mesh, *, triangulation: IntrinsicTriangulation | None = None, mass: str = "voronoi"
) -> SparseMatrix:
    """Mass matrix of the intrinsic Delaunay triangulation, a `SparseMatrix`.

    The mass matrix of the intrinsic triangles (`mass_matrix_from_lengths_sq` on
    `IntrinsicTriangulation.face_lengths_sq`), `mass` one of `ddgjax.MASS_MATRICES`:
    `"voronoi"` (default, as `mass_matrix`) sums the mixed Voronoi area of Meyer et al. 2003 of each
    intrinsic triangle at a vertex, as libigl's `massmatrix_intrinsic(l, F, MASSMATRIX_TYPE_VORONOI)`
    on the intrinsic triangulation; `"barycentric"` a third of each triangle, the mass matrix of
    `robust_laplacian.mesh_laplacian`; `"galerkin"` the consistent FEM mass matrix of the intrinsic
    hat functions (on the intrinsic Laplacian's pattern). The total is the surface area (flips keep
    the metric), or slightly more where mollification lengthened the edges of near-degenerate faces
    (module docstring). Pairs with `intrinsic_delaunay_laplacian` (pass the same `triangulation`):
    `-M^{-1} L` is the pointwise Laplace-Beltrami operator. Differentiable in `mesh.vertices` as the
    Laplacian is.

    Args:
        mesh: a triangle mesh (non-manifold and non-oriented ones: the tufted cover, `intrinsic_delaunay`).
        triangulation: `intrinsic_delaunay(mesh)` (keyword-only), or `None` to compute it here.
        mass: `"voronoi"`, `"barycentric"` or `"galerkin"` (keyword-only).

    Returns:
        `(nv, nv)` `SparseMatrix`, symmetric positive semidefinite: diagonal for the lumped masses.

    Reference: Meyer, Desbrun, Schroeder, Barr (2003); libigl `massmatrix_intrinsic`.
    """
    check_mass(mass)  # before any flips
    triangulation = _triangulation_for(mesh, triangulation)
    M = mass_matrix_from_lengths_sq(triangulation.face_lengths_sq(mesh), triangulation.plan, mass=mass)
    return M if triangulation.sheets == 1 else M / triangulation.sheets


def _triangulation_for(mesh: Mesh, triangulation) -> IntrinsicTriangulation:
    if triangulation is None:
        return intrinsic_delaunay(mesh)
    if not isinstance(triangulation, IntrinsicTriangulation):
        raise DDGInputError(
            f"triangulation: expected an IntrinsicTriangulation from intrinsic_delaunay(mesh), got {type(triangulation).__name__}"
        )
    return triangulation


def _check_fits(triangulation: IntrinsicTriangulation, mesh) -> Mesh:
    mesh = require_mesh("mesh", mesh)
    # Inside ddgjax's own kernels a mesh has no topology; the edge count is then the check left.
    fits = (
        mesh.topology == triangulation.topology if mesh.topology is not None else mesh.n_edges == triangulation.topology.n_edges
    )
    if not fits:
        raise DDGInputError(
            f"triangulation: was built for another connectivity (a mesh with {triangulation.topology.n_vertices} vertices "
            f"and {triangulation.topology.n_faces} faces), got a mesh with {mesh.n_vertices} vertices and {mesh.n_faces} "
            "faces; build it with intrinsic_delaunay(mesh) for this mesh"
        )
    return mesh


@kernel(static_argnames=("mollify_factor",))
def replayed_lengths_sq(
    vertices: Float[Array, "nv 3"],
    edges: Int[Array, "ne 2"],
    face_edges: Int[Array, "nf 3"],
    flip_slots: Int[Array, "n_steps 5 width"],
    face_length_slots: Int[Array, "n_out 3"],
    *,
    mollify_factor: float,
) -> Float[Array, "n_out 3"]:
    """The mesh's squared edge lengths, mollified, then one scan step per block of flips (`IntrinsicTriangulation`).

    `face_edges` are the input's faces (mollification), `face_length_slots` the flipped faces (twice as many for a
    tufted cover, `ddgjax.laplacian._tufted`)."""
    vectors = take_rows(vertices, edges[:, 1]) - take_rows(vertices, edges[:, 0])
    mesh_lengths_sq = mollified(jnp.sum(vectors * vectors, axis=-1), face_edges, mollify_factor, jnp, safe_sqrt, take_rows)
    n_steps, _, width = flip_slots.shape
    lengths_sq = jnp.concatenate([mesh_lengths_sq, jnp.zeros(n_steps * width, vertices.dtype)])

    def step(lengths_sq, quads_and_start):
        quads, start = quads_and_start
        # One gather per quad edge: (width,) arrays, with no transposes for XLA to materialise in reverse mode.
        quad_lengths_sq = [take_rows(lengths_sq, quads[k]) for k in range(5)]
        diagonals = diagonal_after_flip(quad_lengths_sq, face_areas_from_lengths_sq, safe_div, jnp.stack)
        return jax.lax.dynamic_update_slice(lengths_sq, diagonals, (start,)), None

    if n_steps:  # (no flips: the step would not even trace, its update being wider than the list)
        starts = edges.shape[0] + width * jnp.arange(n_steps, dtype=flip_slots.dtype)
        lengths_sq, _ = jax.lax.scan(step, lengths_sq, (flip_slots, starts))
    return take_rows(lengths_sq, face_length_slots)
