"""Shape-optimisation objectives of a mesh: the Willmore energy and PyTorch3D's mesh regularisers.

Each is a plain scalar JAX function of a `Mesh`, differentiable in `mesh.vertices`
(`jax.grad(lambda V: objective(mesh.with_vertices(V)))(V)`), usable under `jit` / `vmap`, NaN-safe on
degenerate triangles (DESIGN.md, Numerics). Curvature follows the library's conventions: `H` is the
mean of the principal curvatures (`1/r` on a sphere of radius `r`), the integrated mean curvature
normal is `(H N A)_i = (L V)_i / 2` with the PSD cotan Laplacian `L` (DESIGN.md).

The regularisers reproduce the losses of PyTorch3D's mesh-fitting tutorial (`mesh_edge_loss`,
`mesh_normal_consistency`, `mesh_laplacian_smoothing`) for one mesh, so a loss written against
PyTorch3D moves over unchanged; each docstring states the formula and where it differs.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from .._indexing import take_rows
from .._numerics import safe_div, safe_norm
from .._options import check_weights
from ..mesh import (
    Mesh,
    edge_cotan_weights,
    edge_dihedral_angles,
    edge_lengths,
    require_mesh,
    vertex_dual_areas,
    vertex_mean_curvature_normals,
)


def willmore_energy(mesh: Mesh, *, dual: str = "voronoi") -> Float[Array, ""]:
    r"""Discrete Willmore energy `W = sum_i H_i^2 A_i = sum_i |(H N A)_i|^2 / A_i`, a scalar `()`.

    $$W = \sum_i H_i^2 A_i = \sum_i \frac{\lVert (H N A)_i \rVert^2}{A_i}, \qquad (H N A)_i = \tfrac12 (L V)_i$$

    `(H N A)_i = (L V)_i / 2` is the integrated mean curvature normal
    (`ddgjax.mesh.vertex_mean_curvature_normals`), `A_i` the dual area of vertex `i`
    (`vertex_dual_areas(mesh, dual=dual)`, the mixed Voronoi area by default), so that
    `H_i = |L V|_i / (2 A_i)` is the pointwise mean curvature. Smooth counterpart: $W = \int H^2 \, dA$
    with $H = (\kappa_1 + \kappa_2) / 2$: $4\pi$ for every round sphere (its minimum over closed surfaces) and
    `pi^2 c^2 / sqrt(c^2 - 1)` for the torus of revolution with radii ratio `c = R / r` (`2 pi^2`,
    the Clifford torus, at `c = sqrt 2`); it is invariant under scaling. Some authors integrate
    `(k1 - k2)^2 / 4 = H^2 - K` instead, which differs by `2 pi chi` on a closed surface (Gauss-Bonnet).

    Boundary vertices are left out: there `(L V)_i` contains the boundary's geodesic curvature and is
    not a mean curvature normal. A vertex of zero dual area contributes 0 (finite gradient).
    Needs no orientation (`|H|` is unsigned).

    Reference: M. Meyer, M. Desbrun, P. Schroeder, A. Barr, "Discrete differential-geometry operators
    for triangulated 2-manifolds" (2003); T. J. Willmore, "Note on embedded surfaces" (1965).
    libigl: `HN = -Minv @ igl.cotmatrix(V, F) @ V / 2`, then `sum(|HN|^2 * Mdiag)`.

    Args:
        mesh: the mesh.
        dual: the dual cell of the areas `A_i`, `ddgjax.DUAL_CELLS` (keyword-only; default `"voronoi"`).

    Returns:
        Scalar float array `()`, `>= 0`.
    """
    mesh = require_mesh("mesh", mesh)
    normals = vertex_mean_curvature_normals(mesh)
    areas = vertex_dual_areas(mesh, dual=dual)
    density = safe_div(jnp.sum(normals * normals, axis=-1), areas)
    return jnp.sum(jnp.where(_boundary_vertex_mask(mesh), 0.0, density))


def edge_length_loss(mesh: Mesh, *, target_length: float | Float[Array, ""] = 0.0) -> Float[Array, ""]:
    """Mean squared deviation of the edge lengths from `target_length`, `mean_e (|e| - t)^2`, a scalar `()`.

    With the default `t = 0` it is the mean squared edge length (computed without a square root),
    which pulls a mesh together evenly. PyTorch3D: `mesh_edge_loss(meshes, target_length)` (one mesh;
    the same formula).

    Args:
        mesh: the mesh.
        target_length: the target edge length `t` (keyword-only; default 0), a number or a scalar array.

    Returns:
        Scalar float array `()`, `>= 0`.
    """
    mesh = require_mesh("mesh", mesh)
    heads = take_rows(mesh.vertices, mesh.edges[:, 1])
    tails = take_rows(mesh.vertices, mesh.edges[:, 0])
    if isinstance(target_length, (int, float)) and target_length == 0:
        return jnp.mean(jnp.sum((heads - tails) ** 2, axis=-1))
    return jnp.mean((edge_lengths(mesh) - target_length) ** 2)


def normal_consistency_loss(mesh: Mesh) -> Float[Array, ""]:
    """Mean of `1 - cos theta_e` over interior edges, `theta_e` the angle between the two face normals, a scalar `()`.

    `cos theta_e = N_f . N_g` for the faces `f, g` of edge `e`, taken from
    `ddgjax.mesh.edge_dihedral_angles` (NaN-safe atan2 of area-weighted normals, so degenerate faces
    give finite gradients). Boundary and non-manifold edges are left out of the mean. 0 for a flat
    sheet; `1 - cos` is about `theta^2 / 2` on smooth meshes. PyTorch3D: `mesh_normal_consistency`
    (which also counts every pair of faces at a non-manifold edge).

    Args:
        mesh: the mesh.

    Returns:
        Scalar float array `()` in `[0, 2]` (0 without interior edges).
    """
    mesh = require_mesh("mesh", mesh)
    interior = _interior_edge_mask(mesh)
    terms = jnp.where(interior, 1.0 - jnp.cos(edge_dihedral_angles(mesh)), 0.0)
    return safe_div(jnp.sum(terms), jnp.sum(interior).astype(terms.dtype))


def laplacian_smoothing_loss(mesh: Mesh, *, weights: str = "uniform") -> Float[Array, ""]:
    """Mean over vertices of `|v_i - sum_j w_ij v_j / sum_j w_ij|`, a scalar `()`: PyTorch3D's `mesh_laplacian_smoothing`.

    The distance from each vertex to the weighted mean of its neighbours (not squared, as in
    PyTorch3D). The cotan weights are held fixed under differentiation as PyTorch3D does (its
    weights come from a `no_grad` block): the gradient then moves vertices towards the weighted
    mean, whereas the gradient through the weights would reward collapsing triangles. With them the
    term is `|(L V)_i| / L_ii` with `L` the cotan Laplacian (the factor 1/2 PyTorch3D omits cancels).
    A vertex without neighbours (or a zero weight sum) contributes 0. PyTorch3D's `method=` is this
    `weights=` (`"uniform"`, `"cot"`); its third method,
    `"cotcurv"`, is the pointwise mean curvature normal: use `willmore_energy` or
    `ddgjax.mesh.vertex_pointwise_mean_curvature_normals`.

    Reference: PyTorch3D `pytorch3d.loss.mesh_laplacian_smoothing`; Nealen et al., "Laplacian mesh
    optimization" (2006).

    Args:
        mesh: the mesh.
        weights: `ddgjax.LAPLACIAN_WEIGHTS` (keyword-only): `"uniform"` (default; `w_ij = 1`, the graph
            Laplacian: topology only) or `"cotan"` (`w_ij = (cot a_ij + cot b_ij) / 2`, `ddgjax.mesh.edge_cotan_weights`).

    Returns:
        Scalar float array `()`.
    """
    mesh = require_mesh("mesh", mesh)
    check_weights(weights)
    V = mesh.vertices
    w = jnp.ones(mesh.edges.shape[0], V.dtype) if weights == "uniform" else jax.lax.stop_gradient(edge_cotan_weights(mesh))
    tails, heads = mesh.edges[:, 0], mesh.edges[:, 1]
    difference = w[:, None] * (take_rows(V, heads) - take_rows(V, tails))
    n = mesh.n_vertices
    # (sum_j w_ij (v_j - v_i)) at i: each edge adds +diff at its tail and -diff at its head.
    pull = jax.ops.segment_sum(difference, tails, num_segments=n) - jax.ops.segment_sum(difference, heads, num_segments=n)
    weight_sums = jax.ops.segment_sum(jnp.concatenate([w, w]), mesh.edges.T.reshape(-1), num_segments=n)
    return jnp.mean(safe_norm(safe_div(pull, weight_sums[:, None])))


def _interior_edge_mask(mesh: Mesh) -> Bool[Array, " ne"]:
    """Edges with exactly two faces (computed from the mesh arrays, so it also works without topology)."""
    two = mesh.edge_faces[:, 1] >= 0
    if mesh.edge_faces.shape[1] > 2:
        two = two & (mesh.edge_faces[:, 2] < 0)
    return two


def _boundary_vertex_mask(mesh: Mesh) -> Bool[Array, " nv"]:
    """Vertices on a boundary edge (an edge with one face)."""
    boundary_edge = (mesh.edge_faces[:, 1] < 0).astype(jnp.int32)
    counts = jax.ops.segment_sum(jnp.repeat(boundary_edge, 2), mesh.edges.reshape(-1), num_segments=mesh.n_vertices)
    return counts > 0
