r"""Tetrahedral meshes: the volume counterpart of `ddgjax.mesh`, `ddgjax.laplacian` and `ddgjax.dec`.

- `TetMesh`, `TetTopology`: vertex positions (differentiable) plus tetrahedral connectivity built
  once in NumPy; `tet_mesh.boundary_mesh()` is the boundary surface as a `ddgjax.Mesh`.
- geometry: `tet_signed_volumes`, `tet_volumes`, `tet_edge_lengths_sq`, `edge_lengths`,
  `triangle_areas`, `tet_dihedral_angles`, `tet_cotan_weights`, `tet_hat_gradients`, and the intrinsic
  core from the six squared edge lengths (`*_from_lengths_sq`).
- built-in solids and files: `tet_ball`, `tet_box`, `tet_solid_torus`, `tet_shell`; `load_tet_mesh`,
  `save_tet_mesh` (meshio formats); `tetrahedralize` (fTetWild, the `tetmesh` extra); `check_tet_mesh`.
- operators: `cotan_laplacian` (`== -igl.cotmatrix(V, T)`), `mass_matrix(mass=)` (libigl's three),
  `laplacian_apply`, `dirichlet_energy`, `vertex_dual_volumes`.
- DEC: `d0`, `d1`, `d2`, Hodge stars `hodge0..3` on the `dual=` cells, `gradient`, `divergence`,
  `codifferential`, `hodge_laplacian`; `plane_section` cuts a solid for drawing slices.
- The problem layer takes a `TetMesh` where it takes a `Mesh`: `ddgjax.pde.solve_poisson`,
  `harmonic_interpolation`, `ddgjax.spectral.eigenpairs`, `ddgjax.geodesics.heat_distance`.

$$L_{ij} = -\frac16 \sum_{t \ni ij} \ell_{kl} \cot\theta_{kl}, \qquad L_{ij} = \int \langle \nabla\phi_i, \nabla\phi_j \rangle \, dV, \qquad M_{ij} \approx \int \phi_i \phi_j \, dV$$

Conventions (docs/conventions.md): local edge order `TET_EDGES` (libigl's), triangle `k` of a tet
opposite vertex `k` and oriented outward (`TET_TRIANGLES`), tets positively oriented
($\det(b - a, c - a, d - a) > 0$), global edges low -> high, global triangles sorted triples.
"""

from ._check import TetMeshReport as TetMeshReport
from ._check import check_tet_mesh as check_tet_mesh
from ._dec import d0 as d0
from ._dec import d1 as d1
from ._dec import d2 as d2
from ._dec import hodge0 as hodge0
from ._dec import hodge1 as hodge1
from ._dec import hodge2 as hodge2
from ._dec import hodge3 as hodge3
from ._dec import hodge_star_entries as hodge_star_entries
from ._dual import TET_DUALS as TET_DUALS
from ._dual import tet_edge_dual_volumes_from_lengths_sq as tet_edge_dual_volumes_from_lengths_sq
from ._dual import tet_vertex_dual_volumes_from_lengths_sq as tet_vertex_dual_volumes_from_lengths_sq
from ._dual import vertex_dual_volumes as vertex_dual_volumes
from ._geometry import edge_lengths as edge_lengths
from ._geometry import tet_corner_positions as tet_corner_positions
from ._geometry import tet_cotan_weights as tet_cotan_weights
from ._geometry import tet_cotan_weights_from_lengths_sq as tet_cotan_weights_from_lengths_sq
from ._geometry import tet_dihedral_angles as tet_dihedral_angles
from ._geometry import tet_dihedral_angles_from_lengths_sq as tet_dihedral_angles_from_lengths_sq
from ._geometry import tet_edge_lengths_sq as tet_edge_lengths_sq
from ._geometry import tet_hat_gradients as tet_hat_gradients
from ._geometry import tet_signed_volumes as tet_signed_volumes
from ._geometry import tet_volumes as tet_volumes
from ._geometry import tet_volumes_from_lengths_sq as tet_volumes_from_lengths_sq
from ._geometry import triangle_areas as triangle_areas
from ._io import load_tet_mesh as load_tet_mesh
from ._io import save_tet_mesh as save_tet_mesh
from ._laplacian import cotan_laplacian as cotan_laplacian
from ._laplacian import dirichlet_energy as dirichlet_energy
from ._laplacian import laplacian_apply as laplacian_apply
from ._laplacian import mass_matrix as mass_matrix
from ._meshing import tetrahedralize as tetrahedralize
from ._plan import TetPlan as TetPlan
from ._plan import tet_plan as tet_plan
from ._section import PlaneSection as PlaneSection
from ._section import plane_section as plane_section
from ._shapes import tet_ball as tet_ball
from ._shapes import tet_box as tet_box
from ._shapes import tet_shell as tet_shell
from ._shapes import tet_solid_torus as tet_solid_torus
from ._tet_mesh import TetMesh as TetMesh
from ._tet_mesh import require_tet_mesh as require_tet_mesh
from ._topology import TET_EDGES as TET_EDGES
from ._topology import TET_TRIANGLES as TET_TRIANGLES
from ._topology import TetTopology as TetTopology
from ._vector_calculus import codifferential as codifferential
from ._vector_calculus import divergence as divergence
from ._vector_calculus import gradient as gradient
from ._vector_calculus import hodge_laplacian as hodge_laplacian
