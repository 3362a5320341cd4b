"""Gradient, divergence and curl of piecewise-linear functions and face vector fields; the
codifferential and the Hodge Laplacians of discrete forms.

Conventions (DESIGN.md):

- A function `u` on the vertices is the piecewise-linear interpolant `sum_i u_i phi_i` of the hat
  functions `phi_i`; its gradient is constant on each face.
- Vector fields on faces are `(nf, 3)` arrays of one vector per face (components normal to the face
  are ignored by `divergence` and `curl`).
- `divergence` and `curl` are *integrated* over vertex dual cells (weak form, tested against each hat
  function): `divergence(gradient(u)) == -L u` with `L` the PSD cotan Laplacian, so divide by the
  vertex dual area for pointwise values. Signs are the geometric ones: the divergence of an outward
  (source) field and the curl of a counterclockwise rotation are positive.
- The codifferential is the adjoint of `d` for the inner products `<a, b>_k = a^T *_k b`:
  `delta_k = *_{k-1}^{-1} d_{k-1}^T *_k`, and the Hodge Laplacian `Delta_k = d delta + delta d` is
  self-adjoint and positive semidefinite where the stars are positive (`Delta_0 = *0^{-1} L`, minus
  the Laplace-Beltrami operator; the cotan `*1` of the Voronoi and circumcentric duals turns negative
  on non-Delaunay meshes).
- The stars come from the keyword-only `dual=` shared with `ddgjax.mesh` (`"voronoi"`, the default,
  `"circumcentric"` or `"barycentric"`; `ddgjax.dec` module docstring).

Orientation: `gradient`, `divergence`, `codifferential(degree=1)` and `hodge_laplacian0` work on any
mesh; `curl` (which needs a sense of rotation), `codifferential(degree=2)`, `hodge_laplacian1` and
`hodge_laplacian2` (which use `d1`) need consistently oriented faces and raise `MeshDataError`
otherwise.
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from .._errors import DDGInputError, check_choice
from .._indexing import take_rows
from .._options import DUAL_CELLS
from ..mesh import Mesh, corner_cotangents, face_edge_vectors, face_hat_gradients, require_mesh, scatter_corners_to_vertices
from ..sparse import SparseMatrix
from ._hodge import hodge_star_entries
from ._hodge_laplacian import codifferential_from, hodge_laplacian_from
from ._operators import d0, d1


def gradient(mesh: Mesh, u: Float[ArrayLike, " nv"], /) -> Float[Array, "nf 3"]:
    r"""Gradient of the piecewise-linear interpolant of `u`, one tangent vector per face, `(nf, 3)`.

    $$\nabla u = \sum_{i \in f} u_i \nabla\phi_i \quad \text{on each face } f$$

    (`(grad u)_f = sum_k u[F[f, k]] grad phi_k`, `ddgjax.mesh.face_hat_gradients`). Any mesh.
    libigl: `igl.grad(V, F) @ u` reshaped `(3, nf).T`; gpytoolbox: `grad(V, F) @ u`, likewise.
    Reference: Crane et al., *The heat method for distance computation* (2017), eq. (2).

    Args:
        mesh: any triangle mesh.
        u: `(nv,)` values at the vertices (positional-only).

    Returns:
        `(nf, 3)` gradient vectors, tangent to each face (units of `u` per length).
    """
    mesh = require_mesh("mesh", mesh)
    u = _as_array("u", u, mesh.n_vertices, "nv")
    return jnp.einsum("fk,fkd->fd", take_rows(u, mesh.faces), face_hat_gradients(mesh))


def divergence(mesh: Mesh, field: Float[ArrayLike, "nf 3"]) -> Float[Array, " nv"]:
    r"""Integrated divergence of a face vector field at each vertex, `(nv,)`.

    $$(\operatorname{div} X)(i) = \tfrac12 \sum_{f \ni i} \bigl(\cot\theta_1 \langle e_1, X_f \rangle + \cot\theta_2 \langle e_2, X_f \rangle\bigr),$$

    with $e_1, e_2$
    the edges of $f$ leaving $i$ and $\theta_1, \theta_2$ the angles opposite them; equivalently
    $-\sum_f A_f \langle \nabla\phi_i, X_f \rangle$ (the weak divergence against the hat function `phi_i`). So
    `divergence(gradient(u)) == -L u` (DESIGN.md, `L` PSD) and a source field has positive divergence;
    divide by the vertex dual area for the pointwise value. Works on any mesh (zero-area faces
    contribute 0). Reference: Crane et al. 2017 (heat method), section 3.2.1; the DDG exercises' `div`
    in `test-heat-soln.txt` is `-divergence`.

    Args:
        mesh: any triangle mesh.
        field: `(nf, 3)` one vector per face (components normal to the face are ignored).

    Returns:
        `(nv,)` integrated divergence at each vertex (weak form; divide by the dual areas for pointwise values).
    """
    mesh = require_mesh("mesh", mesh)
    field = _as_array("field", field, mesh.n_faces, "nf")
    edge_terms = 0.5 * corner_cotangents(mesh) * jnp.sum(face_edge_vectors(mesh) * field[:, None, :], axis=-1)
    # Corner j leaves along e_{j+2} (to p_{j+1}) and against e_{j+1} (to p_{j+2}).
    return scatter_corners_to_vertices(mesh, jnp.roll(edge_terms, 1, axis=1) - jnp.roll(edge_terms, -1, axis=1))


def curl(mesh: Mesh, field: Float[ArrayLike, "nf 3"]) -> Float[Array, " nv"]:
    """Integrated curl (vorticity) of a face vector field at each vertex, `(nv,)`.

    `(curl X)_i = 1/2 sum_{f ni i} X_f . e_i^f`, with `e_i^f` the edge of `f` opposite `i`, run in
    the face's vertex order: half the circulation of `X` around the link of `i`, the weak curl against
    the hat function `phi_i`. It is the rotated divergence, `curl(X) == -divergence(n x X)` for tangent
    `X`, counterclockwise positive about the normals given by the face orientation: a rotation
    `X(p) = n x p` about a vertex has curl `2 * barycentric dual area` there. `curl(gradient(u))` vanishes
    at interior vertices (at a boundary vertex it is half the jump of `u` across its fan). Needs
    consistently oriented faces (`MeshDataError` otherwise). Reference: Polthier & Preuss,
    *Identifying vector field singularities using a discrete Hodge decomposition* (2003).

    Args:
        mesh: a consistently oriented triangle mesh (`MeshDataError` otherwise).
        field: `(nf, 3)` one vector per face (components normal to the face are ignored).

    Returns:
        `(nv,)` integrated curl at each vertex (weak form; divide by the dual areas for pointwise values).
    """
    mesh = require_mesh("mesh", mesh)
    mesh.topology.require_oriented("ddgjax.dec.curl")
    field = _as_array("field", field, mesh.n_faces, "nf")
    return scatter_corners_to_vertices(mesh, 0.5 * jnp.sum(face_edge_vectors(mesh) * field[:, None, :], axis=-1))


def _as_array(name: str, array, n: int, symbol: str) -> Array:
    """`array` as a JAX array whose leading dimension is `n`, else `DDGInputError` naming `name`."""
    array = jnp.asarray(array)
    if array.shape[:1] != (n,):
        raise DDGInputError(f"{name}: expected leading dimension {symbol} = {n}, got shape {array.shape}")
    return array


def _exterior_derivative(mesh: Mesh, degree: int) -> SparseMatrix:
    return d0(mesh) if degree == 0 else d1(mesh)


def _form_size(mesh: Mesh, degree: int) -> tuple[int, str]:
    return ((mesh.n_vertices, "nv"), (mesh.n_edges, "ne"), (mesh.n_faces, "nf"))[degree]


def _as_form(name: str, mesh: Mesh, form, degree: int) -> Array:
    n, symbol = _form_size(mesh, degree)
    return _as_array(name, form, n, symbol)


def _complex(mesh: Mesh, dual: str):
    """The surface's `d_k` and `*_k` as `ddgjax.dec._hodge_laplacian` takes them."""
    return (
        lambda degree: _exterior_derivative(mesh, degree),
        lambda degree, inverse: hodge_star_entries(mesh, degree=degree, dual=dual, inverse=inverse),
    )


def codifferential(
    mesh: Mesh, form: Float[ArrayLike, "n *batch"], *, degree: int, dual: str = "voronoi"
) -> Float[Array, "m *batch"]:
    """Codifferential `delta_k` of a primal `degree`-form (`degree` 1 or 2), a primal (k-1)-form.

    `delta_k = *_{k-1}^{-1} d_{k-1}^T *_k`, the adjoint of `d_{k-1}` for `<a, b>_k = a^T *_k b` (module
    docstring); on surfaces this is the smooth `delta = -*d*` up to the discrete stars. So
    `codifferential(d0 u, degree=1) = *0^{-1} L u` (minus the pointwise Laplace-Beltrami), and for a 1-form
    `delta alpha = -div(alpha^sharp)` pointwise. Degree 2 needs consistently oriented faces. Reference: Desbrun
    et al. 2005, section 9; Crane et al. 2013, section 6 (Hodge decomposition uses `*1^{-1} d1^T *2`).

    Args:
        mesh: any triangle mesh; consistently oriented for `degree=2` (`MeshDataError` otherwise).
        form: the primal `degree`-form, `(ne,)` for degree 1 or `(nf,)` for degree 2, optionally with trailing
            batch axes (transformed independently).
        degree: the degree `k` of `form`, 1 or 2 (keyword-only).
        dual: the dual cells of the stars, one of `ddgjax.DUAL_CELLS`: `"voronoi"` (default), `"circumcentric"` or
            `"barycentric"` (keyword-only; `hodge_star_entries`, zero entries invert to zero).

    Returns:
        The primal `(k-1)`-form `delta_k form`: `(nv, *batch)` for degree 1, `(ne, *batch)` for degree 2.
    """
    mesh = require_mesh("mesh", mesh)
    check_choice("dual", dual, DUAL_CELLS)
    check_choice("degree", degree, (1, 2))
    if degree == 2:
        mesh.topology.require_oriented("ddgjax.dec.codifferential(degree=2)")
    return codifferential_from(_as_form("form", mesh, form, degree), degree, *_complex(mesh, dual))


def _hodge_laplacian(mesh: Mesh, name: str, form, degree: int, dual: str, weak: bool):
    if degree > 0:
        mesh.topology.require_oriented(f"ddgjax.dec.hodge_laplacian{degree}")
    check_choice("dual", dual, DUAL_CELLS)
    return hodge_laplacian_from(_as_form(name, mesh, form, degree), degree, 2, *_complex(mesh, dual), weak=weak)


def hodge_laplacian0(
    mesh: Mesh, u: Float[ArrayLike, "nv *batch"], /, *, dual: str = "voronoi", weak: bool = False
) -> Float[Array, "nv *batch"]:
    """Hodge Laplacian on 0-forms, `Delta_0 u = delta_1 d0 u = *0^{-1} d0^T *1 d0 u`, `(nv, *batch)`.

    PSD convention: with the Voronoi (default) or circumcentric dual, `d0^T *1 d0 = L`, the cotan Laplacian
    (`ddgjax.laplacian.cotan_laplacian`), so `Delta_0 = *0^{-1} L` is minus the pointwise Laplace-Beltrami
    operator (pointwise: divided by the dual areas). Works on any mesh; vertices with zero dual area get 0
    (pseudo-inverse). Reference: Desbrun et al., *Discrete Exterior Calculus* (2005); Crane et al. 2013,
    section 6. Equivalents: `weak=True` is `-igl.cotmatrix(V, F) @ u` and `gpytoolbox.cotangent_laplacian(V, F) @ u`;
    with the default `dual="voronoi"` the strong form is `-(igl.cotmatrix(V, F) @ u) / M.diagonal()` with
    `M = igl.massmatrix(V, F, igl.MASSMATRIX_TYPE_VORONOI)`.

    Args:
        mesh: any triangle mesh.
        u: `(nv,)` or `(nv, k)` 0-form (values at the vertices; columns transformed independently; positional-only).
        dual: the dual cells of `*0` and `*1`, one of `ddgjax.DUAL_CELLS`: `"voronoi"` (default), `"circumcentric"`
            or `"barycentric"` (keyword-only; `hodge_star_entries`).
        weak: `False` (default) for the pointwise `Delta_0 u`; `True` for the symmetric, integrated
            `*0 Delta_0 u = d0^T *1 d0 u` (no division by dual areas; keyword-only).

    Returns:
        `(nv, *batch)` 0-form `Delta_0 u` (or `*0 Delta_0 u` with `weak=True`); 0 at vertices with zero dual area.
    """
    mesh = require_mesh("mesh", mesh)
    return _hodge_laplacian(mesh, "u", u, 0, dual, weak)


def hodge_laplacian1(
    mesh: Mesh, alpha: Float[ArrayLike, "ne *batch"], *, dual: str = "voronoi", weak: bool = False
) -> Float[Array, "ne *batch"]:
    """Hodge Laplacian on 1-forms, `Delta_1 = d0 delta_1 + delta_2 d1`, `(ne, *batch)`.

    `Delta_1 alpha = d0 *0^{-1} d0^T *1 alpha + *1^{-1} d1^T *2 d1 alpha` (PSD for positive stars). The kernel
    is the harmonic 1-forms (dimension `2 * genus` on a closed surface, for positive stars). Needs consistently
    oriented faces. Reference: Desbrun et al. 2005; Crane et al. 2013, section 6.

    Args:
        mesh: a consistently oriented triangle mesh (`MeshDataError` otherwise).
        alpha: `(ne,)` or `(ne, k)` 1-form on `mesh.edges` (integrals along low -> high; columns transformed
            independently).
        dual: the dual cells of the stars, one of `ddgjax.DUAL_CELLS`: `"voronoi"` (default), `"circumcentric"` or
            `"barycentric"` (keyword-only; `hodge_star_entries`, zero entries invert to zero).
        weak: `False` (default) for `Delta_1 alpha`; `True` for the symmetric
            `*1 Delta_1 alpha = *1 d0 *0^{-1} d0^T *1 alpha + d1^T *2 d1 alpha` (its second term needs no `*1^{-1}`,
            so it is exact where `*1` has zero entries; keyword-only).

    Returns:
        `(ne, *batch)` 1-form `Delta_1 alpha` (or `*1 Delta_1 alpha` with `weak=True`).
    """
    mesh = require_mesh("mesh", mesh)
    return _hodge_laplacian(mesh, "alpha", alpha, 1, dual, weak)


def hodge_laplacian2(
    mesh: Mesh, omega: Float[ArrayLike, "nf *batch"], *, dual: str = "voronoi", weak: bool = False
) -> Float[Array, "nf *batch"]:
    """Hodge Laplacian on 2-forms, `Delta_2 = d1 delta_2 = d1 *1^{-1} d1^T *2`, `(nf, *batch)`.

    `Delta_2 omega = d1 *1^{-1} d1^T *2 omega`: `*2` turns the face integrals into densities, `d1^T` takes their
    jumps across the edges, `*1^{-1}` and `d1` sum the resulting dual fluxes around each face. PSD for positive
    stars (barycentric always; Voronoi and circumcentric on Delaunay meshes); on a closed surface its kernel is
    the constant density (`omega` proportional to the face areas). Zero `*1` entries invert to 0. Needs
    consistently oriented faces (`MeshDataError` otherwise). Reference: Desbrun et al., *Discrete Exterior
    Calculus* (2005); Crane et al. 2013, section 6. gpytoolbox (its own edge order, which cancels here):
    `dec_d1(F) @ dec_h1inv(V, F) @ dec_d1(F).T @ dec_h2inv(V, F) @ omega`.

    Args:
        mesh: a consistently oriented triangle mesh (`MeshDataError` otherwise).
        omega: `(nf,)` or `(nf, k)` 2-form, integrated over the faces (module docstring; columns transformed
            independently).
        dual: the dual cells of the stars, one of `ddgjax.DUAL_CELLS`: `"voronoi"` (default), `"circumcentric"` or
            `"barycentric"` (keyword-only; `hodge_star_entries`, zero entries invert to zero).
        weak: `False` (default) for `Delta_2 omega`; `True` for the symmetric `*2 d1 *1^{-1} d1^T *2 omega`
            (keyword-only).

    Returns:
        `(nf, *batch)` 2-form `Delta_2 omega`, integrated over the faces (or `*2 Delta_2 omega` with `weak=True`).
    """
    mesh = require_mesh("mesh", mesh)
    return _hodge_laplacian(mesh, "omega", omega, 2, dual, weak)
