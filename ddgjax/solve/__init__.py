"""Laplacian linear systems: differentiable sparse solves (and, to come, Dirichlet / Poisson problems).

- `linear_solve(A, b, *, method=...)` and `factorize(A, *, method=...).solve(b)`: symmetric positive definite `SparseMatrix` systems, by a host
  sparse Cholesky (CHOLMOD through `sparsax`, usable inside `jit` / `scan` / `vmap`) or a pure-JAX
  Jacobi-preconditioned conjugate gradient; differentiable in `b` and in the matrix values by
  implicit differentiation; failures through `ddgjax.RESULTS` (`throw=`).
"""

from ._linear import Factorization as Factorization
from ._linear import LinearSolution as LinearSolution
from ._linear import factorize as factorize
from ._linear import linear_solve as linear_solve
