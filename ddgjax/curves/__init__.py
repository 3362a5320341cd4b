"""Plane curves: the `Curve` type, the reading report's four discrete curvatures, invariants and flows.

Every function is a pure JAX function of `curve.points` (jit, grad, vmap). Conventions: DESIGN.md,
Plane curves, and the docstring of `ddgjax.curves._curvature`.
"""

from ._curvature import (
    curvature as curvature,
    curvature_normals as curvature_normals,
    curvature_vectors as curvature_vectors,
    edge_lengths as edge_lengths,
    interior_vertex_mask as interior_vertex_mask,
    length as length,
    total_curvature as total_curvature,
    turning_angles as turning_angles,
    turning_number as turning_number,
    vertex_dual_lengths as vertex_dual_lengths,
)
from ._curve import Curve as Curve
from ._flow import CurveFlowResult as CurveFlowResult, curve_shortening_flow as curve_shortening_flow
from ._invariants import (
    area_centroid as area_centroid,
    centroid as centroid,
    cyclic_residual as cyclic_residual,
    enclosed_area as enclosed_area,
    is_simple as is_simple,
    isoperimetric_ratio as isoperimetric_ratio,
)
from ._shapes import (
    figure3_polygon as figure3_polygon,
    flower as flower,
    load_polygon as load_polygon,
    random_polygon as random_polygon,
    regular_polygon as regular_polygon,
    star as star,
)
