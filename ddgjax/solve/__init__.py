"""Laplacian linear systems: energies, differentiable sparse solves, Dirichlet / Poisson problems, flows.

- Energies as plain scalar JAX functions of the unknowns and the mesh (`dirichlet_energy`,
  `screened_dirichlet_energy`, `poisson_energy`, the report's `gradient_fitting_energy` `E_X`),
  differentiable in the unknowns and the vertex positions. Sign convention: the report's Poisson
- `linear_solve(A, b, *, method=...)` and `factorize(A, *, method=...).solve(b)`: symmetric (or
  complex Hermitian) positive definite `SparseMatrix` systems, by a host sparse Cholesky (CHOLMOD
  through `sparsax`), SciPy's SuperLU, a pure-JAX conjugate gradient preconditioned by Jacobi or an
  algebraic-multigrid V-cycle (`amg_hierarchy`, `amg_refresh`), or pyamg's CG on the host; all
  usable inside `jit` / `scan` / `vmap`, differentiable in `b` and in the matrix values by implicit
  differentiation; failures through `ddgjax.RESULTS` (`throw=`).
- `SparseCholesky(pattern)`: the same solves as a lineax solver (the matrix recovered from operator
  products by column colouring), so `optimistix.Newton` minimises an energy with them.
"""

from ._amg import AMGHierarchy as AMGHierarchy
from ._amg import amg_hierarchy as amg_hierarchy
from ._amg import amg_preconditioner as amg_preconditioner
from ._amg import amg_refresh as amg_refresh
from ._amg import amg_v_cycle as amg_v_cycle
from ._linear import Factorization as Factorization
from ._linear import LinearSolution as LinearSolution
from ._linear import factorize as factorize
from ._linear import linear_solve as linear_solve
from ._lineax import SparseCholesky as SparseCholesky
