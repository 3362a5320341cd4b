"""Triangle meshes: the `Mesh` type, its NumPy-built topology, differentiable geometry and curvature.

- `Mesh`, `MeshTopology`: vertices (differentiable) plus connectivity built once in NumPy.
- Geometry (jit / grad / vmap over `mesh.vertices`): edge lengths, face areas and normals, corner
  angles and cotangents, cotan weights, vertex normals, dual areas, dihedral angles, area, volume.
- Curvature: angle defects (integrated K), integrated mean curvature (scalar from dihedral angles,
  normal from `L V`), Gauss curvature normals, total mean curvature; pointwise Gaussian / mean
  curvature and mean curvature normals (`vertex_pointwise_*`), principal curvatures.
- Built-in shapes: `icosphere`, `uv_sphere`, `torus`, `disk`, `grid`.
- Checks: `check_mesh` -> `MeshReport`.
"""

from ._geometry import (
    corner_angles as corner_angles,
    corner_angles_from_lengths_sq as corner_angles_from_lengths_sq,
    corner_cotangents as corner_cotangents,
    corner_cotangents_from_lengths_sq as corner_cotangents_from_lengths_sq,
    corner_dual_areas as corner_dual_areas,
    corner_dual_areas_from_lengths_sq as corner_dual_areas_from_lengths_sq,
    edge_cotan_weights as edge_cotan_weights,
    edge_dihedral_angles as edge_dihedral_angles,
    edge_cotan_weights_from_corner_cotangents as edge_cotan_weights_from_corner_cotangents,
    edge_lengths as edge_lengths,
    enclosed_volume as enclosed_volume,
    face_area_vectors as face_area_vectors,
    face_areas as face_areas,
    face_areas_from_lengths_sq as face_areas_from_lengths_sq,
    face_edge_lengths_sq as face_edge_lengths_sq,
    face_edge_vectors as face_edge_vectors,
    face_hat_gradients as face_hat_gradients,
    face_normals as face_normals,
    face_vertex_positions as face_vertex_positions,
    scatter_corners_to_vertices as scatter_corners_to_vertices,
    total_area as total_area,
    vertex_dual_areas as vertex_dual_areas,
    vertex_normals as vertex_normals,
)
from ._check import MeshReport as MeshReport, check_mesh as check_mesh
from ._curvature import (
    total_mean_curvature as total_mean_curvature,
    vertex_angle_defects as vertex_angle_defects,
    vertex_gauss_curvature_normals as vertex_gauss_curvature_normals,
    vertex_mean_curvature_normals as vertex_mean_curvature_normals,
    vertex_mean_curvatures as vertex_mean_curvatures,
    vertex_pointwise_gaussian_curvatures as vertex_pointwise_gaussian_curvatures,
    vertex_pointwise_mean_curvature_normals as vertex_pointwise_mean_curvature_normals,
    vertex_pointwise_mean_curvatures as vertex_pointwise_mean_curvatures,
    vertex_principal_curvatures as vertex_principal_curvatures,
)
from ._mesh import Mesh as Mesh
from ._shapes import disk as disk, grid as grid, icosphere as icosphere, torus as torus, uv_sphere as uv_sphere
from ._topology import MeshTopology as MeshTopology, build_topology as build_topology
