"""What other ddgjax packages need from `ddgjax.sparse` that users should not call (signed incidence matrices and the stable ordering of patterns).

As `lineax.internal`: plain re-exports, visible to import graphs and type checkers (DESIGN.md, layout).
"""

from ._matrix import incidence_matrix as incidence_matrix
from ._pattern import stable_order as stable_order
