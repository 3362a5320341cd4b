"""Direction fields as 3D unit vectors, per vertex or per face, for plotting."""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Complex, Float, Inexact

from .._compile import kernel
from .._errors import check_choice
from .._indexing import take_rows
from .._numerics import safe_atan2, safe_normalize
from ..mesh import Mesh, face_normals, face_vertex_positions, require_mesh
from ._connection import check_boundary_scaling, connection_angles, plan_of, planned_tangent_bases
from ._laplacian import check_degree
from ._smoothest import _complex_field, unit


def _directions(field: Complex[Array, " m"], e1: Float[Array, "m 3"], e2: Float[Array, "m 3"], n: int) -> Float[Array, "m k 3"]:
    """The `n` unit vectors `cos(a_k) e1 + sin(a_k) e2`, `a_k = (arg u + 2 pi k) / n`; zero where `u = 0`."""
    present = (field != 0)[:, None, None]
    angles = (safe_atan2(field.imag, field.real)[:, None] + 2.0 * jnp.pi * jnp.arange(n)) / n
    vectors = jnp.cos(angles)[..., None] * e1[:, None, :] + jnp.sin(angles)[..., None] * e2[:, None, :]
    return jnp.where(present, vectors, 0.0)


@kernel(static_argnames=("n",))
def _vertex_vectors(mesh: Mesh, plan, field, n: int):
    e1, e2, _ = planned_tangent_bases(mesh, plan)
    return _directions(field, e1, e2, n)


@kernel(static_argnames=("n", "boundary_scaling"))
def _face_vectors(mesh: Mesh, plan, field, n: int, boundary_scaling: str):
    vertex_angles = connection_angles(mesh, plan, boundary_scaling=boundary_scaling).corner_polar
    corners = face_vertex_positions(mesh)
    normal = face_normals(mesh)
    x = safe_normalize(corners[:, 1] - corners[:, 0])
    y = jnp.cross(normal, x)
    # Face angle of each corner's first edge (p_{k+1} - p_k) in the face frame (x, y).
    first_edges = jnp.roll(corners, -1, axis=1) - corners
    face_angles = safe_atan2(jnp.sum(first_edges * y[:, None], axis=-1), jnp.sum(first_edges * x[:, None], axis=-1))
    # Each corner's value turned from its vertex's polar coordinates into the face frame, averaged.
    turned = take_rows(field, mesh.faces) * jnp.exp(1j * n * (face_angles - vertex_angles))
    mean = jnp.mean(turned, axis=-1)
    return _directions(unit(mean), x, y, n)


def field_to_vectors(
    mesh: Mesh, field: Inexact[ArrayLike, " nv"], *, n: int, at: str = "vertices", boundary_scaling: str = "geodesic"
) -> Float[Array, "m k 3"]:
    """The `n` directions of an `n`-direction field as 3D unit vectors, `(nv, n, 3)` or `(nf, n, 3)`.

    `at="vertices"`: at vertex `i`, `cos(a_k) e1 + sin(a_k) e2` with `a_k = (arg u_i + 2 pi k) / n`,
    `k = 0..n-1`, in the frame of `tangent_bases` (tangent to the vertex normal). `at="faces"`:
    the three corner values are turned from their vertices' polar coordinates into the face's plane
    (first edge of each corner to its direction in the face), averaged, and drawn in the face's plane
    (a face-based rendering, as geometry-central's face fields; meaningless on singular faces).
    Zero vectors where the field is 0. For plotting with `ddgjax.plot` or polyscope
    (`add_vector_quantity` per direction). Differentiable in the vertex positions and the field.

    Args:
        mesh: the mesh.
        field: `(nv,)` complex `n`-th powers (e.g. `smoothest_field(mesh, n=n).field`).
        n: number of directions (keyword-only).
        at: `"vertices"` (default) or `"faces"`.
        boundary_scaling: the polar coordinates' convention the field was computed with.

    Returns:
        `(nv, n, 3)` (`at="vertices"`) or `(nf, n, 3)` (`at="faces"`) float array of unit vectors, 0 where the
        field is 0.
    """
    mesh = require_mesh("mesh", mesh)
    n = check_degree(n)
    check_choice("at", at, ("vertices", "faces"))
    check_boundary_scaling(boundary_scaling)
    plan = plan_of(mesh)
    field = _complex_field("field", field, mesh.n_vertices)
    if at == "vertices":
        return _vertex_vectors(mesh, plan, field, n)
    return _face_vectors(mesh, plan, field, n=n, boundary_scaling=boundary_scaling)
