"""Fixed-pattern sparse matrices: assembly under jit, products, export to SciPy / BCOO, lineax operators."""

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
