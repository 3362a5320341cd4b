r"""The geodesic toolkit on triangle meshes: distance, transport, log map, centroids, signed distance, differentiable.

`heat_distance` and `heat_distance_solver` take a tetrahedral `ddgjax.volume.TetMesh` too (distance in a
solid from vertex sources, the heat method in 3-D as in Crane et al. 2013).

- `heat_distance(mesh, sources, *, t_coef=1.0, boundary="average", solver="auto", throw=True, ...)`:
  the heat method (Crane, Weischedel & Wardetzky 2013): a short heat flow from the sources, its
  normalised gradient, a Poisson solve. Works on every triangle mesh (strips, single triangles, obtuse
  triangles, several components, unreferenced vertices): distances are never negative, and `inf`
  where no source reaches (another component, a vertex of no face).
- `heat_distance_solver(mesh, ...)`: the same with the factorisations kept, `solver.distance(sources)`
  per query (`HeatDistanceSolver`; `solver.steps(sources)` gives the intermediate `HeatMethodSteps`).
- The vector heat method (Sharp, Soliman & Crane 2019): `vector_heat_solver(mesh, ...)` ->
  `VectorHeatSolver` with `.transport(source, vector)` (`(nv, 3)` world-coordinate tangent vectors,
  parallel transport along shortest geodesics) and `.log_map(source)` (`(nv, 2)` in the source's
  `ddgjax.fields.tangent_bases`); one-shot `parallel_transport(mesh, source, vector)`,
  `log_map(mesh, source)`; `geodesic_centroid(mesh, sources, *, weights)` -> `GeodesicCentroid(vertex,
  face, barycentric, position)`, the weighted Karcher mean.
- The signed heat method (Feng & Crane 2024): `signed_heat_distance(mesh, curves)` and
  `signed_heat_solver(mesh).distance(curves)` (`SignedHeatSolver`): the signed distance to oriented
  curves along mesh edges (closed loops or open pieces; positive on the left), robust to gaps.

The heat method's three steps (`L` the PSD cotan Laplacian, `M` the mass matrix, $t = t_\mathrm{coef} h^2$):

$$(M + tL)\, u = \delta, \qquad X = -\frac{\nabla u}{\lVert \nabla u \rVert}, \qquad L\phi = -\nabla \cdot X$$

The vector heat method diffuses the source vector with the connection Laplacian `A`, and its
magnitude and the source indicator with `L`:

$$(M + tA)\, Y = Y_0, \qquad (M + tL)\, u = u_0, \qquad (M + tL)\, \varphi = \varphi_0, \qquad X = \frac{Y}{\lvert Y \rvert} \, \frac{u}{\varphi}$$
"""

from ._heat import HeatDistanceSolver as HeatDistanceSolver
from ._heat import HeatFactors as HeatFactors
from ._heat import HeatMethodSteps as HeatMethodSteps
from ._heat import heat_distance as heat_distance
from ._heat import heat_distance_solver as heat_distance_solver
from ._signed_heat import SignedHeatSolver as SignedHeatSolver
from ._signed_heat import signed_heat_distance as signed_heat_distance
from ._signed_heat import signed_heat_solver as signed_heat_solver
from ._vector_heat import GeodesicCentroid as GeodesicCentroid
from ._vector_heat import VectorHeatSolver as VectorHeatSolver
from ._vector_heat import geodesic_centroid as geodesic_centroid
from ._vector_heat import log_map as log_map
from ._vector_heat import parallel_transport as parallel_transport
from ._vector_heat import vector_heat_solver as vector_heat_solver
