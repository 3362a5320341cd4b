"""Closed-form 3 x 3 rotation fitting: the sign-fixed SVD `S = U diag(s') W^T`, `U, W` rotations, per matrix.

ARAP's local step needs, for every vertex, `R = argmax_{R in SO(3)} tr(R S)` of a 3 x 3 covariance `S`. A
batched `jnp.linalg.svd` does it with one LAPACK call per matrix under XLA:CPU (~80% of an ARAP step: 16-19 ms
for 10,242 matrices on 2 cores); here the same factorisation is a fixed sequence of elementwise operations on
the nine entries, each a `(n,)` array, which XLA compiles to vectorised loops (2.2 ms; McAdams et al. 2011's
scheme, with exact Jacobi rotations in float64 instead of their single-precision approximations):

1. the symmetric eigendecomposition `S^T S = W diag(s^2) W^T` by cyclic Jacobi sweeps, `W` a rotation;
2. `W`'s columns sorted by decreasing eigenvalue (a swap negates one column, so `W` stays a rotation),
   then `C = S W = U T` by three Givens rotations, `U` a rotation and `T` upper triangular;
   the diagonal of `T` is `s'`, with `s'_1 >= s'_2 >= |s'_3|` and `sign(s'_3) = sign(det S)`;
3. `R = W U^T`: the rotation of the reference, `W diag(1, 1, det(W U^T)) U^T` of an ordinary SVD;
4. one Newton step on SO(3) polishes `R` to the accuracy the problem allows. Step 1 squares `S`, so its
   eigenvectors carry errors of `eps s_1^2 / (s_a^2 - s_b^2)`; the step below needs only `S R`, and
   leaves the error `eps s_1 / (s'_a + s'_b)` that any backward-stable method has.

Rank-deficient matrices are handled: a zero column of `C` gives the identity Givens rotation, so `U`
completes the others to a rotation (`S = 0`: `R = I`).

Reference: A. McAdams, A. Selle, R. Tamstorf, J. Teran, E. Sifakis, "Computing the Singular Value
Decomposition of 3 x 3 matrices with minimal branching and elementary floating point operations",
University of Wisconsin-Madison TR1690, 2011. libigl's `fit_rotations` uses their single-precision SIMD code.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

_SWEEPS = 4
"""Cyclic Jacobi sweeps of step 1 (three rotations each). Measured on 200,000 float64 matrices of each kind
(Gaussian; condition 10^6-10^8; rank 2; two singular values within 1e-4..1e-12; reflections; 1e-30 * Gaussian):
after 4 sweeps (and 5) the singular values are within 1.3e-14 `s_1` of LAPACK's, after 3 within 3.5e-10 `s_1`;
`R` is within `51 eps s_1 / (s'_2 + s'_3)` (its condition) of LAPACK's either way (the Newton step)."""


@jax.custom_jvp
def fit_rotations(covariances: Float[Array, "*batch 3 3"]) -> Float[Array, "*batch 3 3"]:
    """`R = argmax_{R in SO(3)} tr(R S)` for each `S`: with `S = U diag(s) W^T`, `R = W diag(1, 1, det(W U^T)) U^T`.

    `rotation_svd`'s `R`, with a derivative rule (forward and reverse) where the maximiser is isolated,
    `s'_2 + s'_3 > 0`; elsewhere the derivative's undetermined part is 0.
    """
    return rotation_svd(covariances)[0]


@fit_rotations.defjvp
def _fit_rotations_jvp(primals, tangents):
    """`dR = R [omega]_x`, `(tr(P) I - P) omega = vee(R^T dA - dA^T R)`, `A = S^T = R P` (`P` symmetric).

    From `R^T dA = Omega P + dP` with `Omega = R^T dR` skew: its skew part `Omega P + P Omega` is
    `[(tr(P) I - P) omega]_x`, and `tr(P) I - P` has the eigenvalues `s'_a + s'_b`. Solved by its adjugate;
    where it is singular (`S = 0`: an unused vertex; the maximiser not isolated) `omega = 0`.
    """
    (covariances,), (dcov,) = primals, tangents
    rotation = fit_rotations(covariances)
    rt = jnp.swapaxes(rotation, -1, -2)
    p = rt @ jnp.swapaxes(covariances, -1, -2)
    k = rt @ jnp.swapaxes(dcov, -1, -2)
    k = k - jnp.swapaxes(k, -1, -2)
    h = jnp.trace(p, axis1=-2, axis2=-1)[..., None, None] * jnp.eye(3, dtype=p.dtype) - (p + jnp.swapaxes(p, -1, -2)) / 2
    x, y, z = _solve_symmetric([[h[..., i, j] for j in range(3)] for i in range(3)], [k[..., 2, 1], k[..., 0, 2], k[..., 1, 0]])
    o = jnp.zeros_like(x)
    skew = jnp.stack([jnp.stack([o, -z, y], -1), jnp.stack([z, o, -x], -1), jnp.stack([-y, x, o], -1)], -2)
    return rotation, rotation @ skew


def _jacobi(b: dict, w: list[list[Array]], p: int, q: int) -> None:
    """One Jacobi rotation in the plane `(p, q)`: zero `b[p, q]` of the symmetric `b` (`{(i, j): entry}`, `i <= j`)
    and multiply `w` (columns of a rotation, `w[k][i]` the entry `(i, k)`) by it; in place."""
    r = 3 - p - q
    key = lambda i, j: (min(i, j), max(i, j))
    bpp, bqq, bpq = b[p, p], b[q, q], b[p, q]
    d = bqq - bpp
    # t = tan(theta) = sign(d) 2 b_pq / (|d| + sqrt(d^2 + 4 b_pq^2)), the smaller root (Golub & Van Loan 8.5.2)
    denominator = jnp.abs(d) + jnp.sqrt(d * d + 4 * bpq * bpq)
    nonzero = denominator > 0
    t = jnp.where(d < 0, -2.0, 2.0) * bpq / jnp.where(nonzero, denominator, 1.0)
    t = jnp.where(nonzero, t, 0.0)
    c = 1 / jnp.sqrt(1 + t * t)
    s = t * c
    brp, brq = b[key(r, p)], b[key(r, q)]
    b[p, p], b[q, q], b[p, q] = bpp - t * bpq, bqq + t * bpq, jnp.zeros_like(bpq)
    b[key(r, p)], b[key(r, q)] = c * brp - s * brq, s * brp + c * brq
    wp, wq = w[p], w[q]
    w[p] = [c * x - s * y for x, y in zip(wp, wq)]
    w[q] = [s * x + c * y for x, y in zip(wp, wq)]


def _givens(c: list[list[Array]], u: list[list[Array]], p: int, q: int, k: int) -> None:
    """Zero `c[q][k]` (rows of `c`: `c[i][k]` the entry `(i, k)`) with a rotation of rows `p`, `q`; the
    rotation's transpose joins `u` (columns of the rotation: `u[k][i]` the entry `(i, k)`) on the right; in place."""
    a, b = c[p][k], c[q][k]
    norm = jnp.sqrt(a * a + b * b)
    nonzero = norm > 0
    safe = jnp.where(nonzero, norm, 1.0)
    cos, sin = jnp.where(nonzero, a / safe, 1.0), jnp.where(nonzero, b / safe, 0.0)
    cp, cq = c[p], c[q]
    c[p] = [cos * x + sin * y for x, y in zip(cp, cq)]
    c[q] = [-sin * x + cos * y for x, y in zip(cp, cq)]
    up, uq = u[p], u[q]
    u[p] = [cos * x + sin * y for x, y in zip(up, uq)]
    u[q] = [-sin * x + cos * y for x, y in zip(up, uq)]


def _swap_if(condition: Array, columns: list[list[list[Array]]], p: int, q: int) -> None:
    """Where `condition`, replace columns `(p, q)` of each matrix in `columns` by `(q, -p)` (keeps the determinant)."""
    for m in columns:
        mp, mq = m[p], m[q]
        m[p] = [jnp.where(condition, y, x) for x, y in zip(mp, mq)]
        m[q] = [jnp.where(condition, -x, y) for x, y in zip(mp, mq)]


def rotation_svd(
    matrices: Float[Array, "*batch 3 3"],
) -> tuple[Float[Array, "*batch 3 3"], Float[Array, "*batch 3 3"], Float[Array, "*batch 3"]]:
    """`(R, U, s')` of each `S`: `S = U diag(s') W^T` with `U, W` rotations, `s'_1 >= s'_2 >= |s'_3|`, and
    `R = W U^T = argmax_{R in SO(3)} tr(R S)` (module docstring). Forward values only: no derivative rule.

    `s'` is `S`'s singular values with the last one's sign `sign(det S)`; `U`'s columns are the left singular
    vectors, so `S^T = R P` with `P = U diag(s') U^T` symmetric.
    """
    dtype = matrices.dtype
    # Scaled to a largest entry of 1: the squares below neither overflow nor underflow, in float32 too.
    scale = jnp.max(jnp.abs(matrices), axis=(-2, -1))
    scaled = matrices / jnp.where(scale > 0, scale, 1.0)[..., None, None]
    m = [[scaled[..., i, j] for j in range(3)] for i in range(3)]  # m[i][j]: entry (i, j) of S
    one, zero = jnp.ones_like(m[0][0]), jnp.zeros_like(m[0][0])
    # 1. S^T S = W diag(s^2) W^T
    b = {(i, j): sum(m[k][i] * m[k][j] for k in range(3)) for i in range(3) for j in range(i, 3)}
    w = [[one if i == k else zero for i in range(3)] for k in range(3)]  # w[k]: column k

    def sweep(_, state):
        b, w = dict(state[0]), [list(column) for column in state[1]]
        for p, q in ((0, 1), (0, 2), (1, 2)):
            _jacobi(b, w, p, q)
        return b, w

    # A loop, not unrolled sweeps: XLA:CPU's compile time grows with the unrolled code (4.7 s -> 3.6 s for this function).
    b, w = jax.lax.fori_loop(0, _SWEEPS, sweep, (b, w))
    # 2. W's columns sorted by decreasing eigenvalue (= |S w_k|^2), then C = S W = U T
    norms = [b[k, k] for k in range(3)]
    for p, q in ((0, 1), (0, 2), (1, 2)):
        smaller = norms[p] < norms[q]
        _swap_if(smaller, [w], p, q)
        norms[p], norms[q] = jnp.where(smaller, norms[q], norms[p]), jnp.where(smaller, norms[p], norms[q])
    c_columns = _materialised([[sum(m[i][j] * w[k][j] for j in range(3)) for i in range(3)] for k in range(3)])
    c_rows = [[c_columns[k][i] for k in range(3)] for i in range(3)]
    u = [[one if i == k else zero for i in range(3)] for k in range(3)]  # rows of G3 G2 G1 = U^T
    for p, q, k in ((0, 1, 0), (0, 2, 0), (1, 2, 1)):
        _givens(c_rows, u, p, q, k)
    # u[k][i] now holds (G3 G2 G1)[k, i] = U^T[k, i] with C = U T, U = (G3 G2 G1)^T
    s = [c_rows[k][k] for k in range(3)]
    u, s = _materialised((u, s))
    # 3. R = W U^T: R[i, j] = sum_k W[i, k] U^T[k, j]
    rotation = [[sum(w[k][i] * u[k][j] for k in range(3)) for j in range(3)] for i in range(3)]
    # 4. One Newton step on tr(R_0 exp([omega]_x) S): with M = S R_0, g = vee(M - M^T), H = tr(M) I - sym(M),
    # omega = H^{-1} g, and R = R_0 cay(omega), the Cayley map (a rotation, exp's value to second order).
    rotation = _materialised(rotation)
    mm = [[sum(m[i][k] * rotation[k][j] for k in range(3)) for j in range(3)] for i in range(3)]
    g = [mm[1][2] - mm[2][1], mm[2][0] - mm[0][2], mm[0][1] - mm[1][0]]
    trace = mm[0][0] + mm[1][1] + mm[2][2]
    h = [[(trace if i == j else 0) - (mm[i][j] + mm[j][i]) / 2 for j in range(3)] for i in range(3)]
    omega = _solve_symmetric(h, g)
    cayley = _cayley(_materialised(omega))
    rotation = [[sum(rotation[i][k] * cayley[k][j] for k in range(3)) for j in range(3)] for i in range(3)]
    stack = lambda rows: jnp.stack([jnp.stack(row, axis=-1) for row in rows], axis=-2)
    u_matrix = stack([[u[k][i] for k in range(3)] for i in range(3)])
    singular = jnp.stack(s, axis=-1) * scale[..., None]
    return stack(rotation).astype(dtype), u_matrix.astype(dtype), singular.astype(dtype)


def _materialised(tree):
    """`tree`'s arrays, stored before use: a scatter of zero into one element, which XLA never fuses into its consumer.

    XLA:CPU fuses cheap elementwise producers into every consumer fusion and recomputes them there, so the chains of
    Jacobi rotations were recomputed in each of ~100 fusions (3,847 multiplies per matrix); storing the state between
    stages (measured with the sweeps unrolled; the `fori_loop` now stores its carry anyway) leaves 1,538, and 10,242
    matrices take 2.2 ms instead of 3.3 (32 ms instead of 79 for 102,420). (`jax.lax.optimization_barrier` is removed
    by XLA:CPU before fusion: no effect.)"""
    return jax.tree_util.tree_map(lambda x: x.at[(0,) * x.ndim].add(jnp.zeros((), x.dtype)) if x.size else x, tree)


def _solve_symmetric(h: list[list[Array]], g: list[Array]) -> list[Array]:
    """`h^{-1} g` for a symmetric 3 x 3 `h` by its adjugate; 0 where `h` is singular (a rotation not isolated)."""
    adjugate = [
        [
            h[(j + 1) % 3][(i + 1) % 3] * h[(j + 2) % 3][(i + 2) % 3] - h[(j + 1) % 3][(i + 2) % 3] * h[(j + 2) % 3][(i + 1) % 3]
            for j in range(3)
        ]
        for i in range(3)
    ]
    determinant = sum(h[0][k] * adjugate[k][0] for k in range(3))
    invertible = determinant != 0
    safe = jnp.where(invertible, determinant, 1.0)
    return [jnp.where(invertible, sum(adjugate[i][k] * g[k] for k in range(3)) / safe, 0.0) for i in range(3)]


def _cayley(omega: list[Array]) -> list[list[Array]]:
    """The Cayley map `(I - W / 2)^{-1} (I + W / 2)`, `W = [omega]_x`: the rotation of the quaternion `(1, omega / 2)`."""
    x, y, z = (o / 2 for o in omega)
    n = 1 + x * x + y * y + z * z
    return [
        [(1 + x * x - y * y - z * z) / n, 2 * (x * y - z) / n, 2 * (x * z + y) / n],
        [2 * (x * y + z) / n, (1 - x * x + y * y - z * z) / n, 2 * (y * z - x) / n],
        [2 * (x * z - y) / n, 2 * (y * z + x) / n, (1 - x * x - y * y + z * z) / n],
    ]
