r"""Geometry problems on triangle meshes, solved exactly and differentiably: Poisson, harmonic, Hodge, flows.

`solve_poisson` and `harmonic_interpolation` take a tetrahedral `ddgjax.volume.TetMesh` too (the same
problem in a solid, with its cotan Laplacian and mass matrix; `robust=False` only).

- Energies as plain scalar JAX functions of the unknowns and the mesh (`dirichlet_energy`,
  `screened_dirichlet_energy`, `poisson_energy`, the report's `gradient_fitting_energy` `E_X`),
  differentiable in the unknowns and the vertex positions. Sign convention: the report's Poisson
  problem $\Delta\phi = \rho$ with $\Delta = -M^{-1} L$, i.e. $L\phi = -M\rho$ (see `_energies`).
- `solve_poisson(mesh, rho, *, fixed_vertices=..., fixed_values=...)` and
  `harmonic_interpolation(mesh, *, fixed_vertices, fixed_values)`: exact, differentiable Dirichlet /
  Poisson problems.
- `hodge_decomposition(mesh, omega)`: a 1-form split into exact, co-exact and harmonic parts.
- `mean_curvature_flow(mesh, *, tau, steps, modified=...)`: backward-Euler (modified) mean curvature flow.

$$\Delta\phi = \rho, \quad \Delta = -M^{-1} L \qquad\Longleftrightarrow\qquad L\phi = -M\rho.$$

Each solves its linear systems with `ddgjax.solve` (`solver=` names the backend, one of
`ddgjax.LINEAR_SOLVERS`) and reports failure through `ddgjax.RESULTS`: `throw=True` (default) raises,
`throw=False` returns a `ddgjax.Solution` (`value`, `result`, `stats`) or, for the flow, its record.
libigl / gpytoolbox: `min_quad_with_fixed`, `harmonic`; the DDG exercises: `ScalarPoissonProblem`,
`HodgeDecomposition`, `MeanCurvatureFlow`.
"""

from ._energies import dirichlet_energy as dirichlet_energy
from ._energies import gradient_fitting_energy as gradient_fitting_energy
from ._energies import poisson_energy as poisson_energy
from ._energies import screened_dirichlet_energy as screened_dirichlet_energy
from ._hodge_decomposition import HodgeDecomposition as HodgeDecomposition
from ._hodge_decomposition import hodge_decomposition as hodge_decomposition
from ._mean_curvature_flow import MeanCurvatureFlowResult as MeanCurvatureFlowResult
from ._mean_curvature_flow import mean_curvature_flow as mean_curvature_flow
from ._poisson import harmonic_interpolation as harmonic_interpolation
from ._poisson import solve_poisson as solve_poisson
