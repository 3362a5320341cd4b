r"""Triangle meshes: the `Mesh` type, its NumPy-built topology, differentiable geometry and curvature.

- `Mesh`, `MeshTopology`: vertices (differentiable) plus connectivity built once in NumPy.
- Geometry (jit / grad / vmap over `mesh.vertices`): edge lengths, face areas and normals, corner
  angles and cotangents, cotan weights, vertex normals, dual areas, dihedral angles, area, volume.
- Curvature: angle defects (integrated $K$), integrated mean curvature (scalar from dihedral angles,
  normal from `L V`), Gauss curvature normals, total mean curvature; pointwise Gaussian / mean
  curvature and mean curvature normals (`vertex_pointwise_*`), principal curvatures.
- Built-in shapes: `icosphere`, `uv_sphere`, `torus`, `cylinder`, `disk`, `grid`.
- Checks: `check_mesh` -> `MeshReport` (zero-area faces and zero-length edges among them; the policy
  for degenerate geometry, refused by the plain cotan route and handled by `robust=True`, is in
  `ddgjax.mesh._check`).

Discrete Gauss-Bonnet is an identity on every triangle mesh: the angle defects $K_i$ sum to $2\pi$ times
the Euler characteristic,

$$\sum_i K_i = 2\pi\chi, \qquad \chi = V - E + F.$$
"""

from ._check import MeshReport as MeshReport
from ._check import check_mesh as check_mesh
from ._curvature import (
    total_mean_curvature as total_mean_curvature,
)
from ._curvature import (
    vertex_angle_defects as vertex_angle_defects,
)
from ._curvature import (
    vertex_gauss_curvature_normals as vertex_gauss_curvature_normals,
)
from ._curvature import (
    vertex_mean_curvature_normals as vertex_mean_curvature_normals,
)
from ._curvature import (
    vertex_mean_curvatures as vertex_mean_curvatures,
)
from ._curvature import (
    vertex_pointwise_gaussian_curvatures as vertex_pointwise_gaussian_curvatures,
)
from ._curvature import (
    vertex_pointwise_mean_curvature_normals as vertex_pointwise_mean_curvature_normals,
)
from ._curvature import (
    vertex_pointwise_mean_curvatures as vertex_pointwise_mean_curvatures,
)
from ._curvature import (
    vertex_principal_curvatures as vertex_principal_curvatures,
)
from ._geometry import (
    corner_angles as corner_angles,
)
from ._geometry import (
    corner_angles_from_lengths_sq as corner_angles_from_lengths_sq,
)
from ._geometry import (
    corner_cotangents as corner_cotangents,
)
from ._geometry import (
    corner_cotangents_from_lengths_sq as corner_cotangents_from_lengths_sq,
)
from ._geometry import (
    corner_dual_areas as corner_dual_areas,
)
from ._geometry import (
    corner_dual_areas_from_lengths_sq as corner_dual_areas_from_lengths_sq,
)
from ._geometry import (
    edge_cotan_weights as edge_cotan_weights,
)
from ._geometry import (
    edge_cotan_weights_from_corner_cotangents as edge_cotan_weights_from_corner_cotangents,
)
from ._geometry import (
    edge_dihedral_angles as edge_dihedral_angles,
)
from ._geometry import (
    edge_lengths as edge_lengths,
)
from ._geometry import (
    enclosed_volume as enclosed_volume,
)
from ._geometry import (
    face_area_vectors as face_area_vectors,
)
from ._geometry import (
    face_areas as face_areas,
)
from ._geometry import (
    face_areas_from_lengths_sq as face_areas_from_lengths_sq,
)
from ._geometry import (
    face_edge_lengths_sq as face_edge_lengths_sq,
)
from ._geometry import (
    face_edge_vectors as face_edge_vectors,
)
from ._geometry import (
    face_hat_gradients as face_hat_gradients,
)
from ._geometry import (
    face_normals as face_normals,
)
from ._geometry import (
    face_vertex_positions as face_vertex_positions,
)
from ._geometry import (
    scatter_corners_to_vertices as scatter_corners_to_vertices,
)
from ._geometry import (
    total_area as total_area,
)
from ._geometry import (
    vertex_dual_areas as vertex_dual_areas,
)
from ._geometry import (
    vertex_normals as vertex_normals,
)
from ._mesh import Mesh as Mesh
from ._mesh import require_mesh as require_mesh
from ._shapes import cylinder as cylinder
from ._shapes import disk as disk
from ._shapes import grid as grid
from ._shapes import icosphere as icosphere
from ._shapes import torus as torus
from ._shapes import uv_sphere as uv_sphere
from ._topology import MeshTopology as MeshTopology
from ._topology import build_topology as build_topology
