"""What other ddgjax packages need from `ddgjax.mesh` that users should not call (vertex arrays checked, simplex lists checked, the surface topology builder, degenerate faces, per-face geometry from corners).

As `lineax.internal`: plain re-exports, visible to import graphs and type checkers (DESIGN.md, layout).
"""

from ._check import default_area_tol as default_area_tol
from ._check import degenerate_faces as degenerate_faces
from ._check import nondegenerate_face_mask as nondegenerate_face_mask
from ._check import require_nondegenerate as require_nondegenerate
from ._geometry import face_geometry_from_corners as face_geometry_from_corners
from ._mesh import as_float_vertices as as_float_vertices
from ._mesh import checked_vertices as checked_vertices
from ._topology import build_topology as build_topology
from ._topology import validate_simplices as validate_simplices
