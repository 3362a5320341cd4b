"""Singularities of an n-direction field on the vertices: the index of every face.

Along an edge `i -> j` the field turns, relative to the transport, by

    delta_ij = arg(u_j exp(-i n rho_ij) conj(u_i))   in (-pi, pi]

(the smallest such turn: the field is assumed to vary by less than half a period of `u` per edge, so
that it is well sampled). Around face `f` (counterclockwise) the field turns by `sum delta`, and the
frame in which it is measured by the face's holonomy `n Omega_f`; the total is a whole number of
turns, and the face's index is

    I_f = (delta_ab + delta_bc + delta_ca + n Omega_f) / (2 pi n),

a multiple of `1 / n` (`+1` a source, sink or centre of a vector field, `+1/4` the cross field at a
cube corner, negative for saddles). Each interior edge enters its two faces with opposite signs, so
on a closed mesh `sum_f I_f = sum_f Omega_f / 2 pi = chi` (Poincare-Hopf).

Reference: Knoeppel, Crane, Pinkall, Schroeder (2013), section 5.4; K. Crane, M. Desbrun, P.
Schroeder, "Trivial connections on discrete surfaces" (2010). geometry-central:
`computeFaceIndex(geometry, directionField, n)`.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Complex, Float, Inexact

from .._compile import kernel
from .._indexing import take_rows
from .._numerics import safe_atan2
from ..mesh import Mesh, require_mesh
from ._connection import check_boundary_scaling, connection_angles, plan_of
from ._laplacian import check_degree
from ._plan import FieldPlan
from ._smoothest import _complex_field


@kernel(static_argnames=("boundary_scaling",))
def _indices(mesh: Mesh, plan: FieldPlan, field: Complex[Array, " nv"], n, *, boundary_scaling: str) -> Float[Array, " nf"]:
    # `n` is traced, not static: one program per mesh size serves every n.
    angles = connection_angles(mesh, plan, boundary_scaling=boundary_scaling)
    transport, holonomy = angles.transport, angles.holonomy
    rotations = jnp.exp(-1j * n * transport)
    turns = take_rows(field, mesh.edges[:, 1]) * rotations * jnp.conj(take_rows(field, mesh.edges[:, 0]))
    delta = safe_atan2(turns.imag, turns.real)
    signs = mesh.face_edge_signs.astype(delta.dtype)
    around = jnp.sum(signs * take_rows(delta, mesh.face_edges), axis=-1)
    total = around + n * holonomy
    # A whole number of turns up to rounding; the index does not move with the vertices.
    return jax.lax.stop_gradient(jnp.round(total / (2.0 * jnp.pi)) / n)


def field_singularities(
    mesh: Mesh, field: Inexact[ArrayLike, " nv"], *, n: int, boundary_scaling: str = "geodesic"
) -> Float[Array, " nf"]:
    r"""Index of an `n`-direction field around every face, `(nf,)`, multiples of `1 / n` (module docstring).

    $$I_f = \frac{1}{2\pi n} \Bigl( \sum_{\text{edges } ij \text{ of } f} \delta_{ij} + n\, \Omega_f \Bigr),$$

    rounded to the nearest multiple of
    `1 / n` (it is one up to round-off); non-zero faces are the singularities. On a closed mesh the
    indices sum to the Euler characteristic. Piecewise constant in the vertex positions (gradient 0).

    Args:
        mesh: the mesh.
        field: `(nv,)` complex `n`-th powers in the vertices' polar coordinates (e.g.
            `smoothest_field(mesh, n=n).field`), with the same `boundary_scaling` convention.
        n: number of directions (keyword-only, required: the field's representation does not say it).
        boundary_scaling: `"geodesic"` (default) or `"unscaled"`.

    Returns:
        `(nf,)` face indices.

    Examples:
        >>> import ddgjax
        >>> torus = ddgjax.mesh.torus(n_major=24, n_minor=8)
        >>> field = ddgjax.fields.smoothest_field(torus, n=1).field
        >>> indices = ddgjax.fields.field_singularities(torus, field, n=1)
        >>> indices.shape, float(indices.sum())  # the Euler characteristic
        ((384,), 0.0)
    """
    mesh = require_mesh("mesh", mesh)
    n = check_degree(n)
    check_boundary_scaling(boundary_scaling)
    plan = plan_of(mesh)
    field = _complex_field("field", field, mesh.n_vertices)
    return _indices(mesh, plan, field, float(n), boundary_scaling=boundary_scaling)
