"""Discrete differential forms: the de Rham map (integration of smooth forms over mesh elements),
and flat / sharp between vector fields and discrete 1-forms (Whitney interpolation).

A discrete k-form holds one number per k-simplex, the integral of a smooth k-form over it:

- 0-forms `(nv,)`: values at vertices;
- 1-forms `(ne,)`: integrals along each edge run from its lower to its higher vertex index
  (`mesh.edges`);
- 2-forms `(nf,)`: integrals over each face, oriented by the face's vertex order (right-hand rule).

Smooth forms are given as JAX functions of one position `(3,)` (they are `vmap`ped inside): a
0-form is a scalar function, a 1-form the covector field `alpha(p)` acting on tangent vectors by the
dot product (`alpha = X^flat` for the vector field `X = alpha`), a 2-form the vector field `B(p)`
whose flux it measures, `omega = i_B vol`, so that `d(A^flat) = curl(A)` and Stokes' theorem
`d1 integrate_1form(A) == integrate_2form(curl A)` holds face by face. A scalar density `rho` on a
flat mesh in the plane `z = 0` (counterclockwise faces) is the 2-form of `B = (0, 0, rho)`.

Orientation: 0- and 1-forms, `flat` and `sharp` (at faces or vertices) work on any mesh (edges
carry their own global orientation); `integrate_2form` needs consistently oriented faces, like `d1`
and `hodge2`.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .._errors import DDGInputError, check_choice, check_count
from .._indexing import take_rows
from .._numerics import safe_div
from ..mesh import Mesh, corner_dual_areas, face_hat_gradients, face_vertex_positions, require_mesh, scatter_corners_to_vertices
from ._vector_calculus import _as_array


def _gauss_legendre(n_points: int, dtype) -> tuple[Float[Array, " q"], Float[Array, " q"]]:
    """Gauss-Legendre nodes and weights on `[0, 1]` (exact for polynomials of degree `2 n - 1`)."""
    nodes, weights = np.polynomial.legendre.leggauss(n_points)
    return jnp.asarray(0.5 * (nodes + 1.0), dtype), jnp.asarray(0.5 * weights, dtype)


def _evaluate(name: str, function: Callable, points: Float[Array, "q 3"], trailing: tuple[int, ...]) -> Array:
    values = jax.vmap(function)(points)
    if values.shape[1:] != trailing:
        raise DDGInputError(f"{name}: expected values of shape {trailing} at a point, got {values.shape[1:]}")
    return values


def integrate_0form(mesh: Mesh, f: Callable[[Float[Array, "3"]], Float[Array, ""]], /) -> Float[Array, " nv"]:
    """De Rham map of a 0-form: `f` sampled at the vertices, `u_i = f(p_i)`, `(nv,)`.

    A 0-form is integrated over points, i.e. evaluated: there is no quadrature and no orientation, so it works
    on every mesh (unreferenced vertices are sampled too). `d0 @ integrate_0form(f) == integrate_1form(grad f)`
    exactly (Stokes' theorem on each edge, up to the quadrature error of the right-hand side). Reference:
    Desbrun et al., *Discrete Exterior Calculus* (2005), section 3 (the de Rham map). libigl / gpytoolbox:
    `f(V)` evaluated on the rows of `V`.

    Args:
        mesh: any triangle mesh.
        f: a JAX function of one position `(3,)` returning a scalar `()` (it is `vmap`ped over the vertices;
            positional-only).

    Returns:
        `(nv,)` 0-form, `f` at every vertex (unreferenced ones included).
    """
    mesh = require_mesh("mesh", mesh)
    return _evaluate("f", f, mesh.vertices, ())


def integrate_1form(
    mesh: Mesh, alpha: Callable[[Float[Array, "3"]], Float[Array, "3"]], *, degree: int = 4
) -> Float[Array, " ne"]:
    """De Rham map of a 1-form: `int_e alpha` along each edge from its lower to its higher vertex, `(ne,)`.

    `int_e alpha = int_0^1 alpha(p_t + s (p_h - p_t)) . (p_h - p_t) ds` by Gauss-Legendre quadrature with
    `degree // 2 + 1` nodes: exact when `alpha` is a polynomial of degree <= `degree` in the position. Works on
    any mesh. Reference: Desbrun et al., *Discrete Exterior Calculus* (2005), section 3.

    Args:
        mesh: any triangle mesh.
        alpha: a JAX function of one position `(3,)` returning the covector `(3,)` there (module docstring).
        degree: the polynomial degree in the position the quadrature integrates exactly, `>= 0` (keyword-only,
            default 4).

    Returns:
        `(ne,)` 1-form on `mesh.edges`: the integrals along each edge, low -> high.
    """
    mesh = require_mesh("mesh", mesh)
    degree = check_count("degree", degree, minimum=0)
    nodes, weights = _gauss_legendre(degree // 2 + 1, mesh.vertices.dtype)
    tails = take_rows(mesh.vertices, mesh.edges[:, 0])
    vectors = take_rows(mesh.vertices, mesh.edges[:, 1]) - tails
    points = tails[:, None, :] + nodes[None, :, None] * vectors[:, None, :]
    values = _evaluate("alpha", alpha, points.reshape(-1, 3), (3,)).reshape(points.shape)
    return jnp.einsum("q,eqd,ed->e", weights, values, vectors)


def integrate_2form(
    mesh: Mesh, omega: Callable[[Float[Array, "3"]], Float[Array, "3"]], *, degree: int = 4
) -> Float[Array, " nf"]:
    """De Rham map of a 2-form: the flux `int_f omega . n dA` through each face, `(nf,)`.

    `n` is the unit normal of the face's vertex order. Quadrature: the collapsed (Duffy) product of
    Gauss-Legendre rules, `(degree + 3) // 2` nodes per direction, exact when `omega` is a polynomial of degree
    <= `degree` in the position. Needs consistently oriented faces (`MeshDataError`): the sign of a face
    integral is relative to its orientation. Stokes: `d1 @ integrate_1form(A) == integrate_2form(curl A)`.
    Reference: Desbrun et al., *Discrete Exterior Calculus* (2005), section 3; quadrature: Duffy, "Quadrature
    over a pyramid or cube of integrands with a singularity at a vertex" (1982). No libigl / gpytoolbox
    equivalent.

    Args:
        mesh: a consistently oriented triangle mesh (`MeshDataError` otherwise).
        omega: a JAX function of one position `(3,)` returning the vector `(3,)` whose flux is the 2-form (module
            docstring).
        degree: the polynomial degree in the position the quadrature integrates exactly, `>= 0` (keyword-only,
            default 4).

    Returns:
        `(nf,)` 2-form: integrated (not pointwise) fluxes; divide by the face areas (`hodge2`) for the mean density.
    """
    mesh = require_mesh("mesh", mesh)
    mesh.topology.require_oriented("ddgjax.dec.integrate_2form")
    degree = check_count("degree", degree, minimum=0)
    nodes, weights = _gauss_legendre((degree + 3) // 2, mesh.vertices.dtype)
    # (s, t) = (a, b (1 - a)) maps the unit square onto the reference triangle, with Jacobian 1 - a.
    s = jnp.repeat(nodes, nodes.shape[0])
    t = jnp.tile(nodes, nodes.shape[0]) * (1.0 - s)
    square_weights = jnp.repeat(weights, nodes.shape[0]) * jnp.tile(weights, nodes.shape[0]) * (1.0 - s)
    corners = face_vertex_positions(mesh)
    side1, side2 = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]
    points = corners[:, None, 0] + s[None, :, None] * side1[:, None, :] + t[None, :, None] * side2[:, None, :]
    values = _evaluate("omega", omega, points.reshape(-1, 3), (3,)).reshape(points.shape)
    return jnp.einsum("q,fqd,fd->f", square_weights, values, jnp.cross(side1, side2))


_PLACES = ("faces", "vertices")


def flat(mesh: Mesh, field: Float[ArrayLike, "n 3"], *, at: str = "faces") -> Float[Array, " ne"]:
    """Flat of a discrete vector field: the 1-form `X^flat` on the edges, `(ne,)`.

    - `at="faces"`, `field` `(nf, 3)`, one vector per face: `(X^flat)_e = mean_{f ni e} X_f . (p_h - p_t)`,
      the mean over the faces of the edge (one on a boundary edge, all of them on a non-manifold
      edge). Exact for a constant field; `sharp(flat(X))` is then `X` projected onto each face.
    - `at="vertices"`, `field` `(nv, 3)`: `(X^flat)_e = (X_t + X_h) / 2 . (p_h - p_t)`, the exact
      integral of the linear interpolant of `X` along the edge; equals `integrate_1form` of any field
      that is linear (affine) in the position.

    Works on any mesh. Reference: Hirani, *Discrete Exterior Calculus* (2003), section 5. libigl /
    gpytoolbox have no flat (gpytoolbox's `dec_*` operators start from 1-forms).

    Args:
        mesh: any triangle mesh.
        field: `(nf, 3)` one vector per face (`at="faces"`) or `(nv, 3)` one per vertex (`at="vertices"`).
        at: where `field` lives, `"faces"` (default) or `"vertices"` (keyword-only).

    Returns:
        `(ne,)` 1-form on `mesh.edges` (integrals along low -> high).
    """
    mesh = require_mesh("mesh", mesh)
    check_choice("at", at, _PLACES)
    edge_vectors = take_rows(mesh.vertices, mesh.edges[:, 1]) - take_rows(mesh.vertices, mesh.edges[:, 0])
    if at == "vertices":
        field = _as_array("field", field, mesh.n_vertices, "nv")
        mean_field = 0.5 * (take_rows(field, mesh.edges[:, 0]) + take_rows(field, mesh.edges[:, 1]))
        return jnp.sum(mean_field * edge_vectors, axis=-1)
    field = _as_array("field", field, mesh.n_faces, "nf")
    present = mesh.edge_faces >= 0
    per_face = jnp.einsum("emd,ed->em", field[jnp.where(present, mesh.edge_faces, 0)], edge_vectors)
    return jnp.sum(jnp.where(present, per_face, 0.0), axis=-1) / jnp.sum(present, axis=-1)


def _whitney_corner_values(mesh: Mesh, alpha: Float[Array, " ne"]) -> Float[Array, "nf 3 3"]:
    """The Whitney interpolant of `alpha` at each corner of each face, `W_f(p_i) = sum_{j != i} alpha_ij grad phi_j`."""
    gradients = face_hat_gradients(mesh)
    # Edge k of a face runs p_{k+1} -> p_{k+2}; the face-order value is the global one times its sign.
    along = mesh.face_edge_signs.astype(alpha.dtype) * take_rows(alpha, mesh.face_edges)
    # At corner i: alpha_{i -> i+1} is edge i+2 run forwards, alpha_{i -> i+2} is edge i+1 run backwards.
    to_next, to_prev = jnp.roll(along, -2, axis=1), -jnp.roll(along, -1, axis=1)
    return to_next[..., None] * jnp.roll(gradients, -1, axis=1) + to_prev[..., None] * jnp.roll(gradients, -2, axis=1)


def sharp(mesh: Mesh, alpha: Float[ArrayLike, " ne"], *, at: str = "faces") -> Float[Array, "n 3"]:
    """Sharp of a discrete 1-form: a vector field from its Whitney interpolant, at faces or vertices.

    The Whitney 1-form of `alpha` on a face is `W = sum_{ij} alpha_ij (phi_i grad phi_j - phi_j grad phi_i)`
    (over the face's edges `i -> j`, `alpha_ij` the integral along `i -> j`, `phi` the hat functions);
    it is linear in the `phi`, a tangent vector field on the face, and its value at corner `i` is
    `W_f(p_i) = sum_{j != i} alpha_ij grad phi_j`.

    - `at="faces"` (default), `(nf, 3)`: `W` at the barycentre, where every `phi = 1/3`:
      `X_f = 1/3 sum_{ij} alpha_ij (grad phi_j - grad phi_i)`, the mean of the three corner values.
      It satisfies `X_f . (p_j - p_i) = alpha_ij - c_f / 3` with `c_f` the circulation of `alpha`
      around `f`; so `flat(sharp(alpha)) == alpha` exactly for closed forms (`d1 alpha = 0`, e.g.
      `alpha = d0 u`, where `sharp(d0 u) == gradient(u)` == libigl `igl.grad(V, F) @ u` and
      gpytoolbox `grad(V, F) @ u`, reshaped `(3, nf).T`), and `sharp(flat(X))` is the tangent part of
      a constant `X`.
    - `at="vertices"`, `(nv, 3)`: the corner values `W_f(p_i)` of the faces around vertex `i`,
      averaged with the vertex's Voronoi (mixed) dual-cell areas in each face as weights:
      `X_i = sum_{f ni i} |*i cap f| W_f(p_i) / sum_{f ni i} |*i cap f|`
      (`ddgjax.mesh.corner_dual_areas`, summing to `vertex_dual_areas`). This is Hirani's
      primal-primal sharp, with the always-nonnegative mixed areas in place of the circumcentric
      ones (the same on meshes without obtuse angles). It evaluates the interpolant at the vertex
      itself rather than averaging barycentre values (which sit `h/3` away). Exactness:
      `sharp(flat(X, at="vertices"), at="vertices") == X` for a constant `X` on a flat mesh (on a
      curved one, a weighted mean of its projections onto the incident faces), and for any field
      `a + b J p` (constant plus infinitesimal rotation in the plane: the fields Whitney forms
      reproduce; the mean of face sharps is not exact for these) at every vertex of a flat mesh; for
      a general linear field it is exact where the one-ring is point-symmetric (the interior of a
      regular grid) and first-order accurate elsewhere; for a smooth tangent field on a curved
      surface its error is `O(h)` in general. The vector lies in the span of the incident faces'
      planes, not in one tangent plane. Vertices with zero dual area (unreferenced, or only
      degenerate faces around them) get the zero vector.

    Whitney interpolation is local and defined at every vertex (a per-one-ring least-squares fit is
    underdetermined at boundary vertices with one or two faces).

    Independent of the face orientation: works on any mesh (edges carry their own orientation).

    Args:
        mesh: any triangle mesh.
        alpha: `(ne,)` 1-form on `mesh.edges` (integrals along low -> high).
        at: `"faces"` or `"vertices"` (keyword-only).

    Returns:
        `(nf, 3)` or `(nv, 3)` vectors.

    Reference: Whitney, *Geometric Integration Theory* (1957); Hirani, *Discrete Exterior Calculus*
    (2003), section 5.8 (primal-primal sharp); Crane et al. 2013, section 7.4. Equivalents: for exact
    forms at faces, libigl / gpytoolbox `grad` (above); libigl and gpytoolbox have no sharp of a
    general 1-form and no vertex sharp.
    """
    mesh = require_mesh("mesh", mesh)
    check_choice("at", at, _PLACES)
    alpha = _as_array("alpha", alpha, mesh.n_edges, "ne")
    corner_values = _whitney_corner_values(mesh, alpha)
    if at == "faces":
        return jnp.mean(corner_values, axis=1)
    weights = corner_dual_areas(mesh, dual="voronoi")
    weighted = scatter_corners_to_vertices(mesh, weights[..., None] * corner_values)
    return safe_div(weighted, scatter_corners_to_vertices(mesh, weights)[:, None])
