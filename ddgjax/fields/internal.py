"""What other ddgjax packages need from `ddgjax.fields` that users should not call (the per-mesh field plan, tangent frames and connection angles, the connection Laplacian).

As `lineax.internal`: plain re-exports, visible to import graphs and type checkers (DESIGN.md, layout).
"""

from ._connection import connection_angles as connection_angles
from ._connection import plan_of as plan_of
from ._connection import planned_tangent_bases as planned_tangent_bases
from ._connection import scaled_corner_angles as scaled_corner_angles
from ._laplacian import planned_connection_laplacian as planned_connection_laplacian
from ._plan import FieldPlan as FieldPlan
from ._plan import require_referenced as require_referenced
from ._smoothest import unit as unit
