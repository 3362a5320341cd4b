"""The codifferential and the Hodge Laplacian of primal forms, from a complex's `d` and Hodge stars, in any dimension.

On a simplicial complex of dimension `n` (2 for a triangle mesh, 3 for a tet mesh) with exterior derivatives
`d_k` and diagonal Hodge stars `*_k`,

    delta_k   = *_{k-1}^{-1} d_{k-1}^T *_k                      (the adjoint of d_{k-1} for <a, b>_k = a^T *_k b)
    Delta_k   = d_{k-1} delta_k + delta_{k+1} d_k               (0 <= k <= n; a term is absent at k = 0, k = n)
    *_k Delta_k = *_k d_{k-1} *_{k-1}^{-1} d_{k-1}^T *_k + d_k^T *_{k+1} d_k      (weak: symmetric, integrated)

`ddgjax.dec` (surfaces) and `ddgjax.volume` (solids) each supply their `d` and `*` (as callables of the degree)
and share these two functions, so the operator is written once for every dimension. Zero star entries
invert to zero. Reference: Desbrun, Hirani, Leok, Marsden, "Discrete exterior calculus" (2005), section 9;
Crane et al., "Digital geometry processing with discrete exterior calculus" (2013), section 6.
"""

from __future__ import annotations

from collections.abc import Callable

import jax.numpy as jnp
from jaxtyping import Array, Float

from ..sparse import SparseMatrix

#: `exterior_derivative(k)`: the `d_k` of a complex, a `SparseMatrix`.
ExteriorDerivative = Callable[[int], SparseMatrix]
#: `star(k, inverse)`: the diagonal entries of `*_k` (of `*_k^{-1}` with `inverse=True`, zero for zero entries).
Star = Callable[[int, bool], Float[Array, " n"]]


def scale_rows(entries: Float[Array, " n"], x: Float[Array, "n *batch"]) -> Float[Array, "n *batch"]:
    """`diag(entries) x` for `x` of shape `(n,)` or `(n, *batch)`."""
    return entries.reshape((-1,) + (1,) * (x.ndim - 1)) * x


def codifferential_from(
    form: Float[Array, "n *batch"], degree: int, exterior_derivative: ExteriorDerivative, star: Star
) -> Float[Array, "m *batch"]:
    """`delta_k form = *_{k-1}^{-1} d_{k-1}^T *_k form` for a primal `degree`-form, `degree >= 1` (module docstring)."""
    return scale_rows(star(degree - 1, True), exterior_derivative(degree - 1).T @ scale_rows(star(degree, False), form))


def hodge_laplacian_from(
    form: Float[Array, "n *batch"],
    degree: int,
    dimension: int,
    exterior_derivative: ExteriorDerivative,
    star: Star,
    *,
    weak: bool,
) -> Float[Array, "n *batch"]:
    """`Delta_k form` (or `*_k Delta_k form` with `weak`) on a complex of `dimension` (module docstring)."""
    result = jnp.zeros_like(form)
    if degree < dimension:  # delta_{k+1} d_k
        d = exterior_derivative(degree)
        up = d.T @ scale_rows(star(degree + 1, False), d @ form)
        result = result + (up if weak else scale_rows(star(degree, True), up))
    if degree > 0:  # d_{k-1} delta_k
        down = exterior_derivative(degree - 1) @ codifferential_from(form, degree, exterior_derivative, star)
        result = result + (scale_rows(star(degree, False), down) if weak else down)
    return result
