"""The velocity of a stream function on a surface: `u = n x grad psi` per face."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .._compile import kernel
from .._errors import DDGInputError
from ..mesh import Mesh, face_hat_gradients, face_normals, require_mesh


def stream_function_velocity(mesh: Mesh, stream_function: Float[ArrayLike, " nv"]) -> Float[Array, "nf 3"]:
    """Face velocities `u_f = n_f x grad psi` of a piecewise linear stream function, `(nf, 3)`.

    `grad psi` is constant on each face (`sum_c psi_c grad h_c`, `ddgjax.mesh.face_hat_gradients`),
    `n_f` the unit face normal (right-hand rule of the face order), so `u` is tangent, divergence
    free in the weak sense, and its vorticity `n . curl u` is `Delta psi` (on the unit sphere,
    `psi = -Omega z` is the solid rotation `Omega e_z x p`). Zero on zero-area faces. Differentiable
    in the vertex positions and `psi`.

    Args:
        mesh: a triangle mesh.
        stream_function: `(nv,)` values at the vertices.

    Returns:
        `(nf, 3)` velocity per face.

    Reference: Azencot et al., "Functional fluids on surfaces" (SGP 2014), section 3.
    """
    mesh = require_mesh("mesh", mesh)
    if np.iscomplexobj(stream_function) or np.shape(stream_function) != (mesh.n_vertices,):
        raise DDGInputError(
            f"stream_function: expected a real array of shape ({mesh.n_vertices},), got shape {np.shape(stream_function)}"
        )
    return _velocity(mesh, jnp.asarray(stream_function).astype(mesh.vertices.dtype))


@kernel
def _velocity(mesh: Mesh, stream_function):
    gradient = jnp.einsum("fcd,fc->fd", face_hat_gradients(mesh), stream_function[mesh.faces])
    return jnp.cross(face_normals(mesh), gradient)
