r"""Plane curves: the `Curve` type, the reading report's four discrete curvatures, invariants and flows.

Every function is a pure JAX function of `curve.points` (jit, grad, vmap). Conventions: DESIGN.md,
Plane curves, and the docstring of `ddgjax.curves._curvature`. Options are keyword-only
(`curvature(curve, kind="B")`); a function given anything but a `Curve` for its curve (an array, a
tuple) raises `DDGInputError` saying to build one with `Curve(points, closed=...)`. A flow reports
self-intersection and non-finite states through `ddgjax.RESULTS`: it raises by default, and with
`throw=False` the caller reads `CurveFlowResult.result` (the first failing step's outcome) and
`first_failure_step`; `CurveFlowResult.value` is the final positions.

Modules, one concept each: `_curve` (the type), `_curvature`, `_invariants` (global quantities,
simplicity), `_shapes` (built-in polygons), `_flow_step` (one flow step and its closed-form
derivative), `_flow_certificate` (simplicity certified at every step), `_flow` (the driver).

$$\sum_i \theta_i = 2\pi \cdot \text{turning number}, \qquad p_i \leftarrow p_i + \tau \kappa_i N_i$$
"""

from .._results import RESULTS as RESULTS
from ._curvature import curvature as curvature
from ._curvature import curvature_normals as curvature_normals
from ._curvature import curvature_vectors as curvature_vectors
from ._curvature import edge_lengths as edge_lengths
from ._curvature import interior_vertex_mask as interior_vertex_mask
from ._curvature import length as length
from ._curvature import total_curvature as total_curvature
from ._curvature import turning_angles as turning_angles
from ._curvature import turning_number as turning_number
from ._curvature import vertex_dual_lengths as vertex_dual_lengths
from ._curve import Curve as Curve
from ._curve import require_curve as require_curve
from ._flow import CurveFlowResult as CurveFlowResult
from ._flow import curve_shortening_flow as curve_shortening_flow
from ._invariants import SimplicityAndClearance as SimplicityAndClearance
from ._invariants import area_centroid as area_centroid
from ._invariants import centroid as centroid
from ._invariants import cyclic_residual as cyclic_residual
from ._invariants import enclosed_area as enclosed_area
from ._invariants import is_simple as is_simple
from ._invariants import isoperimetric_ratio as isoperimetric_ratio
from ._invariants import simplicity_and_clearance as simplicity_and_clearance
from ._shapes import figure3_polygon as figure3_polygon
from ._shapes import flower as flower
from ._shapes import load_polygon as load_polygon
from ._shapes import random_polygon as random_polygon
from ._shapes import regular_polygon as regular_polygon
from ._shapes import star as star
