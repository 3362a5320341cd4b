"""The velocity of a stream function on a surface: `u = n x grad psi` per face, or averaged at the vertices."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .._compile import kernel
from .._errors import DDGInputError, check_choice
from .._numerics import safe_div
from ..mesh import (
    Mesh,
    corner_dual_areas,
    face_hat_gradients,
    face_normals,
    require_mesh,
    scatter_corners_to_vertices,
    vertex_normals,
)


def stream_function_velocity(
    mesh: Mesh, stream_function: Float[ArrayLike, " nv"], *, at: str = "faces"
) -> Float[Array, "nf 3"] | Float[Array, "nv 3"]:
    """Velocities `u = n x grad psi` of a piecewise linear stream function, per face `(nf, 3)` or per vertex `(nv, 3)`.

    `grad psi` is constant on each face (`sum_c psi_c grad h_c`, `ddgjax.mesh.face_hat_gradients`),
    `n_f` the unit face normal (right-hand rule of the face order), so `u` is tangent, divergence
    free in the weak sense, and its vorticity `n . curl u` is `Delta psi` (on the unit sphere,
    `psi = -Omega z` is the solid rotation `Omega e_z x p`). Zero on zero-area faces. Differentiable
    in the vertex positions and `psi`.

    At the vertices (`at="vertices"`, for drawing arrows or advecting points): the face velocities
    averaged with the Voronoi (mixed) corner areas as weights, `u_i = sum_f |*i cap f| u_f / sum_f
    |*i cap f|` (as `ddgjax.dec.sharp(..., at="vertices")` weights), minus the component along the
    area-weighted vertex normal, so that it is tangent there (first order in the edge length, as the
    normal is). Zero at vertices without area.

    Args:
        mesh: a triangle mesh.
        stream_function: `(nv,)` values at the vertices.
        at: `"faces"` (default) or `"vertices"` (keyword-only).

    Returns:
        `(nf, 3)` velocity per face, or `(nv, 3)` per vertex.

    Reference: Azencot et al., "Functional fluids on surfaces" (SGP 2014), section 3.
    """
    mesh = require_mesh("mesh", mesh)
    if np.iscomplexobj(stream_function) or np.shape(stream_function) != (mesh.n_vertices,):
        raise DDGInputError(
            f"stream_function: expected a real array of shape ({mesh.n_vertices},), got shape {np.shape(stream_function)}"
        )
    check_choice("at", at, ("faces", "vertices"))
    return _velocity(mesh, jnp.asarray(stream_function).astype(mesh.vertices.dtype), at=at)


@kernel(static_argnames=("at",))
def _velocity(mesh: Mesh, stream_function, *, at):
    gradient = jnp.einsum("fcd,fc->fd", face_hat_gradients(mesh), stream_function[mesh.faces])
    velocity = jnp.cross(face_normals(mesh), gradient)
    if at == "faces":
        return velocity
    weights = corner_dual_areas(mesh)  # (nf, 3)
    summed = scatter_corners_to_vertices(mesh, weights[:, :, None] * velocity[:, None, :])
    mean = safe_div(summed, scatter_corners_to_vertices(mesh, weights)[:, None])
    normals = vertex_normals(mesh)
    return mean - jnp.sum(mean * normals, axis=1, keepdims=True) * normals
