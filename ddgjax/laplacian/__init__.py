"""The cotan Laplacian (FEM and DEC routes), mass matrices and the Dirichlet energy.

Conventions (DESIGN.md): `L` is the positive semidefinite weak (integrated) cotan Laplacian,
`(L u)_i = 1/2 sum_j (cot a_ij + cot b_ij)(u_i - u_j)`, so `L == -igl.cotmatrix(V, F)` and
`L == gpytoolbox.cotangent_laplacian(V, F)`; the pointwise Laplace-Beltrami operator is `-M^{-1} L`.
"""

from ._cotan import cotan_laplacian as cotan_laplacian
from ._cotan import laplacian_apply as laplacian_apply
from ._mass import mass_matrix as mass_matrix
