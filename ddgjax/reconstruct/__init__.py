"""Surfaces from points: Poisson surface reconstruction, differentiable in the points and normals.

- `poisson_reconstruction(points, normals)`: a triangle mesh through oriented points, the level set of
  their indicator function, solved spectrally on a regular grid (Shape As Points) with optional
  screening (Kazhdan & Hoppe 2013; conjugate gradients with a multigrid V-cycle), extracted by marching cubes (`PoissonReconstruction`: `value` the
  mesh, `result`, `stats`, the indicator, its grid, the per-vertex sample density);
- `poisson_indicator(points, normals, grid=...)`: the indicator alone (`Indicator(values, iso_value)`),
  a JAX function of the points and normals (jit, grad); `reconstruction_grid(points)` the grid;
- `level_set_vertices(indicator, grid, vertex_edges)`: the extracted vertices recomputed from an
  indicator, differentiable for a fixed extraction topology;
- `estimate_normals(points)`: PCA normals oriented consistently, for reconstruction from points alone.
"""

from ._extract import level_set_vertices as level_set_vertices
from ._grid import ReconstructionGrid as ReconstructionGrid
from ._grid import reconstruction_grid as reconstruction_grid
from ._indicator import Indicator as Indicator
from ._indicator import poisson_indicator as poisson_indicator
from ._normals import estimate_normals as estimate_normals
from ._poisson import PoissonReconstruction as PoissonReconstruction
from ._poisson import poisson_reconstruction as poisson_reconstruction
