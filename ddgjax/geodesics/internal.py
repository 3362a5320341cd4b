"""What other ddgjax packages need from `ddgjax.geodesics` that users should not call (the heat methods' held (Dirichlet) solves, point sources and combined outcomes).

As `lineax.internal`: plain re-exports, visible to import graphs and type checkers (DESIGN.md, layout).
"""

from ._heat import check_t_coef as check_t_coef
from ._heat import held_block as held_block
from ._heat import solve_held as solve_held
from ._vector_heat import combined_stats as combined_stats
from ._vector_heat import point_masses as point_masses
from ._vector_heat import source_vectors as source_vectors
