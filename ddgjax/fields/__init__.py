r"""Direction fields: the discrete Levi-Civita connection, the connection Laplacian, smoothest n-direction fields.

- Connection (angle form; conventions in `ddgjax.fields._connection`, whose treatment of boundary
  vertices every function takes as `boundary_scaling="geodesic" | "unscaled"`): `edge_polar_angles`,
  `edge_transport_angles` ($\rho_{ij} = \theta_{ji} + \pi - \theta_{ij}$), `face_holonomies`,
  `tangent_bases` (`TangentBases(e1, e2, normal)`).
- `connection_laplacian(mesh, *, n=1)`: complex Hermitian PSD, $u^H A u = \sum w_{ij} \lvert u_j - e^{i n \rho_{ij}} u_i \rvert^2$;
  `connection_mass_matrix`.
- `smoothest_field(mesh, *, n=1, alignment=None, alignment_weight=1.0, throw=True)` ->
  `SmoothestField(field, solution, energy)`: the globally smoothest field (smallest eigenvector) or
  the screened alignment to a guidance field (`principal_curvature_alignment`), differentiable in
  the vertex positions; `field` is `(nv,)` complex.
- `field_singularities(mesh, field, *, n)`: the index of every face (Poincare-Hopf: they sum to $\chi$).
- `interpolate_field(mesh, *, fixed_vertices, fixed_values, n=1)`: the smoothest field through given values.
- `field_to_vectors(mesh, field, *, n, at="vertices" | "faces")`: the `n` directions as 3D unit vectors.

Fields are complex `n`-th powers in the vertices' polar coordinates. Reference: Knoeppel, Crane,
Pinkall, Schroeder, "Globally optimal direction fields" (2013).

$$u^H A u = \sum_{ij} w_{ij} \lvert u_j - e^{i n \rho_{ij}} u_i \rvert^2, \qquad A u = \lambda M u, \qquad \sum_f I_f = \chi.$$
"""

from ._connection import TangentBases as TangentBases
from ._connection import edge_polar_angles as edge_polar_angles
from ._connection import edge_transport_angles as edge_transport_angles
from ._connection import face_holonomies as face_holonomies
from ._connection import tangent_bases as tangent_bases
from ._interpolation import interpolate_field as interpolate_field
from ._laplacian import connection_laplacian as connection_laplacian
from ._laplacian import connection_mass_matrix as connection_mass_matrix
from ._singularities import field_singularities as field_singularities
from ._smoothest import SmoothestField as SmoothestField
from ._smoothest import principal_curvature_alignment as principal_curvature_alignment
from ._smoothest import smoothest_field as smoothest_field
from ._vectors import field_to_vectors as field_to_vectors
