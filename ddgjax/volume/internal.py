"""What other ddgjax packages need from `ddgjax.volume` that users should not call (the problem layer's checks of a TetMesh).

As `lineax.internal`: plain re-exports, visible to import graphs and type checkers (DESIGN.md, layout).
"""

from ._check import require_tet_problem as require_tet_problem
