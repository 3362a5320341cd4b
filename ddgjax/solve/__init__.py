r"""Sparse linear algebra: differentiable solves of symmetric (Hermitian) positive definite systems.

- `linear_solve(A, b, *, solver=...)` and `factorize(A, *, solver=...).solve(b)`: symmetric (or
  complex Hermitian) positive definite `SparseMatrix` systems, by a host sparse Cholesky (CHOLMOD
  through `sparsax`), SciPy's SuperLU, a pure-JAX conjugate gradient preconditioned by Jacobi or an
  algebraic-multigrid V-cycle, or pyamg's CG on the host (`solver` one of `ddgjax.LINEAR_SOLVERS`);
  all usable inside `jit` / `scan` / `vmap`, differentiable in `b` and in the matrix values by
  implicit differentiation; the answer is a `LinearSolution` with `value`, `result` (an item of
  `ddgjax.RESULTS`) and `stats` (`residual`, `num_steps`; `throw=`). Every failure is a result, on every backend;
  a float32 system warns once per process (`PrecisionWarning`).
- `amg_hierarchy`, `amg_refresh`, `amg_v_cycle`, `amg_preconditioner`: a smoothed-aggregation
  multigrid hierarchy built by pyamg on the host, applied in pure JAX (any device).
- `SparseCholesky(pattern)`: the same solves as a lineax solver (the matrix recovered from operator
  products by column colouring), so `optimistix.Newton` minimises an energy with them.

The geometry problems that solve with these (Poisson, harmonic interpolation, Hodge decomposition,
mean curvature flow) are in `ddgjax.pde`; there too `solver=` names the backend.

Each solve returns $x = A^{-1} b$ for $A = A^\top \succ 0$ (or $A = A^{H} \succ 0$), and its derivative
is implicit: for a loss $f(x)$, with $\bar x = \partial f / \partial x$ (real case),

$$\bar b = A^{-1} \bar x, \qquad \bar A = -\bar b\, x^\top.$$
"""

from ._amg import AMGHierarchy as AMGHierarchy
from ._amg import amg_hierarchy as amg_hierarchy
from ._amg import amg_preconditioner as amg_preconditioner
from ._amg import amg_refresh as amg_refresh
from ._amg import amg_v_cycle as amg_v_cycle
from ._linear import Factorization as Factorization
from ._linear import LinearSolution as LinearSolution
from ._linear import PrecisionWarning as PrecisionWarning
from ._linear import factorize as factorize
from ._linear import linear_solve as linear_solve
from ._lineax import SparseCholesky as SparseCholesky
