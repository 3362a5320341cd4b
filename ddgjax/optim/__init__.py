r"""Shape optimisation: objectives, the Large Steps reparametrisation, and a compiled optimisation driver.

- Objectives (plain scalar JAX functions, differentiable in the vertex positions): `willmore_energy`;
  `chamfer_distance` (SciPy k-d trees on a CPU, chunked brute force on accelerators) with `sample_points` (area-uniform samples of a mesh; with
  normals a `SampledPoints`) and `nearest_neighbors` (a `NearestNeighbors` pair of index arrays);
  PyTorch3D's mesh-fitting regularisers `edge_length_loss`, `normal_consistency_loss`,
  `laplacian_smoothing_loss`, and the tutorial's whole objective `mesh_fitting_loss(target,
  n_samples=...)`. Re-exported from where they live, for one import: `total_area`,
  `enclosed_volume` (`ddgjax.mesh`), `dirichlet_energy`, `poisson_energy` (`ddgjax.pde`),
  `conformal_energy_matrix` and `map_distortion` (a map's energies, `ddgjax.param`), `eigenpairs`
  (`ddgjax.spectral`), `heat_distance` (`ddgjax.geodesics`).
- `large_steps(mesh, *, lambda_, weights=, fixed_vertices=, solver=)`: $U = (I + \lambda L) V$ and
  back with one kept factorisation (Nicolet, Jacobson, Jakob 2021); `adam_uniform` /
  `scale_by_adam_uniform`, the paper's optimiser, as optax transformations.
- `minimize_energy(energy, x0, *, mesh=, fixed_vertices=, fixed_values=)`: Newton's method with the
  sparse Hessian (the mesh's vertex adjacency, recovered by colouring, factorised by CHOLMOD) for
  energies of vertex values; an `optx.Solution`. A quadratic energy takes one factorisation.
- `minimize_shape(loss, mesh, *, steps, ...)`: the whole step compiled, `lax.scan` in chunks with a
  progress bar (`ddgjax._loop`, the loop the flows share), fixed vertices, a volume constraint or
  bounds; `ShapeOptimizationResult` with `.value` (the final vertices), `.result` and
  `first_failure_step` (docs/conventions.md, Outcomes).

$$W = \sum_i H_i^2 A_i, \qquad U = (I + \lambda L) V$$
"""

from ..geodesics import heat_distance as heat_distance
from ..mesh import enclosed_volume as enclosed_volume
from ..mesh import total_area as total_area
from ..param import conformal_energy_matrix as conformal_energy_matrix
from ..param import map_distortion as map_distortion
from ..pde import dirichlet_energy as dirichlet_energy
from ..pde import poisson_energy as poisson_energy
from ..spectral import eigenpairs as eigenpairs
from ._chamfer import NearestNeighbors as NearestNeighbors
from ._chamfer import SampledPoints as SampledPoints
from ._chamfer import chamfer_distance as chamfer_distance
from ._chamfer import nearest_neighbors as nearest_neighbors
from ._chamfer import sample_points as sample_points
from ._driver import ShapeOptimizationResult as ShapeOptimizationResult
from ._driver import minimize_shape as minimize_shape
from ._energy import minimize_energy as minimize_energy
from ._fitting import mesh_fitting_loss as mesh_fitting_loss
from ._large_steps import LargeSteps as LargeSteps
from ._large_steps import ScaleByAdamUniformState as ScaleByAdamUniformState
from ._large_steps import adam_uniform as adam_uniform
from ._large_steps import large_steps as large_steps
from ._large_steps import scale_by_adam_uniform as scale_by_adam_uniform
from ._objectives import edge_length_loss as edge_length_loss
from ._objectives import laplacian_smoothing_loss as laplacian_smoothing_loss
from ._objectives import normal_consistency_loss as normal_consistency_loss
from ._objectives import willmore_energy as willmore_energy
