"""Which symmetric systems each `linear_solve` backend accepts: the table of `ddgjax.solve`'s module docstring,
measured (issue 41: whether an indefinite matrix fails depends on the backend, and the documentation says so)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from ddgjax import RESULTS
from ddgjax.laplacian import cotan_laplacian
from ddgjax.solve import linear_solve
from ddgjax.sparse import from_scipy

SOLVED = RESULTS.successful
# system -> backend -> the documented outcome
TABLE = {
    "definite": dict(cholesky=SOLVED, superlu=SOLVED, cg=SOLVED, pyamg=SOLVED),
    "indefinite": dict(cholesky=RESULTS.not_positive_definite, superlu=SOLVED, cg=SOLVED, pyamg=SOLVED),
    "negative": dict(cholesky=RESULTS.not_positive_definite, superlu=SOLVED, cg=SOLVED, pyamg=SOLVED),
    "singular": dict(cholesky=RESULTS.singular, superlu=RESULTS.singular, cg=RESULTS.singular, pyamg=RESULTS.singular),
}
# CG on a singular system either stalls (max_steps_reached) or stops at a residual above residual_tolerance.
ITERATIVE_ON_SINGULAR = (RESULTS.singular, RESULTS.max_steps_reached)


@pytest.mark.parametrize("solver", ["cholesky", "superlu", "cg", "pyamg"])
@pytest.mark.parametrize("system", sorted(TABLE))
def test_backend_outcomes_match_the_documented_table(system, solver, icosphere2):
    L = cotan_laplacian(icosphere2).to_scipy()
    identity = sp.identity(L.shape[0])
    A = {"definite": L + identity, "indefinite": L - 3 * identity, "negative": -L - identity, "singular": L}[system]
    b = np.random.default_rng(0).standard_normal(L.shape[0])
    solution = linear_solve(from_scipy(sp.csr_matrix(A)), b, solver=solver, throw=False)
    if system == "singular" and solver in ("cg", "pyamg"):
        assert any(solution.result == outcome for outcome in ITERATIVE_ON_SINGULAR)
    else:
        assert solution.result == TABLE[system][solver]
    if solution.result == SOLVED:
        x = np.asarray(solution.value)
        # CG's default rtol is 1e-10 of |b|; the direct solves reach round-off.
        assert np.linalg.norm(A @ x - b) <= 1e-9 * np.linalg.norm(b)
