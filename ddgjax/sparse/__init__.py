"""Fixed-pattern sparse matrices: assembly under jit, products, export to SciPy / BCOO, lineax operators."""

from ._matrix import SparseMatrix as SparseMatrix
from ._pattern import SparsityPattern as SparsityPattern
