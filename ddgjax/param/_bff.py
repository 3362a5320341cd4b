"""Boundary First Flattening (Sawhney & Crane 2017): conformal flattening with control of the boundary.

A conformal map of a disk is determined, up to rigid motion, by its log scale factor `u` on the
boundary or by the curvature (exterior angles) `k~` of its boundary curve; BFF converts one into the
other with one Poisson solve, builds the boundary curve, and extends it into the interior.

Discrete data (`L` the PSD cotan Laplacian, angle defects from `ddgjax.mesh.vertex_angle_defects`):
`Omega_i = 2 pi - sum theta` at interior vertices (integrated Gaussian curvature) and
`k_i = pi - sum theta` at boundary vertices (integrated geodesic curvature). A conformal change by
`e^u` changes the integrated curvature by `L u` (the smooth `K~ dA~ = (K - Delta u) dA`, with
`L = -Delta` weakly):

    Omega~ = Omega + L u (interior),   k~ = k + L u (boundary).

- Dirichlet-to-Neumann (`u` on the boundary given, default 0): a flat interior (`Omega~ = 0`) means
  `(L u)_I = -Omega_I`, a Dirichlet problem for `u_I`; then `k~ = k + (L u)_B`.
- Neumann-to-Dirichlet (`k~` given; must sum to `2 pi`, Gauss-Bonnet): `L u = [-Omega_I; k~ - k_B]`,
  a Neumann problem solved with one vertex pinned (the right-hand side sums to 0 exactly); `u` is
  then shifted to zero boundary-length-weighted mean (the constant is the map's global scale).

Boundary curve: target edge lengths `l~_p = exp((u_a + u_b) / 2) l_p` for the boundary edge
`p = (a, b)`, tangent directions `T_p = (cos phi_p, sin phi_p)` with `phi_0 = 0` and
`phi_p = phi_{p-1} + k~_{loop[p]}`. The polygon `sum_p l~_p T_p` need not close; the closest lengths
that close it, minimising `sum_p (l*_p - l~_p)^2 / l~_p` subject to `sum_p l*_p T_p = 0`, are
`l*_p = l~_p (1 + T_p . lambda)` with the `2 x 2` system `(sum_p l~_p T_p T_p^T) lambda = -sum_p l~_p T_p`
(the paper's minimal length correction; the directions, so the angles `k~`, are kept). The vertices
are the partial sums, `loop[0]` at the origin and the first boundary edge along `+x`.

Interior: harmonic extension of both coordinates with the cotan Laplacian (the paper's extension by
harmonic functions; the same free-free block as the Dirichlet-to-Neumann step, factored once).

Targets (`shape=`, as the fixed-boundary maps name theirs): `"circle"`, the flat disk,
`k~_i = 2 pi l_i* / perimeter` with `l_i*` the dual boundary length (constant curvature);
`"rectangle"`, `k~ = pi / 2` at four corner vertices and 0 elsewhere, so four right angles and
straight sides (the aspect ratio is the conformal one, not fixed).

Everything is differentiable in the vertex positions and in `boundary_scale` / `boundary_angles`
(`ddgjax.solve.linear_solve`'s implicit differentiation), under `jit`, `grad` and `vmap`. Two solves
run (the Poisson problem of the conversion, the extension); the map's outcome is the first failing
one's (`throw=`). Eagerly, one compiled program assembles the systems, the free-free block is factored
and the Neumann-to-Dirichlet system solved outside every program (their host checks included), and a
second program does the rest, so both programs can be kept across processes (`ddgjax._program_store`);
under `jit` / `grad` / `vmap` all of it is traced into the caller's program.

Reference: R. Sawhney, K. Crane, "Boundary First Flattening", ACM Trans. Graph. 37(1), 2017, sections
4-5 (Dirichlet-to-Neumann and Neumann-to-Dirichlet maps, curve construction, minimal length
correction, extension). Reference implementation: geometry-central's / the authors' `bff` program.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int

from .._compile import kernel
from .._errors import DDGInputError, check_choice, is_traced
from .._indexing import take_rows
from .._options import check_solver
from .._results import Solution, outcome
from ..laplacian import cotan_laplacian
from ..laplacian.internal import vertex_plan
from ..mesh import Mesh, vertex_angle_defects
from ..solve import factorize, linear_solve
from ..solve.internal import cholmod_analysis
from ..sparse import dirichlet_blocks, dirichlet_plan
from ._disk import (
    boundary_dual_lengths,
    boundary_edge_lengths,
    boundary_values,
    cached_plan,
    on_device,
    require_disk,
)
from ._tutte import boundary_plan, harmonic_extension, solves_outcome

SHAPES = ("circle", "rectangle")
"""`shape=` of `boundary_first_flattening`: a circle (the flat disk) or a rectangle of free aspect ratio."""
# Tolerance of the Gauss-Bonnet check of concrete `boundary_angles` (their sum must be 2 pi).
_ANGLE_SUM_TOLERANCE = 1e-6


def boundary_first_flattening(
    mesh: Mesh,
    *,
    boundary_scale: Float[ArrayLike, " nb"] | None = None,
    boundary_angles: Float[ArrayLike, " nb"] | None = None,
    shape: str | None = None,
    corners: Int[ArrayLike, " 4"] | None = None,
    solver: str = "auto",
    throw: bool = True,
) -> Float[Array, "nv 2"] | Solution:
    r"""Conformal flattening of a disk-topology mesh by Boundary First Flattening (module docstring), `(nv, 2)`.

    $$\tilde\ell_{ij} = e^{(u_i + u_j)/2} \, \ell_{ij}, \qquad \tilde\kappa = \kappa - \partial u / \partial n$$

    Give at most one of `boundary_scale`, `boundary_angles`, `shape`; with none, $u = 0$ on the
    boundary: the conformal map that keeps boundary lengths (least area distortion along the
    boundary; on a hemisphere, the stereographic projection).

    Args:
        mesh: a topological disk (else `DDGInputError`).
        boundary_scale: `(nb,)` log scale factors `u` at the boundary vertices (loop order,
            `mesh.topology.boundary_loops[0]`): boundary lengths scale by `exp(u)`.
        boundary_angles: `(nb,)` target exterior (turning) angles `k~` of the boundary curve at the
            boundary vertices, summing to `2 pi` (checked when concrete; `DDGInputError`).
        shape: `"circle"` (the flat disk: constant curvature) or `"rectangle"` (four right-angle
            corners, straight sides).
        corners: for `shape="rectangle"`: four distinct boundary vertex indices, in loop order.
            Default: `loop[round(j nb / 4)]`, `j = 0..3` (spread by count along the loop).
        solver: the `ddgjax.solve.linear_solve` backend (`ddgjax.LINEAR_SOLVERS`).
        throw: raise when a solve fails (default), or return a `ddgjax.Solution` (`result`: the
            first failing solve's; `stats`: their largest `"residual"` and total `"num_steps"`).

    Returns:
        `(nv, 2)` positions, `loop[0]` at the origin, the first boundary edge along `+x`,
        unreferenced vertices at the origin (in a `ddgjax.Solution` with `throw=False`).
        Differentiable in the vertex positions and in `boundary_scale` / `boundary_angles`.

    Reference: Sawhney & Crane 2017. libigl / gpytoolbox: none; the authors' `bff` command line tool.

    Examples:
        >>> import jax.numpy as jnp
        >>> import ddgjax
        >>> disk = ddgjax.mesh.disk(4)
        >>> cap = disk.with_vertices(disk.vertices.at[:, 2].set(1.0 - jnp.sum(disk.vertices[:, :2] ** 2, axis=1)))
        >>> uv = ddgjax.param.boundary_first_flattening(cap, shape="circle")
        >>> uv.shape, int(ddgjax.param.map_distortion(cap, uv).flipped.sum())
        ((61, 2), 0)
    """
    check_solver(solver)
    given = [
        name
        for name, value in (("boundary_scale", boundary_scale), ("boundary_angles", boundary_angles), ("shape", shape))
        if value is not None
    ]
    if len(given) > 1:
        raise DDGInputError(
            f"{', '.join(given)}: give at most one of boundary_scale, boundary_angles and shape, got {len(given)}"
        )
    if shape is not None:
        check_choice("shape", shape, SHAPES)
    if corners is not None and shape != "rectangle":
        raise DDGInputError("corners: only shape='rectangle' takes corners")
    disk = require_disk(mesh, "boundary_first_flattening")
    loop = disk.loop
    scale = None if boundary_scale is None else boundary_values("boundary_scale", boundary_scale, disk, ())
    angles = None if boundary_angles is None else boundary_values("boundary_angles", boundary_angles, disk, ())
    if angles is not None and not is_traced(angles):
        total = float(np.sum(np.asarray(angles)))  # on the host: no eager program
        if abs(total - 2 * np.pi) > _ANGLE_SUM_TOLERANCE:
            raise DDGInputError(
                f"boundary_angles: the exterior angles of a closed simple curve sum to 2 pi (Gauss-Bonnet), got "
                f"{total!r}; rescale them or spread the difference along the boundary"
            )
    corner_mask = _corner_mask(disk.loop, corners) if shape == "rectangle" else None
    dirichlet = boundary_plan(mesh, disk)
    neumann = None
    if angles is not None or shape is not None:
        fixed = np.concatenate([loop[:1], disk.unreferenced])
        neumann = cached_plan(disk, "bff-neumann", lambda: dirichlet_plan(vertex_plan(mesh).pattern, fixed))
    uv, result, stats = _flatten(
        mesh,
        cotan_laplacian(mesh),
        dirichlet,
        neumann,
        on_device(disk, "loop"),
        scale,
        angles,
        corner_mask,
        shape=shape,
        solver=solver,
    )
    return outcome(uv, result, throw, stats)


def _corner_mask(loop: np.ndarray, corners) -> np.ndarray:
    """`(nb,)` bool mask of the rectangle's corners along the loop (checked; default: spread by count)."""
    nb = loop.size
    if nb < 4:
        raise DDGInputError(f"mesh: a rectangle layout needs at least 4 boundary vertices, this boundary has {nb}")
    if corners is None:
        positions = np.round(np.arange(4) * nb / 4).astype(np.int64)
    else:
        if is_traced(corners):
            raise DDGInputError("corners: the corner vertices must be concrete indices, not traced")
        corners = np.asarray(corners)
        if corners.shape != (4,) or not np.issubdtype(corners.dtype, np.integer):
            raise DDGInputError(
                f"corners: expected 4 integer boundary vertex indices, got shape {corners.shape} dtype {corners.dtype}"
            )
        where = {int(v): p for p, v in enumerate(loop)}
        missing = [int(c) for c in corners if int(c) not in where]
        if missing:
            raise DDGInputError(f"corners: vertices {missing} are not on the boundary loop")
        positions = np.array([where[int(c)] for c in corners])
        if np.unique(positions).size != 4:
            raise DDGInputError(f"corners: expected 4 distinct boundary vertices, got {corners.tolist()}")
    mask = np.zeros(nb, dtype=bool)
    mask[positions] = True
    return mask


def _flatten(mesh, L, dirichlet, neumann, loop, scale, angles, corner_mask, *, shape, solver):
    """`(uv, result, stats)` of `boundary_first_flattening`: `_systems`, the factorisation of the Dirichlet
    block and the Neumann-to-Dirichlet solve (`ddgjax.solve`, eagerly outside every program), then `_map`."""
    block, problem, angles = _systems(mesh, L, dirichlet, neumann, loop, angles, corner_mask, shape=shape)
    # The factorisation CHOLMOD chooses, as when it was made inside the map's program (two solves use it).
    with cholmod_analysis("auto"):
        factor = None if block is None else factorize(block, solver=solver)
    conversion = None if problem is None else linear_solve(*problem, solver=solver, throw=False)
    return _map(mesh, L, dirichlet, neumann, loop, factor, conversion, scale, angles)


# One program per mesh size for each kernel; the Laplacian (a kernel of its own) and the plans are made outside.
@kernel(static_argnames=("shape",))
def _systems(mesh, L, dirichlet, neumann, loop, angles, corner_mask, *, shape):
    """`(L_II, (L_nn, b) or None, k~ or None)`: the free-free block of `L` with the boundary held (`None`
    when no vertex is free) and, when the target angles `k~` are given or set by `shape`, the
    Neumann-to-Dirichlet system `L u = [-Omega_I; k~ - k_B]` with one vertex pinned (module docstring)."""
    dtype = L.values.dtype
    block = None if dirichlet is None else dirichlet_blocks(L, dirichlet)[0]
    if shape == "circle":
        duals = boundary_dual_lengths(boundary_edge_lengths(mesh.vertices, loop))
        angles = 2.0 * jnp.pi * duals / jnp.sum(duals)
    elif shape == "rectangle":
        angles = jnp.where(jnp.asarray(corner_mask), 0.5 * jnp.pi, 0.0).astype(dtype)
    if angles is None:
        return block, None, None
    angles = angles.astype(dtype)
    defects = vertex_angle_defects(mesh)
    rhs = (-defects).at[loop].set(angles - take_rows(defects, loop))
    return block, (dirichlet_blocks(L, neumann)[0], rhs[neumann.free]), angles


@kernel
def _map(mesh, L, dirichlet, neumann, loop, factor, conversion, scale, angles):
    """`(uv, result, stats)` from `_systems`'s factored block `factor` and the solved Neumann-to-Dirichlet
    `conversion` (`None` when `angles` is `None`: then the Dirichlet-to-Neumann solve runs here)."""
    dtype = L.values.dtype
    lengths = boundary_edge_lengths(mesh.vertices, loop)
    nb, n = loop.shape[0], mesh.n_vertices
    if angles is None:
        # Dirichlet-to-Neumann: (L u)_I = -Omega_I with u_B given, then k~ = k + (L u)_B.
        defects = vertex_angle_defects(mesh)
        u_boundary = jnp.zeros(nb, dtype) if scale is None else scale.astype(dtype)
        if dirichlet is None:
            u = jnp.zeros(n, dtype).at[loop].set(u_boundary)
        else:
            n_unreferenced = dirichlet.fixed.shape[0] - nb
            fixed = jnp.concatenate([u_boundary, jnp.zeros(n_unreferenced, dtype)])
            free_fixed = dirichlet_blocks(L, dirichlet)[1]
            conversion = factor.solve(-defects[dirichlet.free] - free_fixed @ fixed, throw=False)
            u = dirichlet.join(conversion.value, fixed)
        angles = take_rows(defects + L @ u, loop)
    else:
        # Neumann-to-Dirichlet (solved by `_flatten`): u with its pinned vertex at 0, then centred.
        u = neumann.join(conversion.value, jnp.zeros(neumann.fixed.shape[0], dtype))
        u_loop = take_rows(u, loop)
        duals = boundary_dual_lengths(lengths)
        u_boundary = u_loop - jnp.sum(duals * u_loop) / jnp.sum(duals)
    curve = _boundary_curve(lengths, u_boundary, angles)
    uv, extension = harmonic_extension(L, dirichlet, factor, loop, curve)
    return uv, *solves_outcome(conversion, extension)


def _boundary_curve(lengths: Float[Array, " nb"], u: Float[Array, " nb"], angles: Float[Array, " nb"]) -> Float[Array, "nb 2"]:
    """Closed polygon with edge lengths `exp((u_a + u_b) / 2) l` and exterior angles `angles` (module docstring)."""
    target = jnp.exp(0.5 * (u + jnp.roll(u, -1))) * lengths
    phi = jnp.cumsum(angles) - angles[0]
    tangents = jnp.stack([jnp.cos(phi), jnp.sin(phi)], axis=-1)
    gram = jnp.einsum("p,pi,pj->ij", target, tangents, tangents)
    multiplier = jnp.linalg.solve(gram, -(target @ tangents))
    closed = target * (1.0 + tangents @ multiplier)
    steps = closed[:, None] * tangents
    return jnp.cumsum(steps, axis=0) - steps
