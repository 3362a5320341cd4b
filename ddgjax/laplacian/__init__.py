r"""The cotan Laplacian, mass matrices, the Dirichlet energy and converters, all assembled from squared edge lengths.

The intrinsic core (`cotan_laplacian_from_lengths_sq`, `mass_matrix_from_lengths_sq` on a
`triangulation_plan`) serves the mesh's own operators (`cotan_laplacian`, `mass_matrix`, the
matrix-free `laplacian_apply` and `dirichlet_energy`) and the intrinsic Delaunay ones (edge flips
replayed in JAX); `laplacian_and_mass(mesh, mass=, robust=)` is the pair a solver runs on
(`robust=` picks the intrinsic ones).

Conventions (DESIGN.md): `L` is the positive semidefinite weak (integrated) cotan Laplacian,

$$\sum_j L_{ij} u_j = \tfrac12 \sum_{j \sim i} (\cot\alpha_{ij} + \cot\beta_{ij})(u_i - u_j),$$

with $\alpha_{ij}, \beta_{ij}$ the angles opposite edge $ij$, so `L == -igl.cotmatrix(V, F)` and
`L == gpytoolbox.cotangent_laplacian(V, F)`; the pointwise Laplace-Beltrami operator is $\Delta = -M^{-1} L$.
"""

from ._convert import from_pytorch3d_cot_laplacian as from_pytorch3d_cot_laplacian
from ._convert import to_gpytoolbox_cotangent_laplacian as to_gpytoolbox_cotangent_laplacian
from ._convert import to_igl_cotmatrix as to_igl_cotmatrix
from ._convert import to_pytorch3d_cot_laplacian as to_pytorch3d_cot_laplacian
from ._cotan import cotan_laplacian as cotan_laplacian
from ._cotan import dirichlet_energy as dirichlet_energy
from ._cotan import laplacian_apply as laplacian_apply
from ._intrinsic import IntrinsicTriangulation as IntrinsicTriangulation
from ._intrinsic import intrinsic_delaunay as intrinsic_delaunay
from ._intrinsic import intrinsic_delaunay_laplacian as intrinsic_delaunay_laplacian
from ._intrinsic import intrinsic_delaunay_mass_matrix as intrinsic_delaunay_mass_matrix
from ._lengths import cotan_laplacian_from_lengths_sq as cotan_laplacian_from_lengths_sq
from ._lengths import mass_matrix_from_lengths_sq as mass_matrix_from_lengths_sq
from ._mass import mass_matrix as mass_matrix
from ._operators import LaplacianAndMass as LaplacianAndMass
from ._operators import laplacian_and_mass as laplacian_and_mass
from ._plan import TriangulationPlan as TriangulationPlan
from ._plan import triangulation_plan as triangulation_plan
