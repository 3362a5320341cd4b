"""Geodesic distance on triangle meshes, differentiable in the vertex positions.

- `heat_distance(mesh, sources, *, t_coef=1.0, boundary="average", solver="auto", throw=True, ...)`:
  the heat method (Crane, Weischedel & Wardetzky 2013): a short heat flow from the sources, its
  normalised gradient, a Poisson solve. Works on every triangle mesh (strips, single triangles, obtuse
  triangles, several components, unreferenced vertices): distances are never negative, and `inf`
  where no source reaches (another component, a vertex of no face).
- `heat_distance_solver(mesh, ...)`: the same with the factorisations kept, `solver.distance(sources)`
  per query (`HeatDistanceSolver`; `solver.steps(sources)` gives the intermediate `HeatMethodSteps`).
"""

from ._heat import HeatDistanceSolver as HeatDistanceSolver
from ._heat import HeatMethodSteps as HeatMethodSteps
from ._heat import heat_distance as heat_distance
from ._heat import heat_distance_solver as heat_distance_solver
