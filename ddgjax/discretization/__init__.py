r"""One discretisation for the problem layer: a triangle or tet mesh, with `mass=` and `robust=`, as `L`, `M` and plans.

- `discretize(mesh, *, mass="voronoi", robust=False)` -> `Discretization(domain, laplacian, mass, triangulation,
  pattern)`: what `ddgjax.pde.solve_poisson`, `harmonic_interpolation`, `ddgjax.spectral.eigenpairs`
  and every heat method of `ddgjax.geodesics` solve with, built the same way for all of them (module
  `ddgjax.discretization._discretization`).

Each problem is posed with the same pair: `L` the PSD cotan Laplacian, `M` the mass matrix, and the
pointwise Laplace-Beltrami operator

$$\Delta = -M^{-1} L.$$
"""

from ._discretization import Discretization as Discretization
from ._discretization import discretize as discretize
