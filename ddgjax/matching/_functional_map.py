"""The least-squares functional map between two spectral shapes: pyFM's `fit` energy, solved exactly.

The energy is quadratic in `C`, so its minimiser solves one symmetric positive definite linear system
in the `k_t (k_s - 1)` free entries of `C` (the first column is fixed, as pyFM fixes it). It is solved
with lineax, two ways (`method=`):

- `"cholesky"`: assemble the `(k_t k_s, k_t k_s)` Hessian (`O(d k^4)`, one matrix product for the
  descriptor operators' cross terms) and factorise it (`O(k^6)`);
- `"cg"`: matrix-free conjugate gradients, `O(d k^3)` an iteration (four matrix products over the
  stacked operators), preconditioned by block Jacobi: the exact Hessian block that couples the
  entries of one row of `C`, inverted once per row.

With `d` about 100 the assembled Hessian is the faster route up to `k` about 60, and above it the
`(k^2)^2` matrix costs more time and memory than a few hundred CG iterations, so `"auto"` assembles
up to `k_t k_s = 4096`. Both differentiate through lineax's implicit differentiation of the solve.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .._compile import device_array, kernel
from .._errors import DDGInputError, check_choice
from .._numerics import safe_div, safe_norm
from .._results import RESULTS, Solution, outcome
from ._shape import SpectralShape, require_connected, require_spectral_shape

ORIENTATIONS = ("preserving", "reversing")
FUNCTIONAL_MAP_METHODS = ("auto", "cholesky", "cg")
# Up to this many entries of C, assembling and factorising the dense Hessian beats CG (d ~ 100).
_DENSE_UNKNOWNS = 4096
# pyFM's `fit(use_resolvent_laplacian=True, resolvent_gamma=0.5)`.
_RESOLVENT_GAMMA = 0.5


def functional_map(
    source: SpectralShape,
    target: SpectralShape,
    source_descriptors: Float[ArrayLike, "n_source d"],
    target_descriptors: Float[ArrayLike, "n_target d_target"],
    *,
    k_source: int | None = None,
    k_target: int | None = None,
    descriptor_weight: float = 1e-1,
    laplacian_weight: float = 1e-3,
    commutativity_weight: float = 1.0,
    orientation_weight: float = 1.0,
    orientation: str = "preserving",
    method: str = "auto",
    rtol: float | None = None,
    max_steps: int = 1000,
    throw: bool = True,
) -> Float[Array, "k_target k_source"] | Solution:
    r"""The functional map `C` `(k_target, k_source)` minimising pyFM's `fit` energy, by one linear solve.

    With `A = Phi_s^T M_s F_s` `(k_s, d)` and `B = Phi_t^T M_t F_t` `(k_t, d)` the descriptors' spectral
    coefficients, `C` minimises

    $$E(C) = \frac{\mu_d}{2} \lVert C A - B \rVert^2 + \frac{\mu_l}{2} \sum_{ij} R_{ij} C_{ij}^2 + \frac{\mu_c}{2} \sum_p \lVert C P_p - Q_p C \rVert^2 + \frac{\mu_o}{2} \sum_p \lVert C G_p - s H_p C \rVert^2$$

    over the maps whose first column is `(sign sqrt(area_t / area_s), 0, ..., 0)` (constants map to
    constants; `sign` that of `phi^s_0 phi^t_0` at vertex 0, as pyFM fixes it), where

    - `R_ij = |r(lambda^t_i) - r(lambda^s_j)|^2`, `r(x) = 1 / (x^gamma - i)` with both spectra divided by
      the larger of their largest eigenvalues, `gamma = 0.5` (Ren et al. 2019's resolvent Laplacian
      commutativity, pyFM's default);
    - `P_p = Phi_s^T M_s diag(f^s_p) Phi_s`, `Q_p` likewise on the target: multiplication by each
      descriptor (Nogneng & Ovsjanikov 2017);
    - `G_p = Phi_s^T W_p Phi_s`: the orientation operator of Ren et al. 2018,
      `(W_p g)(v) = sum_{faces f at v} (area_f / 3) <n_f x grad f_p, grad g>` (per-face gradients,
      face normals, averaged to the vertices and divided by the vertex area, so `M^-1 W` in the
      spectral basis is `Phi^T W Phi`); `s = +1` for `orientation="preserving"`, `-1` for `"reversing"`;
    - `mu_x = w_x / (w_total tau_x)`: the weights divided by their sum and by pyFM's `canonical_taus`
      (the scale of each term at a generic map, from `A`, `R` and the operators), so only their
      ratios matter.

    The normal equations `H(C) = mu_d B A^T` (in the free entries) are solved once, by Cholesky or
    preconditioned CG (`method`); `E` is strictly convex when the descriptors tell the shape's
    symmetries apart (with symmetric descriptors and no orientation term the minimiser is not unique). The map is smooth in
    the descriptors and in the shapes' arrays and differentiates through the solve (lineax's
    implicit differentiation); it works under `jit` and `vmap` (over batched descriptors).
    Each shape's mesh is one connected surface: a mesh of several components is refused
    (`DDGInputError`, as `match_shapes` does), because its extra zero eigenvalues leave the fixed first
    column meaningless.

    Args:
        source, target: `SpectralShape`s (pyFM's mesh1 and mesh2).
        source_descriptors, target_descriptors: `(n_source, d)`, `(n_target, d)` descriptors
            (`ddgjax.matching.descriptors`), the same `d` on both.
        k_source, k_target: basis sizes (default: all of each shape's eigenpairs).
        descriptor_weight, laplacian_weight, commutativity_weight, orientation_weight: host numbers
            `>= 0` (pyFM's `w_descr=0.1, w_lap=1e-3, w_dcomm=1`; its `w_orient` is 0, ddgjax's 1 as in
            `match_shapes`: without the term a symmetric pair's map may come out mirrored).
        orientation: `"preserving"` (default) or `"reversing"` (pyFM's `orient_reversing`).
        method: `"cholesky"` (assemble the `(k_t k_s)^2` Hessian, `O(d k^4 + k^6)`, and factorise it),
            `"cg"` (matrix-free conjugate gradients, `O(d k^3)` an iteration, block-Jacobi
            preconditioned), or `"auto"` (default): Cholesky up to `k_t k_s = 4096`, CG above.
        rtol, max_steps: CG stops when every entry of the residual of the normal equations is below
            `rtol` times their right-hand side's largest entry (default `1e-10` in float64, `1e-5` in
            float32), or fails after `max_steps` iterations.
        throw: raise if CG does not converge or the map is not finite (default); `False` returns a
            `ddgjax.Solution` with `stats["num_steps"]` (CG's iterations, 0 for Cholesky).

    Returns:
        `C` `(k_target, k_source)`: it maps source coefficients `Phi_s^T M_s f` to target ones.

    pyFM: `model = FunctionalMapping(mesh1, mesh2); model.preprocess(...); model.fit(K=(k_s, k_t),
    w_descr=..., w_lap=..., w_dcomm=..., w_orient=..., orient_reversing=...)`; `model.FM_12`, but
    exact where pyFM's L-BFGS stops at its tolerance.
    References: M. Ovsjanikov et al., "Functional maps" (2012); D. Nogneng & M. Ovsjanikov,
    "Informative descriptor preservation via commutativity for shape matching" (2017); J. Ren, A.
    Poulenard, P. Wonka & M. Ovsjanikov, "Continuous and orientation-preserving correspondences via
    functional maps" (2018); J. Ren, M. Panine, P. Wonka & M. Ovsjanikov, "Structured regularization
    of functional map computations" (2019).

    Examples:
        >>> import jax.numpy as jnp
        >>> import ddgjax
        >>> sphere = ddgjax.mesh.icosphere(2)
        >>> x, y, z = sphere.vertices.T
        >>> bumpy = sphere.with_vertices(sphere.vertices * (1 + 0.3 * x**2 + 0.2 * y * z + 0.1 * z)[:, None])
        >>> shape = ddgjax.matching.spectral_shape(bumpy, 20)
        >>> F = ddgjax.matching.descriptors(shape, kind="wks", n_descriptors=20)
        >>> C = ddgjax.matching.functional_map(shape, shape, F, F)
        >>> C.shape, bool(jnp.allclose(C, jnp.eye(20), atol=1e-6))  # a shape onto itself: the identity
        ((20, 20), True)
    """
    source, target = require_spectral_shape("source", source), require_spectral_shape("target", target)
    require_connected("source", source.mesh, "functional_map")
    require_connected("target", target.mesh, "functional_map")
    k_s = _basis_size("k_source", k_source, source)
    k_t = _basis_size("k_target", k_target, target)
    F_s = _descriptor_array("source_descriptors", source_descriptors, source)
    F_t = _descriptor_array("target_descriptors", target_descriptors, target)
    if F_s.shape[1] != F_t.shape[1]:
        raise DDGInputError(
            f"target_descriptors: expected as many columns as source_descriptors ({F_s.shape[1]}), got {F_t.shape[1]}"
        )
    sign = {"preserving": 1.0, "reversing": -1.0}[check_choice("orientation", orientation, ORIENTATIONS)]
    weights = {}
    for name, value in (
        ("descriptor_weight", descriptor_weight),
        ("laplacian_weight", laplacian_weight),
        ("commutativity_weight", commutativity_weight),
        ("orientation_weight", orientation_weight),
    ):
        if isinstance(value, (bool, jax.Array)) or not isinstance(value, (int, float, np.number)) or not value >= 0:
            raise DDGInputError(f"{name}: expected a host number >= 0, got {value!r}")
        weights[name] = float(value)
    total = sum(weights.values())
    if total <= 0:
        raise DDGInputError("descriptor_weight ... orientation_weight: at least one weight must be positive")
    method = check_choice("method", method, FUNCTIONAL_MAP_METHODS)
    if method == "auto":
        method = "cholesky" if k_s * k_t <= _DENSE_UNKNOWNS else "cg"
    # One compiled program per sizes and method (eagerly, a few hundred small ones compiled op by op).
    C, result, num_steps = _fit(
        _traceable(source),
        _traceable(target),
        F_s,
        F_t,
        device_array(np.asarray([w / total for w in weights.values()], F_s.dtype)),
        sign,
        k_s=k_s,
        k_t=k_t,
        method=method,
        rtol=rtol,
        max_steps=max_steps,
        commutativity=weights["commutativity_weight"] > 0,
        orientation_term=weights["orientation_weight"] > 0,
    )
    return outcome(C, result, throw, {"num_steps": num_steps})


def _traceable(shape: SpectralShape) -> SpectralShape:
    """`shape` with its mesh's host topology dropped: the compiled fit needs only its arrays (`ddgjax._compile.kernel`)."""
    return eqx.tree_at(lambda s: s.mesh, shape, shape.mesh.without_topology())


@kernel(static_argnames=("k_s", "k_t", "method", "rtol", "max_steps", "commutativity", "orientation_term"))
def _fit(
    source: SpectralShape,
    target: SpectralShape,
    F_s,
    F_t,
    weights,
    sign,
    *,
    k_s: int,
    k_t: int,
    method: str,
    rtol,
    max_steps,
    commutativity: bool,
    orientation_term: bool,
):
    """`functional_map`'s computation on checked arguments: `(C, result, CG steps)` (its docstring)."""
    w_d, w_l, w_c, w_o = weights[0], weights[1], weights[2], weights[3]
    Phi_s, Phi_t = source.vectors[:, :k_s], target.vectors[:, :k_t]
    A = Phi_s.T @ (source.mass[:, None] * F_s)
    B = Phi_t.T @ (target.mass[:, None] * F_t)
    mask = _resolvent_mask(source.values[:k_s], target.values[:k_t])
    p_eff = jnp.maximum((_effective_p(A) + _effective_p(B)) / 2, 1e-12)
    m = min(k_s, k_t)
    # Each term's weight over its scale at a generic map (pyFM's `canonical_taus`).
    terms = [(w_d / _guard(m * jnp.sum(A[1:] ** 2) / k_s / p_eff), None), (w_l / _guard(m * jnp.sum(mask) / (k_s * k_t)), None)]
    operator_terms = []
    if commutativity:
        P, Q = _multiplication_operators(source, Phi_s, F_s), _multiplication_operators(target, Phi_t, F_t)
        operator_terms.append((w_c / _operator_tau(P, Q, m, p_eff, skew=False), P, Q))
    if orientation_term:
        G, H = _orientation_operators(source, Phi_s, F_s), sign * _orientation_operators(target, Phi_t, F_t)
        operator_terms.append((w_o / _operator_tau(G, H, m, p_eff, skew=True), G, H))
    mu_d, mu_l = terms[0][0], terms[1][0]
    AAt = A @ A.T

    # Each operator term's H(C) = sum_p (C P_p - Q_p C) P_p^T - Q_p^T (C P_p - Q_p C), as four plain
    # matrix products over the stacked operators (faster than batched products on the CPU).
    layouts = [
        (
            mu,
            jnp.transpose(P, (1, 0, 2)).reshape(k_s, -1),
            Q.reshape(-1, k_t),
            jnp.transpose(P, (0, 2, 1)).reshape(-1, k_s),
            jnp.transpose(Q, (2, 0, 1)).reshape(k_t, -1),
        )
        for mu, P, Q in operator_terms
    ]

    def hessian(C):
        out = mu_d * C @ AAt + mu_l * mask * C
        for mu, P_right, Q_stacked, P_back, Q_back in layouts:
            n = Q_stacked.shape[0] // k_t
            D = jnp.transpose((C @ P_right).reshape(k_t, n, k_s), (1, 0, 2)) - (Q_stacked @ C).reshape(n, k_t, k_s)
            out = out + mu * (jnp.transpose(D, (1, 0, 2)).reshape(k_t, -1) @ P_back - Q_back @ D.reshape(-1, k_s))
        return out

    free = jnp.arange(k_s) > 0
    C0 = jnp.zeros((k_t, k_s), A.dtype)
    first = jnp.sign(Phi_s[0, 0] * Phi_t[0, 0]) * jnp.sqrt(jnp.sum(target.mass) / jnp.sum(source.mass))
    C0 = C0.at[0, 0].set(first)
    rhs = jnp.where(free, mu_d * B @ A.T - hessian(C0), 0.0)
    # lineax's CG tests |r_i| <= atol + rtol |b_i| entrywise: with b scaled to unit max-norm and
    # atol = rtol, that is a residual below rtol relative to the largest entry, zero entries included.
    scale = jax.lax.stop_gradient(jnp.max(jnp.abs(rhs)))
    scale = jnp.where(scale > 0, scale, 1.0)
    structure = jax.ShapeDtypeStruct((k_t, k_s), A.dtype)
    if method == "cholesky":
        matrix = _hessian_matrix(mu_d, AAt, mu_l, mask, operator_terms, free)
        # The energy can be flat along some maps (a shape matched to itself: every map commuting with its
        # operators): a ridge at round-off of the diagonal picks the minimiser nearest 0, as CG from 0 does.
        ridge = jax.lax.stop_gradient(jnp.max(jnp.diagonal(matrix))) * jnp.finfo(matrix.dtype).eps * matrix.shape[0]
        matrix = matrix + ridge * jnp.eye(matrix.shape[0], dtype=matrix.dtype)
        operator = lx.MatrixLinearOperator(matrix, lx.positive_semidefinite_tag)
        solution = lx.linear_solve(operator, (rhs / scale).reshape(-1), lx.Cholesky(), throw=False)
        solution = eqx.tree_at(lambda sol: sol.value, solution, solution.value.reshape(k_t, k_s))
        num_steps = jnp.asarray(0)
    else:
        operator = lx.FunctionLinearOperator(
            lambda X: jnp.where(free, hessian(jnp.where(free, X, 0.0)), X), structure, lx.positive_semidefinite_tag
        )
        # The preconditioner only speeds CG up: built from values whose derivatives the solve does not need.
        blocks_inverse = jax.lax.stop_gradient(_row_blocks_inverse(mu_d, AAt, mu_l, mask, operator_terms, free))
        preconditioner = lx.FunctionLinearOperator(
            lambda X: jnp.einsum("rc,rcd->rd", X, blocks_inverse), structure, lx.positive_semidefinite_tag
        )
        if rtol is None:
            rtol = 1e-10 if A.dtype == jnp.float64 else 1e-5
        solution = lx.linear_solve(
            operator,
            rhs / scale,
            lx.CG(rtol=rtol, atol=rtol, max_steps=max_steps),
            options={"preconditioner": preconditioner},
            throw=False,
        )
        num_steps = solution.stats["num_steps"]
    C = C0 + scale * jnp.where(free, solution.value, 0.0)
    result = RESULTS.where(
        solution.result == lx.RESULTS.successful,
        RESULTS.successful,
        RESULTS.where(solution.result == lx.RESULTS.max_steps_reached, RESULTS.max_steps_reached, RESULTS.nonfinite),
    )
    result = RESULTS.where(jnp.all(jnp.isfinite(C)), result, RESULTS.nonfinite)
    return C, result, num_steps


def _basis_size(name: str, k, shape: SpectralShape) -> int:
    k = shape.k if k is None else k
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 1 <= k <= shape.k:
        raise DDGInputError(
            f"{name}: expected an integer in [1, {shape.k}] (the shape's eigenpairs; compute more with "
            f"`spectral_shape(mesh, k)`), got {k!r}"
        )
    return int(k)


def _descriptor_array(name: str, descriptors, shape: SpectralShape) -> Float[Array, "nv d"]:
    descriptors = jnp.asarray(descriptors)
    nv = shape.vectors.shape[0]
    if descriptors.ndim != 2 or descriptors.shape[0] != nv or descriptors.shape[1] == 0:
        raise DDGInputError(f"{name}: expected shape ({nv}, d) (one row per vertex of the shape), got {descriptors.shape}")
    return descriptors


def _guard(value):
    """pyFM's `_guard`: a non-positive scale counts as 1."""
    return jnp.where(value > 0, value, 1.0)


def _effective_p(F: Float[Array, "k d"]):
    """pyFM's `effective_p` of one bank: `(tr G)^2 / ||G||_F^2`, `G = F[1:]^T F[1:]` (constant mode left out)."""
    gram = F[1:].T @ F[1:]
    denominator = jnp.sum(gram**2)
    return jnp.where(denominator > 0, jnp.trace(gram) ** 2 / jnp.where(denominator > 0, denominator, 1.0), 1.0)


def _operator_tau(P, Q, m: int, p_eff, *, skew: bool):
    """pyFM's `canonical_taus` for an operator list: `sum_p k_t||P_p||^2 + k_s||Q_p||^2 (- 2 tr P_p tr Q_p)`."""
    k_s, k_t = P.shape[1], Q.shape[1]
    positive = k_t * jnp.sum(P**2) + k_s * jnp.sum(Q**2)
    total = positive if skew else positive - 2 * jnp.sum(jnp.trace(P, axis1=1, axis2=2) * jnp.trace(Q, axis1=1, axis2=2))
    total = jnp.maximum(total, 0.0)
    return jnp.where(total <= 1e-12 * positive, 1.0, total * m / (k_s * k_t) / p_eff)


def _resolvent_mask(values_s: Float[Array, " k_s"], values_t: Float[Array, " k_t"]) -> Float[Array, "k_t k_s"]:
    """pyFM's `resolvent_mask(evals1, evals2, gamma=0.5)`: `|r(lambda_t) - r(lambda_s)|^2`, `r(x) = 1/(x^gamma - i)`."""
    scale = jnp.maximum(jnp.max(jnp.abs(values_s)), jnp.max(jnp.abs(values_t)))

    def resolvent(values):
        x = jnp.abs(values) / scale
        # x^gamma with a finite derivative at the zero eigenvalue.
        powered = jnp.where(x > 0, jnp.where(x > 0, x, 1.0) ** _RESOLVENT_GAMMA, 0.0)
        return powered / (powered**2 + 1), 1 / (powered**2 + 1)

    (re_s, im_s), (re_t, im_t) = resolvent(values_s), resolvent(values_t)
    return (re_s[None, :] - re_t[:, None]) ** 2 + (im_s[None, :] - im_t[:, None]) ** 2


def _multiplication_operators(shape: SpectralShape, Phi, F) -> Float[Array, "d k k"]:
    """`Phi^T M diag(f_p) Phi` for each descriptor column `f_p` (pyFM's `_compute_descr_op`)."""
    weighted = shape.mass[:, None] * F
    return jax.lax.map(lambda f: Phi.T @ (f[:, None] * Phi), weighted.T, batch_size=16)


def _orientation_operators(shape: SpectralShape, Phi, F) -> Float[Array, "d k k"]:
    """`Phi^T W_p Phi` for each descriptor (pyFM's `_compute_orientation_op`, `M^-1` cancelled by `Phi^T M`).

    On face `f` with corners `u` and `J_u = n_f x e_u / 2` (`e_u` the edge opposite `u`, so `J_u / area_f`
    is the gradient of the hat function of `u`), `W_p` adds `(1/3) sum_u <J_u, n_f x grad f_p> g_u` to each
    of the face's vertices: `Phi^T W_p Phi = sum_f s_f^T (sum_u c_fu Phi_u)`, `s_f` the corner mean of `Phi`.
    """
    faces = shape.mesh.faces
    V = shape.mesh.vertices
    v1, v2, v3 = V[faces[:, 0]], V[faces[:, 1]], V[faces[:, 2]]
    cross = jnp.cross(v2 - v1, v3 - v1)
    double_area = safe_norm(cross, axis=1)
    normals = safe_div(cross, double_area[:, None])  # a zero-area face has no normal and contributes nothing
    # The hat-function gradient directions times the face area (pyFM's `Jc1, Jc2, Jc3`).
    J = jnp.stack([jnp.cross(normals, v3 - v2), jnp.cross(normals, v1 - v3), jnp.cross(normals, v2 - v1)], axis=1) / 2
    corner_mean = (Phi[faces[:, 0]] + Phi[faces[:, 1]] + Phi[faces[:, 2]]) / 3
    corners = Phi[faces]  # (nf, 3, k)

    def operator(f):
        # pyFM's `grad_f`: (f2 - f1) grad_2 + (f3 - f1) grad_3 with grad_u = J_u / area.
        gradient = (f[faces[:, 1]] - f[faces[:, 0]])[:, None] * J[:, 1] + (f[faces[:, 2]] - f[faces[:, 0]])[:, None] * J[:, 2]
        gradient = safe_div(gradient, double_area[:, None] / 2)
        rotated = jnp.cross(normals, gradient)
        coefficients = jnp.einsum("fuc,fc->fu", J, rotated)  # (nf, 3)
        return corner_mean.T @ jnp.einsum("fu,fuk->fk", coefficients, corners)

    return jax.lax.map(operator, F.T, batch_size=16)


def _row_blocks_inverse(mu_d, AAt, mu_l, mask, operator_terms, free) -> Float[Array, "k_t k_s k_s"]:
    """Inverse of the Hessian block coupling the entries of each row of `C` (free columns; identity on the fixed one).

    Row `r`, acting on the row `x` from the right: `mu_d A A^T + mu_l diag(R_r) + mu sum_p [P_p P_p^T
    - Q_p[r, r] (P_p + P_p^T) + (Q_p^T Q_p)[r, r]]` for each operator term.
    """
    k_t, k_s = mask.shape
    blocks = mu_d * AAt[None] + mu_l * jax.vmap(jnp.diag)(mask)
    for mu, P, Q in operator_terms:
        PPt = jnp.einsum("pab,pcb->ac", P, P)
        QtQ_diagonal = jnp.einsum("pba,pba->a", Q, Q)
        Q_diagonal = jnp.diagonal(Q, axis1=1, axis2=2)  # (d, k_t)
        symmetric = P + jnp.swapaxes(P, 1, 2)
        blocks = blocks + mu * (
            PPt[None] - jnp.einsum("pr,pab->rab", Q_diagonal, symmetric) + QtQ_diagonal[:, None, None] * jnp.eye(k_s)
        )
    both_free = free[:, None] & free[None, :]
    blocks = jnp.where(both_free[None], blocks, jnp.eye(k_s)[None])
    inverse = jnp.linalg.inv(blocks)
    return (inverse + jnp.swapaxes(inverse, 1, 2)) / 2


def _hessian_matrix(mu_d, AAt, mu_l, mask, operator_terms, free) -> Float[Array, "n n"]:
    """The Hessian of `E` as a `(k_t k_s, k_t k_s)` matrix on row-major `C` (identity on the fixed column).

    Entry `[(r, c), (a, b)]`: `delta_ra (mu_d A A^T + mu sum_p P_p P_p^T)_cb + delta_cb (mu sum_p Q_p^T
    Q_p)_ra - mu sum_p (Q_p[r, a] P_p[c, b] + Q_p[a, r] P_p[b, c])` plus `mu_l R_rc` on the diagonal.
    """
    k_t, k_s = mask.shape
    right = mu_d * AAt
    left = jnp.zeros((k_t, k_t), AAt.dtype)
    cross = jnp.zeros((k_t, k_s, k_t, k_s), AAt.dtype)
    for mu, P, Q in operator_terms:
        right = right + mu * jnp.einsum("pab,pcb->ac", P, P)
        left = left + mu * jnp.einsum("pba,pbc->ac", Q, Q)
        # sum_p Q_p[r, a] P_p[c, b] as one (k_t^2, d) @ (d, k_s^2) product.
        products = (Q.reshape(Q.shape[0], -1).T @ P.reshape(P.shape[0], -1)).reshape(k_t, k_t, k_s, k_s)
        cross = cross - mu * jnp.transpose(products, (0, 2, 1, 3))
    cross = cross + jnp.transpose(cross, (2, 3, 0, 1))
    tensor = (
        cross
        + jnp.einsum("ra,cb->rcab", jnp.eye(k_t, dtype=AAt.dtype), right)
        + jnp.einsum("ra,cb->rcab", left, jnp.eye(k_s, dtype=AAt.dtype))
    )
    n = k_t * k_s
    matrix = tensor.reshape(n, n) + jnp.diag(mu_l * mask.reshape(-1))
    kept = jnp.broadcast_to(free[None, :], (k_t, k_s)).reshape(-1)
    return jnp.where(kept[:, None] & kept[None, :], matrix, jnp.eye(n, dtype=matrix.dtype))
