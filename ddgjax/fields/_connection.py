"""The discrete Levi-Civita connection in angle form: polar angles of edges, transport angles, tangent bases.

Conventions (one place; every function of `ddgjax.fields` follows them):

- **Polar coordinates at a vertex.** The corner angles `alpha` around vertex `i` are rescaled by
  `s_i = 2 pi / sum alpha` at an interior vertex, so that they close up to a full turn. At a
  boundary vertex, `boundary_scaling="geodesic"` (the default, as Knoeppel et al. 2013 and
  geometry-central / potpourri3d do) rescales them to sum to `pi`, as if the boundary were a geodesic
  (a field along the boundary is then parallel along it); `boundary_scaling="unscaled"` keeps them
  (`s_i = 1`), so a flat region stays flat up to its boundary (a flat disk carries the constant field
  with zero energy). Every function of `ddgjax.fields` takes this choice as `boundary_scaling=`
  (`boundary=` is a boundary condition elsewhere in ddgjax; docs/conventions.md).
  The *reference outgoing edge* of vertex `i` (polar angle 0) is the first edge of its reference
  corner (`ddgjax.fields._plan`); walking counterclockwise (with the faces' orientation) each edge
  `i -> j` gets the polar angle `theta_ij` in `[0, 2 pi)`: the sum of the rescaled corner angles
  between the reference edge and it.
- **Tangent vectors** at `i` are complex numbers `z = r exp(i phi)` in these coordinates.
- **Transport** from `i` to its neighbour `j` along the edge (the discrete Levi-Civita connection):
  `z_j = exp(i rho_ij) z_i`, `rho_ij = theta_ji + pi - theta_ij` (the vector along `i -> j` goes to
  the vector continuing past `j`, i.e. opposite to `j -> i`), so `rho_ji = -rho_ij`.
- **n-direction fields** are stored as the n-th power `u = z^n` (one complex number for `n` directions
  `z exp(2 pi i k / n)`), transported by `exp(i n rho_ij)`.
- **Face curvature** (holonomy): transport around face `abc` turns vectors by
  `Omega_f = sum_corners s_i alpha - pi` (mod `2 pi`); `sum_f Omega_f = 2 pi chi` on a closed mesh (and
  with `boundary_scaling="geodesic"` on every mesh), the discrete Gauss-Bonnet theorem of the rescaled angles.

References: F. Knoeppel, K. Crane, U. Pinkall, P. Schroeder, "Globally optimal direction fields"
(SIGGRAPH 2013), section 5; N. Sharp, Y. Soliman, K. Crane, "The vector heat method" (2019), section
5.1; geometry-central `transportVectorsAlongHalfedge` / `vertexTangentBasis`.
"""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from .._compile import kernel
from .._errors import check_choice
from .._indexing import take_rows
from .._numerics import safe_div, safe_normalize
from ..mesh import Mesh, corner_angles, face_area_vectors, scatter_corners_to_vertices
from ..mesh.internal import nondegenerate_face_mask
from ._plan import FieldPlan, field_plan

BOUNDARY_SCALINGS = ("geodesic", "unscaled")
"""`boundary_scaling=`: how the polar coordinates treat boundary vertices (module docstring)."""
_OPERATION = "ddgjax.fields (the discrete connection)"


def check_boundary_scaling(boundary_scaling: str) -> str:
    """`boundary_scaling` if it is one of `BOUNDARY_SCALINGS`, else `DDGInputError`."""
    return check_choice("boundary_scaling", boundary_scaling, BOUNDARY_SCALINGS)


def plan_of(mesh: Mesh) -> FieldPlan:
    """The connection's host plan (refusing non-manifold and inconsistently oriented meshes)."""
    return field_plan(mesh, _OPERATION)


def scaled_corner_angles(mesh: Mesh, plan: FieldPlan, boundary_scaling: str) -> Float[Array, "nf 3"]:
    """Corner angles times their vertex's scale `s_i` (module docstring), `(nf, 3)`."""
    angles = corner_angles(mesh)
    sums = scatter_corners_to_vertices(mesh, angles)
    if boundary_scaling == "geodesic":
        target = jnp.where(plan.boundary, jnp.pi, 2.0 * jnp.pi)
    else:
        target = jnp.where(plan.boundary, sums, 2.0 * jnp.pi)
    scales = safe_div(target, sums)  # 0 on unreferenced vertices
    return angles * take_rows(scales, mesh.faces)


def corner_polar_angles(
    scaled: Float[Array, "nf 3"], plan: FieldPlan
) -> tuple[Float[Array, " n_corners"], Float[Array, " n_corners"]]:
    """Polar angles of the first and second edge of every flat corner `3 f + k`, unwrapped (in `[0, 2 pi]`).

    A segmented prefix sum of the rescaled corner angles along each vertex's fan (one associative
    scan of the corners in fan order; the sums restart at each fan, so no angle carries the rounding
    of other vertices).
    """
    scaled = scaled.reshape(-1)
    in_fans = take_rows(scaled, plan.fan_order)

    def combine(left, right):
        left_start, left_sum = left
        right_start, right_sum = right
        return left_start | right_start, jnp.where(right_start, right_sum, left_sum + right_sum)

    _, inclusive = jax.lax.associative_scan(combine, (plan.fan_start, in_fans))
    second = take_rows(inclusive, plan.corner_position)
    return second - scaled, second


class ConnectionAngles(eqx.Module):
    """Everything the angle form of the connection gives, from one pass over the corners (`connection_angles`).

    Attributes:
        edge_polar: `(ne, 2)` `theta_ij` at the low end and `theta_ji` at the high end, in `[0, 2 pi)`.
        transport: `(ne,)` `rho_ij = theta_ji + pi - theta_ij`, low -> high, in `(-pi, 3 pi)` (unwrapped).
        holonomy: `(nf,)` `Omega_f = sum_corners s_i alpha - pi`.
        corner_polar: `(nf, 3)` polar angle of each corner's first edge at its vertex (unwrapped).
    """

    edge_polar: Float[Array, "ne 2"]
    transport: Float[Array, " ne"]
    holonomy: Float[Array, " nf"]
    corner_polar: Float[Array, "nf 3"]


@kernel(static_argnames=("boundary_scaling",))
def connection_angles(mesh: Mesh, plan: FieldPlan, boundary_scaling: str) -> ConnectionAngles:
    """`ConnectionAngles` of the mesh (one compiled program per mesh size; the other kernels take its output)."""
    scaled = scaled_corner_angles(mesh, plan, boundary_scaling)
    first, second = corner_polar_angles(scaled, plan)
    edge_polar = jnp.mod(take_rows(jnp.concatenate([first, second]), plan.edge_angle_source), 2.0 * jnp.pi)
    return ConnectionAngles(
        edge_polar=edge_polar,
        transport=edge_polar[:, 1] + jnp.pi - edge_polar[:, 0],
        holonomy=jnp.sum(scaled, axis=-1) - jnp.pi,
        corner_polar=first.reshape(-1, 3),
    )


def connection(mesh: Mesh, boundary_scaling: str) -> ConnectionAngles:
    """`connection_angles` after the checks of `boundary_scaling` and of the mesh (`plan_of`)."""
    check_boundary_scaling(boundary_scaling)
    return connection_angles(mesh, plan_of(mesh), boundary_scaling=boundary_scaling)


def connection_part(mesh: Mesh, boundary_scaling: str, part: str) -> Float[Array, "..."]:
    """One field of `ConnectionAngles` (`"edge_polar"`, `"holonomy"`, or `"transport"` wrapped into `[-pi, pi)`)
    after the checks of `connection`, as its own program: an eager call computes only that field."""
    check_boundary_scaling(boundary_scaling)
    return _connection_part(mesh, plan_of(mesh), boundary_scaling=boundary_scaling, part=part)


@kernel(static_argnames=("boundary_scaling", "part"))
def _connection_part(mesh: Mesh, plan: FieldPlan, *, boundary_scaling: str, part: str) -> Float[Array, "..."]:
    angles = connection_angles(mesh, plan, boundary_scaling=boundary_scaling)
    return wrap_angle(angles.transport) if part == "transport" else getattr(angles, part)


def edge_polar_angles(mesh: Mesh, *, boundary_scaling: str = "geodesic") -> Float[Array, "ne 2"]:
    """Polar angle of each edge at both its ends, `(ne, 2)`, in `[0, 2 pi)` (module docstring).

    Column 0 is `theta_ij` of the edge `i -> j` at `i = mesh.edges[:, 0]` (the low end), column 1 is
    `theta_ji` at `j = mesh.edges[:, 1]`. Intrinsic (corner angles only), differentiable in the
    vertex positions (jit / grad / vmap). Needs a manifold, consistently oriented mesh
    (`MeshDataError` otherwise).

    Args:
        mesh: the mesh.
        boundary_scaling: `"geodesic"` (default; boundary angle sums rescaled to `pi`) or `"unscaled"`.

    Returns:
        `(ne, 2)` float array of angles in radians, in `[0, 2 pi)`.

    Reference: Knoeppel et al. 2013, section 5.1. geometry-central: `halfedgeVectorsInVertex` (as
    complex numbers `l exp(i theta)`).
    """
    return connection_part(mesh, boundary_scaling, "edge_polar")


def wrap_angle(angle: Float[Array, "..."]) -> Float[Array, "..."]:
    """`angle` shifted by a multiple of `2 pi` into `[-pi, pi)` (derivative 1)."""
    return angle - 2.0 * jnp.pi * jnp.floor((angle + jnp.pi) / (2.0 * jnp.pi))


def edge_transport_angles(mesh: Mesh, *, boundary_scaling: str = "geodesic") -> Float[Array, " ne"]:
    """Transport angle `rho_ij` of each edge from its low end `i` to its high end `j`, `(ne,)`, in `[-pi, pi)`.

    A tangent vector `z` at `i` (in `i`'s polar coordinates) transported along the edge is
    `exp(i rho_ij) z` at `j`, with `rho_ij = theta_ji + pi - theta_ij` (module docstring); the reverse
    transport is `exp(-i rho_ij)`. Differentiable in the vertex positions. Needs a manifold,
    consistently oriented mesh (`MeshDataError` otherwise).

    Args:
        mesh: the mesh.
        boundary_scaling: `"geodesic"` (default) or `"unscaled"` (module docstring).

    Returns:
        `(ne,)` float array of angles `rho_ij` in radians, in `[-pi, pi)`.

    Reference: Knoeppel et al. 2013, eq. (5); geometry-central `transportVectorsAlongHalfedge` (per
    halfedge, as the unit complex number `exp(i rho)`).
    """
    return connection_part(mesh, boundary_scaling, "transport")


def face_holonomies(mesh: Mesh, *, boundary_scaling: str = "geodesic") -> Float[Array, " nf"]:
    """Curvature of the connection on each face, `Omega_f = sum_corners s_i alpha - pi`, `(nf,)`.

    Transport around the face's boundary (counterclockwise) turns a vector by `Omega_f` (mod
    `2 pi`): `rho_ab + rho_bc + rho_ca = Omega_f + 4 pi`. It is the angle defect of the vertices
    redistributed to their faces by the rescaling, so `sum_f Omega_f = 2 pi chi` on a closed mesh
    (integrated Gaussian curvature, discrete Gauss-Bonnet); 0 on faces whose corners all have
    `s_i = 1` (flat interior vertices). Differentiable in the vertex positions.

    Args:
        mesh: the mesh.
        boundary_scaling: `"geodesic"` (default) or `"unscaled"` (module docstring).

    Returns:
        `(nf,)` float array of holonomy angles `Omega_f` in radians.

    Reference: Knoeppel et al. 2013, section 5.2 (the "angle defect of the rescaled angles").
    """
    return connection_part(mesh, boundary_scaling, "holonomy")


class TangentBases(NamedTuple):
    """Per-vertex orthonormal frames (`tangent_bases`); unpacks as `e1, e2, normal = ...`.

    Attributes:
        e1: `(nv, 3)` the direction of polar angle 0 (the reference outgoing edge, made tangent).
        e2: `(nv, 3)` `normal x e1`, polar angle `pi / 2`.
        normal: `(nv, 3)` the angle-weighted vertex normal.
    """

    e1: Float[Array, "nv 3"]
    e2: Float[Array, "nv 3"]
    normal: Float[Array, "nv 3"]


@kernel
def planned_tangent_bases(mesh: Mesh, plan: FieldPlan) -> TangentBases:
    area_vectors = face_area_vectors(mesh)
    # A face of (near-)zero area has no normal: left out (`nondegenerate_face_mask`), so a flat cap's angle
    # of pi at its middle vertex cannot turn that vertex's normal.
    weights = jnp.where(nondegenerate_face_mask(mesh)[:, None], corner_angles(mesh), 0.0)
    normals = safe_normalize(scatter_corners_to_vertices(mesh, weights[:, :, None] * safe_normalize(area_vectors)[:, None, :]))
    edges = take_rows(mesh.vertices, plan.reference_neighbor) - mesh.vertices
    e1 = safe_normalize(edges - jnp.sum(edges * normals, axis=-1, keepdims=True) * normals)
    return TangentBases(e1, jnp.cross(normals, e1), normals)


def tangent_bases(mesh: Mesh) -> TangentBases:
    """Per-vertex orthonormal frames `TangentBases(e1, e2, normal)`, each `(nv, 3)`, matching the polar coordinates.

    `normal` is the angle-weighted vertex normal (`vertex_normals(mesh, weighting="angle")`, leaving out
    faces of zero or near-zero area, whose normal is undefined: `ddgjax.mesh.check_mesh`), `e1` the
    vertex's reference outgoing edge (polar angle 0) projected to the tangent plane and normalised,
    `e2 = normal x e1`, so that a tangent vector `z` at the vertex is the 3D vector
    `Re(z) e1 + Im(z) e2` and positive angles turn counterclockwise seen from the normal. The
    polar angles are rescaled corner angles, so other edges are only approximately at their
    `theta_ij` in this frame (exactly on a flat interior vertex). Zero vectors on unreferenced
    vertices. Differentiable in the vertex positions.

    Equivalent: potpourri3d `MeshVectorHeatSolver(V, F).get_tangent_frames()` (`basisX, basisY,
    basisN`; geometry-central `vertexTangentBasis`), with its own choice of reference edges.

    Args:
        mesh: the mesh (manifold, consistently oriented).

    Returns:
        `TangentBases(e1, e2, normal)`, three `(nv, 3)` float arrays of unit vectors.
    """
    return planned_tangent_bases(mesh, plan_of(mesh))
