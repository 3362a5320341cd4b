"""What other ddgjax packages need from `ddgjax.pde` that users should not call (the closed cocycles of a surface).

As `lineax.internal`: plain re-exports, visible to import graphs and type checkers (DESIGN.md, layout).
"""

from ._hodge_decomposition import closed_cocycle_basis as closed_cocycle_basis
