"""ARAP's local step: the closed-form sign-fixed 3 x 3 SVD against LAPACK, and the rotations' derivative."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from ddgjax.deform._rotations import fit_rotations, rotation_svd

from finite_differences import central_difference

EPS = np.finfo(np.float64).eps


def _reference(matrices):
    """`(R, s')` from NumPy's SVD: `R = W diag(1, 1, det(W U^T)) U^T`, `s'` the singular values with that sign last."""
    u, s, wt = np.linalg.svd(matrices)
    w = np.swapaxes(wt, -1, -2)
    flip = np.ones(s.shape)
    flip[:, 2] = np.sign(np.linalg.det(w @ np.swapaxes(u, -1, -2)))
    return (w * flip[:, None, :]) @ np.swapaxes(u, -1, -2), s * flip


def _with_singular_values(rng, singular):
    """Random rotations `Q1 diag(singular) Q2^T` (a negative last value: a reflection)."""
    q1, q2 = (np.linalg.qr(rng.standard_normal((singular.shape[0], 3, 3)))[0] for _ in range(2))
    q1 = q1 * np.sign(np.linalg.det(q1))[:, None, None]  # proper rotations: the sign of det S is singular's
    q2 = q2 * np.sign(np.linalg.det(q2))[:, None, None]
    return q1 @ (singular[:, :, None] * np.swapaxes(q2, -1, -2))


def _cases(n=4000):
    rng = np.random.default_rng(0)
    ones = np.ones(n)
    return {
        "gaussian": rng.standard_normal((n, 3, 3)),
        "ill-conditioned": _with_singular_values(
            rng, np.stack([ones, 10 ** rng.uniform(-6, 0, n), 10 ** rng.uniform(-8, -6, n)], -1)
        ),
        "rank 2": _with_singular_values(rng, np.stack([ones, rng.uniform(0.01, 1, n), np.zeros(n)], -1)),
        "rank 1": _with_singular_values(rng, np.stack([ones, np.zeros(n), np.zeros(n)], -1)),
        "clustered": _with_singular_values(rng, np.stack([ones, 1 - 10 ** rng.uniform(-12, -4, n), rng.uniform(0, 1, n)], -1)),
        "reflection": _with_singular_values(rng, np.stack([ones, rng.uniform(0.1, 1, n), -rng.uniform(0, 0.1, n)], -1)),
        "near identity": np.eye(3) + 1e-9 * rng.standard_normal((n, 3, 3)),
        "tiny": 1e-150 * rng.standard_normal((n, 3, 3)),
        "huge": 1e150 * rng.standard_normal((n, 3, 3)),
    }


_DEGENERATE = np.stack(
    [np.zeros((3, 3)), np.eye(3), -np.eye(3), np.diag([1.0, 1.0, -1.0]), np.diag([1.0, 0.0, 0.0]), np.diag([2.0, 1.0, -1.0])]
)


@functools.cache
def _factored():
    """`(matrices, R, U, s')`: `_cases()` then `_DEGENERATE`, in one call (one compilation)."""
    matrices = np.concatenate([*_cases().values(), _DEGENERATE])
    return (matrices, *(np.asarray(x) for x in jax.jit(rotation_svd)(jnp.asarray(matrices))))


def test_rotation_svd_matches_lapack():
    """`R` is a rotation maximising `tr(R S)`, equal to LAPACK's up to the problem's conditioning; `s'` and `U` factor `S`."""
    matrices, rotation, u, signed = (x[: -len(_DEGENERATE)] for x in _factored())
    expected, expected_signed = _reference(matrices)
    largest = np.abs(expected_signed[:, 0])
    np.testing.assert_allclose(rotation @ np.swapaxes(rotation, -1, -2), np.broadcast_to(np.eye(3), rotation.shape), atol=1e-14)
    np.testing.assert_allclose(np.linalg.det(rotation), 1.0, atol=1e-14)
    np.testing.assert_allclose(np.linalg.det(u), 1.0, atol=1e-14)
    np.testing.assert_array_less(np.abs(signed - expected_signed).max(axis=1), 1e-13 * largest + 1e-300)
    # The optimum itself: tr(R S) = s'_1 + s'_2 + s'_3, the maximum over SO(3) (measured within 2.7e-15 s_1).
    np.testing.assert_array_less(
        np.abs(np.einsum("nij,nji->n", rotation, matrices) - expected_signed.sum(axis=1)), 1e-14 * largest
    )
    # R is determined to eps s_1 / (s'_2 + s'_3) (the smallest sum of two signed singular values: the polar factor's
    # condition); measured at most 51 eps times it (LAPACK's own rotation is no closer). Rank 1 has no unique R:
    # checked by tr(R S) above.
    separation = expected_signed[:, 1] + expected_signed[:, 2]
    unique = separation > 1e-6 * largest
    error = np.abs(rotation - expected).max(axis=(1, 2))
    np.testing.assert_array_less(error[unique], 200 * EPS * largest[unique] / separation[unique])
    # S = U diag(s') W^T with W = R U. U comes from step 1's squared matrix (not polished), so it carries
    # eps s_1^2 / (s_2^2 - s_3^2) in the small singular directions: measured 2.4e-11 s_1 on the ill-conditioned kind.
    rebuilt = (u * signed[:, None, :]) @ np.swapaxes(rotation @ u, -1, -2)
    np.testing.assert_array_less(np.abs(rebuilt - matrices).max(axis=(1, 2)), 1e-10 * largest + 1e-300)


def test_rotation_svd_degenerate_matrices():
    """Zero, rank-deficient and reflected diagonal matrices: finite rotations that maximise `tr(R S)`."""
    matrices, rotation, _, signed = (x[-len(_DEGENERATE) :] for x in _factored())
    np.testing.assert_array_equal(rotation[0], np.eye(3))
    np.testing.assert_allclose(np.linalg.det(rotation), 1.0, atol=1e-15)
    np.testing.assert_allclose(signed, [[0, 0, 0], [1, 1, 1], [1, 1, -1], [1, 1, -1], [1, 0, 0], [2, 1, -1]], atol=1e-15)
    np.testing.assert_allclose(np.einsum("nij,nji->n", rotation, matrices), signed.sum(axis=1), atol=1e-15)


def test_rotations_derivative_matches_finite_differences():
    """`fit_rotations`' derivative rule (from the polar decomposition) against central differences of LAPACK's rotations."""
    rng = np.random.default_rng(3)
    matrices = np.concatenate([rng.standard_normal((20, 3, 3)), _with_singular_values(rng, np.tile([1.0, 0.5, -0.1], (20, 1)))])
    direction = rng.standard_normal(matrices.shape)
    _, tangent = jax.jvp(fit_rotations, (jnp.asarray(matrices),), (jnp.asarray(direction),))
    step = 1e-6
    central = central_difference(lambda m: _reference(m)[0], matrices, direction, step)
    # Central differences: O(step^2) truncation and eps / step round-off, measured 7.3e-10 at step 1e-6 (2e-8 at 1e-5).
    np.testing.assert_allclose(np.asarray(tangent), central, atol=1e-8)
