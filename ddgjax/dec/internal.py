"""What other ddgjax packages need from `ddgjax.dec` that users should not call (the dimension-free codifferential and
Hodge Laplacian that `ddgjax.volume` applies to its own `d` and stars).

As `lineax.internal`: plain re-exports, visible to import graphs and type checkers (DESIGN.md, layout).
"""

from ._hodge_laplacian import codifferential_from as codifferential_from
from ._hodge_laplacian import hodge_laplacian_from as hodge_laplacian_from
