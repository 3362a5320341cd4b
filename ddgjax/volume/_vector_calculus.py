"""Gradient and divergence in a solid, the codifferential and the Hodge Laplacians of discrete forms on tets.

Conventions (DESIGN.md, as `ddgjax.dec` on surfaces):

- a function `u` on the vertices is the piecewise-linear interpolant `sum_i u_i phi_i`; its gradient
  is constant in each tet, `(nt, 3)`;
- `divergence` of a per-tet vector field is *integrated* over the vertex dual cells (weak form,
  tested against each hat function): `divergence(gradient(u)) == -L u` with `L` the PSD cotan
  Laplacian (`cotan_laplacian`); a source field has positive divergence; divide by the vertex dual
  volume for the pointwise value;
- the codifferential is the adjoint of `d` for `<a, b>_k = a^T *_k b`,
  `delta_k = *_{k-1}^{-1} d_{k-1}^T *_k`, and the Hodge Laplacian `Delta_k = d delta + delta d` is
  self-adjoint, positive semidefinite where the stars are positive (always for
  `dual="barycentric"`); its kernel is the harmonic k-forms, of dimension the k-th Betti number
  (absolute cohomology: a ball 1, 0, 0, 0; a solid torus 1, 1, 0, 0; a spherical shell 1, 0, 1, 0).

Per-tet corner values reach the vertices through one fixed gather (`ddgjax.sparse.gather_sum`), so
the divergence and its derivatives have no scatter-add.

Reference: Crane, Weischedel, Wardetzky, *The heat method for distance computation* (2017), section
3.2; Desbrun, Hirani, Leok, Marsden, *Discrete Exterior Calculus* (2005).
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from .._compile import device_array, kernel
from .._errors import DDGInputError, check_choice
from .._indexing import take_rows
from ..dec.internal import codifferential_from, hodge_laplacian_from
from ._dec import TET_DUALS, TetIncidence, exterior_derivative, hodge_star_entries, sum_onto_vertices, tet_incidence
from ._geometry import tet_hat_gradients, tet_volumes
from ._tet_mesh import TetMesh, require_tet_mesh


@kernel
def _gradient(tet_mesh: TetMesh, u: Float[Array, " nv"]) -> Float[Array, "nt 3"]:
    return jnp.einsum("tk,tkd->td", take_rows(u, tet_mesh.tets), tet_hat_gradients(tet_mesh))


def gradient(tet_mesh: TetMesh, u: Float[ArrayLike, " nv"], /) -> Float[Array, "nt 3"]:
    """Gradient of the piecewise-linear interpolant of `u`, one vector per tet, `(nt, 3)`.

    `(grad u)_t = sum_k u[T[t, k]] grad phi_k` (`tet_hat_gradients`); exact for linear `u`; 0 on a
    zero-volume tet. libigl: `igl.grad(V, T) @ u` reshaped `(3, nt).T`.

    Args:
        tet_mesh: the tet mesh.
        u: `(nv,)` values at the vertices (positional-only).

    Returns:
        `(nt, 3)` float array, one gradient vector per tet.
    """
    tet_mesh = require_tet_mesh("tet_mesh", tet_mesh)
    return _gradient(tet_mesh, _as_array("u", u, tet_mesh.n_vertices, "nv", trailing=()))


@kernel
def _divergence(tet_mesh: TetMesh, incidence: TetIncidence, field: Float[Array, "nt 3"]) -> Float[Array, " nv"]:
    corner_terms = -tet_volumes(tet_mesh)[:, None] * jnp.einsum("tkd,td->tk", tet_hat_gradients(tet_mesh), field)
    return sum_onto_vertices(tet_mesh, incidence, corner_terms)


def divergence(tet_mesh: TetMesh, field: Float[ArrayLike, "nt 3"]) -> Float[Array, " nv"]:
    """Integrated divergence of a per-tet vector field at each vertex, `(nv,)`.

    `(div X)_i = -sum_{t ni i} V_t grad phi_i . X_t`, the weak divergence against the hat function
    `phi_i`; so `divergence(gradient(u)) == -L u` (`L = cotan_laplacian`, PSD) and an outward field
    has positive divergence inside. Divide by the vertex dual volume for the pointwise value. The
    sign of `ddgjax.dec.divergence` on surfaces. libigl: `-igl.grad(V, T).T @ (vol * X)` with `vol`
    the tet volumes repeated per component. Reference: Crane et al. 2017 (heat method).

    Args:
        tet_mesh: the tet mesh.
        field: `(nt, 3)` one vector per tet.

    Returns:
        `(nv,)` float array of integrated divergences.
    """
    tet_mesh = require_tet_mesh("tet_mesh", tet_mesh)
    field = _as_array("field", field, tet_mesh.n_tets, "nt", trailing=(3,))
    return _divergence(tet_mesh, tet_incidence(tet_mesh), field)


def _as_array(name: str, array, n: int, symbol: str, *, trailing: tuple[int, ...] | None = None) -> Array:
    """`array` as a float JAX array of leading dimension `n` (and exactly `trailing` after it when given), else `DDGInputError`."""
    array = device_array(array)
    if array.shape[:1] != (n,) or (trailing is not None and array.shape[1:] != trailing):
        expected = (
            f"({n}{''.join(f', {size}' for size in trailing)})" if trailing is not None else f"leading dimension {symbol} = {n}"
        )
        raise DDGInputError(f"{name}: expected shape {expected}, got {array.shape}")
    return array if jnp.issubdtype(array.dtype, jnp.floating) else array.astype(jnp.result_type(float))


_FORM_SIZES = (("n_vertices", "nv"), ("n_edges", "ne"), ("n_triangles", "ntri"), ("n_tets", "nt"))


def _as_form(name: str, tet_mesh: TetMesh, form, degree: int) -> Array:
    attribute, symbol = _FORM_SIZES[degree]
    return _as_array(name, form, getattr(tet_mesh, attribute), symbol)


def _complex(tet_mesh: TetMesh, dual: str):
    """The solid's `d_k` and `*_k` as `ddgjax.dec`'s dimension-free Hodge Laplacian takes them."""
    return (
        lambda degree: exterior_derivative(tet_mesh, degree),
        lambda degree, inverse: hodge_star_entries(tet_mesh, degree=degree, dual=dual, inverse=inverse),
    )


def codifferential(
    tet_mesh: TetMesh, form: Float[ArrayLike, "n *batch"], *, degree: int, dual: str = "voronoi"
) -> Float[Array, "m *batch"]:
    """Codifferential `delta_k` of a primal `degree`-form (`degree` 1, 2 or 3), a primal (k-1)-form.

    `delta_k = *_{k-1}^{-1} d_{k-1}^T *_k`, the adjoint of `d_{k-1}` for `<a, b>_k = a^T *_k b`
    (module docstring); `codifferential(d0 u, degree=1) = *0^{-1} L u`. Reference: Desbrun et al. 2005,
    section 9.

    Args:
        tet_mesh: the tet mesh.
        form: `(ne,)`, `(ntri,)` or `(nt,)` primal form, optionally with trailing batch axes.
        degree: the degree `k` of `form`, 1, 2 or 3 (keyword-only).
        dual: `"voronoi"` (default), `"circumcentric"` or `"barycentric"` (keyword-only): the stars
            (`hodge_star_entries`; zero entries invert to zero).

    Returns:
        Float array of the (k-1)-form, `(nv,)`, `(ne,)` or `(ntri,)` with `form`'s trailing axes.
    """
    tet_mesh = require_tet_mesh("tet_mesh", tet_mesh)
    check_choice("dual", dual, TET_DUALS)
    check_choice("degree", degree, (1, 2, 3))
    return codifferential_from(_as_form("form", tet_mesh, form, degree), degree, *_complex(tet_mesh, dual))


def hodge_laplacian(
    tet_mesh: TetMesh, form: Float[ArrayLike, "n *batch"], *, degree: int, dual: str = "voronoi", weak: bool = False
) -> Float[Array, "n *batch"]:
    """Hodge Laplacian `Delta_k = d_{k-1} delta_k + delta_{k+1} d_k` on primal `degree`-forms of a tet mesh.

    The columns of a batch are transformed independently, so `hodge_laplacian(m, eye(n), ...)` is the dense matrix.
    `weak=True` returns the symmetric integrated form
    `*_k Delta_k = *_k d_{k-1} *_{k-1}^{-1} d_{k-1}^T *_k + d_k^T *_{k+1} d_k` (its second term needs no
    inverse star). PSD where the stars are positive (`dual="barycentric"` always); its kernel is the
    harmonic forms, of dimension the Betti number `b_k` (module docstring). `Delta_0` with the
    Voronoi (default) or circumcentric dual is `*0^{-1} L` (`weak=True`: `L = cotan_laplacian`,
    `-igl.cotmatrix(V, T)`). The surface counterparts are `ddgjax.dec.hodge_laplacian0/1/2`.
    Reference: Desbrun et al., *Discrete Exterior Calculus* (2005); Crane et al. 2013, section 6.

    Args:
        tet_mesh: the tet mesh.
        form: `(nv,)`, `(ne,)`, `(ntri,)` or `(nt,)` primal form, optionally with trailing batch axes.
        degree: the degree `k` of `form`, 0..3 (keyword-only).
        dual: `"voronoi"` (default), `"circumcentric"` or `"barycentric"` (keyword-only): the stars.
        weak: `True` for the integrated form `*_k Delta_k` (keyword-only; default `False`).

    Returns:
        Float array of `form`'s shape: `Delta_k form` (`*_k Delta_k form` when `weak`).
    """
    tet_mesh = require_tet_mesh("tet_mesh", tet_mesh)
    check_choice("dual", dual, TET_DUALS)
    check_choice("degree", degree, (0, 1, 2, 3))
    return hodge_laplacian_from(_as_form("form", tet_mesh, form, degree), degree, 3, *_complex(tet_mesh, dual), weak=weak)
