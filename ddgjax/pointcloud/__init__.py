r"""Operators on point clouds: the Laplacian of Sharp & Crane 2020, PCA normals, geodesic distance, transport, log map.

- `point_cloud_triangulation(points, n_neighbors=30)`: the tufted intrinsic Delaunay triangulation of
  the points' local Delaunay triangulations, built once on the host (`PointCloudTriangulation`),
  whose metric is replayed in JAX from the positions;
- `point_cloud_laplacian(points, n_neighbors=30)`: `LaplacianAndMass(L, M)`, robust_laplacian's
  `point_cloud_laplacian` (PSD `L`, the same sign), differentiable in the points;
- `point_cloud_normals(points, n_neighbors=30)`: unoriented PCA normals, differentiable;
- `point_cloud_heat_distance(points, sources)` and `point_cloud_heat_solver(points).distance(sources)`
  (`PointCloudHeatSolver`): the heat method on the tufted triangulation, as potpourri3d's
  `PointCloudHeatSolver.compute_distance`;
- `point_cloud_parallel_transport(points, source, vector)`, `point_cloud_log_map(points, source)` and
  `point_cloud_heat_solver(points).transport(source, vector)` (world tangent vectors, `(n, 3)`),
  `.log_map(source)` (`(n, 2)` in the source's frame) and `.tangent_frames` (`TangentBases`, normals
  oriented along the cloud): the vector heat method with the connection Laplacian of the minimal
  rotations between neighbouring PCA normals, as potpourri3d's `transport_tangent_vector`,
  `compute_log_map`, `get_tangent_frames`.

The Laplacian is the cotan Laplacian of that triangulation, with the pointwise operator
$\Delta = -M^{-1} L$; the heat method solves with it

$$(M + tL)\, u = \delta, \qquad X = -\frac{\nabla u}{\lVert \nabla u \rVert}, \qquad L\phi = -\nabla \cdot X$$
"""

from ._heat import PointCloudHeatSolver as PointCloudHeatSolver
from ._heat import point_cloud_heat_distance as point_cloud_heat_distance
from ._heat import point_cloud_heat_solver as point_cloud_heat_solver
from ._heat import point_cloud_log_map as point_cloud_log_map
from ._heat import point_cloud_parallel_transport as point_cloud_parallel_transport
from ._laplacian import point_cloud_laplacian as point_cloud_laplacian
from ._laplacian import point_cloud_normals as point_cloud_normals
from ._triangulation import PointCloudTriangulation as PointCloudTriangulation
from ._triangulation import point_cloud_triangulation as point_cloud_triangulation
