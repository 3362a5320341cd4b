r"""Fixed-pattern sparse matrices: the positions built once on the host, the values JAX arrays.

- `SparsityPattern`: the stored positions of a matrix and the storage order of its values (ELL, CSR
  or COO layout), built once per connectivity with NumPy. `SparseMatrix`: values on a pattern, with
  products `A @ x`, arithmetic that carries the structure flags (symmetric, Hermitian,
  semidefinite), and exports (`todense`, `to_scipy`, `to_bcoo`, `as_lineax_operator`);
  `diagonal_matrix`, `identity`, `from_scipy` make them. `nonnegative(t)` declares a traced scalar
  `>= 0`, so that `M + nonnegative(t) * L` keeps its positive semidefinite flag under `jit`.
- `dirichlet_plan` / `dirichlet_blocks`: the free-free and free-fixed blocks of a Dirichlet problem
  (libigl's `min_quad_with_fixed` split), one fixed gather each.
- `congruence_plan` / `congruence`: $D^\top \operatorname{diag}(w) D$ on a given pattern (the DEC Laplacians).
- `gather_sum`: a fixed gather-and-sum whose reverse pass is a gather too (assembly without scatters).

Inside `jit` only values move: no sort, search or deduplication; every operation is differentiable in
the values (and `jit`-, `vmap`- and `grad`-able). SciPy: `scipy.sparse`; JAX: `jax.experimental.sparse`.
"""

from ._blocks import DirichletBlocks as DirichletBlocks
from ._blocks import DirichletPlan as DirichletPlan
from ._blocks import dirichlet_blocks as dirichlet_blocks
from ._blocks import dirichlet_plan as dirichlet_plan
from ._gather import gather_sum as gather_sum
from ._matrix import SparseMatrix as SparseMatrix
from ._matrix import diagonal_matrix as diagonal_matrix
from ._matrix import from_scipy as from_scipy
from ._matrix import identity as identity
from ._nonnegative import NonNegative as NonNegative
from ._nonnegative import nonnegative as nonnegative
from ._pattern import SparsityPattern as SparsityPattern
from ._products import CongruencePlan as CongruencePlan
from ._products import congruence as congruence
from ._products import congruence_plan as congruence_plan
