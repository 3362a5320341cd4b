"""What other ddgjax packages need from `ddgjax.solve` that users should not call (preconditioners, the automatic method choice, CG, the solution record, CHOLMOD analysis choices, lineax outcomes, AMG levels).

As `lineax.internal`: plain re-exports, visible to import graphs and type checkers (DESIGN.md, layout).
"""

from ._amg import AMGLevel as AMGLevel
from ._amg import jacobi_steps as jacobi_steps
from ._linear import PRECONDITIONERS as PRECONDITIONERS
from ._linear import auto_solver as auto_solver
from ._linear import cholmod_analysis as cholmod_analysis
from ._linear import kept_analysis as kept_analysis
from ._linear import linear_solution as linear_solution
from ._linear import preconditioned_cg as preconditioned_cg
from ._lineax import LINEAX_RESULTS as LINEAX_RESULTS
