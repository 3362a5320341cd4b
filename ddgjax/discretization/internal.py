"""What other ddgjax packages need from `ddgjax.discretization` that users should not call (Dirichlet bookkeeping,
the per-cell pieces of a domain a kernel traces).

As `lineax.internal`: plain re-exports, visible to import graphs and type checkers (DESIGN.md, layout).
"""

from ._dirichlet import DirichletData as DirichletData
from ._discretization import cell_measure_gradients as cell_measure_gradients
from ._discretization import cells as cells
from ._discretization import domain_edge_lengths as domain_edge_lengths
from ._discretization import intrinsic_measure_gradients as intrinsic_measure_gradients
from ._discretization import require_domain as require_domain
