"""The smallest left singular vector of many `3 x k` matrices, signed as Eigen's `JacobiSVD` signs it.

robust_laplacian takes each point's normal from Eigen's `JacobiSVD<MatrixXd>(A, ComputeThinU)` of the
`3 x k` matrix of its neighbours' offsets, and the sign of that normal decides which way the tangent
plane's angular walk turns (`_triangulation.local_triangles`), so which nearly co-circular triangles
it keeps: the same local triangles need the same sign, which an eigen-solver does not give. The steps
(Eigen 3.3 / 3.4, real matrices with more columns than rows), vectorised over the matrices:

1. `A` divided by its largest absolute entry;
2. the column-pivoting Householder QR of `A^T = Q R P^T` (pivot: the remaining column of largest
   norm; Householder `beta = -sign(c0) |x|`); `U` starts as `P`, the work matrix is `R^T`;
3. sweeps of two-sided 2x2 Jacobi rotations over the pairs `(1, 0), (2, 0), (2, 1)` while an
   off-diagonal entry exceeds `max(tiny, 2 eps max|diagonal|)` (`real_2x2_jacobi_svd`: a rotation
   making the 2x2 block symmetric, then `JacobiRotation::makeJacobi`), the left ones accumulated in `U`;
4. a column of `U` negated where its diagonal entry is negative; the singular values sorted
   descending, so the smallest comes last.

The column norms of step 2 are recomputed rather than down-dated: the pivots differ only where two
columns tie to round-off. Only the sign of the result is Eigen's to round-off; its direction is the
exact smallest singular vector either way.

Reference: Eigen `JacobiSVD`, `ColPivHouseholderQR`, `JacobiRotation::makeJacobi` (eigen.tuxfamily.org).
"""

from __future__ import annotations

import numpy as np

_TINY = np.finfo(np.float64).tiny
_PRECISION = 2.0 * np.finfo(np.float64).eps
# A bound on the sweeps: the cyclic Jacobi method converges quadratically, in a handful for 3 x 3.
_MAX_SWEEPS = 64


def smallest_left_singular_vectors(matrices: np.ndarray) -> np.ndarray:
    """`(n, 3)` unit left singular vectors of the smallest singular values of `matrices` `(n, 3, k)`, Eigen's signs.

    See the module docstring; `k >= 3`. NumPy, on the host.
    """
    n = matrices.shape[0]
    rows = np.arange(n)
    scale = np.abs(matrices).max(axis=(1, 2))
    scale = np.where(scale == 0, 1.0, scale)
    work = np.swapaxes(matrices / scale[:, None, None], 1, 2).copy()  # A^T, (n, k, 3)
    pivots = np.tile(np.arange(3), (n, 1))
    for k in range(3):
        norms = np.sqrt(np.sum(work[:, k:, k:] ** 2, axis=1))
        biggest = k + np.argmax(norms, axis=1)
        _swap(work, (rows, slice(None), k), (rows, slice(None), biggest))
        _swap(pivots, (rows, k), (rows, biggest))
        head, tail = work[:, k, k], work[:, k + 1 :, k]
        tail_sq = np.sum(tail**2, axis=1)
        trivial = tail_sq <= _TINY
        beta = np.sqrt(head**2 + tail_sq)
        beta = np.where(head >= 0, -beta, beta)
        with np.errstate(divide="ignore", invalid="ignore"):
            essential = np.where(trivial[:, None], 0.0, tail / (head - beta)[:, None])
            tau = np.where(trivial, 0.0, (beta - head) / beta)
        vector = np.concatenate([np.ones((n, 1)), essential], axis=1)
        rest = work[:, k:, k + 1 :]
        rest -= tau[:, None, None] * vector[:, :, None] * np.einsum("nr,nrc->nc", vector, rest)[:, None, :]
        work[:, k, k] = np.where(trivial, head, beta)
    work = np.swapaxes(np.triu(work[:, :3, :3]), 1, 2).copy()  # R^T
    left = np.zeros((n, 3, 3))
    left[rows[:, None], pivots, np.arange(3)[None, :]] = 1.0
    max_diagonal = np.abs(np.diagonal(work, axis1=1, axis2=2)).max(axis=1)
    live = np.ones(n, dtype=bool)
    for _ in range(_MAX_SWEEPS):
        if not live.any():
            break
        rotated = np.zeros(n, dtype=bool)
        for p, q in ((1, 0), (2, 0), (2, 1)):
            threshold = np.maximum(_TINY, _PRECISION * max_diagonal)
            which = np.flatnonzero(live & ((np.abs(work[:, p, q]) > threshold) | (np.abs(work[:, q, p]) > threshold)))
            if which.size == 0:
                continue
            rotated[which] = True
            (c_left, s_left), (c_right, s_right) = _jacobi_2x2(
                work[which, p, p], work[which, p, q], work[which, q, p], work[which, q, q]
            )
            _rotate(work, which, p, q, c_left, s_left, rows_axis=True)
            _rotate(left, which, p, q, c_left, s_left, rows_axis=False)
            _rotate(work, which, p, q, c_right, -s_right, rows_axis=False)
            max_diagonal[which] = np.maximum(
                max_diagonal[which], np.maximum(np.abs(work[which, p, p]), np.abs(work[which, q, q]))
            )
        live &= rotated
    diagonal = np.diagonal(work, axis1=1, axis2=2)
    left = left * np.where(diagonal < 0, -1.0, 1.0)[:, None, :]
    # The sort puts the largest first, taking the first of equal ones: the smallest is what remains last.
    slots = np.tile(np.arange(3), (n, 1))
    values = np.abs(diagonal)
    for i in range(2):
        largest = i + np.argmax(values[:, i:], axis=1)
        _swap(slots, (rows, i), (rows, largest))
        _swap(values, (rows, i), (rows, largest))
    smallest = left[rows, :, slots[:, 2]]
    return smallest / np.linalg.norm(smallest, axis=1, keepdims=True)


def _swap(array: np.ndarray, a: tuple, b: tuple) -> None:
    first, second = array[a].copy(), array[b].copy()
    array[a], array[b] = second, first


def _jacobi_2x2(m00, m01, m10, m11):
    """`((c_left, s_left), (c_right, s_right))`: Eigen's `real_2x2_jacobi_svd` rotations of `[[m00, m01], [m10, m11]]`."""
    t, d = m00 + m11, m10 - m01
    symmetric = np.abs(d) < _TINY
    with np.errstate(divide="ignore", invalid="ignore"):
        u = t / d
        root = np.sqrt(1.0 + u * u)
        s1, c1 = np.where(symmetric, 0.0, 1.0 / root), np.where(symmetric, 1.0, u / root)
    # The block after the first rotation (its lower-left entry is not read).
    a00, a01, a11 = c1 * m00 + s1 * m10, c1 * m01 + s1 * m11, -s1 * m01 + c1 * m11
    diagonal_only = 2.0 * np.abs(a01) < _TINY
    with np.errstate(divide="ignore", invalid="ignore"):
        tau = (a00 - a11) / (2.0 * np.abs(a01))
        w = np.sqrt(tau * tau + 1.0)
        t = np.where(tau > 0, 1.0 / (tau + w), 1.0 / (tau - w))
        norm = 1.0 / np.sqrt(t * t + 1.0)
        s_right = np.where(diagonal_only, 0.0, -np.where(t > 0, 1.0, -1.0) * np.sign(a01) * np.abs(t) * norm)
    c_right = np.where(diagonal_only, 1.0, norm)
    # left = first rotation composed with the transposed right one.
    return (c1 * c_right + s1 * s_right, -c1 * s_right + s1 * c_right), (c_right, s_right)


def _rotate(array: np.ndarray, which: np.ndarray, p: int, q: int, c: np.ndarray, s: np.ndarray, *, rows_axis: bool) -> None:
    """Rows (or columns) `p, q` of `array[which]` become `c x + s y`, `-s x + c y` (Eigen's plane rotation)."""
    index_p = (which, p, slice(None)) if rows_axis else (which, slice(None), p)
    index_q = (which, q, slice(None)) if rows_axis else (which, slice(None), q)
    x, y = array[index_p].copy(), array[index_q].copy()
    array[index_p] = c[:, None] * x + s[:, None] * y
    array[index_q] = -s[:, None] * x + c[:, None] * y
